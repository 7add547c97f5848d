"""Joint regions, once per character and weighting, and the search state a
stage keeps over them.

:class:`JointRegions` holds what the per-frame stages read of a character's
joint regions: each region's two sides, the triangles it touches, each side's
flesh radius, the rest normals the crossing test carries with their bones,
and, made on first use, the tet zones' sides (the solve's contact planes), the
volume stage's mobility and the triangles around every vertex.
:meth:`skin_node.character.Character.regions` builds it once and every
pipeline and stage of the character shares it; nothing in it changes after.
:class:`RegionSearch` is the mutable part, one per stage that tests skin for
crossings: the boxes of each region's tree as last fit, and the last nearest
triangle of every vertex.
"""
from __future__ import annotations

from functools import cached_property
from typing import NamedTuple

import numba
import numpy as np
from scipy.spatial import cKDTree

from ..kernels.collision import (FoldPlan, RegionTest, crossed_at, longest_edge, resolve_region,
                                 tree_fit, triangle_trees)
from ..kernels.smoothing import vertex_faces
from ..metrics import region_volume
from .weights import point_segment_distance


def dominant_bones(Widx: np.ndarray, Wval: np.ndarray) -> np.ndarray:
    """(n,) the bone of each row's largest weight (the first of equal ones)."""
    return Widx[np.arange(len(Widx)), np.argmax(Wval, axis=1)]


class TetSides(NamedTuple):
    """Per joint ``j`` (empty for roots): the tet vertices of its zone
    ``verts[j]``, their side ``side[j]`` (+1 child, -1 parent) and ``R[j]``
    (2,) the largest rest distance of each side's vertices from its bone
    (the parent's bone into ``j``, ``j``'s own)."""

    verts: list
    side: list
    R: np.ndarray


class SwellTables(NamedTuple):
    """What the volume stage moves skin with, per joint ``j`` (empty for the root).

    ``mobility[:, j]`` is ``4 s (1 - s)``, ``s`` the weight a surface vertex
    takes from bones below ``j``: 1 where the weights split evenly across the
    joint, 0 where one side owns the vertex. ``zone[j]`` lists the vertices of
    mobility above 0.02 and ``side[j]`` theirs (1 where ``s > 0.5``).
    ``verts[j]``: the region's vertices of the zone (they may move), ``vside[j]``
    their side, ``mob[j]`` their mobility, falling smoothly to 0 towards the
    region's border (over a third of the limb radius); ``vol0[j]`` the region's
    rest volume about its joint (:func:`skin_node.metrics.region_volume`)."""

    mobility: np.ndarray
    zone: list
    side: list
    verts: list
    vside: list
    mob: list
    vol0: np.ndarray


class JointRegions:
    """Per-joint surface regions split into their two sides.

    For joint ``j``: ``verts[j]`` its region's vertices, ``vside[j]`` 1 for those
    whose dominant bone is below ``j`` in the tree (the child side) and 0
    otherwise, ``tris[j]`` the triangles touching the region with their
    majority side ``tside[j]``; ``R[j]`` (2,) the largest rest distance of
    each side's skin from its bone (the parent's bone into ``j``, ``j``'s own).
    :meth:`tree` gives a region's :func:`triangle_trees`, made on first use.
    Sides and triangle bones come from ``weights`` (a
    :class:`~skin_node.rigging.build.Weights`; the character's by default).
    ``dom`` and ``tdom`` are the dominant bones of the surface and of the tet
    mesh's vertices.
    """

    def __init__(self, character, weights=None):
        skel, r, F = character.skeleton, character.rig, character.F
        w = self.weights = weights or r.weights()
        self.character = character
        self.skel = skel
        J = skel.n_joints
        self.below = below = skel.subtree()          # below[j, b]: b is j or under j
        self.dom = dom = dominant_bones(w.Widx, w.Wval)
        self.tdom = dominant_bones(w.TWidx, w.TWval)
        self.child = np.array([skel.children(j)[0] if skel.children(j) else -1 for j in range(J)])
        self.verts, self.vside, self.tris, self.tside = [], [], [], []
        self.R = np.zeros((J, 2))
        for j in range(J):
            v = np.flatnonzero(r.region == j)
            side = below[j, dom[v]].astype(np.int64)
            full = np.zeros(len(character.V), dtype=np.int64)
            full[v] = side
            t = np.flatnonzero((r.region[F] == j).any(axis=1))
            tside = (full[F[t]].sum(1) >= 2).astype(np.int64)
            self.verts.append(v)
            self.vside.append(side)
            self.tris.append(t)
            self.tside.append(tside)
            if len(v) and skel.parents[j] >= 0:
                A, B = self.rest_segments(j)
                for s_ in (0, 1):
                    d = point_segment_distance(character.V[v[side == s_]], A[s_:s_ + 1],
                                               B[s_:s_ + 1])
                    self.R[j, s_] = 1.05 * d.max() if d.size else 0.0
        # Rest normals and the dominant bone of every triangle, to carry normals.
        V = character.V
        N = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
        self.tri_normal = N / np.maximum(np.linalg.norm(N, axis=1, keepdims=True), 1e-30)
        wsum = np.zeros((len(F), J))
        for k in range(3):
            np.add.at(wsum, (np.repeat(np.arange(len(F)), w.Widx.shape[1]),
                             w.Widx[F[:, k]].ravel()), w.Wval[F[:, k]].ravel())
        self.tri_bone = np.argmax(wsum, axis=1)
        e = np.linalg.norm(character.V[F[:, 0]] - character.V[F[:, 1]], axis=1)
        self.edge = float(np.median(e))
        self.emax = float(e.max())
        self.radius = r.radius
        # Trees are made on first use: only the joints that fold are tested
        # (every region's tree: several MB on the 24k humanoid).
        self._V0, self._F = character.V, F
        self._trees = [None] * J
        # positions of every vertex of each region (a test of the whole region)
        self.every = [np.arange(len(v), dtype=np.int64) for v in self.verts]
        self._rest_seg = self._all_rest_segments()

    def rest_segments(self, j: int):
        """(2,3), (2,3): the parent side's bone into ``j`` and ``j``'s own bone."""
        P, skel = self.skel.rest_positions, self.skel
        end = P[self.child[j]] if self.child[j] >= 0 else skel.tips[j]
        return np.array([P[skel.parents[j]], P[j]]), np.array([P[j], end])

    def _all_rest_segments(self):
        """(J,2,3) x2 :meth:`rest_segments` of every non-root joint (zeros for
        roots) and (J,2) the two bones' matrices they are posed by."""
        J = self.skel.n_joints
        A, B = np.zeros((J, 2, 3)), np.zeros((J, 2, 3))
        pair = np.zeros((J, 2), dtype=np.int64)
        for j in range(J):
            if self.skel.parents[j] >= 0:
                A[j], B[j] = self.rest_segments(j)
                pair[j] = self.skel.parents[j], j
        return A, B, pair

    def posed_segments(self, j: int, M: np.ndarray, memo: dict | None = None):
        """(2,3), (2,3): :meth:`rest_segments` of ``j`` posed by the skinning
        matrices ``M``. With ``memo`` (a frame's), every joint's are posed at
        once and each joint's pair is kept: the same object for the whole
        frame, which :meth:`RegionSearch.crossed` takes as the mark of its
        pose. Read-only."""
        if memo is None:
            A, B = self._pose_segments(M)
            return A[j], B[j]
        hit = memo.get(("segments", j))
        if hit is None:
            AB = memo.get("segments")
            if AB is None:
                AB = memo["segments"] = self._pose_segments(M)
            hit = memo[("segments", j)] = (AB[0][j], AB[1][j])
        return hit

    def _pose_segments(self, M: np.ndarray):
        A, B, pair = self._rest_seg
        Ms = M[pair]                                            # (J, 2, 4, 4)
        R, t = Ms[..., :3, :3], Ms[..., :3, 3]
        A = np.einsum("jsik,jsk->jsi", R, A) + t
        B = np.einsum("jsik,jsk->jsi", R, B) + t
        A.flags.writeable = B.flags.writeable = False
        return A, B

    def tree(self, j: int):
        """Joint ``j``'s :func:`triangle_trees` (its topology, fixed at rest)."""
        if self._trees[j] is None:
            self._trees[j] = triangle_trees(self._V0, self._F, self.tris[j], self.tside[j])
        return self._trees[j]

    def region_test(self, j: int, X0: np.ndarray, F: np.ndarray, M: np.ndarray,
                    posed) -> RegionTest:
        """Joint ``j``'s crossing test (:class:`RegionTest`) against the rest
        surface ``X0, F`` in the pose of the skinning matrices ``M``, whose
        :meth:`posed_segments` of ``j`` are ``posed``."""
        return RegionTest(X0, F, np.ascontiguousarray(M), self.tri_bone, self.tri_normal,
                          self.tree(j), self.tris[j], self.tside[j], self.verts[j], self.vside[j],
                          self.R[j], posed[0], posed[1], *self.test_limits(j))

    def test_limits(self, j: int):
        """``rest_sep``, ``rest_tol`` and ``reach`` of joint ``j``'s crossing
        test (:func:`crossed_vertices`)."""
        return 3.0 * self.edge, 0.5 * self.radius[j], self.cell(j)

    def cell(self, j: int) -> float:
        """How near the other side's skin the crossing test looks, for joint
        ``j`` (three median edges, at least a quarter of the limb radius)."""
        return max(3.0 * self.edge, 0.25 * self.radius[j])

    def longest_edge(self, j: int, X: np.ndarray) -> float:
        """The longest edge of joint ``j``'s triangles in ``X``."""
        return float(longest_edge(X, self._F, self.tris[j]))

    @cached_property
    def surface_zone(self) -> np.ndarray:
        """(n, J) bool: the surface vertices embedded in a tet with a vertex of
        joint ``j``'s zone (those the solve can move while ``j`` is bent)."""
        return self.weights.zone[self.character.rig.Etet].any(axis=1)

    @cached_property
    def faces_around(self) -> tuple[np.ndarray, np.ndarray]:
        """:func:`~skin_node.kernels.smoothing.vertex_faces` of the surface: the
        triangles around every vertex, CSR ``(ptr, faces)``."""
        return vertex_faces(self._F, len(self._V0))

    @cached_property
    def tet_sides(self) -> TetSides:
        """:class:`TetSides` of the tet zones (the solve's contact planes)."""
        skel, TV, w = self.skel, self.character.rig.TV, self.weights
        J = skel.n_joints
        verts, sides = [], []
        R = np.zeros((J, 2))
        for j in range(J):
            v = np.flatnonzero(w.zone[:, j]) if skel.parents[j] >= 0 else np.zeros(0, np.int64)
            side = self.below[j, self.tdom[v]]
            verts.append(v)
            sides.append(np.where(side, 1.0, -1.0))
            if len(v):
                A, B = self.rest_segments(j)
                for s_ in (0, 1):
                    pts = TV[v[side == bool(s_)]]
                    d = point_segment_distance(pts, A[s_:s_ + 1], B[s_:s_ + 1])
                    R[j, s_] = d.max() if d.size else 0.0
        return TetSides(verts, sides, R)

    @cached_property
    def swell(self) -> SwellTables:
        """:class:`SwellTables` of the volume stage."""
        ch, w = self.character, self.weights
        skel, r, F = ch.skeleton, ch.rig, self._F
        J = skel.n_joints
        mobility = np.zeros((len(ch.V), J))
        zone, side = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)]
        for j in range(1, J):
            s = (w.Wval * self.below[j][w.Widx]).sum(1)
            mobility[:, j] = 4.0 * s * (1.0 - s)
            z = np.flatnonzero(mobility[:, j] > 0.02)
            zone.append(z)
            side.append((s[z] > 0.5).astype(np.int64))
        verts, vside, mobs = [], [], []
        vol0 = np.zeros(J)
        for j in range(J):
            t = self.tris[j]
            v = np.unique(F[t]) if len(t) and j > 0 else np.zeros(0, np.int64)
            keep = (np.isin(v, zone[j]) & (r.region[v] == j)) if j > 0 else np.zeros(0, bool)
            v = v[keep]
            mob = mobility[v, j] if j > 0 else np.zeros(0)
            outside = np.unique(F[t])
            outside = outside[r.region[outside] != j] if len(t) else outside
            if len(v) and len(outside):
                d, _ = cKDTree(ch.V[outside]).query(ch.V[v])
                x = np.clip(d / max(r.radius[j] / 3.0, 1e-9), 0.0, 1.0)
                mob = mob * x * x * (3.0 - 2.0 * x)
            verts.append(v.astype(np.int64))
            mobs.append(mob)
            vside.append(side[j][np.searchsorted(zone[j], v)] if j > 0
                         else np.zeros(0, np.int64))
            if len(t):
                vol0[j] = region_volume(ch.V, F, t, skel.rest_positions[j])
        return SwellTables(mobility, zone, side, verts, vside, mobs, vol0)


class RegionSearch:
    """What the crossing tests over ``regions`` (:class:`JointRegions`) carry
    from one test to the next: per joint, the boxes of its tree as last fit
    (:func:`tree_fit` buffers), the pose and skin they were fit to, and the
    nearest triangle each vertex found last (the hints of :func:`crossed_at`).
    One per stage that tests: the regions are shared by every pipeline of a
    character, this state is not. None of it changes an answer, only how fast
    it comes."""

    def __init__(self, regions: JointRegions) -> None:
        self.regions = regions
        J = regions.skel.n_joints
        self._fits = [None] * J
        self._fitted = [(None, None)] * J          # (posed, X) each fit is for
        self._hints = [None] * J                    # last nearest triangle, per vertex

    def state(self, j: int, X: np.ndarray, posed):
        """Joint ``j``'s tree and fit buffers, whether the boxes must be fit
        afresh, and its per-vertex hints (:func:`crossed_at`), for a test of the
        skin ``X`` in the pose ``posed`` (:meth:`JointRegions.posed_segments`
        with the frame's memo, or None). The boxes are fit once per pose; the
        frame's later tests only grow them where the skin has moved since."""
        tree = self.regions.tree(j)
        if self._fits[j] is None:
            self._fits[j] = tree_fit(tree)
        was, wasX = self._fitted[j]
        refit = posed is None or was is not posed or wasX is not X
        self._fitted[j] = (None, None) if posed is None else (posed, X)
        if self._hints[j] is None:
            self._hints[j] = -np.ones(len(self.regions.verts[j]), dtype=np.int64)
        return tree, self._fits[j], refit, self._hints[j]

    def crossed(self, X: np.ndarray, X0: np.ndarray, F: np.ndarray, M: np.ndarray,
                j: int, sub: np.ndarray | None = None, posed=None) -> np.ndarray:
        """Per vertex of ``verts[j]`` (or of its subset ``sub``, positions into
        ``verts[j]``): the crossed triangle, -2 deep inside, -1 not crossed.
        ``posed``: :meth:`JointRegions.posed_segments` of ``(j, M)`` with the
        frame's memo, if already at hand."""
        regs = self.regions
        _, fit, refit, hint = self.state(j, X, posed)
        test = regs.region_test(j, X0, F, M, regs.posed_segments(j, M) if posed is None else posed)
        return crossed_at(X, test, fit, refit, hint, regs.every[j] if sub is None else sub,
                          numba.get_num_threads())

    def resolve(self, X, X0, F, M, j: int, pos: np.ndarray, posed, ends, *, planar: bool,
                paper: bool, upfront: bool, halfspace: bool, pushout: bool, passes: int,
                eps: float):
        """The collision stage's detect-and-resolve passes over joint ``j``'s
        vertices at positions ``pos`` (:func:`resolve_region`); ``posed`` as
        in :meth:`crossed` (the frame's), ``ends`` the joint and its bones' far
        ends (:class:`FoldPlan` says what the others do). Returns (the vertices
        moved, how many projected, how many pushed)."""
        _, fit, refit, hint = self.state(j, X, posed)
        return resolve_region(X, self.regions.region_test(j, X0, F, M, posed), fit, refit, hint,
                              pos, FoldPlan(*ends, passes, planar, paper, upfront, halfspace,
                                            pushout, eps), numba.get_num_threads())


def count_crossings(X, X0, F, M, regions: JointRegions, joints=None,
                    search: RegionSearch | None = None) -> int:
    """Number of joint-region vertices that have passed through the skin.

    ``M`` are the pose's skinning matrices; ``joints`` defaults to all.
    ``search``: the :class:`RegionSearch` to test with (a fresh one by
    default; one kept from call to call finds the same, sooner)."""
    search = search or RegionSearch(regions)
    joints = range(1, regions.skel.n_joints) if joints is None else joints
    return int(sum((search.crossed(X, X0, F, M, j) != -1).sum()
                   for j in joints if len(regions.verts[j])))
