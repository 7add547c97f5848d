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
from ..rigging.weights import point_segment_distance
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


class Volume(Stage):
    """Global volume constraint on the surface, moving the bent joints' regions."""

    name = "volume"

    def __init__(self, character, params):
        super().__init__(character, params)
        skel, r = character.skeleton, character.rig
        J = skel.n_joints
        below = np.zeros((J, J), dtype=bool)
        for b in range(J):
            a = b
            while a >= 0:
                below[a, b] = True
                a = skel.parents[a]
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
            self._key = key
            self._verts = np.unique(np.concatenate([self.zone[j] for j in js]))
        v = self._verts
        X = fr.surface
        m = (self.mobility[v][:, js] * fr.fade[js]).max(axis=1)
        for j in js:
            # The fold stays where collision put it: no inflation within the other
            # side's flesh radius, fading in up to 1.5 times that radius.
            z, side = self.zone[j], self.side[j]
            loc = np.searchsorted(v, z)
            A, B = self.regions.posed_segments(j, fr.M)
            for s_ in (0, 1):
                o = 1 - s_
                sel = side == s_
                d = point_segment_distance(X[z[sel]], A[o:o + 1], B[o:o + 1])[:, 0]
                R = max(self.regions.R[j, o], 1e-9)
                m[loc[sel]] *= np.clip((d / R - 1.0) / 0.5, 0.0, 1.0)
        for j in fr.counts.get("collision_joints", ()):
            # the region whose fold the collision stage resolved stays as it is
            rv = np.unique(self.F[self.regions.tris[j]])
            loc = np.searchsorted(v, rv)
            ok = (loc < len(v)) & (v[np.minimum(loc, len(v) - 1)] == rv)
            m[loc[ok]] = 0.0
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
