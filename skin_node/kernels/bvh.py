"""A static bounding-volume tree over a triangle mesh, and the queries set-up
needs of it: closest point, segment hits and inside/outside (numba).

Built once per rest mesh (rig building, field grids, visibility of bones); the
per-frame stages never query it.
"""
from __future__ import annotations

from typing import NamedTuple

import numba as nb
import numpy as np

from .collision import _box_near2, _closest_on_triangle

#: Triangles per leaf.
LEAF = 8


class MeshTree(NamedTuple):
    """A tree over the triangles ``F`` of vertices ``V`` (see :func:`mesh_tree`).

    ``lo, hi`` (m, 3) node boxes; ``child`` (m, 2), -1 for a leaf; ``first,
    count`` (m,) a leaf's range in ``order`` (triangle ids, leaf order).
    """

    V: np.ndarray
    F: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    child: np.ndarray
    first: np.ndarray
    count: np.ndarray
    order: np.ndarray


def mesh_tree(V: np.ndarray, F: np.ndarray) -> MeshTree:
    """Median-split tree over the triangles ``F`` (m, 3) of ``V`` (n, 3)."""
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    tri = V[F]
    tlo, thi, cen = tri.min(1), tri.max(1), tri.mean(1)
    child, first, count, order = [], [], [], []
    lo, hi = [], []
    stack = [(np.arange(len(F)), -1, 0)]
    # iterative, children after parents
    while stack:
        idx, parent, which = stack.pop()
        node = len(child)
        child.append([-1, -1])
        first.append(0)
        count.append(0)
        lo.append(tlo[idx].min(0) if len(idx) else np.zeros(3))
        hi.append(thi[idx].max(0) if len(idx) else np.zeros(3))
        if parent >= 0:
            child[parent][which] = node
        if len(idx) <= LEAF:
            first[node], count[node] = len(order), len(idx)
            order.extend(idx.tolist())
            continue
        c = cen[idx]
        axis = int(np.argmax(c.max(0) - c.min(0)))
        s = idx[np.argsort(c[:, axis], kind="stable")]
        h = len(s) // 2
        stack.append((s[h:], node, 1))
        stack.append((s[:h], node, 0))
    return MeshTree(V=V, F=F, lo=np.array(lo), hi=np.array(hi),
                    child=np.array(child, dtype=np.int64).reshape(-1, 2),
                    first=np.array(first, dtype=np.int64), count=np.array(count, dtype=np.int64),
                    order=np.array(order, dtype=np.int64))


@nb.njit(cache=True, nogil=True)
def closest_points(P, V, F, lo, hi, child, first, count, order, bound, dist, C, face):
    """Unsigned distance ``dist`` (k,) and closest surface point ``C`` (k, 3) of
    every point ``P`` (k, 3) and its triangle ``face`` (left as it was where
    no triangle beats ``bound``), nearest child first; ``bound`` (k,) is an
    upper bound of each distance (the nearest vertex's, say) that prunes the
    search."""
    stack = np.empty(128, dtype=np.int64)
    for i in range(P.shape[0]):
        p = P[i]
        best = bound[i] * bound[i] * (1.0 + 1e-9) + 1e-30
        top = 1
        stack[0] = 0
        while top > 0:
            top -= 1
            nd = stack[top]
            if _box_near2(p[0], p[1], p[2], lo, hi, nd) >= best:
                continue
            if child[nd, 0] < 0:
                for q in range(first[nd], first[nd] + count[nd]):
                    f = order[q]
                    a, b, c = F[f, 0], F[f, 1], F[f, 2]
                    x, y, z, _ = _closest_on_triangle(
                        p[0], p[1], p[2], V[a, 0], V[a, 1], V[a, 2], V[b, 0], V[b, 1], V[b, 2],
                        V[c, 0], V[c, 1], V[c, 2])
                    d = (x - p[0]) ** 2 + (y - p[1]) ** 2 + (z - p[2]) ** 2
                    if d < best:
                        best = d
                        C[i, 0], C[i, 1], C[i, 2] = x, y, z
                        face[i] = f
                continue
            a, b = child[nd, 0], child[nd, 1]
            da = _box_near2(p[0], p[1], p[2], lo, hi, a)
            db = _box_near2(p[0], p[1], p[2], lo, hi, b)
            if da < db:
                a, b = b, a
            stack[top], stack[top + 1] = a, b       # the nearer one on top
            top += 2
        dist[i] = np.sqrt(best)


@nb.njit(cache=True, nogil=True)
def _segment_triangle(p, q, a, b, c):
    """Whether the segment ``p``-``q`` passes through triangle ``abc``
    (Moller-Trumbore, the segment's ends excluded)."""
    d = q - p
    e1, e2 = b - a, c - a
    h = np.cross(d, e2)
    det = e1 @ h
    if abs(det) < 1e-300:
        return False
    s = p - a
    u = (s @ h) / det
    if u < 0.0 or u > 1.0:
        return False
    qv = np.cross(s, e1)
    v = (d @ qv) / det
    if v < 0.0 or u + v > 1.0:
        return False
    t = (e2 @ qv) / det
    return 0.0 < t < 1.0


@nb.njit(cache=True, nogil=True)
def _segment_box(p, q, lo, hi):
    """Slab test: whether segment ``p``-``q`` meets the box."""
    t0, t1 = 0.0, 1.0
    for k in range(3):
        d = q[k] - p[k]
        if abs(d) < 1e-300:
            if p[k] < lo[k] or p[k] > hi[k]:
                return False
            continue
        a, b = (lo[k] - p[k]) / d, (hi[k] - p[k]) / d
        if a > b:
            a, b = b, a
        t0, t1 = max(t0, a), min(t1, b)
        if t0 > t1:
            return False
    return True


@nb.njit(cache=True, nogil=True)
def segment_crossings(P, Q, V, F, lo, hi, child, first, count, order, skip, out):
    """``out[i]``: how many triangles segment ``P[i]``-``Q[i]`` passes through,
    ignoring triangles with a corner at vertex ``skip[i]`` (-1: none)."""
    stack = np.empty(128, dtype=np.int64)
    for i in range(P.shape[0]):
        p, q = P[i], Q[i]
        n = 0
        top = 1
        stack[0] = 0
        while top > 0:
            top -= 1
            nd = stack[top]
            if not _segment_box(p, q, lo[nd], hi[nd]):
                continue
            if child[nd, 0] >= 0:
                stack[top], stack[top + 1] = child[nd, 0], child[nd, 1]
                top += 2
                continue
            for r in range(first[nd], first[nd] + count[nd]):
                f = order[r]
                s = skip[i]
                if F[f, 0] == s or F[f, 1] == s or F[f, 2] == s:
                    continue
                if _segment_triangle(p, q, V[F[f, 0]], V[F[f, 1]], V[F[f, 2]]):
                    n += 1
        out[i] = n


def closest(tree: MeshTree, P: np.ndarray, band: float = np.inf):
    """(k,) unsigned distances, (k, 3) closest points of ``P`` on the mesh
    and (k,) their triangles (-1 where the closest point is the nearest
    vertex, (k,) ``vertex``); points whose nearest vertex is further than
    ``band`` keep that vertex (off by at most an edge, where the exact answer
    is seldom wanted). Returns ``dist, C, face, vertex``."""
    from scipy.spatial import cKDTree            # deferred: set-up only
    P = np.ascontiguousarray(P, dtype=np.float64)
    d, C = np.empty(len(P)), np.empty((len(P), 3))
    t = tree
    # the nearest vertex bounds the search: only boxes nearer than it are opened
    bound, nn = cKDTree(t.V).query(P)
    C[:] = t.V[nn]
    d[:] = bound
    near = np.flatnonzero(bound <= band)
    dn, Cn = np.empty(len(near)), np.ascontiguousarray(C[near])
    fn = np.full(len(near), -1, dtype=np.int64)
    closest_points(np.ascontiguousarray(P[near]), t.V, t.F, t.lo, t.hi, t.child, t.first,
                   t.count, t.order, np.ascontiguousarray(bound[near]), dn, Cn, fn)
    d[near], C[near] = dn, Cn
    face = np.full(len(P), -1, dtype=np.int64)
    face[near] = fn
    return d, C, face, nn.astype(np.int64)


def crossings(tree: MeshTree, P: np.ndarray, Q: np.ndarray, skip: np.ndarray | None = None):
    """(k,) number of triangles each segment ``P[i]``-``Q[i]`` passes through."""
    P = np.ascontiguousarray(P, dtype=np.float64)
    Q = np.ascontiguousarray(Q, dtype=np.float64)
    skip = np.full(len(P), -1, np.int64) if skip is None else np.ascontiguousarray(skip, np.int64)
    out = np.empty(len(P), dtype=np.int64)
    t = tree
    segment_crossings(P, Q, t.V, t.F, t.lo, t.hi, t.child, t.first, t.count, t.order, skip, out)
    return out


#: Ray directions for :func:`inside`: skewed so no ray runs along a grid line
#: or through a lattice of vertices by accident.
_RAYS = np.array([[0.5773, 0.5774, 0.5775], [-0.6, 0.3, 0.74162], [0.21, -0.83, 0.51706]])


def inside(tree: MeshTree, P: np.ndarray, reach: float) -> np.ndarray:
    """(k,) bool: points ``P`` inside the closed mesh, by the parity of three
    skewed rays of length ``reach`` (longer than the mesh) and a majority vote,
    so a ray grazing an edge cannot flip the answer alone."""
    votes = np.zeros(len(P), dtype=np.int64)
    for d in _RAYS:
        d = d / np.linalg.norm(d)
        votes += crossings(tree, P, P + reach * d) % 2
    return votes >= 2


def signed_distance(tree: MeshTree, P: np.ndarray) -> np.ndarray:
    """(k,) signed distance of ``P`` to the closed mesh, negative inside."""
    d = closest(tree, P)[0]
    reach = 2.0 * float(np.linalg.norm(tree.hi[0] - tree.lo[0])) + 1.0
    return np.where(inside(tree, P, reach), -d, d)
