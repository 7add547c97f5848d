"""Exact triangle-triangle intersections of a surface with itself (numba).

An independent check of the collision stage: its crossing test asks whether a
vertex sits behind the skin nearest to it, which is how it finds what to move;
this asks the geometric question directly, for every pair of triangles.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from .collision import fit_tree, tree_fit, triangle_trees


@nb.njit(cache=True, nogil=True, inline="always")
def _normal(X, i0, i1, i2):
    """(X[i1] - X[i0]) x (X[i2] - X[i0]): the unnormalised normal of a triangle."""
    ux, uy, uz = X[i1, 0] - X[i0, 0], X[i1, 1] - X[i0, 1], X[i1, 2] - X[i0, 2]
    vx, vy, vz = X[i2, 0] - X[i0, 0], X[i2, 1] - X[i0, 1], X[i2, 2] - X[i0, 2]
    return uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx


@nb.njit(cache=True, nogil=True, inline="always")
def _side(X, n, a, p):
    """n . (X[p] - X[a]): which side of the plane through ``X[a]`` with normal
    ``n`` point ``p`` is on."""
    return (n[0] * (X[p, 0] - X[a, 0]) + n[1] * (X[p, 1] - X[a, 1])
            + n[2] * (X[p, 2] - X[a, 2]))


@nb.njit(cache=True, nogil=True)
def _span(p0, p1, p2, d0, d1, d2):
    """Where a triangle meets the other one's plane, as an interval of the
    projections ``p`` of its corners onto the planes' common line, from the
    corners' signed distances ``d`` to that plane (not all of one sign)."""
    # the corner alone on its side of the plane, and the other two
    if d0 * d1 > 0.0:
        a, b, c, da, db, dc = p2, p0, p1, d2, d0, d1
    elif d0 * d2 > 0.0:
        a, b, c, da, db, dc = p1, p0, p2, d1, d0, d2
    elif d1 * d2 > 0.0 or d0 != 0.0:
        a, b, c, da, db, dc = p0, p1, p2, d0, d1, d2
    elif d1 != 0.0:
        a, b, c, da, db, dc = p1, p0, p2, d1, d0, d2
    else:
        a, b, c, da, db, dc = p2, p0, p1, d2, d0, d1
    t1 = a + (b - a) * da / (da - db) if da != db else b
    t2 = a + (c - a) * da / (da - dc) if da != dc else c
    return min(t1, t2), max(t1, t2)


@nb.njit(cache=True, nogil=True)
def triangles_intersect(X, i0, i1, i2, j0, j1, j2):
    """Whether triangles ``X[i0, i1, i2]`` and ``X[j0, j1, j2]`` meet (Moller
    1997, "A fast triangle-triangle intersection test"). Coplanar pairs count
    as apart: skin lying flat on skin has not passed through it."""
    n2 = _normal(X, j0, j1, j2)
    a0, a1, a2 = _side(X, n2, j0, i0), _side(X, n2, j0, i1), _side(X, n2, j0, i2)
    if (a0 > 0.0 and a1 > 0.0 and a2 > 0.0) or (a0 < 0.0 and a1 < 0.0 and a2 < 0.0):
        return False
    if a0 == 0.0 and a1 == 0.0 and a2 == 0.0:
        return False
    n1 = _normal(X, i0, i1, i2)
    b0, b1, b2 = _side(X, n1, i0, j0), _side(X, n1, i0, j1), _side(X, n1, i0, j2)
    if (b0 > 0.0 and b1 > 0.0 and b2 > 0.0) or (b0 < 0.0 and b1 < 0.0 and b2 < 0.0):
        return False
    # the planes' common line runs along n1 x n2: project onto its largest axis
    lx = abs(n1[1] * n2[2] - n1[2] * n2[1])
    ly = abs(n1[2] * n2[0] - n1[0] * n2[2])
    lz = abs(n1[0] * n2[1] - n1[1] * n2[0])
    ax = 0 if lx >= ly and lx >= lz else (1 if ly >= lz else 2)
    s0, s1 = _span(X[i0, ax], X[i1, ax], X[i2, ax], a0, a1, a2)
    t0, t1 = _span(X[j0, ax], X[j1, ax], X[j2, ax], b0, b1, b2)
    return s0 <= t1 and t0 <= s1


@nb.njit(cache=True, nogil=True, inline="always")
def meets_apart(X, F, i0, i1, i2, g):
    """Whether triangle ``g`` of ``F`` shares no corner with triangle
    ``X[i0, i1, i2]`` and meets it (:func:`triangles_intersect`)."""
    j0, j1, j2 = F[g, 0], F[g, 1], F[g, 2]
    if (i0 == j0 or i0 == j1 or i0 == j2 or i1 == j0 or i1 == j1 or i1 == j2
            or i2 == j0 or i2 == j1 or i2 == j2):
        return False
    return triangles_intersect(X, i0, i1, i2, j0, j1, j2)


@nb.njit(cache=True, nogil=True)
def crossing_pairs(X, F, query, inq, fpart, npart, roots, child, first, count, slot, tris,
                   lo, hi, tlo, thi, out):
    """Pairs of triangles that intersect in ``X`` (exactly), one of them from
    ``query``, of two different parts (``fpart``) and sharing no corner, each
    once, found through a bounding-volume tree over all of them
    (:func:`~skin_node.kernels.collision.triangle_trees` over ``tris``,
    boxes fit to ``X``); ``inq[f]`` marks the query triangles (a pair of two
    is written from its lower one's side). Every triangle a query and its
    own part: all intersecting pairs, lower first. ``npart`` (one per tree
    node, :func:`node_parts`): the one part of every triangle under a node
    (-1: several), so a query skips its own part's subtrees without
    changing what it finds or the order it finds it in. Writes up to
    len(out) pairs (face ids) into ``out``; returns how many there are."""
    n = 0
    stack = np.empty(128, dtype=np.int64)
    for k in range(query.shape[0]):
        f = query[k]
        i0, i1, i2 = F[f, 0], F[f, 1], F[f, 2]
        bl0 = min(X[i0, 0], X[i1, 0], X[i2, 0])
        bl1 = min(X[i0, 1], X[i1, 1], X[i2, 1])
        bl2 = min(X[i0, 2], X[i1, 2], X[i2, 2])
        bh0 = max(X[i0, 0], X[i1, 0], X[i2, 0])
        bh1 = max(X[i0, 1], X[i1, 1], X[i2, 1])
        bh2 = max(X[i0, 2], X[i1, 2], X[i2, 2])
        for r in range(roots.shape[0]):
            if roots[r] < 0:
                continue
            stack[0] = roots[r]
            top = 1
            while top > 0:
                top -= 1
                nd = stack[top]
                if (lo[nd, 0] > bh0 or hi[nd, 0] < bl0 or lo[nd, 1] > bh1 or hi[nd, 1] < bl1
                        or lo[nd, 2] > bh2 or hi[nd, 2] < bl2 or npart[nd] == fpart[f]):
                    continue
                if child[nd, 0] >= 0:
                    stack[top], stack[top + 1] = child[nd, 0], child[nd, 1]
                    top += 2
                    continue
                for q in range(first[nd], first[nd] + count[nd]):
                    g = tris[slot[q]]
                    if fpart[g] == fpart[f] or (inq[g] and g < f):
                        continue
                    if (tlo[q, 0] > bh0 or thi[q, 0] < bl0 or tlo[q, 1] > bh1
                            or thi[q, 1] < bl1 or tlo[q, 2] > bh2 or thi[q, 2] < bl2):
                        continue
                    if meets_apart(X, F, i0, i1, i2, g):
                        if n < out.shape[0]:
                            out[n, 0], out[n, 1] = f, g
                        n += 1
    return n


def node_parts(tree, tris: np.ndarray, fpart: np.ndarray) -> np.ndarray:
    """(nodes,) int64: for every node of ``tree``
    (:func:`~skin_node.kernels.collision.triangle_trees` over ``tris``) the
    part (``fpart``, one per triangle) of all the triangles under it, -1
    where they are of several (children come after their parent: filled
    backwards)."""
    child, first, count = tree.child, tree.first, tree.count
    out = np.full(len(child), -1, dtype=np.int64)
    tp = np.asarray(fpart, dtype=np.int64)[np.asarray(tris)[tree.slot]]
    for nd in range(len(child) - 1, -1, -1):
        a, b = child[nd]
        if a < 0:
            p = tp[first[nd]:first[nd] + count[nd]]
            if len(p) and (p == p[0]).all():
                out[nd] = p[0]
        elif out[a] >= 0 and out[a] == out[b]:
            out[nd] = out[a]
    return out


class SelfIntersections:
    """Counts the pairs of a surface's triangles that pass through each other.

    Pairs that share a corner are not tested (neighbours meet along their
    shared edge or corner). A pair whose triangles were more than ``apart``
    from each other at rest (centre to centre) is skin through skin: two
    parts of the surface that cross; a nearer one is the surface crumpling
    over itself, folding a few triangles through their neighbours.

    Parameters
    ----------
    V0 : (n, 3) rest surface, F : (m, 3) its triangles, apart : metres.
    """

    def __init__(self, V0: np.ndarray, F: np.ndarray, apart: float) -> None:
        self.F = np.ascontiguousarray(F, dtype=np.int64)
        self.tris = np.arange(len(F), dtype=np.int64)
        # every triangle a query, and a part of its own (crossing_pairs)
        self._every = np.ones(len(F), dtype=np.bool_)
        self.tree = triangle_trees(V0, self.F, self.tris, np.zeros(len(F), dtype=np.int64))
        self.fit = tree_fit(self.tree)
        self._mixed = np.full(len(self.tree.child), -1, dtype=np.int64)   # no part skipped
        self.centre0 = V0[self.F].mean(axis=1)
        self.apart = float(apart)
        self._out = np.empty((4096, 2), dtype=np.int64)

    def pairs(self, X: np.ndarray) -> np.ndarray:
        """(k, 2) the intersecting pairs' face ids in ``X``."""
        X = np.ascontiguousarray(X, dtype=np.float64)
        fit_tree(X, self.tree, self.fit, True)
        t = self.tree
        lo, hi, tlo, thi, _ = self.fit
        while True:
            n = crossing_pairs(X, self.F, self.tris, self._every, self.tris, self._mixed,
                               t.roots, t.child, t.first, t.count, t.slot, self.tris, lo, hi,
                               tlo, thi, self._out)
            if n <= len(self._out):
                return self._out[:n].copy()
            self._out = np.empty((2 * n, 2), dtype=np.int64)

    def through(self, pairs: np.ndarray) -> np.ndarray:
        """(k,) bool: which of ``pairs`` (:meth:`pairs`) are skin through skin."""
        d = np.linalg.norm(self.centre0[pairs[:, 0]] - self.centre0[pairs[:, 1]], axis=1)
        return d >= self.apart

    def __call__(self, X: np.ndarray) -> tuple[int, int]:
        """(skin-through-skin pairs, crumpled pairs) in ``X``."""
        p = self.pairs(X)
        through = int(np.count_nonzero(self.through(p)))
        return through, len(p) - through
