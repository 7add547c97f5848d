"""Stage 2: the extended position-based solve over the tet mesh."""
from __future__ import annotations

import numpy as np

from ..kernels.skinning import embed_update
from ..kernels.solver import (BIND, CONSTRAINTS, CONTACT, ENERGY, STRETCH, VOLUME, ZONE,
                              carry_correction, contact_sweep, fade_correction, max_move, sweep,
                              zone_volume_sweep)
from ..rigging.weights import point_segment_distance
from .base import Frame, KeyedCache, Stage


def partition(idx: np.ndarray, members: np.ndarray, part: np.ndarray, parts: int):
    """Order constraints ``idx`` (rows of ``members``, vertex ids) for a
    parallel sweep: those whose vertices all lie in part ``h`` (``part``, per
    vertex) first, part by part, then the separator (the rest). Returns the
    ordered indices and the ``parts + 2`` range bounds that
    :func:`~skin_node.kernels.solver.sweep` takes."""
    p = part[members[idx]]
    own = np.where((p == p[:, :1]).all(axis=1), p[:, 0], parts)
    order = np.argsort(own, kind="stable")
    bounds = np.searchsorted(own[order], np.arange(parts + 2)).astype(np.int64)
    return np.ascontiguousarray(idx[order], dtype=np.int64), bounds


def slabs(X: np.ndarray, T: np.ndarray, parts: int) -> np.ndarray:
    """Per point of ``X`` (the tet mesh's vertices, tets ``T``), its slab
    0..parts-1: cut along the axis whose cuts the fewest tets straddle (the
    separator, swept on one thread), at quantiles of how many tets each vertex
    is in, so every thread gets about the same work."""
    weight = np.bincount(T.ravel(), minlength=len(X)).astype(np.float64)
    best, best_n = None, None
    for axis in range(X.shape[1]):
        x = X[:, axis]
        order = np.argsort(x)
        cum = np.cumsum(weight[order])
        cuts = x[order][np.searchsorted(cum, cum[-1] * np.arange(1, parts) / parts)]
        part = np.searchsorted(cuts, x, side="right").astype(np.int64)
        p = part[T]
        n = int((p != p[:, :1]).any(axis=1).sum())
        if best_n is None or n < best_n:
            best, best_n = part, n
    return best


class PBD(Stage):
    """Extended PBD (Chen & Pan 2017) from the stage-1 result, then the surface
    follows the tets' correction through its embedding.

    Past the paper, each behind a parameter: XPBD compliance (``solver:
    xpbd``); simulating only the zones of joints the pose bent
    (``active_regions``); a Gauss-Seidel sweep split into vertex-disjoint
    slabs, one per thread, and the constraints between them (``solve_slabs``);
    stopping once the largest correction is below ``tolerance``.
    """

    name = "pbd"

    def __init__(self, character, params):
        super().__init__(character, params)
        r = character.rig
        self.rig = r
        self.T, self.E = r.T, r.E
        self.mass = r.mass
        self.w_all = 1.0 / np.maximum(r.mass, 1e-30)
        self.lam = {k: np.zeros(n) for k, n in
                    ((STRETCH, len(r.E)), (VOLUME, len(r.T)), (ENERGY, len(r.T)), (BIND, len(r.TV)))}
        self._key = None
        self._sets, self._zsets, self._slabs = KeyedCache(), KeyedCache(), KeyedCache(4)
        self._g = np.zeros((len(r.TV), 3))
        self._regions = regions = character.regions(params["weight_scheme"])
        # Warm start: last frame's correction in the frame of each vertex's main bone.
        self._dom = regions.tdom
        self._corr = np.zeros((len(r.TV), 3))
        self._dX = None
        # Contact planes: per joint, its zone's tet vertices, their side (child +1 /
        # parent -1) and each side's flesh radius around its bone.
        self.cverts, self.cside, self.cR = regions.tet_sides

    def _zones(self, bent: np.ndarray):
        """(tets, vertices, rest volume) of each bent joint's zone, cached."""
        def make():
            r = self.rig
            out = []
            for j in np.flatnonzero(bent):
                zt = np.flatnonzero(self.weights.zone[r.T, j].any(axis=1))
                if len(zt):
                    out.append((zt, np.unique(r.T[zt]), float(r.vol0[zt].sum())))
            return out
        return self._zsets.get(bent.tobytes(), make)

    def _contacts(self, fr: Frame):
        """Contact planes of the joints bent past ``contact_angle`` and the tet
        vertices of their folds (within the other side's flesh radius)."""
        idx, pof, planes = [], [], []
        for j in np.flatnonzero(fr.bent & (fr.angles > self.params["contact_angle"])):
            v = self.cverts[j]
            if not len(v):
                continue
            A, B = self._regions.posed_segments(j, fr.M, fr.memo)
            c = B[0]                                  # the joint, where the bones meet
            u = A[0] - c
            t = B[1] - c
            u /= np.linalg.norm(u) + 1e-300
            t /= np.linalg.norm(t) + 1e-300
            n = t - u
            nn = np.linalg.norm(n)
            if nn < 1e-6:
                continue
            n /= nn
            side = self.cside[j]
            X = fr.tet[v]
            near = np.zeros(len(v), dtype=bool)
            for s_ in (0, 1):           # vertices of side s_ near the other bone
                m = side == (1.0 if s_ else -1.0)
                o = 1 - s_
                d = point_segment_distance(X[m], A[o:o + 1], B[o:o + 1])[:, 0]
                near[m] = d < self.cR[j, o]
            sel = np.flatnonzero(near)
            if not len(sel):
                continue
            idx.append(v[sel])
            pof.append(np.full(len(sel), len(planes)))
            planes.append(np.concatenate([c, n]))
            # the parent side keeps to the negative side: flip its normal
            planes.append(np.concatenate([c, -n]))
            pof[-1] = np.where(side[sel] > 0, len(planes) - 2, len(planes) - 1)
        if not idx:
            return None
        return (np.concatenate(idx).astype(np.int64), np.array(planes),
                np.concatenate(pof).astype(np.int64))

    def reset(self) -> None:
        self._key = None
        self._sets.clear()
        self._corr[:] = 0.0

    def _parts(self) -> int:
        """Slabs the solve is split into: one per thread with ``solve_slabs``."""
        return int(self.params["threads"]) if self.params["solve_slabs"] else 1

    def _active(self, bent: np.ndarray):
        """Index arrays of the constraints to solve and the inverse masses, cached
        per set of bent joints (a walk cycles through a few sets)."""
        p = self.params
        key = (bent.tobytes() if p["active_regions"] else b"all", self._parts())
        act = self._sets.get(key, lambda: self._make_active(bent, key[1]))
        if key != self._key:
            self._key = key
            # warm-start corrections of vertices that left the solve are stale
            self._corr[~act[2] if act is not None else slice(None)] = 0.0
        return act

    def _make_active(self, bent: np.ndarray, parts: int):
        r = self.rig
        if self.params["active_regions"]:
            vmask = self.weights.zone[:, bent].any(axis=1)
        else:
            vmask = np.ones(len(r.TV), dtype=bool)
        if not vmask.any():
            return None
        tet = np.flatnonzero(vmask[r.T].any(axis=1))
        edge = np.flatnonzero(vmask[r.E].any(axis=1))
        vert = np.flatnonzero(vmask)
        w = np.where(vmask, self.w_all, 0.0)       # zone borders are pinned to stage 1
        if parts > 1:
            # Slabs of the whole tet mesh, the same for every bent set: a joint entering
            # the solve then adds its constraints without reordering the others. The
            # order differs from one thread's (index order), and a one-iteration result
            # depends on it (up to 3 cm in the armpits of the humanoid's walk).
            part = self._slabs.get(parts, lambda: slabs(r.TV, r.T, parts))
            sets = {STRETCH: partition(edge, r.E, part, parts),
                    VOLUME: partition(tet, r.T, part, parts),
                    BIND: partition(vert, np.arange(len(r.TV))[:, None], part, parts)}
        else:
            one = lambda a: (np.ascontiguousarray(a, dtype=np.int64),
                             np.array([0, len(a)], dtype=np.int64))
            sets = {STRETCH: one(edge), VOLUME: one(tet), BIND: one(vert)}
        sets[ENERGY] = sets[VOLUME]
        # per vertex, the largest zone membership of each joint (for the fade band)
        vzone = np.ascontiguousarray(self.weights.zone[sets[BIND][0]][:, bent], dtype=np.float64)
        # the surface vertices embedded in a tet with a simulated vertex
        sverts = np.flatnonzero(vmask[r.Etet].any(axis=1)).astype(np.int64)
        # every tet vertex the solve and the embedding read: those of the tets
        # with a simulated vertex (the surface's tets among them)
        used = np.unique(r.T[tet]).astype(np.int64)
        return sets, w, vmask, vzone, sverts, used

    def tet_vertices(self, fr: Frame):
        if self.params["iterations"] <= 0:
            return super().tet_vertices(fr)
        act = self._active(fr.bent)
        return super().tet_vertices(fr) if act is None else act[5]

    def __call__(self, fr: Frame) -> None:
        p = self.params
        act = self._active(fr.bent)
        if act is None or p["iterations"] <= 0:
            fr.counts["active_tets"] = 0
            return
        sets, w, vmask, vzone, sverts, _ = act
        r = self.rig
        X = fr.tet
        xpbd = p["solver"] == "xpbd"
        k_of = {STRETCH: p["stretch_stiffness"], VOLUME: p["volume_stiffness"],
                ENERGY: p["stiffness"], BIND: p["bind_stiffness"]}
        a_of = {STRETCH: p["stretch_compliance"], VOLUME: p["volume_compliance"],
                ENERGY: p["energy_compliance"], BIND: p["bind_compliance"]}
        kinds = [CONSTRAINTS[c] for c in p["constraints"]]
        contacts = self._contacts(fr) if CONTACT in kinds else None
        zones = self._zones(fr.bent) if ZONE in kinds else []
        kinds = [c for c in kinds if c not in (CONTACT, ZONE)]
        ks = np.full(4, p["stiffness"])
        for kind in kinds:
            if xpbd and a_of[kind] > 0.0:      # multipliers only matter with compliance
                self.lam[kind][:] = 0.0
        fr.counts["contacts"] = 0 if contacts is None else len(contacts[0])
        tol = p["tolerance"]
        it = 0
        prev = X.copy() if tol > 0 else None
        verts = sets[BIND][0]
        if p["warm_start"]:
            carry_correction(X, verts, fr.M, self._dom, self._corr, True)
        for it in range(1, int(p["iterations"]) + 1):
            for kind in kinds:
                idx, bounds = sets[kind]
                # Energy keeps its spring constant as its step scale in both modes
                # (a uniform k cancels out of C / |grad C|^2 otherwise).
                k = k_of[kind] if (not xpbd or kind == ENERGY) else 1.0
                alpha = a_of[kind] if xpbd else 0.0
                sweep(kind, X, w, self.mass, r.E, r.T, ks, r.bseg, fr.seg_A, fr.seg_B,
                      r.len0 if kind == STRETCH else r.vol0 if kind == VOLUME else r.brest,
                      r.erest, self.lam[kind], idx, bounds, k, alpha, self._parts())
            for tets, verts, v0 in zones:
                zone_volume_sweep(X, r.T, tets, verts, w, v0, 1.0, self._g)
            if contacts is not None:
                contact_sweep(X, w, *contacts)
            if prev is not None:
                moved = max_move(X, prev, sets[BIND][0])
                if moved < tol:
                    break
                prev[:] = X
        fr.counts["active_tets"] = len(sets[VOLUME][0])
        fr.counts["iterations"] = it
        if p["warm_start"]:
            self._dX = X - fr.tet_base if self._dX is None else \
                np.subtract(X, fr.tet_base, out=self._dX)
            carry_correction(self._dX, verts, fr.M, self._dom, self._corr, False)
        f = fr.fade
        if p["active_regions"] and np.any((f > 0) & (f < 1)):
            # Joints still in their fade band pass on only part of the correction.
            fade_correction(X, fr.tet_base, verts, vzone, f[fr.bent])
        embed_update(fr.surface_base, X, fr.tet_base, r.Etet, r.Ebary, sverts, fr.surface)
