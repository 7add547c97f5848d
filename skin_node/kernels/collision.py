"""Skin-through-skin detection over refit bounding-volume trees (numba)."""
from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from . import FAST


@nb.njit(cache=True, nogil=True)
def _closest_on_triangle(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Closest point of triangle abc to p (Ericson, Real-Time Collision Detection 5.1.5)
    and whether it lies in the face's interior."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az, False
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bx, by, bz, False
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3)
        return ax + v * abx, ay + v * aby, az + v * abz, False
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cx, cy, cz, False
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6)
        return ax + w * acx, ay + w * acy, az + w * acz, False
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        return bx + w * (cx - bx), by + w * (cy - by), bz + w * (cz - bz), False
    den = 1.0 / (va + vb + vc)
    v = vb * den
    w = vc * den
    return ax + abx * v + acx * w, ay + aby * v + acy * w, az + abz * v + acz * w, True


@nb.njit(cache=True, nogil=True)
def _plane(X, F, f):
    a, b, c = F[f, 0], F[f, 1], F[f, 2]
    ux, uy, uz = X[b, 0] - X[a, 0], X[b, 1] - X[a, 1], X[b, 2] - X[a, 2]
    vx, vy, vz = X[c, 0] - X[a, 0], X[c, 1] - X[a, 1], X[c, 2] - X[a, 2]
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    L = math.sqrt(nx * nx + ny * ny + nz * nz)
    if L > 0.0:
        nx, ny, nz = nx / L, ny / L, nz / L
    gx = (X[a, 0] + X[b, 0] + X[c, 0]) / 3.0
    gy = (X[a, 1] + X[b, 1] + X[c, 1]) / 3.0
    gz = (X[a, 2] + X[b, 2] + X[c, 2]) / 3.0
    return gx, gy, gz, nx, ny, nz


@nb.njit(cache=True, nogil=True, inline="always")
def seg_dist(px, py, pz, A, B):
    """Distance from point ``p`` to the segment ``A``-``B`` (3-vectors)."""
    ex, ey, ez = B[0] - A[0], B[1] - A[1], B[2] - A[2]
    qx, qy, qz = px - A[0], py - A[1], pz - A[2]
    ee = ex * ex + ey * ey + ez * ez
    t = 0.0
    if ee > 0.0:
        t = min(1.0, max(0.0, (qx * ex + qy * ey + qz * ez) / ee))
    dx, dy, dz = qx - t * ex, qy - t * ey, qz - t * ez
    return math.sqrt(dx * dx + dy * dy + dz * dz)


#: Triangles per leaf of a :func:`triangle_trees` tree.
LEAF_SIZE = 8


class TriangleTree(NamedTuple):
    """A bounding-volume tree over a joint region's triangles (see
    :func:`triangle_trees`). Nodes ``m``, triangle slots ``n``."""

    roots: np.ndarray      # (2,) the root node of each side's tree, -1 none
    child: np.ndarray      # (m, 2) a node's two children, -1 for a leaf
    first: np.ndarray      # (m,) a leaf's first slot
    count: np.ndarray      # (m,) a leaf's number of slots
    parent: np.ndarray     # (m,) a node's parent, -1 for a root
    slot: np.ndarray       # (n,) positions into the region's triangles, leaf order
    leaf: np.ndarray       # (n,) each slot's leaf
    rcen: np.ndarray       # (n, 3) each slot's triangle centre at rest
    tcorner: np.ndarray    # (n, 3) each slot's corner vertex ids
    tloc: np.ndarray       # (n, 3) the same as positions into ``tv``
    tv: np.ndarray         # the triangles' vertices, sorted
    inc_ptr: np.ndarray    # CSR over ``tv``: the slots each vertex is a corner of
    inc: np.ndarray


class RegionTest(NamedTuple):
    """One joint region's crossing test in one pose, as :func:`crossed_at`,
    :func:`resolve_region` and :func:`~skin_node.kernels.volume.swell_checked`
    read it (each field's part in the test: :func:`crossed_vertices`)."""

    X0: np.ndarray          # (n, 3) the rest surface
    F: np.ndarray           # (m, 3) its triangles
    M: np.ndarray           # (J, 4, 4) the pose's skinning matrices, C order
    tri_bone: np.ndarray    # (m,) the bone that carries each triangle's rest normal
    tri_normal: np.ndarray  # (m, 3) the triangles' rest unit normals
    tree: TriangleTree      # over the region's triangles
    tris: np.ndarray        # the region's triangles
    tside: np.ndarray       # their sides
    verts: np.ndarray       # the region's vertices
    vside: np.ndarray       # their sides
    R: np.ndarray           # (2,) each side's flesh radius about its bone
    segA: np.ndarray        # (2, 3) starts of the posed bones (parent side's, child side's)
    segB: np.ndarray        # (2, 3) their ends
    rest_sep: float         # a triangle nearer a vertex than this at rest is its own skin
    rest_tol: float         # how far behind a far triangle a vertex may sit at rest
    reach: float            # how far the test looks for the other side's skin


class FoldPlan(NamedTuple):
    """How :func:`resolve_region` resolves a joint region's crossings."""

    pj: np.ndarray          # (3,) the posed joint
    pa: np.ndarray          # (3,) the far end of the bone to its parent
    pb: np.ndarray          # (3,) the far end of its own bone (its child, or its tip)
    passes: int             # detect-and-resolve rounds, at most
    planar: bool            # a folding joint: project onto its fold plane first
    paper: bool             # that plane through the farthest crossing (else the bisector)
    upfront: bool           # project before the first detection (the bisector)
    halfspace: bool         # also project the skin on the wrong side of the plane
    pushout: bool           # push still-crossed skin out in front of what it crossed
    eps: float              # moved skin ends this far on its own side


def triangle_trees(X0: np.ndarray, F: np.ndarray, tris: np.ndarray,
                   tside: np.ndarray) -> TriangleTree:
    """Bounding-volume trees over the triangles ``tris`` of a joint region, one
    per side ``tside``, split at the median of the rest centres along their
    longest extent, :data:`LEAF_SIZE` triangles a leaf. The topology is made
    once, at rest; :func:`fit_tree` fits the boxes to each pose (skin deforms
    smoothly, so the rest grouping stays tight), the way cloth solvers keep
    their trees. Children come after their parent, so a refit runs the nodes
    backwards.
    """
    tris = np.asarray(tris, dtype=np.int64)
    cen = X0[F[tris]].mean(axis=1) if len(tris) else np.zeros((0, 3))
    child, first, count, slot = [], [], [], []

    def build(idx):
        node = len(child)
        child.append([-1, -1])
        first.append(0)
        count.append(0)
        if len(idx) <= LEAF_SIZE:
            first[node], count[node] = len(slot), len(idx)
            slot.extend(idx)
            return node
        c = cen[idx]
        axis = int(np.argmax(c.max(axis=0) - c.min(axis=0)))
        order = idx[np.argsort(c[:, axis], kind="stable")]
        half = len(order) // 2
        a = build(order[:half])
        b = build(order[half:])
        child[node] = [a, b]
        return node

    roots = np.array([build(np.flatnonzero(tside == s)) if (tside == s).any() else -1
                      for s in (0, 1)], dtype=np.int64)
    slot = np.array(slot, dtype=np.int64)
    child = np.array(child, dtype=np.int64).reshape(-1, 2)
    first, count = np.array(first, dtype=np.int64), np.array(count, dtype=np.int64)
    parent = -np.ones(len(child), dtype=np.int64)
    for n, (a, b) in enumerate(child):
        if a >= 0:
            parent[a] = parent[b] = n
    leaf = np.empty(len(slot), dtype=np.int64)
    for n in np.flatnonzero(child[:, 0] < 0):
        leaf[first[n]:first[n] + count[n]] = n
    corners = F[tris[slot]].ravel() if len(slot) else np.zeros(0, dtype=np.int64)
    tv, which = np.unique(corners, return_inverse=True)
    order = np.argsort(which, kind="stable")
    return TriangleTree(
        roots=roots, child=child, first=first, count=count, parent=parent, slot=slot,
        leaf=leaf, rcen=np.ascontiguousarray(cen[slot]).reshape(-1, 3),
        tcorner=corners.astype(np.int64).reshape(-1, 3),
        tloc=which.astype(np.int64).reshape(-1, 3), tv=tv.astype(np.int64),
        inc_ptr=np.searchsorted(which[order], np.arange(len(tv) + 1)).astype(np.int64),
        inc=(order // 3).astype(np.int64))


def tree_fit(tree: TriangleTree):
    """Buffers for :func:`fit_tree`: node boxes low / high (m, 3), triangle
    boxes low / high (n, 3) and the corners' positions they were fit to
    (len(tv), 3), which the search reads instead of the scattered skin."""
    m, n, k = len(tree.child), len(tree.slot), len(tree.tv)
    return np.empty((m, 3)), np.empty((m, 3)), np.empty((n, 3)), np.empty((n, 3)), \
        np.empty((k, 3))


@nb.njit(cache=True, nogil=True)
def fit_tree(X, tree, fit, full):
    """Fit the boxes of ``tree`` (:func:`triangle_trees`) to the skin ``X``.

    ``full``: refit every box. Otherwise only the corners that moved since the
    last fit grow their triangles' boxes and those boxes' ancestors: boxes
    that only grow still hold their triangles, so the search stays exact, and
    a recheck after a push-out touches a few boxes instead of every one.
    """
    child, first, count = tree.child, tree.first, tree.count
    parent, leaf, tv, inc_ptr, inc, tloc = (tree.parent, tree.leaf, tree.tv, tree.inc_ptr,
                                            tree.inc, tree.tloc)
    lo, hi, tlo, thi, snap = fit
    if full:
        for k in range(tv.shape[0]):
            for d in range(3):
                snap[k, d] = X[tv[k], d]
        _refit(snap, tloc, child, first, count, lo, hi, tlo, thi)
        return
    for k in range(tv.shape[0]):
        v = tv[k]
        if X[v, 0] == snap[k, 0] and X[v, 1] == snap[k, 1] and X[v, 2] == snap[k, 2]:
            continue
        for b in range(inc_ptr[k], inc_ptr[k + 1]):
            q = inc[b]
            for d in range(3):
                tlo[q, d] = min(tlo[q, d], X[v, d])
                thi[q, d] = max(thi[q, d], X[v, d])
            n = leaf[q]
            while n >= 0:
                if (lo[n, 0] <= X[v, 0] <= hi[n, 0] and lo[n, 1] <= X[v, 1] <= hi[n, 1]
                        and lo[n, 2] <= X[v, 2] <= hi[n, 2]):
                    break              # so do all its ancestors
                for d in range(3):
                    lo[n, d] = min(lo[n, d], X[v, d])
                    hi[n, d] = max(hi[n, d], X[v, d])
                n = parent[n]
        for d in range(3):
            snap[k, d] = X[v, d]


@nb.njit(cache=True, nogil=True)
def _refit(P, tloc, child, first, count, lo, hi, tlo, thi):
    """Each triangle's box (``tlo``, ``thi``, in slot order) and each node's
    around its triangles (children before parents), the corners at
    ``P[tloc]``."""
    for n in range(child.shape[0] - 1, -1, -1):
        if child[n, 0] < 0:
            for d in range(3):
                lo[n, d] = np.inf
                hi[n, d] = -np.inf
            for q in range(first[n], first[n] + count[n]):
                for d in range(3):
                    x0, x1, x2 = P[tloc[q, 0], d], P[tloc[q, 1], d], P[tloc[q, 2], d]
                    b0, b1 = min(x0, x1, x2), max(x0, x1, x2)
                    tlo[q, d], thi[q, d] = b0, b1
                    lo[n, d] = min(lo[n, d], b0)
                    hi[n, d] = max(hi[n, d], b1)
        else:
            a, b = child[n, 0], child[n, 1]
            for d in range(3):
                lo[n, d] = min(lo[a, d], lo[b, d])
                hi[n, d] = max(hi[a, d], hi[b, d])


@nb.njit(cache=True, nogil=True, inline="always")
def _box_near2(px, py, pz, lo, hi, n):
    """Squared distance from p to box ``n`` (corners ``lo[n]``, ``hi[n]``; 0 inside)."""
    dx = max(lo[n, 0] - px, 0.0, px - hi[n, 0])
    dy = max(lo[n, 1] - py, 0.0, py - hi[n, 1])
    dz = max(lo[n, 2] - pz, 0.0, pz - hi[n, 2])
    return dx * dx + dy * dy + dz * dz


@nb.njit(cache=True, nogil=True, parallel=True, fastmath=FAST)
def crossed_vertices(X, X0, F, verts, vside, tris, tree, fit, M, tri_bone, tri_normal, segA,
                     segB, R, rest_sep, rest_tol, reach, hint, nth=1):
    """The paper's sign test for skin passing through skin, made unambiguous.

    A joint region has two sides, 0 (parent bone) and 1 (child bone); each
    side's bone is the posed segment ``segA[s]``-``segB[s]`` and ``R[s]`` the
    largest rest distance of that side's skin from it. A vertex ``p`` of side
    ``s`` can only be inside the other side's flesh when it is within ``R[o]``
    of bone ``o`` (a cheap filter). For those, take the nearest triangle of
    side ``o`` within ``reach`` (at least ``rest_sep`` from ``p`` at rest, so no
    vertex is tested against its own neighbourhood; the lowest face index
    among equally near ones); with ``c`` its centre and ``n`` its unit normal,
    ``F = (p - c) . n``. ``n`` is the triangle's rest normal ``tri_normal``
    carried by its bone ``tri_bone`` (skinning matrices ``M``), not the
    current one: a triangle crumpled flat in a crease has a meaningless
    normal, the skin it belongs to still faces the way its bone says. The
    vertex has passed through the skin when its closest point is inside that
    face and ``F`` is negative now and below its rest value ``F0`` (a vertex
    of a concave rest fold may already sit behind a far plane: it has crossed
    only once it is further behind it than at rest), and ``F0 > -rest_tol``.
    A candidate with no skin of side ``o`` within ``reach`` but deep in its
    flesh (closer than ``R[o] / 2`` to bone ``o`` and farther than ``R[o]``
    from the joint) has crossed too. ``nth``: how many interleaved slices the
    vertices are dealt into, one per thread.

    The nearest triangle is exact (a stretched triangle counts from wherever
    its face is near): ``tree`` is :func:`triangle_trees` of ``tris`` and
    ``fit`` its boxes, fit to ``X`` by :func:`fit_tree`; a vertex skips every
    subtree whose box is beyond the nearest triangle found so far. ``hint``
    (len(verts),) is, per vertex, a triangle to measure first: -1 or what an
    earlier call left there for the same vertex, which on return is the slot
    in the tree of the nearest triangle found (-1 for none within ``reach``;
    untouched for a vertex the bone filter drops). Skin moves little between
    frames, so last frame's nearest is at or near this frame's, and its
    distance bounds the search from the start rather than ``reach``. The
    answer does not depend on the hint.

    Returns
    -------
    (len(verts),) int: the crossed triangle of each vertex, -2 for a deep
    vertex, or -1.
    """
    nv = verts.shape[0]
    out = -np.ones(nv, dtype=np.int64)
    if tris.shape[0] == 0 or nv == 0:
        return out
    for t in nb.prange(nth):
        # the index typed int64 whatever the caller: each type is another compile
        _crossed_range(X, X0, F, verts, vside, tris, tree, fit, M, tri_bone, tri_normal, segA,
                       segB, R, rest_sep, rest_tol, reach, hint, np.int64(t), nth, out)
    return out


@nb.njit(cache=True, nogil=True)
def crossed_at(X, test, fit, refit, hint, pos, nth):
    """:func:`crossed_vertices` of the region's vertices ``test.verts[pos]``
    (:class:`RegionTest`), the tree's boxes ``fit`` fit to ``X`` first
    (:func:`fit_tree`: afresh with ``refit``, else grown where skin moved) and
    the region's ``hint`` (len(verts),) read and kept at ``pos``."""
    fit_tree(X, test.tree, fit, refit)
    h = hint[pos]
    out = crossed_vertices(X, test.X0, test.F, test.verts[pos], test.vside[pos], test.tris,
                           test.tree, fit, test.M, test.tri_bone, test.tri_normal, test.segA,
                           test.segB, test.R, test.rest_sep, test.rest_tol, test.reach, h, nth)
    hint[pos] = h
    return out


@nb.njit(cache=True, nogil=True, fastmath=FAST)
def _crossed_range(X, X0, F, verts, vside, tris, tree, fit, M, tri_bone, tri_normal, segA, segB,
                   R, rest_sep, rest_tol, reach, hint, first_v, step, out):
    """The per-vertex test of :func:`crossed_vertices` for ``verts[first_v::step]``."""
    roots, child, first, count = tree.roots, tree.child, tree.first, tree.count
    slot, rcen, tloc, tcorner = tree.slot, tree.rcen, tree.tloc, tree.tcorner
    lo, hi, tlo, thi, P = fit
    sep2 = rest_sep * rest_sep
    stack = np.empty(128, dtype=np.int64)
    near = np.empty(128)                   # each stacked node's box distance, squared
    for a in range(first_v, verts.shape[0], step):
        i = verts[a]
        o = 1 - vside[a]
        if roots[o] < 0:
            continue
        px, py, pz = X[i, 0], X[i, 1], X[i, 2]
        dbone = seg_dist(px, py, pz, segA[o], segB[o])
        if dbone > R[o]:
            continue
        rx, ry, rz = X0[i, 0], X0[i, 1], X0[i, 2]
        best, best_d, best_in, best_q = -1, reach * reach, False, -1
        stack[0] = roots[o]
        near[0] = _box_near2(px, py, pz, lo, hi, roots[o])
        top = 1
        # Last frame's nearest first, as a leaf of its own: its distance bounds
        # the search from the start. The leaf code below measures it, exactly as
        # when the search meets it again, and ties still go to the lowest face,
        # so the answer is the one without the hint.
        seed = hint[a]
        while top > 0 or seed >= 0:
            if seed >= 0:
                q0, q1, seed = seed, seed + 1, -1
            else:
                top -= 1
                n = stack[top]
                if near[top] > best_d:
                    continue                   # beyond the nearest triangle found since
                c0 = child[n, 0]
                if c0 >= 0:
                    c1 = child[n, 1]
                    d0 = _box_near2(px, py, pz, lo, hi, c0)
                    d1 = _box_near2(px, py, pz, lo, hi, c1)
                    # the nearer child on top, so it is searched first
                    if d0 > d1:
                        c0, c1, d0, d1 = c1, c0, d1, d0
                    if d1 <= best_d:
                        stack[top], near[top] = c1, d1
                        top += 1
                    if d0 <= best_d:
                        stack[top], near[top] = c0, d0
                        top += 1
                    continue
                q0, q1 = first[n], first[n] + count[n]
            for q in range(q0, q1):
                if _box_near2(px, py, pz, tlo, thi, q) > best_d:
                    continue
                gx, gy, gz = rcen[q, 0] - rx, rcen[q, 1] - ry, rcen[q, 2] - rz
                if gx * gx + gy * gy + gz * gz < sep2:
                    continue
                if tcorner[q, 0] == i or tcorner[q, 1] == i or tcorner[q, 2] == i:
                    continue
                a0, a1, a2 = tloc[q, 0], tloc[q, 1], tloc[q, 2]
                qx, qy, qz, inside = _closest_on_triangle(
                    px, py, pz, P[a0, 0], P[a0, 1], P[a0, 2], P[a1, 0], P[a1, 1],
                    P[a1, 2], P[a2, 0], P[a2, 1], P[a2, 2])
                d = (px - qx) ** 2 + (py - qy) ** 2 + (pz - qz) ** 2
                f = tris[slot[q]]
                if d < best_d or (d == best_d and f < best):
                    best, best_d, best_in, best_q = f, d, inside, q
        hint[a] = best_q
        if best < 0:
            # deep in the other side's flesh: near its bone, away from the joint
            # (segA[1] is the joint, where both bones start and the flesh is shared)
            dj = math.sqrt((px - segA[1, 0]) ** 2 + (py - segA[1, 1]) ** 2
                           + (pz - segA[1, 2]) ** 2)
            if dbone < 0.5 * R[o] and dj > R[o]:
                out[a] = -2
            continue
        if not best_in:
            continue
        a0, a1, a2 = F[best, 0], F[best, 1], F[best, 2]
        n0, n1, n2 = _carried(M, tri_bone, tri_normal, best)
        Fnow = ((px - (X[a0, 0] + X[a1, 0] + X[a2, 0]) / 3.0) * n0
                + (py - (X[a0, 1] + X[a1, 1] + X[a2, 1]) / 3.0) * n1
                + (pz - (X[a0, 2] + X[a1, 2] + X[a2, 2]) / 3.0) * n2)
        g0, g1, g2, m0, m1, m2 = _plane(X0, F, best)
        Frest = (rx - g0) * m0 + (ry - g1) * m1 + (rz - g2) * m2
        if Fnow < min(0.0, Frest) and Frest > -rest_tol:
            out[a] = best
    return out


@nb.njit(cache=True, nogil=True)
def dragged_reach(X, tree, tside, verts, reach, out, sides):
    """How far moving each vertex of ``verts`` can change the crossing test,
    and for which side's skin.

    A vertex drags the triangles of ``tree`` (:func:`triangle_trees`) it is a
    corner of, and a triangle lies within its corner's longest edge of it;
    the test looks ``reach`` beyond a triangle. Per vertex, raises ``out`` to
    ``reach`` plus that edge in ``X``, and sets bit ``s`` of ``sides`` for
    each side ``s`` (``tside``, per region triangle) among those triangles:
    only the other side's skin is tested against them."""
    tv, inc_ptr, inc, tcorner, slot = tree.tv, tree.inc_ptr, tree.inc, tree.tcorner, tree.slot
    for a in range(verts.shape[0]):
        i = verts[a]
        k = np.searchsorted(tv, i)
        if k >= tv.shape[0] or tv[k] != i:
            continue
        best = 0.0
        for b in range(inc_ptr[k], inc_ptr[k + 1]):
            q = inc[b]
            sides[a] |= 1 << tside[slot[q]]
            for e in range(3):
                u = tcorner[q, e]
                best = max(best, (X[u, 0] - X[i, 0]) ** 2 + (X[u, 1] - X[i, 1]) ** 2
                           + (X[u, 2] - X[i, 2]) ** 2)
        out[a] = max(out[a], reach + math.sqrt(best))


@nb.njit(cache=True, nogil=True)
def near_dragged(X, verts, vside, P, R, sides):
    """Positions into ``verts`` (sides ``vside``) of the vertices within
    ``R[b]`` of a point ``P[b]`` whose ``sides[b]`` (:func:`dragged_reach`)
    has the other side's bit."""
    out = np.empty(verts.shape[0], dtype=np.int64)
    n = 0
    for a in range(verts.shape[0]):
        i = verts[a]
        o = 1 - vside[a]
        for b in range(P.shape[0]):
            if not (sides[b] >> o) & 1:
                continue
            d = (X[i, 0] - P[b, 0]) ** 2 + (X[i, 1] - P[b, 1]) ** 2 + (X[i, 2] - P[b, 2]) ** 2
            if d < R[b] * R[b]:
                out[n] = a
                n += 1
                break
    return out[:n]


@nb.njit(cache=True, nogil=True)
def longest_edge(X, F, tris):
    """The longest edge of the triangles ``tris`` (rows of ``F``) in ``X``."""
    best = 0.0
    for a in range(tris.shape[0]):
        f = tris[a]
        for e in range(3):
            i, k = F[f, e], F[f, (e + 1) % 3]
            d = (X[i, 0] - X[k, 0]) ** 2 + (X[i, 1] - X[k, 1]) ** 2 + (X[i, 2] - X[k, 2]) ** 2
            best = max(best, d)
    return math.sqrt(best)


@nb.njit(cache=True, nogil=True)
def near_points(X, verts, P, r):
    """Positions into ``verts`` of the vertices within ``r`` of any point of ``P``."""
    out = np.empty(verts.shape[0], dtype=np.int64)
    n = 0
    rr = r * r
    for a in range(verts.shape[0]):
        i = verts[a]
        for b in range(P.shape[0]):
            d = (X[i, 0] - P[b, 0]) ** 2 + (X[i, 1] - P[b, 1]) ** 2 + (X[i, 2] - P[b, 2]) ** 2
            if d < rr:
                out[n] = a
                n += 1
                break
    return out[:n]


@nb.njit(cache=True, nogil=True)
def in_box(X, verts, sub, P, r):
    """The entries of ``sub`` (positions into ``verts``) whose vertex lies in the
    bounding box of the points ``P`` grown by ``r``."""
    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for b in range(P.shape[0]):
        for d in range(3):
            lo[d] = min(lo[d], P[b, d] - r)
            hi[d] = max(hi[d], P[b, d] + r)
    out = np.empty(sub.shape[0], dtype=np.int64)
    n = 0
    for a in range(sub.shape[0]):
        i = verts[sub[a]]
        if (lo[0] <= X[i, 0] <= hi[0] and lo[1] <= X[i, 1] <= hi[1]
                and lo[2] <= X[i, 2] <= hi[2]):
            out[n] = sub[a]
            n += 1
    return out[:n]


@nb.njit(cache=True, nogil=True)
def push_out(X, X0, F, M, tri_bone, tri_normal, verts, tris, eps):
    """Move each ``verts[a]`` along the carried normal ``n`` of the triangle
    ``tris[a]`` it crossed to ``eps`` in front of where it sat at rest relative
    to that triangle's centre plane, or of the plane itself when it was in
    front of it (see :func:`crossed_vertices`). All planes are taken before any
    vertex moves."""
    k = verts.shape[0]
    step = np.empty((k, 3))
    for a in range(k):
        i, f = verts[a], tris[a]
        g0, g1, g2, m0, m1, m2 = _plane(X0, F, f)
        rest = min(0.0, (X0[i, 0] - g0) * m0 + (X0[i, 1] - g1) * m1 + (X0[i, 2] - g2) * m2)
        n0, n1, n2 = _carried(M, tri_bone, tri_normal, f)
        c0 = (X[F[f, 0], 0] + X[F[f, 1], 0] + X[F[f, 2], 0]) / 3.0
        c1 = (X[F[f, 0], 1] + X[F[f, 1], 1] + X[F[f, 2], 1]) / 3.0
        c2 = (X[F[f, 0], 2] + X[F[f, 1], 2] + X[F[f, 2], 2]) / 3.0
        d = rest + eps - ((X[i, 0] - c0) * n0 + (X[i, 1] - c1) * n1 + (X[i, 2] - c2) * n2)
        step[a, 0], step[a, 1], step[a, 2] = d * n0, d * n1, d * n2
    for a in range(k):
        for r in range(3):
            X[verts[a], r] += step[a, r]


@nb.njit(cache=True, nogil=True)
def push_and_recheck(X, X0, F, M, tri_bone, tri_normal, tree, tside, reach, verts, vside, pos,
                     hit, eps, use_plane, pc, pn):
    """One push-out pass of the collision stage over ``verts[pos]`` (a joint
    region's vertices, ``pos`` sorted positions into them), given their
    :func:`crossed_vertices` answer ``hit``.

    Each vertex that crossed a triangle is pushed out in front of it
    (:func:`push_out`); with ``use_plane``, each deep one (-2) is projected
    onto the plane through ``pc`` with unit normal ``pn``, ``eps`` to its own
    side. Returns (the positions into ``verts`` to test again, the pushed
    vertices, the projected ones). To test again: the moved vertices, and
    every vertex of the other side within :func:`dragged_reach` of where a
    moved vertex was or is (:func:`near_dragged`): a pushed vertex drags its
    triangles, up to its longest edge away, over the other side's skin."""
    n_hit = n_tri = 0
    for a in range(hit.shape[0]):
        if hit[a] != -1:
            n_hit += 1
            if hit[a] >= 0:
                n_tri += 1
    moved, where = np.empty(n_hit, np.int64), np.empty(n_hit, np.int64)
    tri_v, tri_f = np.empty(n_tri, np.int64), np.empty(n_tri, np.int64)
    deep = np.empty(n_hit - n_tri, np.int64)
    m = t = d = 0
    for a in range(hit.shape[0]):
        if hit[a] == -1:
            continue
        moved[m], where[m] = verts[pos[a]], pos[a]
        m += 1
        if hit[a] >= 0:
            tri_v[t], tri_f[t] = verts[pos[a]], hit[a]
            t += 1
        else:
            deep[d] = a
            d += 1
    P = np.empty((2 * n_hit, 3))
    for a in range(n_hit):
        for c in range(3):
            P[a, c] = X[moved[a], c]
    drag, sides = np.zeros(n_hit), np.zeros(n_hit, np.int64)
    dragged_reach(X, tree, tside, moved, reach, drag, sides)
    push_out(X, X0, F, M, tri_bone, tri_normal, tri_v, tri_f, eps)
    projected = np.empty(deep.shape[0] if use_plane else 0, np.int64)
    for b in range(projected.shape[0]):
        a = deep[b]
        i = verts[pos[a]]
        sgn = 2.0 * vside[pos[a]] - 1.0
        dist = (X[i, 0] - pc[0]) * pn[0] + (X[i, 1] - pc[1]) * pn[1] + (X[i, 2] - pc[2]) * pn[2]
        for c in range(3):
            X[i, c] -= (dist - sgn * eps) * pn[c]
        projected[b] = i
    dragged_reach(X, tree, tside, moved, reach, drag, sides)
    R2, sides2 = np.empty(2 * n_hit), np.empty(2 * n_hit, np.int64)
    for a in range(n_hit):
        for c in range(3):
            P[n_hit + a, c] = X[moved[a], c]
        R2[a] = R2[n_hit + a] = drag[a]
        sides2[a] = sides2[n_hit + a] = sides[a]
    near = near_dragged(X, verts, vside, P, R2, sides2)
    return merge_sorted(where, near), tri_v, projected


@nb.njit(cache=True, nogil=True)
def merge_sorted(a, b):
    """The union of two sorted int arrays, sorted, each value once."""
    out = np.empty(a.shape[0] + b.shape[0], dtype=np.int64)
    i = j = n = 0
    while i < a.shape[0] or j < b.shape[0]:
        if j == b.shape[0] or (i < a.shape[0] and a[i] <= b[j]):
            x = a[i]
            i += 1
        else:
            x = b[j]
            j += 1
        if n == 0 or out[n - 1] != x:
            out[n] = x
            n += 1
    return out[:n]


@nb.njit(cache=True, nogil=True, inline="always")
def _carried(M, tri_bone, tri_normal, t):
    """Triangle ``t``'s rest normal turned by its bone's skinning matrix."""
    b = tri_bone[t]
    return ((M[b, 0, 0] * tri_normal[t, 0] + M[b, 0, 1] * tri_normal[t, 1]
             + M[b, 0, 2] * tri_normal[t, 2]),
            (M[b, 1, 0] * tri_normal[t, 0] + M[b, 1, 1] * tri_normal[t, 1]
             + M[b, 1, 2] * tri_normal[t, 2]),
            (M[b, 2, 0] * tri_normal[t, 0] + M[b, 2, 1] * tri_normal[t, 1]
             + M[b, 2, 2] * tri_normal[t, 2]))


@nb.njit(cache=True, nogil=True)
def halfspace_project(X, verts, vside, crossed, segA, segB, R, c, n, eps, halfspace, moved):
    """Project onto the plane ``(c, n)``, ``eps`` to their own side (child side +n),
    the region vertices flagged ``crossed`` and, with ``halfspace``, every one on
    the wrong side of it within the other side's flesh radius of its bone.
    Writes the moved vertex ids into ``moved``; returns how many."""
    k = 0
    for a in range(verts.shape[0]):
        i = verts[a]
        sgn = 2.0 * vside[a] - 1.0
        dist = (X[i, 0] - c[0]) * n[0] + (X[i, 1] - c[1]) * n[1] + (X[i, 2] - c[2]) * n[2]
        move = crossed[a]
        if not move and halfspace and sgn * dist < eps:
            o = 1 - vside[a]
            move = seg_dist(X[i, 0], X[i, 1], X[i, 2], segA[o], segB[o]) < R[o]
        if move:
            f = dist - sgn * eps
            X[i, 0] -= f * n[0]
            X[i, 1] -= f * n[1]
            X[i, 2] -= f * n[2]
            moved[k] = i
            k += 1
    return k


@nb.njit(cache=True, nogil=True)
def fold_plane(pj, pa, pb, q, paper):
    """Unit normal of the collision plane of a fold at joint ``pj`` between the
    bone to its parent end ``pa`` and the bone to its child end ``pb``.

    The plane is perpendicular to the plane of the two bones; with ``paper``
    it passes through the crossing point ``q`` (Chen & Pan 2017), otherwise it
    bisects the bones (normal ``v - u``). The normal points to the child side.
    Returns (False, zeros) when the bones are straight (no fold to part)."""
    # scalars throughout: array expressions cost seconds of compiling here
    ux, uy, uz = pa[0] - pj[0], pa[1] - pj[1], pa[2] - pj[2]
    vx, vy, vz = pb[0] - pj[0], pb[1] - pj[1], pb[2] - pj[2]
    L = math.sqrt(ux * ux + uy * uy + uz * uz) + 1e-300
    ux, uy, uz = ux / L, uy / L, uz / L
    L = math.sqrt(vx * vx + vy * vy + vz * vz) + 1e-300
    vx, vy, vz = vx / L, vy / L, vz / L
    n = np.zeros(3)
    mx, my, mz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    if math.sqrt(mx * mx + my * my + mz * mz) < 1e-3:
        return False, n
    dx, dy, dz = vx - ux, vy - uy, vz - uz
    if paper:
        wx, wy, wz = q[0] - pj[0], q[1] - pj[1], q[2] - pj[2]
        nx, ny, nz = my * wz - mz * wy, mz * wx - mx * wz, mx * wy - my * wx
    else:
        nx, ny, nz = dx, dy, dz
    if math.sqrt(nx * nx + ny * ny + nz * nz) < 1e-9:
        nx, ny, nz = dx, dy, dz
    L = math.sqrt(nx * nx + ny * ny + nz * nz)
    nx, ny, nz = nx / L, ny / L, nz / L
    if nx * dx + ny * dy + nz * dz < 0:
        nx, ny, nz = -nx, -ny, -nz
    n[0], n[1], n[2] = nx, ny, nz
    return True, n


@nb.njit(cache=True, nogil=True)
def resolve_region(X, test, fit, refit, hint, pos, fold, nth):
    """The collision stage on one joint region (:class:`RegionTest`): up to
    ``fold.passes`` rounds of detection (:func:`crossed_vertices` over
    ``test.verts[pos]``) and resolution as ``fold`` (:class:`FoldPlan`) says.

    A folding joint (``planar``) first has its crossed skin projected onto
    the plane of its fold (:func:`fold_plane` of ``pj``, ``pa``, ``pb``, then
    :func:`halfspace_project`): up front for the bisector with ``halfspace``
    (``upfront``: the bisector does not depend on where skin crossed, so it
    needs no detection first), else once after the first detection, through
    the farthest crossed vertex with ``paper``. Skin still crossed (creases the
    plane cannot part) is pushed out in front of the skin it crossed and the
    moves rechecked (:func:`push_and_recheck`), with ``pushout``. ``refit``:
    fit the tree's boxes ``fit`` afresh first (the region's first test this
    frame), else only grow them where skin moved. ``hint`` as in
    :func:`crossed_at`; the test's ``reach`` is the recheck's too
    (:func:`push_and_recheck`). Returns (the vertices moved, how many were
    projected onto the plane, how many pushed out)."""
    X0, F, M, tri_bone, tri_normal, tree = (test.X0, test.F, test.M, test.tri_bone,
                                            test.tri_normal, test.tree)
    tside, verts, vside, R, segA, segB = (test.tside, test.verts, test.vside, test.R, test.segA,
                                          test.segB)
    reach = test.reach
    pj, pa, pb, passes, planar, paper = (fold.pj, fold.pa, fold.pb, fold.passes, fold.planar,
                                         fold.paper)
    upfront, halfspace, pushout, eps = fold.upfront, fold.halfspace, fold.pushout, fold.eps
    nv = verts.shape[0]
    moved = np.empty((passes + 1) * nv + 1, dtype=np.int64)
    nm = projected = pushed = 0
    have_plane = False
    n = np.zeros(3)
    none = np.zeros(nv, dtype=np.bool_)
    if upfront and planar:
        have_plane, n = fold_plane(pj, pa, pb, pj, False)
        if have_plane:
            k = halfspace_project(X, verts, vside, none, segA, segB, R, pj, n, eps, halfspace,
                                  moved[nm:])
            nm += k
            projected += k
    for _ in range(passes):
        hit = crossed_at(X, test, fit, refit, hint, pos, nth)
        refit = False
        n_hit = 0
        for a in range(hit.shape[0]):
            if hit[a] != -1:
                n_hit += 1
        if n_hit == 0:
            break
        if planar and not have_plane:
            planar = False                     # one try at the paper's plane
            far, far_d = -1, -1.0
            for a in range(hit.shape[0]):
                if hit[a] != -1:
                    i = verts[pos[a]]
                    d = math.sqrt((X[i, 0] - pj[0]) ** 2 + (X[i, 1] - pj[1]) ** 2
                                  + (X[i, 2] - pj[2]) ** 2)
                    if d > far_d:
                        far, far_d = i, d
            have_plane, n = fold_plane(pj, pa, pb, X[far], paper)
            if have_plane:
                crossed = np.zeros(nv, dtype=np.bool_)
                for a in range(hit.shape[0]):
                    crossed[pos[a]] = hit[a] != -1
                k = halfspace_project(X, verts, vside, crossed, segA, segB, R, pj, n, eps,
                                      halfspace, moved[nm:])
                nm += k
                projected += k
                pos = np.arange(nv)
                continue
        if not pushout:
            break
        pos, pushed_v, deep_v = push_and_recheck(
            X, X0, F, M, tri_bone, tri_normal, tree, tside, reach, verts, vside, pos, hit, eps,
            have_plane, pj, n)
        moved[nm:nm + pushed_v.shape[0]] = pushed_v
        nm += pushed_v.shape[0]
        moved[nm:nm + deep_v.shape[0]] = deep_v
        nm += deep_v.shape[0]
        pushed += n_hit
    return moved[:nm], projected, pushed
