"""Untangle: coarse skin's triangles that still pass through another part's
are pushed apart."""
from __future__ import annotations

import math

import numpy as np

from ..kernels.collision import fit_tree
from ..kernels.intersect import SelfIntersections, crossing_pairs, node_parts
from ..kernels.shape import bent_edges
from ..kernels.smoothing import EVEN, gather_weights, laplacian_smooth, ring_layout, vertex_faces
from ..kernels.topology import patches, ring_distance
from ..kernels.untangle import push_apart
from ..metrics import interior_edges, unit_normals
from .base import Frame, Stage
from .turn import pivot

#: Where a round of pushes bent an edge by more than EASE_BEND degrees since
#: the stage began, the push (not the skin) at its four corners is smoothed
#: by EASE_PASSES Laplacian passes: pushes along different triangles' normals
#: creased the hand where it lies on the hip (CesiumMan's walk on automatic
#: weights, every frame: 15 of its 23 sharp folds were the untangle's, none
#: of its 12 with the smoothing; see docs/design.md for what it costs).
EASE_BEND = 45.0
EASE_PASSES = 2
#: Two crossing parts within this factor of each other's size both move
#: (half each) when the rounds leave them crossing; else the smaller alone.
SHARE_SIZE = 1.5
#: The move of a limb left crossing is searched in steps of SHIFT_STEP of
#: its limit (``untangle_shift``), then the last step halved SHIFT_BISECT
#: times.
SHIFT_STEP = 0.1
SHIFT_BISECT = 4
#: A limb is turned about the first joint up its chain far enough that the
#: largest move (``untangle_shift``) turns it by at most MAX_TURN radians.
MAX_TURN = 0.4
#: Two crossing triangles of coarse skin with corners at most CRUMPLE_RINGS
#: rings apart are a crumple (skin that skinning folded through itself at a
#: joint), which :class:`CoarseCrumples` smooths out; crossings further
#: apart are two parts' skins meeting, which the rounds push apart. Every
#: pair the stage left on CesiumMan's file-weighted clips lay within 3 rings.
CRUMPLE_RINGS = 3
#: Skin cannot cross itself a few rings away without folding between: the
#: crumples are searched for within CRUMPLE_RINGS rings of an edge bent by
#: more than CRUMPLE_BEND degrees since rest. From 30 to 90 the search found
#: the same pairs as one from every coarse triangle (CesiumMan's file-weighted
#: punch, walk, run and jumps); at 90 it takes the stage 0.2 ms a frame on
#: automatic weights, which have no crumple, against 1 ms at 45.
CRUMPLE_BEND = 90.0


def _turn(R: np.ndarray, axis: np.ndarray, angle: float) -> np.ndarray:
    """Rows ``R`` turned by ``angle`` radians about unit ``axis`` (Rodrigues)."""
    c, s = math.cos(angle), math.sin(angle)
    return (R * c + np.cross(axis, R) * s
            + np.outer(R @ axis, axis) * (1.0 - c))


def coarse_triangles(character, below: float):
    """``(F, fpart, coarse)``: the triangles (int64), each one's part (that
    of two of its corners, else its first's) and the coarse ones, those of
    the parts whose median vertex resolves its limb less than ``below``
    (:attr:`~skin_node.Character.resolved`, the ``coarse_below`` parameter):
    CesiumMan's, none of the built-in characters' at their default
    resolutions."""
    F = np.ascontiguousarray(character.F, dtype=np.int64)
    part = character.rig.part
    p = part[F]
    fpart = np.ascontiguousarray(np.where(p[:, 1] == p[:, 2], p[:, 1], p[:, 0]))
    # the coarse parts: most of their skin is (a few coarse vertices at a
    # fine limb's knee or hand are the contact's to keep apart)
    J = character.skeleton.n_joints
    coarse = np.array([np.median(character.resolved[part == j]) < below
                       if np.any(part == j) else False for j in range(J)])
    return F, fpart, np.flatnonzero(coarse[fpart])


def coarse_edges(F: np.ndarray, coarse: np.ndarray):
    """``(fa, fb)``: the pairs of triangles that share an edge, one of them
    among ``coarse``."""
    fa, fb, _ = interior_edges(F)
    mask = np.zeros(len(F), dtype=np.bool_)
    mask[coarse] = True
    keep = mask[fa] | mask[fb]
    return fa[keep], fb[keep]


class CoarseCrossings:
    """The exact crossing test of coarse skin's triangles against every
    triangle of another part.

    A triangle's part is that of two of its corners, else its first's; the
    coarse parts are those whose median vertex resolves its limb less than
    ``below`` (:func:`coarse_triangles`: CesiumMan's, none of the built-in
    characters' at their default resolutions), whose triangles
    :attr:`coarse` lists. Falsy when there are none, and then it builds
    nothing."""

    def __init__(self, character, below: float):
        V = character.V
        self.F, self.fpart, self.coarse = coarse_triangles(character, below)
        F = self.F
        # the tree over every triangle that the pair counts search too
        self._si = SelfIntersections(V, F, 0.0) if len(self.coarse) else None
        # each tree node's one part (-1: several): a query skips its own
        # part's subtrees (CesiumMan's walk: the search 2.6 -> 2.2 ms a
        # frame; the same pairs, found in the same order)
        self._npart = node_parts(self._si.tree, self._si.tris, self.fpart) if self._si else None
        self.inq = np.zeros(len(F), dtype=np.bool_)
        self._out = np.empty((1024, 2), dtype=np.int64)

    def __bool__(self) -> bool:
        return self._si is not None

    def near(self, mask: np.ndarray) -> np.ndarray:
        """The coarse triangles with a corner in ``mask`` (n,) bool."""
        return self.coarse[mask[self.F[self.coarse]].any(axis=1)]

    def pairs(self, X: np.ndarray, query: np.ndarray, inq: np.ndarray, full: bool,
              parts: tuple | None = None) -> np.ndarray:
        """The pairs with a triangle of ``query`` (marked in ``inq``), see
        :func:`~skin_node.kernels.intersect.crossing_pairs`; ``full`` refits
        every box, else only those a moved corner grows. ``parts``: each
        triangle's part and each tree node's (:func:`node_parts`) to search
        by instead of the parts' (``fpart``)."""
        fpart, npart = parts if parts is not None else (self.fpart, self._npart)
        si = self._si
        t = si.tree
        fit_tree(X, t, si.fit, full)
        lo, hi, tlo, thi, _ = si.fit
        while True:
            n = crossing_pairs(X, self.F, query, inq, fpart, npart, t.roots, t.child,
                               t.first, t.count, t.slot, si.tris, lo, hi,
                               tlo, thi, self._out)
            if n <= len(self._out):
                return self._out[:n].copy()
            self._out = np.empty((2 * n, 2), dtype=np.int64)

    def crossed(self, X: np.ndarray, query: np.ndarray) -> np.ndarray:
        """The pairs (k, 2) of the triangles ``query`` with another part's,
        every box refit."""
        if not len(query):
            return np.zeros((0, 2), dtype=np.int64)
        self.inq[query] = True
        try:
            return self.pairs(X, query, self.inq, True)
        finally:
            self.inq[query] = False


class CoarseCrumples:
    """Coarse skin folded through itself, smoothed out where that parts it.

    Where a coarse limb's skinning blends its weights over an edge or two
    (CesiumMan's file weights at the shoulders, 40 mm triangles), a bent
    joint folds its skin through itself: triangles a ring or two apart
    cross, and DQS leaves the same crumples. The mush would round them, but
    on skin that coarse a few rings reach across the joint and lose its
    volume (:class:`~skin_node.stages.mush.Mush`). Here only the crumple
    itself moves: the corners of coarse triangles that cross another
    triangle within :data:`CRUMPLE_RINGS` rings (near a fold,
    :data:`CRUMPLE_BEND`) get ``passes`` Laplacian passes of their
    positions, their neighbours held, and each connected patch of them keeps
    the smoothing only where it leaves fewer crossing pairs on its
    triangles (exact tests), else it stays as it was. The volume the
    smoothing takes, inflation (after it) gives back. Falsy where no part
    is coarse (``cross``, whose tree it searches too): it builds nothing
    then."""

    def __init__(self, character, cross: CoarseCrossings):
        self.F, self.coarse, self._cross = cross.F, cross.coarse, cross
        if not cross:
            return
        # every triangle its own part, so the coarse crossing search finds
        # every pair that shares no corner, a part's with itself too
        own = np.arange(len(self.F), dtype=np.int64)
        self._own = (own, node_parts(cross._si.tree, cross._si.tris, own))
        self._inq = np.zeros(len(self.F), dtype=np.bool_)
        r = character.rig
        self._ptr, self._adj, self._w_adj = r.adj_ptr, r.adj, character.edge_weights
        n = len(character.V)
        self._hops = np.full(n, 1 << 30, dtype=np.int64)
        self._queue = np.empty(n, dtype=np.int64)
        self._label = np.full(n, -2, dtype=np.int64)
        self._V0 = np.ascontiguousarray(character.V)
        #: the pairs of triangles sharing an edge, one of them coarse
        self.edges = coarse_edges(self.F, self.coarse)
        self._all, self._hit = np.ones(n, dtype=np.bool_), np.zeros(n, dtype=np.bool_)
        self._bend = math.radians(CRUMPLE_BEND)

    def __bool__(self) -> bool:
        return bool(self._cross)

    def _pairs(self, X: np.ndarray, query: np.ndarray) -> np.ndarray:
        """The crossing pairs (k, 2) with a triangle of ``query``."""
        self._inq[query] = True
        try:
            return self._cross.pairs(X, query, self._inq, True, self._own)
        finally:
            self._inq[query] = False

    def _near(self, f: int, g: int) -> bool:
        """Whether triangles ``f`` and ``g`` have corners within
        :data:`CRUMPLE_RINGS` rings of each other."""
        hops, queue = self._hops, self._queue
        reached = ring_distance(self.F[f], self._ptr, self._adj, hops, CRUMPLE_RINGS + 1, queue)
        near = bool((hops[self.F[g]] <= CRUMPLE_RINGS).any())
        hops[queue[:reached]] = 1 << 30
        return near

    def _by_patch(self, P: np.ndarray, m: int) -> np.ndarray:
        """(m,) how many pairs of ``P`` have a triangle with a corner in each
        patch (``self._label``)."""
        count = np.zeros(m, dtype=np.int64)
        for row in self._label[self.F[P]].reshape(len(P), 6):
            count[np.unique(row[row >= 0])] += 1
        return count

    def _folded(self, X: np.ndarray) -> np.ndarray:
        """The coarse triangles within :data:`CRUMPLE_RINGS` rings of an edge
        bent more than :data:`CRUMPLE_BEND` degrees since rest: skin
        cannot cross itself a few rings away without folding somewhere
        between."""
        hit = self._hit
        if not bent_edges(X, self._V0, self.F, *self.edges, self._all, self._bend, hit):
            return self.coarse[:0]
        src = np.flatnonzero(hit)
        hit[src] = False
        hops, queue = self._hops, self._queue
        reached = ring_distance(src, self._ptr, self._adj, hops, CRUMPLE_RINGS + 1, queue)
        near = queue[:reached]
        hit[near] = True
        query = self.coarse[hit[self.F[self.coarse]].any(axis=1)]
        hit[near] = False
        hops[near] = 1 << 30
        return query

    def __call__(self, X: np.ndarray, passes: int) -> int:
        """Smooths the crumples of ``X`` in place; returns how many vertices
        moved."""
        query = self._folded(X)
        if not len(query):
            return 0
        P = self._pairs(X, query)
        P = P[[self._near(f, g) for f, g in P]] if len(P) else P
        if not len(P):
            return 0
        zone = np.unique(self.F[P].ravel())
        label = self._label
        label[zone] = -1
        m = patches(zone, self._ptr, self._adj, label, self._queue)
        # the triangles the smoothing moves: the pairs counted on each patch
        query = np.flatnonzero((label[self.F] >= 0).any(axis=1))
        before = self._by_patch(self._pairs(X, query), m)
        start = X[zone]
        ring, loc, lptr, lnbr = ring_layout(zone, self._ptr, self._adj)
        lw = gather_weights(zone, self._ptr, self._w_adj, lptr)
        laplacian_smooth(X, X, False, ring, loc, lptr, lnbr, lw, 0.5, EVEN, passes,
                         np.empty((len(ring), 3)), np.empty((len(zone), 3)))
        after = self._by_patch(self._pairs(X, query), m)
        undo = (after >= before)[label[zone]]
        X[zone[undo]] = start[undo]
        label[zone] = -2
        return int(len(zone) - undo.sum())


class LimbTurn:
    """A coarse limb that passes through another part turned out of it
    about a joint up its chain, with the skin its bones carry.

    Where two parts' skin still crosses after the stages that move vertices
    (flesh through flesh that 40 mm triangles cannot show as a dent: the
    retargeted walk drives CesiumMan's hand 20-37 mm into its hip, the
    punch its two fists into each other), the smaller part turns (both,
    half each, within SHARE_SIZE of each other's size) about the first
    joint up its chain ``untangle_shift`` / MAX_TURN limb radii from where
    it crosses (a hand: about the elbow), never above the limb's top (the
    shoulder, the hip) and never a limb's top part itself, away from the
    other part's triangles, by the least move that leaves no pair of the
    two and no new pair of anything, a turn moving no skin further than
    ``untangle_shift`` of its limb radii (skin to bone at rest: a move in
    mean edges let RiggedFigure's 100 mm-edged limbs swing 40 cm between
    two frames); where no such move parts them the limb stays. The
    skeleton is not changed: the pose's bones stay where the mocap put
    them, and the skin of that limb stands off them (the benchmark's bulge
    sees it). The untangle turns what its pushes leave, inflation what its
    layers run through (see docs/design.md).

    Parameters
    ----------
    character, weights : the character and the skin weights its pipeline uses.
    cross : :class:`CoarseCrossings` whose triangles it tests.
    params : the pipeline's live parameters (``untangle_shift``).
    count : the frame's count of limbs turned.
    """

    def __init__(self, character, weights, cross: CoarseCrossings, params: dict,
                 count: str = "untangle_turned") -> None:
        self.weights, self.params, self.count = weights, params, count
        self._cross, self.F = cross, cross.F
        sk = character.skeleton
        self._parents, self._below = sk.parents, sk.subtree()
        self._kids = np.bincount(sk.parents[1:], minlength=sk.n_joints)
        part = character.rig.part
        J = sk.n_joints
        # each part's size at rest: the larger of two crossing parts stays
        self._size = np.array([np.ptp(character.V[part == j], axis=0).max()
                               if np.any(part == j) else 0.0 for j in range(J)])
        # each part's limb radius (skin to bone at rest): the turn's unit
        radius = character.nearest_segments[1][:, 0]
        self._radius = np.array([np.median(radius[part == j])
                                 if np.any(part == j) else 0.0 for j in range(J)])
        self._carry = {}
        self._mask = np.zeros(len(character.V), dtype=np.bool_)
        self._in2 = np.zeros(len(self.F), dtype=np.bool_)

    def _carried(self, j: int) -> tuple[np.ndarray, np.ndarray]:
        """The vertices bone ``j`` or a bone below it moves, and by how much
        (the sum of those bones' weights): what moves with the bone."""
        if j not in self._carry:
            w = self.weights
            s = (w.Wval * self._below[j][w.Widx]).sum(axis=1)
            v = np.flatnonzero(s > 1e-6)
            self._carry[j] = (v, s[v][:, None])
        return self._carry[j]

    def _movers(self, a: int, b: int) -> tuple:
        """Which of crossing parts ``a`` and ``b`` move, with their share of
        the move (the second of two moves the opposite way): the smaller, alone,
        unless the two are within SHARE_SIZE of each other's size (both,
        half each). A part never moves out of its parent or out of a part
        it carries."""
        par, below, kids = self._parents, self._below, self._kids

        def free(j, other):
            # not the root nor a limb's top part (whose parent branches):
            # turning an upper arm out of the hip moves the hand twice as far
            return (par[j] > 0 and kids[par[j]] == 1 and par[j] != other
                    and not below[j, other])

        sa, sb = self._size[a], self._size[b]
        if max(sa, sb) <= SHARE_SIZE * min(sa, sb) and free(a, b) and free(b, a):
            return ((a, 0.5), (b, -0.5))
        j, other = (a, b) if sa <= sb else (b, a)
        return ((j, 1.0),) if free(j, other) else ()

    def _pivot(self, j: int, others: np.ndarray, c: np.ndarray, reach: float,
               G: np.ndarray):
        """The joint part ``j``'s skin turns about to move its point ``c``:
        the first up its chain from ``j`` at least ``reach`` from ``c``,
        climbing no higher than the top of the limb (the joint whose parent
        branches: a shoulder, a hip) and never to a joint that carries one
        of the parts ``others``; None when ``j`` itself carries one."""
        if self._parents[j] < 0 or self._below[j, others].any():
            return None
        return pivot(self._parents, self._kids, self._below, j, others, c, reach, G)

    def _turns(self, X: np.ndarray, G: np.ndarray, movers: tuple, sel: np.ndarray,
               span: float):
        """How the ``movers`` of crossing pairs ``sel`` turn: per mover
        ``(k, o, axis, per, gain)``, turned about joint ``k`` at ``o`` by
        ``per`` radians for each metre the two sides part (its crossing
        triangles' centre moves its share of it along ``d``, the way the
        first moves: out of the other side's triangles and away from its
        own, their outward normals' means the one's minus the other's; the
        second the other way), the farthest skin it carries moving ``gain``
        metres a metre. None when one of them cannot turn."""
        F, fpart = self.F, self._cross.fpart
        mine = fpart[sel[:, 0]] == movers[0][0]
        sides = (np.where(mine, sel[:, 0], sel[:, 1]), np.where(mine, sel[:, 1], sel[:, 0]))
        own, other = (unit_normals(X, F[t]).mean(axis=0) for t in sides)
        d = other - own
        nd = np.linalg.norm(d)
        if nd < 1e-12:
            return None
        d /= nd
        turns = []
        for m, (j, share) in enumerate(movers):
            c = X[F[sides[m]]].reshape(-1, 3).mean(axis=0)
            k = self._pivot(j, np.unique(fpart[sides[1 - m]]), c, span / MAX_TURN, G)
            if k is None:
                return None
            o = G[k, :3, 3]
            axis = np.cross(c - o, d)
            lever = np.linalg.norm(axis)        # |c - o| times the sine
            if lever < 1e-9:
                return None                     # d runs along the limb
            axis *= math.copysign(1.0 / lever, share)
            v, w = self._carried(k)
            far = float((w[:, 0] * np.linalg.norm(np.cross(axis, X[v] - o), axis=1)).max())
            turns.append((k, o, axis, abs(share) / lever, abs(share) * far / lever))
        return turns

    def _least_turn(self, X: np.ndarray, turns: list, keys: np.ndarray, span: float) -> float:
        """Turn ``turns`` by the least move that parts the pairs of the parts
        ``keys`` (``a * J + b``, ``a < b``) and crosses nothing new, moving
        no skin further than ``span``; returns that move (0: none parts
        them, and ``X`` is as it was)."""
        F, fpart, J = self.F, self._cross.fpart, len(self._parents)
        verts = np.unique(np.concatenate([self._carried(k)[0] for k, *_ in turns]))
        mask = self._mask
        mask[:] = False
        mask[verts] = True
        query = np.flatnonzero(mask[F].any(axis=1))
        base = X[verts].copy()

        def place(t):
            X[verts] = base
            for k, o, axis, per, _ in turns:
                v, w = self._carried(k)
                X[v] += w * (_turn(X[v] - o, axis, t * per) - (X[v] - o))
            got = self._cross.pairs(X, query, self._in2, True)
            ab = np.sort(fpart[got], axis=1)
            return len(got), int(np.isin(ab[:, 0] * J + ab[:, 1], keys).sum())

        def parted(t):
            n_all, n_ab = place(t)
            return n_ab == 0 and n_all <= enough

        self._in2[query] = True
        try:
            before, crossing = place(0.0)
            enough = before - crossing
            if not crossing:
                return 0.0          # parted by a move before
            top = span / max(gain for *_, gain in turns)
            step, lo = SHIFT_STEP * span, 0.0
            for t in np.arange(1, int(top / step) + 1) * step:
                if parted(t):
                    # the least move that parts them: halve the last step
                    hi = t
                    for _ in range(SHIFT_BISECT):
                        mid = 0.5 * (lo + hi)
                        lo, hi = (lo, mid) if parted(mid) else (mid, hi)
                    place(hi)
                    return hi
                lo = t
            place(0.0)
            return 0.0
        finally:
            self._in2[query] = False

    def __call__(self, X: np.ndarray, P: np.ndarray, fr: Frame) -> None:
        """The limbs of crossing pairs ``P`` (coarse triangles, each with
        another part's) turned out of the other part where a turn parts
        them; ``X`` changes in place."""
        limit = float(self.params["untangle_shift"])
        if limit <= 0.0 or not len(P):
            return
        fpart, J = self._cross.fpart, len(self._parents)
        ab = np.sort(fpart[P], axis=1)
        groups = {}
        for i, (a, b) in enumerate(ab):
            movers = self._movers(int(a), int(b))
            if movers:
                groups.setdefault(movers, []).append(i)
        for movers, rows in sorted(groups.items(), key=lambda g: -len(g[1])):
            span = limit * min(self._radius[j] for j, _ in movers)
            turns = self._turns(X, fr.G, movers, P[rows], span)
            if turns is None:
                continue
            keys = np.unique(ab[rows, 0] * J + ab[rows, 1])
            t = self._least_turn(X, turns, keys, span)
            if t > 0.0:
                fr.counts[self.count] = fr.counts.get(self.count, 0) + 1
                fr.touched.append(np.unique(self.F[P[rows]]))


class Untangle(Stage):
    """Triangles of two parts that pass through each other, on coarse skin,
    are pushed apart.

    The contact moves vertices out of the other parts' flesh. On a coarse
    mesh (CesiumMan's 40 mm edges around 40 mm limbs) a triangle's edge can
    run through another part's triangle while every vertex of both stays
    outside the other's flesh, and where one side of a contact has no
    vertex there is nothing for it to move. Here the triangles of coarse
    parts (:func:`coarse_triangles`: a part's median vertex resolves its
    limb less than ``coarse_below``; none on the built-in characters at
    their default resolutions) near a contact (a corner the
    contact moved, or within ``untangle_reach`` mean edges of another
    part's flesh: :attr:`~skin_node.stages.base.Frame.clearance`) are
    tested exactly against every triangle of another part
    (:func:`~skin_node.kernels.intersect.crossing_pairs`), and the pairs that
    meet are parted (:func:`~skin_node.kernels.untangle.push_apart`): each
    triangle's corners behind the other's plane, by less than
    ``untangle_depth`` mean edges, go to ``untangle_gap`` mean edges in
    front of it, half the way each, and their unpushed neighbours go
    ``untangle_spread`` of the way with them (a 40 mm triangle's corner
    pushed alone crossed the triangles around it: CesiumMan's walk on
    automatic weights, every 4th frame, 301 pairs alone, 180 with half), and
    where a round bent an edge past ``EASE_BEND`` degrees the push at its
    corners is smoothed, for up
    to ``untangle_rounds`` rounds while pairs remain and each round leaves
    fewer (a round that does not is tried again at half its move, then
    taken back). Skin near no contact, or
    fine, is not tested. The vertices it pushed join the frame's skin in
    contact
    (:attr:`~skin_node.stages.base.Frame.touched`), so inflation does not
    swell them back through (the punch on automatic weights kept 1,089
    pairs instead of 639).

    What the rounds leave is flesh through flesh the skin cannot show as a
    dent: there the limb is turned out of the other part
    (:class:`LimbTurn`), where a turn parts them. Last, coarse skin that
    skinning folded through itself at a joint, contact or none, is smoothed
    out where that parts it (:class:`CoarseCrumples`, ``untangle_unfold``).

    The exact test is the one that counts the intersecting pairs
    :mod:`skin_node.bench` reports, so those counts do not grade this stage
    alone: sharp folds, roughness, the joints' volumes and the z-buffer
    pictures do.
    """

    name = "untangle"

    def __init__(self, character, params):
        super().__init__(character, params)
        self._cross = CoarseCrossings(character, float(params["coarse_below"]))
        self.F, self.coarse = self._cross.F, self._cross.coarse
        self._edge = character.mean_edges
        self._crumples = CoarseCrumples(character, self._cross)
        if not self._cross:
            return          # nothing coarse: the stage tests nothing
        n, m = len(character.V), len(self.F)
        self._inq = self._cross.inq
        self._in2 = np.zeros(m, dtype=np.bool_)
        self._vf_ptr, self._vf = vertex_faces(self.F, n)
        self._ptr, self._adj = character.rig.adj_ptr, character.rig.adj
        self._efaces = self._crumples.edges
        self._moved, self._hit = np.zeros(n, dtype=np.bool_), np.zeros(n, dtype=np.bool_)
        self._near = np.zeros(n, dtype=np.bool_)
        self._disp, self._count = np.zeros((n, 3)), np.zeros(n, dtype=np.int64)
        self._touched = np.empty(n, dtype=np.int64)
        self._turn = LimbTurn(character, self.weights, self._cross, params)

    def _query(self, fr: Frame) -> np.ndarray:
        """The coarse triangles near a contact this frame."""
        near = self._near
        near[:] = False
        if fr.clearance is not None:
            near |= fr.clearance < float(self.params["untangle_reach"]) * self._edge
        for t in fr.touched:
            near[t] = True
        return self._cross.near(near)

    def _again(self, X: np.ndarray, P: np.ndarray, moved: np.ndarray) -> np.ndarray:
        """The pairs after a push that moved vertices ``moved``: those of ``P``
        with no corner among them stand; the triangles around them are
        tested again (pairs with none of this frame's query dropped)."""
        around = np.unique(np.concatenate(
            [self._vf[self._vf_ptr[v]:self._vf_ptr[v + 1]] for v in moved]))
        self._in2[around] = True
        new = self._cross.pairs(X, around, self._in2, False)
        stand = P[~(self._in2[P[:, 0]] | self._in2[P[:, 1]])]
        self._in2[around] = False
        new = new[self._inq[new[:, 0]] | self._inq[new[:, 1]]]
        return np.concatenate([stand, new])

    def _ease(self, X: np.ndarray, start: np.ndarray, moved: np.ndarray) -> np.ndarray:
        """Where the round that moved ``moved`` left an edge bent by more than
        EASE_BEND degrees since ``start``, the push at its corners smoothed;
        returns every vertex the round moved, those included."""
        self._moved[moved] = True
        bent_edges(X, start, self.F, *self._efaces, self._moved, math.radians(EASE_BEND),
                   self._hit)
        self._moved[moved] = False
        zone = np.flatnonzero(self._hit)
        if not len(zone):
            return moved
        self._hit[zone] = False
        ring, loc, lptr, lnbr = ring_layout(zone, self._ptr, self._adj)
        laplacian_smooth(X, start, True, ring, loc, lptr, lnbr, EVEN, 0.5, EVEN, EASE_PASSES,
                         np.empty((len(ring), 3)), np.empty((len(loc), 3)))
        return np.union1d(moved, zone)

    def __call__(self, fr: Frame) -> None:
        if not self._cross:
            return
        self._untangle(fr)
        unfold = int(self.params["untangle_unfold"])
        fr.counts["untangle_unfolded"] = self._crumples(fr.surface, unfold) if unfold else 0

    def _untangle(self, fr: Frame) -> None:
        """The rounds of pushes, then the turns of limbs left crossing."""
        query = self._query(fr)
        fr.counts["untangle_pairs"] = fr.counts["untangle_moves"] = 0
        fr.counts["untangle_spread"] = fr.counts["untangle_turned"] = 0
        if not len(query):
            return
        X = fr.surface
        gap = float(self.params["untangle_gap"]) * self._edge
        depth = float(self.params["untangle_depth"]) * self._edge
        spread = float(self.params["untangle_spread"])
        self._inq[query] = True
        parted = []
        P = self._cross.pairs(X, query, self._inq, True)
        fr.counts["untangle_pairs"] += len(P)
        start = X.copy()
        for _ in range(int(self.params["untangle_rounds"])):
            if not len(P):
                break
            before = X.copy()
            pushed, moved = push_apart(X, self.F, P, gap, depth, spread, self._ptr,
                                       self._adj, self._disp, self._count, self._touched)
            if not moved:
                break
            eased = self._ease(X, start, self._touched[:moved].copy())
            after = self._again(X, P, eased)
            if len(after) >= len(P):
                # half the move first: the file-weighted CesiumMan's armpit
                # went 46 -> 50 pairs at the full move, 50 -> 3 at the end
                # of the stage with the half (docs/design.md)
                X[:] = 0.5 * (before + X)
                after = self._again(X, P, eased)
            if len(after) >= len(P):
                # pushing made it no better (flesh through flesh: two hands
                # pushed through each other crumpled): take the round back
                X[:] = before
                break
            fr.counts["untangle_moves"] += pushed
            fr.counts["untangle_spread"] += moved - pushed
            parted.append(self._touched[:pushed].copy())
            P = after
        self._inq[query] = False
        self._turn(X, P, fr)
        if parted:
            fr.touched.append(np.unique(np.concatenate(parted)))
