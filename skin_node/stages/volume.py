"""Post-processing past the paper: give back the volume the skin lost.

After the solve, the collision projection and the smoothing, the skin around a
bent joint holds less than it did at rest: flesh squeezed at a fold was
flattened away and smoothing shrinks. Following the closed-mesh volume
constraint of Müller et al. 2007 (section 4.5) and the normal displacements of
von Funck et al. 2008 ("Volume-preserving mesh skinning"), a volume constraint
``C = V(p) - V0`` moves skin along its unit normals, scaled by a mobility
that is 1 where a vertex's weights are split evenly across the joint and 0
where one bone owns it, so the bulge forms around the joint and fades out
smoothly.

``volume_regions: joints`` (the default) keeps every bent joint's own region
at its rest volume: the volume enclosed by the region's skin and the cone from
the joint's posed centre to it (:func:`skin_node.metrics.region_volume`), one
constraint per joint. Skin the collision stage pressed into contact, and its
neighbours within half the joint's limb radius, does not move, nor does skin
within the other side's flesh radius of its bone, so resolved folds stay
resolved and the volume reappears as a bulge on the outside of the bend. No
skin moves farther than ``volume_max_bulge`` limb radii, less past a right
angle (the cones of a deeply folded region overlap: that share was never
flesh). Those guards are cautious: skin within the other side's flesh radius
can as well swell away from that flesh as into it. A region still more than
``volume_checked_below`` short after them (a shoulder under a hanging arm, a
knee past 120 degrees) swells all its mobile skin instead, is tested for skin
crossings as the collision stage tests it, and puts back the skin around each
new crossing: it keeps every move that crosses nothing. Whatever the whole
mesh then misses by more than 1% goes to the bent joints' zones around the
folds, as in ``inside``.
``inside`` / ``outside`` keep only the whole mesh's volume instead, moving
the bent joints' zones with or without their joint regions.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from ..kernels.topology import ring_distance
from ..kernels.volume import (RegionSwell, restore_region, swell_checked, volume_and_gradient,
                              zone_mobility)
from ..metrics import mesh_volume
from ..rigging.regions import RegionSearch
from .base import Frame, KeyedCache, Stage


class Volume(Stage):
    """Volume constraints on the surface: one per bent joint's region, or one
    for the whole mesh (``volume_regions``)."""

    name = "volume"

    def __init__(self, character, params):
        super().__init__(character, params)
        r = character.rig
        self.F = character.F
        self._region = r.region
        self._threshold = r.threshold
        self.V0 = mesh_volume(character.V, character.F)
        self.regions = regs = character.regions(params["weight_scheme"])
        self.search = RegionSearch(regs)
        # Per joint: the zone's vertices, their side and mobility; per joint region:
        # its vertices that may move, their side and mobility, its rest volume.
        sw = regs.swell
        self.mobility, self.zone, self.side = sw.mobility, sw.zone, sw.side
        self.rverts, self.rside, self.rmob, self.rvol0 = sw.verts, sw.vside, sw.mob, sw.vol0
        # skin in contact keeps still over half the joint's limb radius (in rings)
        self._ring_edge = max(regs.edge, 1e-9)
        self._ring_width = np.maximum(0.5 * r.radius / self._ring_edge, 1.0)
        self._hop_limit = int(min(np.ceil(self._ring_width.max()) + 1, 64))
        self._hops = np.full(len(character.V), self._hop_limit, dtype=np.int64)
        self._queue = np.empty(len(character.V), dtype=np.int64)
        self._ptr, self._adj = r.adj_ptr, r.adj
        self._g = np.zeros((len(character.V), 3))
        self._none, self._gnone = np.zeros(0, np.int64), np.zeros((0, 3))
        self._m = np.zeros(len(character.V))
        # vertex -> incident faces, CSR
        self.inc_ptr, self.inc = regs.faces_around
        self._entries, self._fold = KeyedCache(), KeyedCache(64)

    def __call__(self, fr: Frame) -> None:
        js = np.flatnonzero(fr.bent)
        if not len(js) or not self.params["volume_preserve"]:
            return
        posed = self._posed(fr, js)          # the bent joints' bone segments, (J, 2, 3) x2
        if self.params["volume_regions"] == "joints":
            self._joints(fr, js, posed)
            # What the regions could not take back (a fold past a right angle) and
            # the whole mesh misses by more than 1% goes to the bent joints' zones
            # around the folds; within 1% the skin is left alone.
            self._whole(fr, js, posed, slack=0.01)
        else:
            self._whole(fr, js, posed)

    def _posed(self, fr: Frame, js):
        J = len(fr.fade)
        A = np.zeros((J, 2, 3))
        B = np.zeros((J, 2, 3))
        for j in js:
            A[j], B[j] = self.regions.posed_segments(j, fr.M, fr.memo)
        return A, B

    def _joints(self, fr: Frame, js, posed) -> None:
        X = fr.surface
        A, B = posed
        hops = self._hops
        reached = 0
        if fr.touched:
            src = np.concatenate(fr.touched).astype(np.int64)
            # Rings past the widest bent joint's width count as far (mobility 1):
            # the walk needs 5 or 6 of the 8 the chest would.
            limit = int(min(np.ceil(self._ring_width[js].max()) + 1, self._hop_limit))
            reached = ring_distance(src, self._ptr, self._adj, hops, limit, self._queue)
        worst = 1.0
        cap = float(self.params["volume_max_bulge"])
        checked = float(self.params["volume_checked_below"])
        regs = self.regions
        for j in js:
            v = self.rverts[j]
            if not len(v):
                continue
            # No vertex moves farther than volume_max_bulge limb radii, and less past
            # a right angle: there the region's cones from the joint overlap more and
            # more, that share of the "lost" volume was never flesh, and giving it
            # back would balloon the elbow. The allowance falls linearly from 90
            # degrees to nothing at 180.
            fold = min(1.0, max(0.0, (np.pi - fr.angles[j]) / (0.5 * np.pi)))
            max_move = cap * fold * regs.radius[j]
            swell = RegionSwell(self.F, regs.tris[j], fr.G[j, :3, 3], v, self.rmob[j],
                                self.rside[j], fr.fade[j], A[j], B[j], regs.R[j], hops,
                                self._ring_width[j], self.rvol0[j], max_move, self._g, self._m, 2)
            ratio = restore_region(X, swell, True)
            if ratio < 1.0 - checked and self.params["self_collision"]:
                ratio = self._checked(fr, j, swell, ratio, self._m[:len(v)].copy())
            worst = min(worst, ratio)
        if reached:
            hops[self._queue[:reached]] = self._hop_limit
        fr.counts["region_volume_min"] = worst

    def _checked(self, fr: Frame, j: int, swell: RegionSwell, ratio: float,
                 m_guarded: np.ndarray) -> float:
        """Past the guards, where they leave region ``j`` short: skin within the
        other side's flesh radius, or next to a resolved contact, may as well
        swell away from that skin as into it. Move all of the region's mobile
        skin, then test it for skin crossings as the collision stage does (where
        the move can have changed them), and put back the skin around every new
        crossing, over a growing radius, up to five times; if crossings remain,
        the whole region goes back to what the guards left (:func:`swell_checked`).

        Only skin the guards held back moved further than they let it, and only
        skin within the test's reach of where that was or is now can have
        changed: the detection cell and a stretched edge (two of the longest
        rest edges) or, where longer, the longest edge of the region's
        triangles after the move (a lowered arm stretches skin to several rest
        edges; no corner moved more than ``max_move``). The radius put back
        grows from a ring to the test's reach while crossings stay.
        ``swell``: the region's constraint (its ``max_move`` the most any skin
        moves); ``m_guarded``: the mobilities of the guarded pass. Returns the
        region's volume ratio."""
        regs = self.regions
        posed = regs.posed_segments(j, fr.M, fr.memo)
        _, fit, refit, hint = self.search.state(j, fr.surface, posed)
        test = regs.region_test(j, self.character.V, self.F, fr.M, posed)
        return swell_checked(fr.surface, swell, ratio, m_guarded, test, fit, refit, hint,
                             regs.edge, regs.emax, nb.get_num_threads())

    def _whole(self, fr: Frame, js, posed, slack: float = 0.0) -> None:
        """One constraint on the whole mesh's volume, moving the bent joints' zones;
        with ``slack`` it only lifts a volume below ``(1 - slack)`` of rest to that."""
        if slack > 0.0:
            vol = volume_and_gradient(fr.surface, self.F, self.inc_ptr, self.inc,
                                      self._none, self._gnone)
            fr.counts["volume_ratio"] = vol / self.V0
            if vol >= (1.0 - slack) * self.V0:
                return
        key = fr.bent.tobytes()

        def entries():
            v = np.unique(np.concatenate([self.zone[j] for j in js]))
            Z = np.concatenate([self.zone[j] for j in js])
            ZJ = np.concatenate([np.full(len(self.zone[j]), j) for j in js])
            mob = np.concatenate([self.mobility[self.zone[j], j] for j in js])
            ZS = np.concatenate([self.side[j] for j in js])
            return v, (Z, ZJ, np.searchsorted(v, Z), ZS, mob)

        v, (Z, ZJ, ZL, ZS, mob) = self._entries.get(key, entries)
        X = fr.surface
        A, B = posed
        m = np.zeros(len(v))
        zone_mobility(X, mob, Z, ZJ, ZL, ZS, fr.fade, A, B, self.regions.R, m)
        if self.params["volume_regions"] == "outside":
            # Inflating the joint regions themselves can push skin through skin where
            # two of them meet (CesiumMan's chest): grow the limbs between them instead.
            m[self._fold.get((key, -1), lambda: np.flatnonzero(self._region[v] >= 0))] = 0.0
        for j in fr.counts.get("collision_joints", ()):
            # The region whose fold the collision stage resolved stays as it is; the
            # mobility rises smoothly past it (a step there would leave a ridge).
            def ramp(j=j):
                d = np.linalg.norm(self.character.V[v] - self.character.skeleton.rest_positions[j],
                                   axis=1) / max(self._threshold[j], 1e-9)
                return np.clip((d - 1.0) / 0.75, 0.0, 1.0)
            m *= self._fold.get((key, j), ramp)
        g = np.empty((len(v), 3))
        vol = volume_and_gradient(X, self.F, self.inc_ptr, self.inc, v, g)
        fr.counts["volume_ratio"] = vol / self.V0
        target = (1.0 - slack) * self.V0
        if slack > 0.0 and vol >= target:
            return
        # Move along unit normals n = g/|g| by lam * m: an even layer whatever the
        # triangle sizes. To first order dV = sum g . dp = lam * sum m |g|.
        a = np.linalg.norm(g, axis=1)
        den = float((m * a).sum())
        if den > 0.0:
            n = g / np.maximum(a, 1e-30)[:, None]
            X[v] -= ((vol - target) / den) * m[:, None] * n
