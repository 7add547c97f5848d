"""Post-processing past the paper: give back the volume the skin lost.

After the solve, the collision projection and the smoothing, the enclosed
volume is short of the rest volume: flesh squeezed at a fold was flattened
away and smoothing shrinks. Following the closed-mesh volume constraint of
Müller et al. 2007 (section 4.5) and the normal displacements of von Funck et
al. 2008 ("Volume-preserving mesh skinning"), one global constraint
``C = V(p) - V0`` moves the skin of the bent joints' regions along its
unit normals, scaled by a mobility that is 1 where a vertex's weights
are split evenly across the joint and 0 where one bone owns it, so the bulge
forms around the joint and fades out smoothly. The regions whose folds the
collision stage resolved, and any vertex within the other side's flesh
radius, do not move, so the folds stay resolved.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from ..metrics import mesh_volume
from .base import Frame, Stage
from .collision import JointRegions


@nb.njit(cache=True)
def volume_and_gradient(X, F, inc_ptr, inc, verts, g):
    """Enclosed volume of the whole mesh, and ``g_i = dV/dp_i`` for ``verts`` only:
    ``(1/6) sum over the faces (i, b, c) around i of p_b x p_c``."""
    vol = 0.0
    for f in range(F.shape[0]):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        vol += (X[a, 0] * (X[b, 1] * X[c, 2] - X[b, 2] * X[c, 1])
                + X[a, 1] * (X[b, 2] * X[c, 0] - X[b, 0] * X[c, 2])
                + X[a, 2] * (X[b, 0] * X[c, 1] - X[b, 1] * X[c, 0])) / 6.0
    for k in range(verts.shape[0]):
        i = verts[k]
        gx = gy = gz = 0.0
        for q in range(inc_ptr[i], inc_ptr[i + 1]):
            f = inc[q]
            e = 0
            while F[f, e] != i:
                e += 1
            b, c = F[f, (e + 1) % 3], F[f, (e + 2) % 3]
            gx += X[b, 1] * X[c, 2] - X[b, 2] * X[c, 1]
            gy += X[b, 2] * X[c, 0] - X[b, 0] * X[c, 2]
            gz += X[b, 0] * X[c, 1] - X[b, 1] * X[c, 0]
        g[k, 0], g[k, 1], g[k, 2] = gx / 6.0, gy / 6.0, gz / 6.0
    return vol


@nb.njit(cache=True)
def _mobility(X, mob, Z, ZJ, ZL, ZS, fade, A, B, R, m):
    """``m[ZL] = max over entries of mob[Z, j] * fade[j] * ramp``, with ramp 0
    within the other side's flesh radius ``R`` of its bone, 1 past 1.5 R."""
    for e in range(Z.shape[0]):
        i, j, o = Z[e], ZJ[e], 1 - ZS[e]
        ax, ay, az = A[j, o, 0], A[j, o, 1], A[j, o, 2]
        ex, ey, ez = B[j, o, 0] - ax, B[j, o, 1] - ay, B[j, o, 2] - az
        px, py, pz = X[i, 0] - ax, X[i, 1] - ay, X[i, 2] - az
        ee = ex * ex + ey * ey + ez * ez
        t = 0.0
        if ee > 0.0:
            t = min(1.0, max(0.0, (px * ex + py * ey + pz * ez) / ee))
        dx, dy, dz = px - t * ex, py - t * ey, pz - t * ez
        d = np.sqrt(dx * dx + dy * dy + dz * dz)
        ramp = min(1.0, max(0.0, (d / max(R[j, o], 1e-9) - 1.0) / 0.5))
        val = mob[e] * fade[j] * ramp
        if val > m[ZL[e]]:
            m[ZL[e]] = val


class Volume(Stage):
    """Global volume constraint on the surface, moving the bent joints' regions."""

    name = "volume"

    def __init__(self, character, params):
        super().__init__(character, params)
        skel, r = character.skeleton, character.rig
        J = skel.n_joints
        below = skel.subtree()          # below[j, b]: b is j or under j
        # mobility[:, j]: 4 s (1 - s) with s the weight a vertex takes from below j.
        self.mobility = np.zeros((len(character.V), J))
        self.zone, self.side = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
        for j in range(1, J):
            s = (r.Wval * below[j][r.Widx]).sum(1)
            self.mobility[:, j] = 4.0 * s * (1.0 - s)
            z = np.flatnonzero(self.mobility[:, j] > 0.02)
            self.zone.append(z)
            self.side.append((s[z] > 0.5).astype(np.int64))
        self.F = character.F
        self._region = r.region
        self._threshold = r.threshold
        self.V0 = mesh_volume(character.V, character.F)
        self.regions = JointRegions(character)
        # vertex -> incident faces, CSR
        F = character.F
        order = np.argsort(F.ravel(), kind="stable")
        self.inc = (order // 3).astype(np.int64)
        self.inc_ptr = np.searchsorted(F.ravel()[order], np.arange(len(character.V) + 1))
        self._key, self._verts = None, None

    def __call__(self, fr: Frame) -> None:
        js = np.flatnonzero(fr.bent)
        if not len(js) or not self.params["volume_preserve"]:
            return
        key = fr.bent.tobytes()
        if key != self._key:
            self._key, self._fold = key, {}
            v = np.unique(np.concatenate([self.zone[j] for j in js]))
            Z = np.concatenate([self.zone[j] for j in js])
            ZJ = np.concatenate([np.full(len(self.zone[j]), j) for j in js])
            mob = np.concatenate([self.mobility[self.zone[j], j] for j in js])
            ZS = np.concatenate([self.side[j] for j in js])
            self._verts, self._entries = v, (Z, ZJ, np.searchsorted(v, Z), ZS, mob)
        v = self._verts
        Z, ZJ, ZL, ZS, mob = self._entries
        X = fr.surface
        J = len(fr.fade)
        A = np.zeros((J, 2, 3))
        B = np.zeros((J, 2, 3))
        for j in js:
            A[j], B[j] = self.regions.posed_segments(j, fr.M)
        m = np.zeros(len(v))
        _mobility(X, mob, Z, ZJ, ZL, ZS, fr.fade, A, B, self.regions.R, m)
        if self.params["volume_regions"] == "outside":
            # Inflating the joint regions themselves can push skin through skin where
            # two of them meet (CesiumMan's chest): grow the limbs between them instead.
            if (key, -1) not in self._fold:
                self._fold[(key, -1)] = np.flatnonzero(self._region[v] >= 0)
            m[self._fold[(key, -1)]] = 0.0
        for j in fr.counts.get("collision_joints", ()):
            # The region whose fold the collision stage resolved stays as it is; the
            # mobility rises smoothly past it (a step there would leave a ridge).
            if (key, j) not in self._fold:
                d = np.linalg.norm(self.character.V[v] - self.character.skeleton.rest_positions[j],
                                   axis=1) / max(self._threshold[j], 1e-9)
                self._fold[(key, j)] = np.clip((d - 1.0) / 0.75, 0.0, 1.0)
            m *= self._fold[(key, j)]
        g = np.empty((len(v), 3))
        vol = volume_and_gradient(X, self.F, self.inc_ptr, self.inc, v, g)
        # Move along unit normals n = g/|g| by lam * m: an even layer whatever the
        # triangle sizes. To first order dV = sum g . dp = lam * sum m |g|.
        a = np.linalg.norm(g, axis=1)
        den = float((m * a).sum())
        if den > 0.0:
            n = g / np.maximum(a, 1e-30)[:, None]
            X[v] -= ((vol - self.V0) / den) * m[:, None] * n
        fr.counts["volume_ratio"] = vol / self.V0
