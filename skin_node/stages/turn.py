"""Turn: a limb the pose drives deep into another part's flesh is turned out
of it about a joint up its chain before it is skinned."""
from __future__ import annotations

import math

import numpy as np

from ..kernels.contact import flesh_depth
from .base import Frame, Stage

#: A limb is turned about the first joint up its chain far enough that its
#: largest move (``turn_shift``) turns it by at most MAX_TURN radians (as
#: :data:`~skin_node.stages.untangle.MAX_TURN`).
MAX_TURN = 0.4
#: Halvings of the search for the least turn (a 1/4096 of the largest).
BISECT = 12


def _rotation(axis: np.ndarray, angle: float, o: np.ndarray) -> np.ndarray:
    """(4, 4): a turn by ``angle`` about unit ``axis`` through point ``o``."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]],
                  [-axis[1], axis[0], 0.0]])
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)
    T[:3, 3] = o - T[:3, :3] @ o
    return T


class Turn(Stage):
    """Limbs the pose drives deep into another part's flesh turned out of it,
    bones and all, before skinning.

    Mocap retargeted onto a body of other proportions (or a pose held with
    the arms at the sides and the torso leaning) can drive a forearm or a
    hand through the hip and thigh, deeper than skin can be moved out of it:
    the contact then flattens both sides onto one surface inside the body
    (the humanoid, arms lowered 80 degrees and leaning 20 degrees sideways:
    237 intersecting pairs of DQS's 328, 12 sharp folds at 40 degrees where
    DQS has none; see docs/design.md). A body would move the arm. So before skinning, each part
    that is not a limb's top part (a forearm, a hand, a shin, a foot: its
    parent has no other child) is tested against every larger part that
    meets it at no joint: its rest skin, carried by its bone, read in the
    other part's rest field (:func:`~skin_node.kernels.contact.flesh_depth`).
    Where it lies deeper than ``turn_depth`` of its limb radius (skin to
    bone at rest), the bones from the first joint up its chain at least
    ``turn_shift`` / MAX_TURN limb radii from where it is deepest (the
    shoulder for a forearm, climbing no higher than the limb's top and to no
    joint that carries the other part) turn, away from the other part's
    flesh along its field's gradient, by the least angle that leaves it no
    deeper than ``turn_depth`` (bisected), at most so far that no skin it
    carries moves more than ``turn_shift`` limb radii. The contact then
    meets the rest as a crease. The least angle grows from zero as the limb
    sinks in, so the turn comes in without a jump; the poses that the
    contact creases cleanly (every built-in clip's frames, the test poses
    beyond them) stay below ``turn_depth`` and are skinned as posed.

    The frame's bones (``G``, ``M``, the posed segments) are the turned ones
    for every stage after this one; the skin stands on them. How many limbs
    turned and the farthest any skin moved (mm) are the frame's counts
    ``turned`` and ``turn_mm``.
    """

    name = "turn"
    #: runs on the pose, before the skinning stage
    poses = True

    def __init__(self, character, params):
        super().__init__(character, params)
        sk = character.skeleton
        J = sk.n_joints
        self._parents = np.asarray(sk.parents)
        self._below = sk.subtree()
        self._kids = np.bincount(self._parents[self._parents >= 0], minlength=J)
        part = character.rig.part
        self._V0 = np.ascontiguousarray(character.V)
        self._pf = character.rig.fields
        self._verts = [np.flatnonzero(part == j).astype(np.int64) for j in range(J)]
        has = np.array([len(v) > 0 for v in self._verts])
        radius = character.nearest_segments[1][:, 0]
        self._radius = np.array([np.median(radius[v]) if len(v) else 0.0 for v in self._verts])
        size = np.array([np.ptp(self._V0[v], axis=0).max() if len(v) else 0.0
                         for v in self._verts])
        # each part's rest skin in a ball: a cheap test of which parts can meet
        self._centre = np.array([self._V0[v].mean(axis=0) if len(v) else np.zeros(3)
                                 for v in self._verts])
        self._ball = np.array([np.sqrt(((self._V0[v] - c) ** 2).sum(axis=1)).max()
                               if len(v) else 0.0 for v, c in zip(self._verts, self._centre)])
        par, kids, below = self._parents, self._kids, self._below
        field = character.rig.field_dims[:, 0] > 1
        pairs = []
        for a in range(J):
            # not the root, not a limb's top part (its parent branches), and
            # carried by a bone with flesh of its own
            if not has[a] or par[a] <= 0 or kids[par[a]] != 1:
                continue
            for b in range(J):
                # another part it meets at no joint and does not carry, larger
                # (of two the same size, the first turns)
                if (b == a or not field[b] or par[a] == b or par[b] == a or below[a, b]
                        or (size[a], a) >= (size[b], b)):
                    continue
                pairs.append((a, b))
        self._pairs = np.array(pairs, dtype=np.int64).reshape(-1, 2)
        # the farthest rest skin each joint carries, from that joint: caps a turn
        self._reach = np.zeros(J)
        for k in range(J):
            v = np.concatenate([self._verts[j] for j in np.flatnonzero(below[k])])
            if len(v):
                self._reach[k] = np.sqrt(((self._V0[v] - sk.rest_positions[k]) ** 2)
                                         .sum(axis=1)).max()
        self._seg_joint, self._segA, self._segB = sk.bone_segments()
        self._out = np.zeros(7)

    def _depth(self, fr: Frame, a: int, b: int, excess: float) -> float:
        """How deep part ``a``'s skin lies in part ``b``'s flesh in ``fr``."""
        T = np.ascontiguousarray(np.linalg.solve(fr.M[b], fr.M[a]))
        self._out[:] = 0.0
        return flesh_depth(self._V0, self._verts[a], T, b, self._pf, excess, self._out)

    def _pivot(self, a: int, b: int, c: np.ndarray, reach: float, G: np.ndarray) -> int:
        """The first joint up ``a``'s chain at least ``reach`` from ``c``, no
        higher than the limb's top and carrying no part ``b``."""
        par, kids, below = self._parents, self._kids, self._below
        k = a
        while (np.linalg.norm(c - G[k, :3, 3]) < reach and par[par[k]] >= 0
               and kids[par[k]] == 1 and not below[par[k], b]):
            k = par[k]
        return k

    def __call__(self, fr: Frame) -> None:
        fr.counts["turned"], fr.counts["turn_mm"] = 0, 0.0
        depth, shift = float(self.params["turn_depth"]), float(self.params["turn_shift"])
        if depth <= 0.0 or shift <= 0.0 or not len(self._pairs):
            return
        M, G = fr.M, fr.G
        a, b = self._pairs[:, 0], self._pairs[:, 1]
        ca = np.einsum("pij,pj->pi", M[a, :3, :3], self._centre[a]) + M[a, :3, 3]
        cb = np.einsum("pij,pj->pi", M[b, :3, :3], self._centre[b]) + M[b, :3, 3]
        near = np.linalg.norm(ca - cb, axis=1) <= self._ball[a] + self._ball[b]
        moved = np.zeros(len(M), dtype=bool)
        for a, b in self._pairs[near]:
            D = depth * self._radius[a]
            if self._depth(fr, a, b, D) <= D:
                continue
            # where it lies deep, and the way out: b's field gradient there
            R, t = M[b, :3, :3], M[b, :3, 3]
            out = self._out
            g = R @ out[1:4]
            c = R @ (out[4:7] / out[0]) + t
            span = shift * self._radius[a]
            k = self._pivot(a, b, c, span / MAX_TURN, G)
            o = G[k, :3, 3].copy()
            axis = np.cross(c - o, g)
            n = float(np.linalg.norm(axis))
            if n < 1e-12:
                continue        # the way out runs through the pivot
            axis /= n
            # no skin carried further than the span: a chord of the farthest
            top = 2.0 * math.asin(min(1.0, span / (2.0 * max(self._reach[k], 1e-9))))
            sub = self._below[k]
            M0, G0 = M[sub].copy(), G[sub].copy()

            def place(angle):
                T = _rotation(axis, angle, o)
                M[sub] = T @ M0
                G[sub] = T @ G0
                return self._depth(fr, a, b, D)

            if place(top) <= D:
                lo, hi = 0.0, top
                for _ in range(BISECT):
                    mid = 0.5 * (lo + hi)
                    lo, hi = (lo, mid) if place(mid) <= D else (mid, hi)
                place(hi)
            else:
                hi = top            # as far as it may go: the contact meets the rest
            moved |= sub
            fr.counts["turned"] += 1
            fr.counts["turn_mm"] = max(fr.counts["turn_mm"],
                                       2e3 * math.sin(0.5 * hi) * self._reach[k])
        if moved.any():
            s = moved[self._seg_joint]
            j = self._seg_joint[s]
            fr.seg_A[s] = np.einsum("sij,sj->si", M[j, :3, :3], self._segA[s]) + M[j, :3, 3]
            fr.seg_B[s] = np.einsum("sij,sj->si", M[j, :3, :3], self._segB[s]) + M[j, :3, 3]
