"""Post-processing: skin passing through skin in the joint regions."""
from __future__ import annotations

import numba
import numpy as np

from ..kernels.collision import (crossed_at, longest_edge, resolve_region, tree_fit,
                                 triangle_trees)
from ..rigging.weights import point_segment_distance
from .base import Frame, KeyedCache, Stage


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
    """

    def __init__(self, character, weights=None):
        skel, r, F = character.skeleton, character.rig, character.F
        w = weights or r.weights()
        self.skel = skel
        J = skel.n_joints
        below = skel.subtree()          # below[j, b]: b is j or under j
        dom = w.Widx[np.arange(len(w.Widx)), np.argmax(w.Wval, axis=1)]
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
        self._key, self._sets = None, None
        # Trees are made on first use: three stages keep regions and only the
        # joints that fold are tested (every region's tree and fit: 6 MB on the
        # 24k humanoid, per stage).
        self._V0, self._F = character.V, F
        self._trees, self._fits = [None] * J, [None] * J
        self._fitted = [(None, None)] * J          # (posed, X) each fit is for
        self._hints = [None] * J                    # last nearest triangle, per vertex
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
        frame, which :meth:`crossed` takes as the mark of its pose. Read-only."""
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
        """Joint ``j``'s :func:`triangle_trees` and its fit buffers."""
        if self._trees[j] is None:
            self._trees[j] = triangle_trees(self._V0, self._F, self.tris[j], self.tside[j])
            self._fits[j] = tree_fit(self._trees[j])
        return self._trees[j], self._fits[j]

    def search_state(self, j: int, X: np.ndarray, posed):
        """Joint ``j``'s tree and fit buffers, whether the boxes must be fit
        afresh, and its per-vertex hints (:func:`crossed_at`), for a test of the
        skin ``X`` in the pose ``posed`` (:meth:`posed_segments` with the
        frame's memo, or None). The boxes are fit once per pose; the frame's
        later tests only grow them where the skin has moved since."""
        tree, fit = self.tree(j)
        was, wasX = self._fitted[j]
        refit = posed is None or was is not posed or wasX is not X
        self._fitted[j] = (None, None) if posed is None else (posed, X)
        if self._hints[j] is None:
            self._hints[j] = -np.ones(len(self.verts[j]), dtype=np.int64)
        return tree, fit, refit, self._hints[j]

    def test_limits(self, j: int):
        """``rest_sep``, ``rest_tol`` and ``reach`` of joint ``j``'s crossing
        test (:func:`crossed_vertices`)."""
        return 3.0 * self.edge, 0.5 * self.radius[j], self.cell(j)

    def crossed(self, X: np.ndarray, X0: np.ndarray, F: np.ndarray, M: np.ndarray,
                j: int, sub: np.ndarray | None = None, posed=None) -> np.ndarray:
        """Per vertex of ``verts[j]`` (or of its subset ``sub``, positions into
        ``verts[j]``): the crossed triangle, -2 deep inside, -1 not crossed.
        ``posed``: :meth:`posed_segments` of ``(j, M)`` with the frame's memo,
        if already at hand."""
        tree, fit, refit, hint = self.search_state(j, X, posed)
        A, B = self.posed_segments(j, M) if posed is None else posed
        return crossed_at(X, X0, F, np.ascontiguousarray(M), self.tri_bone, self.tri_normal, tree,
                          fit, refit, self.tris[j], self.verts[j], self.vside[j], self.R[j], A, B,
                          *self.test_limits(j), hint, self.every[j] if sub is None else sub,
                          numba.get_num_threads())

    def resolve(self, X, X0, F, M, j: int, pos: np.ndarray, posed, ends, *, planar: bool,
                paper: bool, upfront: bool, halfspace: bool, pushout: bool, passes: int,
                eps: float):
        """The collision stage's detect-and-resolve passes over joint ``j``'s
        vertices at positions ``pos`` (:func:`resolve_region`); ``posed`` as
        in :meth:`crossed` (the frame's), ``ends`` the joint and its bones' far
        ends. Returns (the vertices moved, how many projected, how many pushed)."""
        tree, fit, refit, hint = self.search_state(j, X, posed)
        return resolve_region(
            X, X0, F, np.ascontiguousarray(M), self.tri_bone, self.tri_normal, tree, fit, refit,
            self.tris[j], self.tside[j], self.verts[j], self.vside[j], self.R[j], posed[0],
            posed[1], *self.test_limits(j), hint, pos, passes, planar, paper, upfront,
            halfspace, pushout, *ends, eps, numba.get_num_threads())

    def cell(self, j: int) -> float:
        """How near the other side's skin :meth:`crossed` looks, for joint ``j``
        (three median edges, at least a quarter of the limb radius)."""
        return max(3.0 * self.edge, 0.25 * self.radius[j])

    def longest_edge(self, j: int, X: np.ndarray) -> float:
        """The longest edge of joint ``j``'s triangles in ``X``."""
        return float(longest_edge(X, self._F, self.tris[j]))

    def active(self, bent: np.ndarray):
        """Joints of the bent joints' regions (cached per set of bent joints)."""
        key = bent.tobytes()
        if key != self._key:
            self._key = key
            self._sets = [j for j in np.flatnonzero(bent) if len(self.verts[j])]
        return self._sets


def count_crossings(X, X0, F, M, regions: JointRegions, joints=None) -> int:
    """Number of joint-region vertices that have passed through the skin.

    ``M`` are the pose's skinning matrices; ``joints`` defaults to all."""
    joints = range(1, regions.skel.n_joints) if joints is None else joints
    return int(sum((regions.crossed(X, X0, F, M, j) != -1).sum()
                   for j in joints if len(regions.verts[j])))


class Collision(Stage):
    """The paper's self-collision handling, joint regions of bent joints only.

    A crossed vertex is projected onto the plane through the joint ``j`` that is
    perpendicular to the plane of the two bones and passes through the farthest
    crossing point ``q`` (``collision_plane: paper``) or bisects the two bones
    (``bisector``, the contact plane of two limbs of equal girth):
    ``p' = p - (n . (p - j)) n``, then nudged ``eps`` to its own side so it does
    not sit exactly on the other skin. Detection and
    projection repeat up to ``collision_passes`` times.
    """

    name = "collision"

    def __init__(self, character, params):
        super().__init__(character, params)
        self.F, self.V0 = character.F, character.V
        self.regions = JointRegions(character, self.weights)
        self.child = self.regions.child
        r = character.rig
        # surface vertices the solve can move, per joint: embedded in a tet of its zone
        self._szone = self.weights.zone[r.Etet].any(axis=1)
        self._moved = KeyedCache()

    def _fold_ends(self, fr: Frame, j: int):
        """Joint ``j``'s posed centre and the far ends of its two bones: its
        parent and its child (or its bone's tip)."""
        skel = self.character.skeleton
        P = fr.G[:, :3, 3]
        if self.child[j] >= 0:
            end = P[self.child[j]]
        else:
            end = fr.M[j, :3, :3] @ skel.tips[j] + fr.M[j, :3, 3]
        return (np.ascontiguousarray(P[j]), np.ascontiguousarray(P[skel.parents[j]]),
                np.ascontiguousarray(end))

    def __call__(self, fr: Frame) -> None:
        if not self.params["self_collision"]:
            return
        X = fr.surface
        regs = self.regions
        eps = 0.5e-3
        projected = pushed = 0
        folded = fr.bent & (fr.angles > self.params["collision_angle"])
        joints = regs.active(folded)
        fr.counts["collision_joints"] = joints
        # A folding joint also pushes skin into its siblings' regions (lowered arms into
        # the neck's): those are checked too, with push-out only (they have no fold plane).
        skel = self.character.skeleton
        near = np.zeros_like(folded)
        for j in joints:
            near |= skel.parents == skel.parents[j]
        near &= ~folded
        near[skel.parents < 0] = False
        siblings = [j for j in np.flatnonzero(near) if len(regs.verts[j])]
        # The parent's region (the chest under lowered arms) is checked too, but only
        # where the folding joints' solve moved its skin.
        up = {int(skel.parents[j]) for j in joints} - set(int(j) for j in joints) - set(siblings)
        parents = [j for j in sorted(up) if skel.parents[j] >= 0 and len(regs.verts[j])] \
            if self.params["collision_parent"] else []
        fr.counts["collision_joints"] = list(joints) + siblings + parents
        p = self.params
        paper = p["collision_plane"] == "paper"
        upfront = not paper and bool(p["collision_halfspace"])
        for j in list(joints) + siblings + parents:
            pos = regs.every[j]      # the first pass tests them all
            if j in parents:
                pos = self._moved.get((j, folded.tobytes()), lambda: np.flatnonzero(
                    self._szone[regs.verts[j]][:, list(joints)].any(axis=1)))
                if not len(pos):
                    continue
            posed = regs.posed_segments(j, fr.M, fr.memo)
            moved, k, n = regs.resolve(
                X, self.V0, self.F, fr.M, j, pos, posed, self._fold_ends(fr, j),
                planar=j in joints, paper=paper, upfront=upfront,
                halfspace=bool(p["collision_halfspace"]), pushout=bool(p["collision_pushout"]),
                passes=int(p["collision_passes"]), eps=eps)
            fr.touched.append(moved)
            projected += k
            pushed += n
        fr.counts["projected"] = projected
        fr.counts["pushed"] = pushed
