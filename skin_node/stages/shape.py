"""The skin's shape at bent joints: no dual-quaternion bulge, and each joint's
volume kept."""
from __future__ import annotations

import math

import numpy as np

from ..kernels.shape import (bent_edges, cone_volume_gradient, enclosed_volume, envelope_clamp,
                             clearance_caps, envelope_room, even_layer, hold_clear,
                             keep_region_volume, limit_bulge, moved_rows, parting_pairs,
                             pull_bulge, region_corners, split_fade)
from ..kernels.smoothing import EVEN, gather_weights, laplacian_smooth, ring_layout
from ..kernels.topology import ring_distance
from .base import Frame, KeyedCache, Stage
from .untangle import CoarseCrossings, LimbTurn, coarse_edges


def _union(verts: list, on: np.ndarray, n: int) -> np.ndarray:
    """The sorted union of ``verts[j]`` over the joints ``j`` with ``on[j]``
    (a zone is rebuilt whenever the set of bent joints changes: a mask, not
    a sort, keeps that within a frame's budget)."""
    mask = np.zeros(n, dtype=np.bool_)
    for j in np.flatnonzero(on):
        mask[verts[j]] = True
    return np.flatnonzero(mask).astype(np.int64)


def _csr(verts: list, values: list):
    """Per-joint vertex lists and values as one CSR: (ptr, verts, values)."""
    ptr = np.zeros(len(verts) + 1, dtype=np.int64)
    ptr[1:] = np.cumsum([len(v) for v in verts])
    def cat(xs, dt):
        return np.concatenate(xs).astype(dt) if len(xs) else np.zeros(0, dt)
    return ptr, cat(verts, np.int64), cat(values, np.float64)


class Bulge(Stage):
    """Skin stays within ``bulge_limit`` of its rest distance from its bone.

    Dual-quaternion skinning keeps a bent joint's volume by swinging the skin
    of its outer side around the joint at a radius larger than the limb's,
    which shows as a bulge (Kavan et al. 2007 name it). This is the paper's
    bind constraint on the skin, made one-sided and soft
    (:func:`~skin_node.kernels.shape.pull_bulge`,
    :func:`~skin_node.kernels.shape.limit_bulge`): skin further from its bone
    than at rest is drawn back to at most ``bulge_limit`` times its rest
    distance out, skin nearer than at rest is left as it is. Skin about as
    near several bones (where its nearest bone changes) is held within the
    limits of each at once (:attr:`~skin_node.Character.nearest_segments`),
    loosened by how far its nearest bones parted since rest
    (:func:`~skin_node.kernels.shape.parting_pairs`; each pair's growth
    saturating at :data:`~skin_node.kernels.shape.PARTING_SPAN` rest
    distances, so far bones that parted much do not loosen skin a little way
    off by centimetres): skin spanning two limbs that part (the crotch in a
    kick, a lunge or the splits) spans the gap as under DQS; held to both it
    crumpled. Only skin whose weights a bent joint splits is drawn in (where
    skinning blends, and so bulges), fading in where the smaller side's
    weight rises from 0.25% to 1.3% (fading in over the first tenth leaves
    the 150-degree elbow's outer skin 2 mm further out).
    """

    name = "bulge"

    def __init__(self, character, params):
        super().__init__(character, params)
        r, skel, V = character.rig, character.skeleton, character.V
        self.seg, self.r0, self.hold = character.nearest_segments
        # how evenly each vertex's weights split across each joint (4 s (1 - s),
        # s the weight from below the joint)
        below = skel.subtree()
        w = self.weights
        split = np.zeros((len(V), skel.n_joints))
        for j in range(1, skel.n_joints):
            s_ = (w.Wval * below[j][w.Widx]).sum(1)
            split[:, j] = 4.0 * s_ * (1.0 - s_)
        # per joint: the skin it splits, and how much of the pull it gets
        # (full from 1.3% of the weight on the other side: split 0.05)
        self.jverts = [np.flatnonzero(split[:, j] > 0.01).astype(np.int64)
                       for j in range(skel.n_joints)]
        self.jsplit = [np.minimum(1.0, split[v, j] / 0.05) for j, v in enumerate(self.jverts)]
        self._jcsr = _csr(self.jverts, self.jsplit)
        self._fade = np.zeros(len(V))
        self._allowed = np.empty(self.seg.shape)
        self._V, self._ptr, self._adj = V, r.adj_ptr, r.adj
        self._w_adj = character.edge_weights
        self._sets = KeyedCache()
        self._width = (None, None)
        seg_joint, A, B = skel.bone_segments()
        self.pairs = parting_pairs(V, A, B, seg_joint)

    def _set(self, bent: np.ndarray):
        """The skin the bent joints split, its ring layout and edge weights."""
        def make():
            v = _union(self.jverts, bent, len(self._V))
            lay = ring_layout(v, self._ptr, self._adj)
            return v, lay, gather_weights(v, self._ptr, self._w_adj, lay[2])
        return self._sets.get(bent.tobytes(), make)

    def __call__(self, fr: Frame) -> None:
        bent = fr.fade > 0.0
        verts, (ring, loc, lptr, lnbr), lw = self._set(bent)
        if not len(verts):
            fr.counts["bulge_vertices"] = 0
            return
        limit = float(self.params["bulge_limit"])
        if self._width[0] != limit:
            self._width = (limit, np.maximum(limit * self.r0[:, 0], 1e-6))
        fade = self._fade
        fade[verts] = 0.0
        split_fade(fade, *self._jcsr, fr.fade)
        X = fr.surface
        # the skin before the pull: a whole copy costs less than gathering the ring
        base = X.copy()
        allowed = self._allowed
        n = pull_bulge(X, verts, self.seg, self.r0, self.hold, fr.seg_A, fr.seg_B,
                       self._width[1], fade, self.pairs, allowed)
        fr.counts["bulge_vertices"] = n
        passes = self.passes("bulge_smoothing")
        if n and passes:
            # each vertex is drawn towards its own nearest bones, and where
            # they change so does the pull: smooth the pull, not the skin, then
            # take back what the smoothing gave away at the peaks (the
            # projection leaves skin within its limits alone)
            laplacian_smooth(X, base, True, ring, loc, lptr, lnbr, lw, 0.5, EVEN, passes,
                             np.empty((len(ring), 3)), np.empty((len(loc), 3)))
            limit_bulge(X, verts, self.seg, fr.seg_A, fr.seg_B, fade, allowed)


#: A joint region's layers fade to none over this many rings (at the
#: counts' resolution) inside the border where its skin meets the next
#: joint's region. Faded only with the distance from its joint, a layer
#: stopped there at up to 0.8 of its full move: a pose within the joint
#: limits (``random_poses`` number 3, the head turned 40 degrees) moved the
#: head region's skin 1.2 mm out and the neck's next to it not at all, a
#: seam round the base of the neck. One ring takes most of it out (edges
#: there bent more than 10 degrees beyond rest: 53 -> 16; 3 rings 13).
#: Not where the region meets skin of no region: the distance has taken
#: the layer to none there, and a ring more of fade gave the rest of the
#: region more to do (an 8k humanoid's knee crease 9 degrees sharper in a
#: squat; CesiumMan's punch a region under 0.97 of its volume on 6% of
#: its frames, 5% without).
REGION_BORDER_RINGS = 1
#: How far inflation may move skin near another part's, as a share of its
#: clearance from that part's flesh (:attr:`~skin_node.stages.base.Frame.clearance`):
#: half, as the other part's skin may swell towards it as far. (Contact keeps
#: skin out of the other parts' rest flesh, not out of their swollen skin.)
CLEAR_SHARE = 0.5
#: Rounds of cutting the inflation's spikes and setting the regions' volumes
#: again (:meth:`Inflate.__call__`). Three cut some of the spikes the new
#: layers bring (CesiumMan's punch, every 8th frame: 352 -> 305 sharp folds)
#: but cost the humanoid's squat 10 ms more at the 90th percentile (27.5 ms
#: against 12.5 for the stage with the cap off, one round 17.6).
RELIEF_ROUNDS = 1
#: Coarse skin (:class:`~skin_node.stages.untangle.CoarseCrossings`):
#: inflation's layers are withheld from the corners of two triangles whose
#: edge they bent by more than WITHHOLD_BEND degrees, and of a triangle they
#: ran through another part's, fading in over WITHHOLD_RINGS rings round
#: them, for up to WITHHOLD_ROUNDS rounds (see :meth:`Inflate.__call__`).
WITHHOLD_BEND = 30.0
WITHHOLD_RINGS = 2
WITHHOLD_ROUNDS = 2
#: Coarse skin: what the withholding rounds leave bent by more than
#: FINAL_BEND degrees goes back to where inflation found it, at the bent
#: edges' corners (CesiumMan's punch on automatic weights, every 2nd frame:
#: 26 -> 0 sharp folds, 904 -> 889 intersecting pairs; its walk has none
#: left to undo since contact eases its creases). Reverting every corner
#: still spoiled (WITHHOLD_BEND or a crossing) cost too much volume: the walk
#: on the file's weights kept 0.959.
FINAL_BEND = 60.0
#: Coarse skin: after the relief cap, the whole mesh's volume is laid again
#: on the skin the cut left (then the regions the cut reached). The spikes
#: it cuts there carry much of the mesh's volume: CesiumMan's walk on its
#: file weights kept 0.961 of its rest volume (every 8th frame; DQS 0.960)
#: and 0.976 with them laid again. On fine skin the cap cuts little, and
#: laid again the arm's elbow past 150 degrees crossed more (155-165
#: degrees: 14, 80, 246 -> 22, 120, 266 intersecting pairs).
RELAY_WHOLE = True
#: Coarse skin: inflation's layers that moved skin within TURN_REACH mean
#: edges of another part's flesh (the contact's clearance) are tested for
#: crossings it made, and a limb they ran through another part is turned
#: out (:class:`~skin_node.stages.untangle.LimbTurn`).
TURN_REACH = 2.0
#: Coarse skin: inflation's bent edges are checked (WITHHOLD_BEND,
#: FINAL_BEND) on the coarse parts' triangles and on every triangle with a
#: coarse corner (:attr:`~skin_node.Character.resolved` below 1) in a finer
#: part. The coarse parts' alone missed the chest's coarse skin at the
#: shoulders of CesiumMan's mesh fitted to the humanoid template (its chest
#: part mostly fine): the walk, every 4th frame, kept 152 sharp folds there
#: (DQS 0); with them, 0. CesiumMan's own rig and the humanoid at 4k and 8k
#: vertices measured the same either way.
COARSE_CORNERS = True
#: Where a joint's region or the whole mesh is still short once the layers
#: within the bulge limit's envelope are spent (skin in contact all round,
#: a coarse mesh), the layers past it stop at an outer envelope
#: PAST_ENVELOPE rest distances further out. Unbounded, on coarse skin a
#: layer of a few lone vertices stood out as a flap: a forearm of
#: CesiumMan's punch 97 mm out of its bone on the file's weights (DQS's
#: skin: 32 mm there), a flap at the walk's inner elbow 43 mm out.
PAST_ENVELOPE = 0.25


class Inflate(Stage):
    """Each bent joint's region keeps its rest volume, and the whole mesh its
    own within ``inflate_slack``.

    The region is the paper's joint region (skin nearer the joint than
    ``region_scale`` limb radii); its volume is the cone from the joint's
    posed centre over its triangles, as :mod:`skin_node.bench.measure`
    counts it. Where contact flattened a fold or the bulge limit drew the
    outer side in, the region's other skin moves out along its normals (in,
    where contact pushed skin out), evenly (a layer, not a lump), fading to
    nothing at the region's border and over ``inflate_rings`` rings around
    skin in contact, by at most ``inflate_max`` limb radii a layer; past the
    bulge limit's envelope no further than :data:`PAST_ENVELOPE` rest
    distances beyond it. On coarse skin
    the layers are withheld where they bent an edge sharply or ran skin
    through another part's, and laid again on the skin left
    (:data:`WITHHOLD_BEND`); where they still bend an edge past
    :data:`FINAL_BEND`, undone.
    """

    name = "inflate"

    def __init__(self, character, params):
        super().__init__(character, params)
        r, skel, F = character.rig, character.skeleton, character.F
        self.F = F
        V = character.V
        self.tris, self.verts, self.mob, self.corners, self.vol0 = [], [], [], [], []
        below = skel.subtree()
        w = self.weights
        for j in range(skel.n_joints):
            if skel.parents[j] < 0:
                t = np.zeros(0, np.int64)
            elif params["inflate_zone"] == "region":
                t = np.flatnonzero((r.region[F] == j).any(axis=1))
            elif params["inflate_zone"] == "reach":
                d = np.linalg.norm(V - skel.rest_positions[j], axis=1)
                near = d < float(params["inflate_reach"]) * r.radius[j]
                t = np.flatnonzero(near[F].any(axis=1))
            else:
                s_ = (w.Wval * below[j][w.Widx]).sum(1)
                t = np.flatnonzero(((s_[F] > 0.02) & (s_[F] < 0.98)).any(axis=1))
            v = np.unique(F[t]).astype(np.int64) if len(t) else np.zeros(0, np.int64)
            if params["inflate_zone"] in ("region", "reach"):
                edge = r.threshold[j] if params["inflate_zone"] == "region" else \
                    float(params["inflate_reach"]) * r.radius[j]
                d = np.linalg.norm(V[v] - skel.rest_positions[j], axis=1) / max(edge, 1e-9)
                x = np.clip((1.0 - d) / 0.35, 0.0, 1.0)
                mob = x * x * (3.0 - 2.0 * x)
            else:
                s_ = (w.Wval[v] * below[j][w.Widx[v]]).sum(1)
                mob = 4.0 * s_ * (1.0 - s_)
            self.tris.append(t.astype(np.int64))
            self.verts.append(v)
            self.mob.append(mob)
            self.corners.append(region_corners(F, t, v))
            c = skel.rest_positions[j]
            self.vol0.append(float(cone_volume_gradient(V, F, t, c, self.corners[-1],
                                                        np.empty((len(v), 3)))))
        self.radius = r.radius
        # the whole mesh: its volume, and per joint the skin whose weights it
        # splits (how evenly: 4 s (1 - s), full from a tenth on the other side)
        self.jverts, self.jsplit = [], []
        for j in range(skel.n_joints):
            s_ = (w.Wval * below[j][w.Widx]).sum(1) if j else np.zeros(len(V))
            sp = 4.0 * s_ * (1.0 - s_)
            v = np.flatnonzero(sp > 0.01).astype(np.int64)
            self.jverts.append(v)
            self.jsplit.append(np.minimum(1.0, sp[v] / 0.36))
        self._jcsr = _csr(self.jverts, self.jsplit)
        self.mesh_vol0 = float(enclosed_volume(V, F))
        # each vertex's nearest bone segments and their distances at rest:
        # skin is not swollen past the bulge limit's envelope around them
        self.seg, self.r0, self.hold = character.nearest_segments
        self._zones = KeyedCache()
        n = len(V)
        self._hops = np.full(n, 1 << 30, dtype=np.int64)
        self._queue = np.empty(n, dtype=np.int64)
        self._ptr, self._adj = r.adj_ptr, r.adj
        self._w_adj = character.edge_weights
        self._edge = character.mean_edges
        self._far = np.full(len(V), np.inf)
        self._near = np.empty(len(V))
        self._resolved = character.resolved
        self.V0 = V
        # a region's skin borders the next region's (the head's the neck's):
        # its layers fade to none over REGION_BORDER_RINGS rings inside that
        # border too, not only with the distance from its joint
        H = int(round(REGION_BORDER_RINGS * character.smoothing_scale))
        # each edge (row, neighbour) whose neighbour is skin of some joint's
        # region, not of none (where the distance already faded the layers out)
        rows = np.repeat(np.arange(n), np.diff(self._ptr))
        regional = r.region[self._adj] >= 0
        inside = np.zeros(n, dtype=np.bool_)
        for j, v in enumerate(self.verts):
            if not len(v) or H < 1:
                continue
            inside[:] = False
            inside[v] = True
            border = np.unique(rows[inside[rows] & ~inside[self._adj] & regional])
            if len(border):
                self.mob[j] = self.mob[j] * self._ramp(border.astype(np.int64), H)[v]
        self._cross = CoarseCrossings(character, float(params["coarse_below"]))
        if self._cross:
            # the pairs of coarse skin's triangles that share an edge: those
            # of the coarse parts, and (COARSE_CORNERS) any with a coarse
            # corner in a finer part
            F, coarse = self._cross.F, self._cross.coarse
            if COARSE_CORNERS:
                coarse = np.union1d(coarse, np.flatnonzero(
                    (character.resolved[F] < 1.0).any(axis=1)))
            self._efaces = coarse_edges(F, coarse)
            self._turn = LimbTurn(character, self.weights, self._cross, params,
                                  "inflate_turned")

    def __call__(self, fr: Frame) -> None:
        js = [j for j in np.flatnonzero(fr.bent) if len(self.verts[j])]
        if not js:
            return
        X = fr.surface
        # skin near another part's (that meets its own at no joint) moves at
        # most CLEAR_SHARE of its clearance, its share of the layers fading
        # out over the last mean edge of that: a forearm along the chest
        # stayed out of the chest's flesh while the chest swelled through it
        start = X.copy()
        if fr.clearance is not None:
            # (not on coarse skin, whose joint has no other skin to take its
            # volume: CesiumMan's shoulder region kept 0.77 of it, not 0.99)
            near = clearance_caps(fr.clearance, self._resolved, CLEAR_SHARE, self._near)
        else:
            near = self._far
        free = self._free(fr)
        ratios, capped = self._inflate(fr, js, free, start, near)
        if self._cross:
            # on coarse skin (a triangle spans much of a limb's curve) even
            # layers bend edges sharply beside a crease and run skin through
            # the other side's: withhold them where they did (and
            # WITHHOLD_RINGS rings round, fading in) and lay the volumes
            # again on the skin left
            withheld = 0
            for _ in range(WITHHOLD_ROUNDS):
                spoiled = self._spoiled(X, start)
                if not len(spoiled):
                    break
                withheld += len(spoiled)
                free = free * self._ramp(spoiled, WITHHOLD_RINGS)
                X[:] = start
                ratios, capped = self._inflate(fr, js, free, start, near)
            moved = moved_rows(X, start)
            hit = np.zeros(len(X), dtype=np.bool_)
            bent_edges(X, start, self.F, *self._efaces, moved, math.radians(FINAL_BEND), hit)
            hit &= moved
            X[hit] = start[hit]
            if hit.any():
                self._after_revert(fr, js, hit, free, start, near, ratios)
            # a limb its layers ran through another part's (the hip swelled
            # into a forearm the untangle had just cleared): turned out. Only
            # skin near another part's flesh can have crossed into it
            fr.counts["inflate_turned"] = 0
            if float(self.params["untangle_shift"]) > 0.0:
                moved = moved_rows(X, start)
                if fr.clearance is not None:
                    moved &= fr.clearance < TURN_REACH * self._edge
                self._turn(X, self._cross.crossed(X, self._cross.near(moved)), fr)
            fr.counts["inflate_withheld"] = withheld
            fr.counts["inflate_reverted"] = int(hit.sum())
        fr.counts["inflate_relief_capped"] = capped
        fr.counts["region_volume_min"] = min(1.0, *ratios.values())

    def _inflate(self, fr: Frame, js: list, free: np.ndarray, start: np.ndarray,
                 near: np.ndarray):
        """The whole mesh's volume and the bent joints' regions' (skin at
        ``start`` on entry), their spikes cut; returns the regions' volume
        ratios and how many vertices the cut changed."""
        X = fr.surface
        if float(self.params["inflate_slack"]) < 1.0:
            self._whole(fr, free, start, near)
        ratios = self._regions(fr, js, free, start, near)
        # the layers go where skin is free to move: past the bulge limit's
        # envelope and beside skin in contact, which on coarse skin may be a
        # few lone vertices pushed out or in as spikes (35 mm beside their
        # neighbours' 6 mm on CesiumMan's punch). Cut them and set the
        # volumes of the regions the cut reached again, by even layers over
        # what it left, for RELIEF_ROUNDS or until a cut finds nothing (cut
        # once and left there, CesiumMan's elbow region kept up to 1.09 of
        # its volume through the walk, 1.20 on the file's weights)
        capped = 0
        for _ in range(RELIEF_ROUNDS):
            before = X.copy()
            now = self.cap_relief(X, start, np.flatnonzero(moved_rows(X, start)))
            capped += now
            if not now:
                break
            cut = moved_rows(X, before)
            if self._cross and RELAY_WHOLE and float(self.params["inflate_slack"]) < 1.0:
                self._whole(fr, free, start, near)
            ratios.update(self._regions(fr, [j for j in js if cut[self.verts[j]].any()],
                                        free, start, near))
        return ratios, capped

    def _spoiled(self, X: np.ndarray, start: np.ndarray) -> np.ndarray:
        """The vertices inflation moved (from ``start``) at a corner of two
        coarse triangles whose edge it bent by more than WITHHOLD_BEND
        degrees, or of a coarse triangle it ran through another part's."""
        moved = moved_rows(X, start)
        hit = np.zeros(len(X), dtype=np.bool_)
        bent_edges(X, start, self.F, *self._efaces, moved, math.radians(WITHHOLD_BEND), hit)
        tris = self._cross.near(moved)
        hit[self.F[self._cross.crossed(X, tris).ravel()]] = True
        return np.flatnonzero(hit & moved).astype(np.int64)

    def _after_revert(self, fr: Frame, js: list, hit: np.ndarray, free: np.ndarray,
                      start: np.ndarray, near: np.ndarray, ratios: dict) -> None:
        """The regions the revert of ``hit`` reached: where it left one above
        its rest volume (it undid a layer that drew skin in: CesiumMan's
        walk on the file's weights, a region at 1.031), set again on the
        skin around it, and taken back where that runs skin through another
        part's. Where it left one below, the volume was a fold's and stays
        out: laid again on the skin around, it swelled that out as a bulge
        (the walk's largest outward change from the bone 43 -> 54 mm, every
        8th frame) and ran the file's punch through more (1,881 -> 2,049
        pairs)."""
        X = fr.surface
        over = []
        for j in js:
            if hit[self.verts[j]].any():
                g = np.empty((len(self.verts[j]), 3))
                ratios[j] = cone_volume_gradient(X, self.F, self.tris[j], fr.G[j, :3, 3],
                                                 self.corners[j], g) / self.vol0[j]
                if ratios[j] > 1.0:
                    over.append(j)
        if not over:
            return
        free = free.copy()
        free[hit] = 0.0
        before = X.copy()
        ratios.update(self._regions(fr, over, free, start, near))
        self._uncross(X, before)

    def _uncross(self, X: np.ndarray, before: np.ndarray) -> None:
        """The corners of coarse triangles that now run through another
        part's, of those moved since ``before``, back there."""
        moved = moved_rows(X, before)
        bad = np.zeros(len(X), dtype=np.bool_)
        bad[self.F[self._cross.crossed(X, self._cross.near(moved)).ravel()]] = True
        bad &= moved
        X[bad] = before[bad]

    def _free(self, fr: Frame) -> np.ndarray:
        """How free each vertex is to swell: 0 on skin in contact, rising to 1
        over ``inflate_rings`` rings round it."""
        H = self.rings("inflate_rings")
        if fr.touched and H > 0:
            return self._ramp(np.concatenate(fr.touched).astype(np.int64), H)
        return np.ones(len(fr.surface))

    def _ramp(self, src: np.ndarray, H: int) -> np.ndarray:
        """0 on vertices ``src``, rising smoothly to 1 over ``H`` rings round
        them, 1 beyond."""
        out = np.ones(len(self.V0))
        reached = ring_distance(src, self._ptr, self._adj, self._hops, H + 1, self._queue)
        q = self._queue[:reached]
        x = self._hops[q] / (H + 1.0)
        out[q] = x * x * (3.0 - 2.0 * x)
        self._hops[q] = 1 << 30
        return out

    def _regions(self, fr: Frame, js: list, free: np.ndarray, start: np.ndarray,
                 near: np.ndarray) -> dict:
        """Each of the bent joints ``js``' region to its rest volume (even
        layers); returns each one's volume over rest."""
        X = fr.surface
        out = {}
        cap = float(self.params["inflate_max"])
        limit = float(self.params["bulge_limit"])
        for j in js:
            v = self.verts[j]
            g, room, share = np.empty((len(v), 3)), np.empty(len(v)), np.empty(len(v))
            vol = keep_region_volume(X, self.F, self.tris[j], fr.G[j, :3, 3], self.corners[j],
                                     v, self.mob[j] * fr.fade[j], free, self.seg, self.r0,
                                     self.hold, fr.seg_A, fr.seg_B, limit, self.vol0[j],
                                     cap * self.radius[j], start, near, self._edge, g, room,
                                     share, limit + PAST_ENVELOPE)
            out[j] = vol / self.vol0[j]
        return out

    def _zone(self, bent: np.ndarray):
        """The skin the bent joints split, its triangles, their corners'
        positions in it (:func:`~skin_node.kernels.shape.region_corners`), its
        ring layout and edge weights."""
        def make():
            n = len(self.V0)
            v = _union(self.jverts, bent, n)
            mask = np.zeros(n, dtype=np.bool_)
            mask[v] = True
            t = np.flatnonzero(mask[self.F].any(axis=1)).astype(np.int64)
            lay = ring_layout(v, self._ptr, self._adj)
            return (v, t, region_corners(self.F, t, v), lay,
                    gather_weights(v, self._ptr, self._w_adj, lay[2]))
        return self._zones.get(bent.tobytes(), make)

    def _whole(self, fr: Frame, free: np.ndarray, start: np.ndarray, near: np.ndarray) -> None:
        """The whole mesh's volume back to within ``inflate_slack`` of rest,
        from the skin the bent joints blend (regions included: the regions
        are set right after), evenly."""
        X = fr.surface
        vol = enclosed_volume(X, self.F)
        slack = float(self.params["inflate_slack"]) * self.mesh_vol0
        deficit = self.mesh_vol0 - vol
        deficit = deficit - slack if deficit > slack else (deficit + slack if deficit < -slack
                                                          else 0.0)
        if deficit == 0.0:
            return
        v, t, corners, (ring, loc, lptr, lnbr), lw = self._zone(fr.bent)
        if not len(v):
            return
        base = X.copy()
        m = np.zeros(len(X))
        split_fade(m, *self._jcsr, fr.fade * fr.bent)
        m = m[v] * free[v]
        lim = float(self.params["inflate_max"]) * self.radius.max()
        target = self.mesh_vol0 - (slack if deficit > 0.0 else -slack)
        # within the bulge limit's envelope first, the layer smoothed (it
        # thins where the envelope or contact holds skin: gradually, not in a
        # step), then what smoothing and the envelope left out, past it
        deficit = self._layer(fr, v, t, corners, m, target, deficit, lim, 3, True, start, near)
        passes = self.passes("inflate_smoothing")
        if passes:
            laplacian_smooth(X, base, True, ring, loc, lptr, lnbr, lw, 0.5, EVEN, passes,
                             np.empty((len(ring), 3)), np.empty((len(loc), 3)))
            if target < self.mesh_vol0:
                # smoothing spreads the layer onto skin the envelope held:
                # take that back (the layers past it come after, evenly)
                envelope_clamp(X, v, self.seg, self.r0, self.hold, fr.seg_A, fr.seg_B,
                               float(self.params["bulge_limit"]), base[v])
            if near is not self._far:
                # and onto skin near another part's
                hold_clear(X, v, start, near)
            deficit = target - enclosed_volume(X, self.F)
            if (deficit > 0.0) != (target < self.mesh_vol0):
                return
        self._layer(fr, v, t, corners, m, target, deficit, lim, 2, False, start, near)

    def _layer(self, fr, v, t, corners, m, target, deficit, lim, steps, within, start, near):
        """Up to ``steps`` even layers over ``v`` (mobility ``m``) towards the
        mesh volume ``target``, where the mesh is short within the bulge
        limit's envelope when ``within``, else within the outer one
        (:data:`PAST_ENVELOPE`), and within ``near`` of ``start``
        (:func:`~skin_node.kernels.shape.hold_clear`), the share fading over
        the last mean edge of it; returns the deficit left."""
        held = near is not self._far
        X = fr.surface
        g, room, share = np.empty((len(v), 3)), np.empty(len(v)), np.empty(len(v))
        limit = float(self.params["bulge_limit"])
        edge = limit if within else limit + PAST_ENVELOPE
        for _ in range(steps):
            if abs(deficit) <= 1e-3 * self.mesh_vol0:
                break
            cone_volume_gradient(X, self.F, t, np.zeros(3), corners, g)
            # within the envelope each vertex takes all of a layer with half
            # the bulge limit's room left or more, fading to none at the
            # envelope (a cap alone would leave a step where capped skin meets
            # free skin); past it, the same within the outer envelope; skin as
            # far from its start as it may be takes no more
            env = deficit > 0.0
            if env:
                envelope_room(X, v, self.seg, self.r0, self.hold, fr.seg_A, fr.seg_B, edge,
                              room)
            if not even_layer(X, v, g, m, deficit, lim, env, room, self.r0, edge, held, near,
                              start, self._edge, share):
                break
            if held:
                hold_clear(X, v, start, near)
            deficit = target - enclosed_volume(X, self.F)
            if (deficit > 0.0) != (target < self.mesh_vol0):
                break
        return deficit

