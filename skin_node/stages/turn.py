"""Turn: a limb the pose drives deep into another part's flesh is turned out
of it about a joint up its chain before it is skinned."""
from __future__ import annotations

import math

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from ..kernels.contact import pair_depths
from ..skeleton import matrix_to_euler_xyz
from .base import Frame, Stage

#: A limb is turned about the first joint up its chain far enough that its
#: largest move (``turn_shift``) turns it by at most MAX_TURN radians (as
#: :data:`~skin_node.stages.untangle.MAX_TURN`).
MAX_TURN = 0.4
#: The least turn that takes a limb out is found in SCAN steps up to its
#: cap, the first that does bisected BISECT times.
SCAN = 8
BISECT = 8
#: A part of fewer vertices is not turned: read at a handful of corners (a
#: limb a box of eight, RiggedFigure's), its depth misses its faces and a
#: turn swung it between frames (the file-weighted punch's worst frame 13
#: -> 43 intersecting pairs of DQS's 100, its largest change between two
#: frames 169 -> 218 mm). CesiumMan's smallest part has 27.
MIN_VERTICES = 20
#: The first test of a pair reads a sample of a part's vertices, one a cube
#: SAMPLE of its limb radius across (of SIBLING_DEPTH of it for a limb's top
#: part, which may lie less deep: the thighs, which touch, were read in full
#: every frame of the walk); a pair whose sample lies no deeper than
#: ``turn_depth`` less the farthest any vertex is from the sample (or stays
#: that far clear) cannot lie deeper (the field is a distance), and only the
#: others are read in full.
SAMPLE = 0.5
#: A limb's top part (a thigh, an upper arm) turns only out of its twin
#: (the other thigh, :data:`TWIN`), about its own joint, once it lies deeper than
#: SIBLING_DEPTH ``turn_depth``s in it, along that part's field gradient.
#: Two limbs side by side meet along their length, a longer crease than a
#: hand's in a hip: a thigh crossed over the other (``random_poses`` number
#: 16, sitting) turned by the least angle that took it to ``turn_depth``
#: kept 239 of DQS's 346 intersecting pairs, at 0.75 of it none (0.6 and
#: 0.9 gave the same on two other seeds' poses). The way it lay at rest
#: runs along the thigh from the hip, and turned that way the legs crossed
#: at the knees instead (a test pose's 0 pairs -> 329). It turns no further
#: than keeps its joint within the skeleton's limits, and not at all on a
#: skeleton without them (a glTF's): on poses past the limits (half the
#: humanoid's channels at up to 92 degrees, seeded) turns that took the hips
#: further past them folded the hips' skin (3,586 intersecting pairs against
#: 3,028 without the top parts' turn; CesiumMan's 852 against 788).
SIBLING_DEPTH = 0.75
#: A limb's top part turns out of a sibling at least TWIN of its size (the
#: other thigh, the other upper arm), not out of a larger one (the spine
#: beside the thighs, the upper arms beside the neck).
TWIN = 0.9
#: With ``turn_rate``, a joint's turn may also change by SETTLE radians a
#: frame beyond the pose's own change, so a turn held back comes in while the
#: pose is held (0.4 radians, a turn at its cap, in 40 frames).
SETTLE = 0.01


def _rotation(axis: np.ndarray, angle: float, o: np.ndarray) -> np.ndarray:
    """(4, 4): a turn by ``angle`` about unit ``axis`` through point ``o``."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]],
                  [-axis[1], axis[0], 0.0]])
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + math.sin(angle) * K + (1.0 - math.cos(angle)) * (K @ K)
    T[:3, 3] = o - T[:3, :3] @ o
    return T


def pivot(parents: np.ndarray, kids: np.ndarray, below: np.ndarray, j: int,
          others: np.ndarray, c: np.ndarray, reach: float, G: np.ndarray) -> int:
    """The joint a limb part ``j`` turns about to move its point ``c``: the
    first up its chain from ``j`` at least ``reach`` from ``c`` (``G`` the
    posed joints), climbing no higher than the limb's top (a joint whose
    parent has other children: a shoulder, a hip) and to no joint that
    carries one of the parts ``others`` (``below``: :meth:`Skeleton.subtree`;
    ``kids``: each joint's count of children)."""
    k = j
    while (np.linalg.norm(c - G[k, :3, 3]) < reach and parents[parents[k]] >= 0
           and kids[parents[k]] == 1 and not below[parents[k], others].any()):
        k = parents[k]
    return k


class Turn(Stage):
    """Limbs the pose drives deep into another part's flesh turned out of it,
    bones and all, before skinning.

    Mocap retargeted onto a body of other proportions (or a pose held with
    the arms at the sides and the torso leaning) can drive a forearm or a
    hand through the hip and thigh, deeper than skin can be moved out of it:
    the contact then flattens both sides onto one surface inside the body
    (the humanoid, arms lowered 80 degrees and leaning 20 degrees sideways:
    237 intersecting pairs of DQS's 328; see docs/design.md). A body would
    move the arm. So before skinning, each part that is not a limb's top
    part (a forearm, a hand, a shin, a foot: its parent has no other child)
    is tested against every larger part that meets it at no joint: its rest
    skin, carried by its bone, read in the other part's rest field
    (:func:`~skin_node.kernels.contact.pair_depths`). Where it lies deeper
    than ``turn_depth`` of its limb radius (skin to bone at rest), the bones
    from the first joint up its chain at least ``turn_shift`` / MAX_TURN
    limb radii from its middle (the shoulder for a forearm, climbing
    no higher than the limb's top and to no joint that carries a part it
    lies in) turn by the least angle that leaves it no deeper than
    ``turn_depth`` in any of those parts while driving nothing they carry
    deeper into a part they do not (than at the pose, or than
    ``turn_depth``). It turns back towards where it sat against those parts
    at rest (the way it lay from the pivot in their frames then: for an arm
    hanging into the hip, out to the side, towards the T-pose), a way that
    follows the pose smoothly. No turn moves the skin it carries more than
    ``turn_shift`` limb radii: a limb that would need more (or that no turn
    within that takes out) is turned that far and the contact does the
    rest (a hand turned after its forearm turns about the same joint
    again: the two add up). The least angle grows from zero as the limb
    sinks in and stays at the cap as it sinks further, so the turn comes in
    and holds without a jump; the poses that the contact creases cleanly
    (every built-in clip's frames, the test poses beyond them but one) stay
    below ``turn_depth`` and are skinned as posed.

    A limb's top part (a thigh, an upper arm) is tested against its twin
    alone (a thigh against the other thigh, :data:`TWIN`), from SIBLING_DEPTH
    ``turn_depth``s deep, and turns about its own joint along the other
    part's field gradients, within that joint's limits (:data:`SIBLING_DEPTH`).

    From one frame to the next each joint's turn changes no faster than
    the pose (``turn_rate``, :meth:`_follow`): a small change of pose can
    change which limb turns, and the turn then comes in over frames.

    The frame's bones (``G``, ``M``, the posed segments) are the turned ones
    for every stage after this one; the skin stands on them. How many joints
    turned and the farthest any rest skin moved, carried by its bone (mm),
    are the frame's counts ``turned`` and ``turn_mm``.
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
        # a limb's top part: its parent branches or is the root
        self._top = np.array([par[a] >= 0 and (par[a] == 0 or kids[par[a]] != 1)
                              for a in range(J)])
        # a top part turns within its joint's limits, so only where it has
        # some (a glTF's skeleton has none)
        limited = sk.limited()
        for a in range(J):
            # not the root, carried by a bone with flesh of its own, of
            # MIN_VERTICES or more, and a limb's top part only within limits
            if (len(self._verts[a]) < MIN_VERTICES or par[a] < 0
                    or (self._top[a] and not limited[a])):
                continue
            for b in range(J):
                # another part it meets at no joint and does not carry, larger
                # (of two the same size, the first turns); a limb's top part,
                # its twin only (a sibling about its size: TWIN)
                if (b == a or not field[b] or par[a] == b or par[b] == a or below[a, b]
                        or (size[a], a) >= (size[b], b)
                        or (self._top[a]
                            and (par[b] != par[a] or size[a] < TWIN * size[b]))):
                    continue
                pairs.append((a, b))
        self._pairs = np.array(pairs, dtype=np.int64).reshape(-1, 2)
        # how deep each part may lie, in ``turn_depth``s
        self._depth = np.where(self._top, SIBLING_DEPTH, 1.0)
        # every two parts that meet at no joint, the first's skin in the
        # second's flesh: a turn may not drive the skin it carries deeper
        # into a part it does not carry
        self._guard = np.array([(c, e) for c in range(J) for e in range(J)
                                if has[c] and field[e] and c != e and par[c] != e
                                and par[e] != c], dtype=np.int64).reshape(-1, 2)
        self._full = self._csr(self._verts)
        # each part's sample, and how far its vertices are from it at most
        sample, self._gap = [], np.zeros(J)
        for j, v in enumerate(self._verts):
            if not len(v):
                sample.append(v)
                continue
            cell = max(SAMPLE * self._limit(j), 1e-9)
            key = np.floor(self._V0[v] / cell).astype(np.int64)
            _, first = np.unique(key, axis=0, return_index=True)
            keep = v[np.sort(first)]
            sample.append(keep)
            self._gap[j] = cKDTree(self._V0[keep]).query(self._V0[v])[0].max()
        self._sample = self._csr(sample)
        # the farthest rest skin each joint carries, from that joint: caps a turn
        self._reach = np.zeros(J)
        for k in range(J):
            v = np.concatenate([self._verts[j] for j in np.flatnonzero(below[k])])
            if len(v):
                self._reach[k] = np.sqrt(((self._V0[v] - sk.rest_positions[k]) ** 2)
                                         .sum(axis=1)).max()
        self._seg_joint, self._segA, self._segB = sk.bone_segments()
        self._rest = np.asarray(sk.rest_positions, dtype=np.float64)
        self._rest_rot = np.asarray(sk.rest_rotations, dtype=np.float64)
        self._limits = sk.limits
        self.reset()

    def reset(self) -> None:
        """Forget the last frame's pose and turns (``turn_rate``)."""
        self._last_q = None
        self._held = None

    def _limit(self, a):
        """How deep parts ``a`` may lie in another's flesh, in ``turn_depth``s
        (times their limb radius)."""
        return self._radius[a] * self._depth[a]

    def _channels(self, q: np.ndarray, k: int, G: np.ndarray) -> np.ndarray:
        """Joint ``k``'s rotation channels as it lies in ``G``, of the two
        Euler triples the one nearest its channels in pose ``q``."""
        p = self._parents[k]
        R = G[p, :3, :3].T @ G[k, :3, :3] @ self._rest_rot[k].T
        e = matrix_to_euler_xyz(R)
        f = np.array([e[0] + np.pi, np.pi - e[1], e[2] + np.pi])
        f = (f + np.pi) % (2.0 * np.pi) - np.pi
        now = q[3 + 3 * k:6 + 3 * k]

        def far(x):
            d = (x - now + np.pi) % (2.0 * np.pi) - np.pi
            return float(d @ d)
        return e if far(e) <= far(f) else f

    def _within_limits(self, q: np.ndarray, k: int, G: np.ndarray, top: float, place) -> float:
        """The turn up to ``top`` (``place(angle)`` puts it) that leaves
        joint ``k`` within its limits: ``top`` if it does, else the largest
        from 0 that does (bisected), 0 if neither the pose nor ``top`` does."""
        lim = self._limits[k]

        def ok(t):
            place(t)
            x = self._channels(q, k, G)
            return bool(np.all(x >= lim[:, 0] - 1e-9) and np.all(x <= lim[:, 1] + 1e-9))
        if ok(top):
            return top
        if not ok(0.0):
            return 0.0
        lo, hi = 0.0, top
        for _ in range(BISECT):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if ok(mid) else (lo, mid)
        return lo

    @staticmethod
    def _csr(verts: list) -> tuple:
        """Lists of vertices as ``(ptr, idx)``."""
        ptr = np.concatenate([[0], np.cumsum([len(v) for v in verts])]).astype(np.int64)
        return ptr, np.concatenate(verts).astype(np.int64)

    def _depths(self, fr: Frame, pairs: np.ndarray, depth: float, Minv: np.ndarray,
                sample: bool = False) -> np.ndarray:
        """How deep each of ``pairs`` of parts (a, b) lies, a's skin (or its
        sample) in b's flesh, in ``fr`` (:func:`~skin_node.kernels.contact.pair_depths`;
        negative: its clearance), and each one's sums of the points deeper
        than ``depth`` of a's radius."""
        excess = depth * self._limit(pairs[:, 0])
        worst, sums = np.zeros(len(pairs)), np.zeros((len(pairs), 7))
        pair_depths(self._V0, *(self._sample if sample else self._full), pairs, fr.M, Minv,
                    self._centre, self._ball, self._pf, excess, worst, sums)
        return worst, sums

    @staticmethod
    def _axis(lever: np.ndarray, way: np.ndarray):
        """The unit axis of the turn about a pivot that moves a point
        ``lever`` from it towards ``way`` (across the lever), or None where
        ``way`` lies along it or the lever is nil."""
        n = float(np.linalg.norm(lever))
        if n < 1e-9:
            return None
        L = lever / n
        u = way - (way @ L) * L
        m = float(np.linalg.norm(u))
        if m <= 1e-6 * max(float(np.linalg.norm(way)), 1e-300):
            return None
        return np.cross(L, u / m)

    def __call__(self, fr: Frame) -> None:
        fr.counts["turned"], fr.counts["turn_mm"] = 0, 0.0
        depth, shift = float(self.params["turn_depth"]), float(self.params["turn_shift"])
        G_posed, M_posed = fr.G.copy(), fr.M.copy()
        if depth > 0.0 and shift > 0.0 and len(self._pairs):
            self._turn(fr, depth, shift)
        self._follow(fr, G_posed, M_posed)

    def _turn(self, fr: Frame, depth: float, shift: float) -> None:
        """Each limb that lies deep turned out, in ``fr.G`` and ``fr.M``
        (the class's text)."""
        M, G = fr.M, fr.G
        a = self._pairs[:, 0]
        D = depth * self._limit(a)
        maybe = self._depths(fr, self._pairs, depth, np.linalg.inv(M), True)[0] + self._gap[a] > D
        moved = np.zeros(len(M), dtype=bool)
        # parents before children (the skeleton's order): a part a turn
        # carried is tested again where it was carried to (an arm turned out
        # of the hip about the shoulder can take its hand into the thigh)
        for a in np.unique(self._pairs[:, 0]):
            D = depth * self._limit(a)
            mine = self._pairs[:, 0] == a
            Minv = np.linalg.inv(M)
            if moved[a]:
                maybe[mine] = (self._depths(fr, self._pairs[mine], depth, Minv, True)[0]
                               + self._gap[a] > D)
            if not (maybe & mine).any():
                continue
            # in full (a turn before this one may have moved it too)
            rows = self._pairs[maybe & mine]
            worst, sums = self._depths(fr, rows, depth, Minv)
            deep = worst > D
            if not deep.any():
                continue
            # about which joint it turns (from its middle), where it lies
            # deep (c) and the way it turns out (back): towards the way that
            # skin lay from the joint at rest (r: its rest place), turned as
            # each part it lies in is turned, so an arm hanging into the hip
            # turns out towards the T-pose; the fields' gradients where that
            # runs along the lever
            c, g, n = np.zeros(3), np.zeros(3), 0.0
            span = shift * self._radius[a]
            k = pivot(self._parents, self._kids, self._below, a, rows[deep, 1],
                      M[a, :3, :3] @ self._centre[a] + M[a, :3, 3], span / MAX_TURN, G)
            o = G[k, :3, 3].copy()
            back = np.zeros(3)
            for b, out in zip(rows[deep, 1], sums[deep]):
                cb = M[b, :3, :3] @ out[4:7] + out[0] * M[b, :3, 3]
                r = Minv[a, :3, :3] @ (cb / out[0]) + Minv[a, :3, 3]
                w = M[b, :3, :3] @ (r - self._rest[k])
                back += out[0] * w / max(float(np.linalg.norm(w)), 1e-12)
                c += cb
                g += M[b, :3, :3] @ out[1:4]
                n += out[0]
            # a limb's top part out of its sibling: along the fields'
            # gradients (the way it lay at rest runs along the lever)
            first, then = (g, back) if self._top[a] else (back, g)
            axis = self._axis(c / n - o, first)
            if axis is None:
                axis = self._axis(c / n - o, then)
            if axis is None:
                continue        # it lies deep at the pivot itself
            # no skin carried further than the span: a chord of the farthest
            top = 2.0 * math.asin(min(1.0, span / (2.0 * max(self._reach[k], 1e-9))))
            sub = self._below[k]
            M0, G0 = M[sub].copy(), G[sub].copy()
            rows = rows[deep]
            # what it carries may go no deeper into a part it does not carry
            # than at the pose, nor deeper than turn_depth where it was clear
            guard = self._guard[sub[self._guard[:, 0]] & ~sub[self._guard[:, 1]]]
            guard = guard[~((guard[:, 0] == a) & np.isin(guard[:, 1], rows[:, 1]))]
            limit = np.maximum(self._depths(fr, guard, depth, Minv)[0],
                               depth * self._radius[guard[:, 0]]) + 1e-9

            def place(axis, angle):
                T = _rotation(axis, angle, o)
                M[sub] = T @ M0
                G[sub] = T @ G0

            def out(axis, angle):
                # only the bones from k down moved: the others' inverses stand
                place(axis, angle)
                return (self._depths(fr, rows, depth, Minv)[0].max() <= D
                        and (not len(guard) or bool(np.all(
                            self._depths(fr, guard, depth, Minv)[0] <= limit))))

            # the least turn within the cap that takes it out; none: the cap,
            # not cut back where the guard holds (cut back, CesiumMan's
            # forearm turn out of its hip flicked on and off between 120 Hz
            # frames of the punch: its upper arm lies in the hip too)
            if self._top[a]:
                # a limb's top part turns about its own joint no further
                # than keeps that joint within its limits
                top = self._within_limits(fr.q, k, G, top, lambda t: place(axis, t))
                if top <= 0.0:
                    place(axis, 0.0)
                    continue
            steps = np.arange(1, SCAN + 1) * (top / SCAN)
            angle = top
            for m in range(SCAN):
                if out(axis, steps[m]):
                    lo, hi = (steps[m - 1] if m else 0.0), steps[m]
                    for _ in range(BISECT):
                        mid = 0.5 * (lo + hi)
                        lo, hi = (lo, mid) if out(axis, mid) else (mid, hi)
                    angle = hi
                    break
            else:
                # none takes it out: to the cap; a limb's top part only if
                # that leaves it less deep (turned along the other's field
                # gradients, it can go in deeper)
                if self._top[a]:
                    place(axis, top)
                    if self._depths(fr, rows, depth, Minv)[0].max() >= worst[deep].max():
                        place(axis, 0.0)
                        continue
            place(axis, angle)
            moved |= sub

    def _follow(self, fr: Frame, G_posed: np.ndarray, M_posed: np.ndarray) -> None:
        """The turns held to ``turn_rate``: each joint's turn (its rotation
        in its parent's frame as turned, against as posed) changes from the
        last frame's by at most ``turn_rate`` times the most any channel of
        the pose turned since it, plus :data:`SETTLE` (the least rotation
        that far towards the turn wanted); then the bones are posed again
        with those turns and the counts say what was applied.

        Each pose's turn is the least way out found for it alone, and a small
        change of pose can change which limb turns, or turn one from its
        least way out to its cap: a thigh turned a quarter degree further in
        towards the other swung the skin 126 mm between frames. The limit
        spreads such a jump over the frames the pose takes to move as far; a
        pose far from the last (independent poses, a jump in the stream) is
        turned as found, and so is the first frame after :meth:`reset`."""
        par = self._parents
        rate, last, held = float(self.params["turn_rate"]), self._last_q, self._held
        self._last_q = fr.q.copy()
        if held is None and np.array_equal(fr.G, G_posed):
            return      # nothing turned, nor held from the last frame
        kids = np.flatnonzero(par >= 0)
        up = par[kids]
        J = len(par)
        # each joint's turn in its parent's frame: turned local rotation
        # times the posed one's inverse
        want = np.tile(np.eye(3), (J, 1, 1))
        local = np.einsum("kji,kjl->kil", G_posed[up, :3, :3], G_posed[kids, :3, :3])
        turned = np.einsum("kji,kjl->kil", fr.G[up, :3, :3], fr.G[kids, :3, :3])
        want[kids] = turned @ np.transpose(local, (0, 2, 1))
        applied = want
        if rate > 0.0 and last is not None:
            if held is None:
                held = np.tile(np.eye(3), (J, 1, 1))
            turn = np.abs((fr.q[3:] - last[3:] + np.pi) % (2.0 * np.pi) - np.pi)
            most = rate * (float(turn.max()) if len(turn) else 0.0) + SETTLE
            E = Rotation.from_matrix(want @ np.transpose(held, (0, 2, 1))).as_rotvec()
            angle = np.sqrt((E * E).sum(axis=1))
            over = angle > most
            if over.any():
                E[over] *= (most / angle[over])[:, None]
                applied = want.copy()
                applied[over] = Rotation.from_rotvec(E[over]).as_matrix() @ held[over]
        on = np.abs(applied - np.eye(3)).max(axis=(1, 2)) > 1e-9
        # (none held: the next frame starts from none)
        self._held = applied if rate > 0.0 and on.any() else None
        fr.counts["turned"] = int(on.sum())
        if applied is not want:
            # posed again, parents first (the skeleton's order), each joint's
            # local rotation turned by what was applied; each skinning matrix
            # follows its bone
            G, M = fr.G, fr.M
            moved = np.zeros(J, dtype=bool)
            for j in range(J):
                p = par[j]
                if p < 0 or not (on[j] or moved[p]):
                    G[j], M[j] = G_posed[j], M_posed[j]
                    continue
                moved[j] = True
                Lp = np.linalg.inv(G_posed[p]) @ G_posed[j]
                G[j, :3, :3] = G[p, :3, :3] @ applied[j] @ Lp[:3, :3]
                G[j, :3, 3] = G[p, :3, :3] @ Lp[:3, 3] + G[p, :3, 3]
                M[j] = G[j] @ np.linalg.inv(G_posed[j]) @ M_posed[j]
        M = fr.M
        moved = np.any(fr.G != G_posed, axis=(1, 2))
        # the farthest any rest skin moved, carried by its bone as turned
        # against as posed (two turns about one joint, a forearm's and then
        # its hand's, add up)
        far = 0.0
        for j in np.flatnonzero(moved):
            v = self._V0[self._verts[j]]
            D = M[j, :3] - M_posed[j, :3]
            if len(v):
                far = max(far, float(np.sqrt(((v @ D[:, :3].T + D[:, 3]) ** 2)
                                             .sum(axis=1)).max()))
        fr.counts["turn_mm"] = 1e3 * far
        if moved.any():
            s = moved[self._seg_joint]
            j = self._seg_joint[s]
            fr.seg_A[s] = np.einsum("sij,sj->si", M[j, :3, :3], self._segA[s]) + M[j, :3, 3]
            fr.seg_B[s] = np.einsum("sij,sj->si", M[j, :3, :3], self._segB[s]) + M[j, :3, 3]
