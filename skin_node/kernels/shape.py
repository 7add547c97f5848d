"""Kernels that shape the skin around bent joints: bulge limit and inflation (numba)."""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from .intersect import _normal


@nb.njit(cache=True, nogil=True, inline="always")
def _closest_on_segment(px, py, pz, A, B, s):
    dx, dy, dz = B[s, 0] - A[s, 0], B[s, 1] - A[s, 1], B[s, 2] - A[s, 2]
    d2 = dx * dx + dy * dy + dz * dz
    t = ((px - A[s, 0]) * dx + (py - A[s, 1]) * dy + (pz - A[s, 2]) * dz) / max(d2, 1e-30)
    t = min(1.0, max(0.0, t))
    return A[s, 0] + t * dx, A[s, 1] + t * dy, A[s, 2] + t * dz


#: Rounds of alternating projections onto the nearest segments' limits: one
#: leaves every vertex within 1.7 mm of where two put it on the walk and the
#: squat (two are within 0.1 mm of four), and no surface measure or z-buffer
#: picture tells them apart, for 15% of the stage's time.
ROUNDS = 1
#: "No limit" in :func:`pull_bulge`'s limits.
NO_LIMIT = 1e30


#: Segments further than this many times a vertex's nearest one (at rest)
#: do not count towards its :func:`parting_pairs`: the weights fall smoothly
#: to 0 there (the limits' own hold ends at 1.3; the parting must reach
#: further, or the skin keeps a ridge where a pair leaves).
PARTING_REACH = 3.0
#: At most this many of a vertex's nearest segments pair up (a hand's
#: fingers would give dozens; the humanoid has up to 14 within
#: :data:`PARTING_REACH`, CesiumMan too). Where more are within reach, a
#: pair can leave before its weight is 0: with 4 the kick's crotch kept a
#: ridge there; 5, 6 and 8 give it the same skin (to 1e-12 m).
PARTING_MOST = 6
#: A pair's growth ``g`` counts as ``s tanh(g / s)``, ``s`` PARTING_SPAN
#: times the vertex's rest distance from its nearest bone: two far points
#: that parted much, times a weight that falls to 0 over the reach, changed
#: the loosening by centimetres between neighbouring vertices (the other
#: thigh 300 mm further from skin above a knee than at rest, weighted 0.027
#: and 0.003 at the two ends of an edge: 8.1 and 0.9 mm), and the skin the
#: limit drew in followed it as a groove (docs/design.md). At 1 the side
#: splits' crotch was drawn in and wrinkled; at 1.5 it is as before.
PARTING_SPAN = 1.5


@nb.njit(cache=True, nogil=True)
def _parting_pairs(V, A, B, seg_joint, reach, most, span, ptr, fill, pa, pb, ta, tb, sep0, pw,
                   cap):
    """:func:`parting_pairs`, counting (``fill`` False: ``ptr[i + 1]`` the
    count of vertex ``i``) or filling its rows from ``ptr``."""
    S = A.shape[0]
    dist, t = np.empty(S), np.empty(S)
    for i in range(V.shape[0]):
        d0 = 1e300
        for g in range(S):
            dx, dy, dz = B[g, 0] - A[g, 0], B[g, 1] - A[g, 1], B[g, 2] - A[g, 2]
            d2 = dx * dx + dy * dy + dz * dz
            u = ((V[i, 0] - A[g, 0]) * dx + (V[i, 1] - A[g, 1]) * dy
                 + (V[i, 2] - A[g, 2]) * dz) / max(d2, 1e-30)
            u = min(1.0, max(0.0, u))
            t[g] = u
            dist[g] = math.sqrt((V[i, 0] - A[g, 0] - u * dx) ** 2 + (V[i, 1] - A[g, 1] - u * dy) ** 2
                                + (V[i, 2] - A[g, 2] - u * dz) ** 2)
            d0 = min(d0, dist[g])
        order = np.argsort(dist)[:most]
        q = ptr[i] if fill else 0
        for m in range(order.shape[0]):
            a = order[m]
            na = _reach_weight(dist[a], d0, reach)
            if na <= 0.0:
                break
            for m2 in range(m + 1, order.shape[0]):
                b = order[m2]
                nb_ = _reach_weight(dist[b], d0, reach)
                if nb_ <= 0.0:
                    break
                if seg_joint[a] == seg_joint[b]:
                    continue
                if fill:
                    pa[q], pb[q], ta[q], tb[q] = a, b, t[a], t[b]
                    x = 0.0
                    for c in range(3):
                        x += ((A[a, c] + t[a] * (B[a, c] - A[a, c]))
                              - (A[b, c] + t[b] * (B[b, c] - A[b, c]))) ** 2
                    sep0[q] = math.sqrt(x)
                    pw[q] = na * nb_
                    cap[q] = max(span * d0, 1e-9)
                q += 1
        if not fill:
            ptr[i + 1] = q


@nb.njit(cache=True, nogil=True, inline="always")
def _reach_weight(d, d0, reach):
    """1 for a vertex's nearest segment (at ``d0``), falling smoothly to 0 at
    ``reach`` times its distance."""
    x = min(1.0, max(0.0, 1.0 - (d - d0) / max((reach - 1.0) * d0, 1e-9)))
    return x * x * (3.0 - 2.0 * x)


def parting_pairs(V, A, B, seg_joint, reach=PARTING_REACH, most=PARTING_MOST,
                  span=PARTING_SPAN):
    """For every vertex of the rest skin ``V``, the pairs of its nearest bone
    segments (rest ``A``-``B``; up to ``most``, within ``reach`` times the
    nearest's distance; on two different bones ``seg_joint``) whose parting
    :func:`pull_bulge` reads: a CSR ``(ptr (n+1,), pa, pb, ta, tb, sep0, w,
    cap)``, each pair's segments, where along each the vertex's closest point
    lies, those points' rest distance, how much the pair counts (the product
    of both segments' nearness, smooth in the vertex's position) and the
    growth its loosening saturates at (``span`` times the vertex's rest
    distance from its nearest segment)."""
    V = np.ascontiguousarray(V, dtype=np.float64)
    A, B = np.ascontiguousarray(A, dtype=np.float64), np.ascontiguousarray(B, dtype=np.float64)
    seg_joint = np.ascontiguousarray(seg_joint, dtype=np.int64)
    ptr = np.zeros(len(V) + 1, dtype=np.int64)
    none_i, none_f = np.zeros(0, np.int64), np.zeros(0)
    _parting_pairs(V, A, B, seg_joint, float(reach), int(most), float(span), ptr, False,
                   none_i, none_i, none_f, none_f, none_f, none_f, none_f)
    ptr = np.cumsum(ptr)
    m = int(ptr[-1])
    pa, pb = np.empty(m, np.int64), np.empty(m, np.int64)
    ta, tb, sep0, w, cap = np.empty(m), np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    _parting_pairs(V, A, B, seg_joint, float(reach), int(most), float(span), ptr, True, pa, pb,
                   ta, tb, sep0, w, cap)
    return ptr, pa, pb, ta, tb, sep0, w, cap


@nb.njit(cache=True, nogil=True, inline="always")
def _parting(i, ptr, pa, pb, ta, tb, sep0, pw, cap, A, B, enough):
    """How much further apart than at rest vertex ``i``'s nearest bones now
    hold it (:func:`parting_pairs`; posed segments ``A``-``B``): the largest
    growth of the distance between two of their points nearest it at rest,
    saturating at the pair's ``cap`` and weighted; 0 if none grew. Once that
    reaches ``enough``, the growth so far."""
    grow = 0.0
    for q in range(ptr[i], ptr[i + 1]):
        if grow >= enough:
            break
        a, b, u, v = pa[q], pb[q], ta[q], tb[q]
        x = (A[a, 0] + u * (B[a, 0] - A[a, 0])) - (A[b, 0] + v * (B[b, 0] - A[b, 0]))
        y = (A[a, 1] + u * (B[a, 1] - A[a, 1])) - (A[b, 1] + v * (B[b, 1] - A[b, 1]))
        z = (A[a, 2] + u * (B[a, 2] - A[a, 2])) - (A[b, 2] + v * (B[b, 2] - A[b, 2]))
        g = math.sqrt(x * x + y * y + z * z) - sep0[q]
        if g <= 0.0:
            continue
        # the pair counts cap tanh(g / cap) pw < g pw (tanh t < t), so where
        # g pw does not beat the growth so far neither does the pair: no
        # tanh, and the same growth to the last bit (the margin covers the
        # roundings of both and tanh's error of a few ulps). Over half of the
        # pairs that grew, once a nearer one has
        if g * pw[q] * (1.0 + 1e-12) <= grow:
            continue
        g = cap[q] * math.tanh(g / cap[q]) * pw[q]
        if g > grow:
            grow = g
    return grow


@nb.njit(cache=True, nogil=True)
def parting(out, verts, ptr, pa, pb, ta, tb, sep0, pw, cap, A, B):
    """``out[k]``: the bones' parting around vertex ``verts[k]`` (what
    :func:`pull_bulge` loosens its limits by), for tests and pictures."""
    for k in range(verts.shape[0]):
        out[k] = _parting(verts[k], ptr, pa, pb, ta, tb, sep0, pw, cap, A, B, np.inf)
    return out


@nb.njit(cache=True, nogil=True, inline="always")
def _pull(X, i, seg, r0, hold, A, B, width, fade, ptr, pa, pb, ta, tb, sep0, pw, cap, allowed):
    """:func:`pull_bulge` of vertex ``i``: its limits into ``allowed[i]``,
    then :func:`_limit`'s projection onto them, each segment's distance
    read once where the vertex has not moved yet (as :func:`_limit` would
    read it again: the same skin to the last bit). ``ptr`` to ``cap``: the
    :func:`parting_pairs`. 1 if it moved, else 0."""
    k = seg.shape[1]
    f = fade[i]
    if f <= 0.0:
        for s in range(k):
            allowed[i, s] = NO_LIMIT
        return 0
    px, py, pz = X[i, 0], X[i, 1], X[i, 2]
    # each segment's distance, kept in ``allowed[i]`` until its limit is known
    over = 0.0
    for s in range(k):
        if hold[i, s] > 0.0:
            cx, cy, cz = _closest_on_segment(px, py, pz, A, B, seg[i, s])
            r = math.sqrt((px - cx) ** 2 + (py - cy) ** 2 + (pz - cz) ** 2)
            allowed[i, s] = r
            over = max(over, r - r0[i, s])
        else:
            allowed[i, s] = NO_LIMIT
    if over <= 0.0:
        # within its rest distance of every segment: no limit applies, and
        # the parting (which only loosens them) need not be read
        for s in range(k):
            allowed[i, s] = NO_LIMIT
        return 0
    # (a parting as large as the most the vertex stands out loosens every
    # limit away: the rest of it need not be read)
    d = _parting(i, ptr, pa, pb, ta, tb, sep0, pw, cap, A, B, over)
    qx, qy, qz = px, py, pz
    moved = False
    for s in range(k):
        r = allowed[i, s]
        if r >= NO_LIMIT:
            continue
        w = width[i] / hold[i, s]
        e = r - r0[i, s] - d
        if e <= 0.0:
            allowed[i, s] = NO_LIMIT
            continue
        lim = r0[i, s] + d + w * math.tanh(e / w)
        allowed[i, s] = lim
        # the first of ROUNDS projections, as :func:`_limit` makes it (until
        # the vertex moves, its distance is the one just read: within its
        # limit, nothing more to read)
        if moved or r > lim:
            cx, cy, cz = _closest_on_segment(qx, qy, qz, A, B, seg[i, s])
            ux, uy, uz = qx - cx, qy - cy, qz - cz
            r = math.sqrt(ux * ux + uy * uy + uz * uz)
            if r > lim and r > 1e-12:
                c = lim / r
                qx, qy, qz = cx + ux * c, cy + uy * c, cz + uz * c
                moved = True
    for _ in range(ROUNDS - 1):
        qx, qy, qz = _project_round(qx, qy, qz, i, seg, A, B, allowed)
    return _move_by(X, i, f, px, py, pz, qx, qy, qz)


@nb.njit(cache=True, nogil=True, inline="always")
def _project_round(qx, qy, qz, i, seg, A, B, allowed):
    """One round of projections of point ``q`` onto vertex ``i``'s limits
    from each of its segments (towards each one's closest point)."""
    for s in range(seg.shape[1]):
        if allowed[i, s] >= NO_LIMIT:
            continue
        cx, cy, cz = _closest_on_segment(qx, qy, qz, A, B, seg[i, s])
        ux, uy, uz = qx - cx, qy - cy, qz - cz
        r = math.sqrt(ux * ux + uy * uy + uz * uz)
        if r > allowed[i, s] and r > 1e-12:
            c = allowed[i, s] / r
            qx, qy, qz = cx + ux * c, cy + uy * c, cz + uz * c
    return qx, qy, qz


@nb.njit(cache=True, nogil=True, inline="always")
def _move_by(X, i, f, px, py, pz, qx, qy, qz):
    """Vertex ``i`` (at ``p``) moved ``f`` of the way to ``q``: 1 if it moved."""
    if qx == px and qy == py and qz == pz:
        return 0
    X[i, 0] = px + f * (qx - px)
    X[i, 1] = py + f * (qy - py)
    X[i, 2] = pz + f * (qz - pz)
    return 1


@nb.njit(cache=True, nogil=True, inline="always")
def _limit(X, i, seg, A, B, fade, allowed):
    """:func:`limit_bulge` of one vertex: 1 if it moved, else 0."""
    f = fade[i]
    if f <= 0.0:
        return 0
    px, py, pz = X[i, 0], X[i, 1], X[i, 2]
    qx, qy, qz = px, py, pz
    for _ in range(ROUNDS):
        qx, qy, qz = _project_round(qx, qy, qz, i, seg, A, B, allowed)
    return _move_by(X, i, f, px, py, pz, qx, qy, qz)


@nb.njit(cache=True, nogil=True, parallel=True)
def limit_bulge(X, verts, seg, A, B, fade, allowed):
    """Bring every vertex of ``verts`` within its limits (:func:`pull_bulge`)
    from each of its segments: :data:`ROUNDS` rounds of alternating projections
    onto the limits (towards each segment's closest point, the skin's radial
    direction), the move scaled by ``fade`` (n,). The limits hold at once,
    where a blend of the pulls left skin between two bones standing out by
    half of each. Projection is idempotent, so a second call after smoothing
    takes back only what the smoothing gave away. Returns how many vertices
    moved (vertices are independent: threads share them out)."""
    n = 0
    for k in nb.prange(verts.shape[0]):
        n += _limit(X, verts[k], seg, A, B, fade, allowed)
    return n


@nb.njit(cache=True, nogil=True, parallel=True)
def pull_bulge(X, verts, seg, r0, hold, A, B, width, fade, pairs, allowed):
    """Every vertex of ``verts`` drawn within how far from each of its
    nearest bone segments it may stand, from where skinning put it (``X``).

    The paper's bind constraint ``C = |p - p'| - d`` (p' the closest point of
    the vertex's bone segment, posed ``A``-``B``; ``d`` its rest distance
    ``r0``), made one-sided and soft: skin further out than at rest by ``e``
    may stand ``w tanh(e / w)`` out (never more than ``w``, unchanged to first
    order where ``e`` is small); skin nearer than at rest has no limit.
    ``seg`` and ``r0`` (n, k) are each vertex's k nearest rest segments and
    distances, ``hold`` (n, k) how far each one's limit holds: ``w = width /
    hold``, 1 for the nearest, falling to 0 (no limit) as a segment is
    further. So a limit comes and goes smoothly wherever the order of the
    nearest segments changes, and skin about as near several (the buttocks,
    between the pelvis's bones and a thigh's) is held by each in full.
    All of a vertex's limits loosen by how far its nearest bones parted
    since rest (``pairs``, :func:`parting_pairs`): skin spanning two limbs
    that part (the crotch as the legs spread or one kicks) cannot keep its
    rest distance from both, and held to each it crumpled. Bones that meet
    at a joint part little near it, so a bent joint's bulge keeps its limit.
    Writes ``allowed[i]`` (n, k): the distances, :data:`NO_LIMIT` where none
    applies (and for vertices whose ``fade`` is 0), then projects onto them as
    :func:`limit_bulge` does, in the same pass (each vertex's limits depend on
    its own skinned position alone). Vertices are independent: threads share
    them out. Returns how many vertices moved."""
    n = 0
    # the pairs' arrays unpacked once: taken from the tuple in the loop, each
    # vertex that reads them counted a reference to all eight and back
    ptr, pa, pb, ta, tb, sep0, pw, cap = pairs
    for k in nb.prange(verts.shape[0]):
        n += _pull(X, verts[k], seg, r0, hold, A, B, width, fade, ptr, pa, pb, ta, tb, sep0, pw,
                   cap, allowed)
    return n


@nb.njit(cache=True, nogil=True, inline="always")
def _envelope(i, s, r0, hold, width):
    """Vertex ``i``'s envelope around its ``s``-th nearest segment: its rest
    distance plus ``width``, loosened as in :func:`pull_bulge`."""
    return r0[i, s] + width / hold[i, s] if hold[i, s] > 0.0 else NO_LIMIT


@nb.njit(cache=True, nogil=True)
def envelope_room(X, verts, seg, r0, hold, A, B, limit, room):
    """``room[k]``: how far vertex ``verts[k]`` may still move out before it
    leaves the bulge limit's envelope (``limit`` times its rest distance past
    it) around any of its nearest segments; 0 past it."""
    for k in range(verts.shape[0]):
        i = verts[k]
        w = limit * r0[i, 0]
        out = NO_LIMIT
        for s in range(seg.shape[1]):
            e = _envelope(i, s, r0, hold, w)
            if e >= NO_LIMIT:
                continue
            cx, cy, cz = _closest_on_segment(X[i, 0], X[i, 1], X[i, 2], A, B, seg[i, s])
            r = math.sqrt((X[i, 0] - cx) ** 2 + (X[i, 1] - cy) ** 2 + (X[i, 2] - cz) ** 2)
            out = min(out, max(e - r, 0.0))
        room[k] = out


@nb.njit(cache=True, nogil=True)
def envelope_clamp(X, verts, seg, r0, hold, A, B, limit, before):
    """Skin of ``verts`` past the envelope of :func:`envelope_room` drawn back
    onto it, towards each segment in turn, by at most how far it moved since
    ``before`` (len(verts), 3): what was past it already stays."""
    for k in range(verts.shape[0]):
        i = verts[k]
        w = limit * r0[i, 0]
        budget = math.sqrt((X[i, 0] - before[k, 0]) ** 2 + (X[i, 1] - before[k, 1]) ** 2
                           + (X[i, 2] - before[k, 2]) ** 2)
        for s in range(seg.shape[1]):
            e = _envelope(i, s, r0, hold, w)
            if e >= NO_LIMIT or budget <= 0.0:
                continue
            cx, cy, cz = _closest_on_segment(X[i, 0], X[i, 1], X[i, 2], A, B, seg[i, s])
            ux, uy, uz = X[i, 0] - cx, X[i, 1] - cy, X[i, 2] - cz
            r = math.sqrt(ux * ux + uy * uy + uz * uz)
            back = min(r - e, budget)
            if back > 0.0 and r > 1e-12:
                c = back / r
                X[i, 0] -= ux * c
                X[i, 1] -= uy * c
                X[i, 2] -= uz * c
                budget -= back


@nb.njit(cache=True, nogil=True, inline="always")
def _hold(X, i, sx, sy, sz, cap):
    """Vertex ``i`` drawn back to within ``cap`` of ``(sx, sy, sz)`` along
    its move from there: 1 if it was, else 0."""
    dx, dy, dz = X[i, 0] - sx, X[i, 1] - sy, X[i, 2] - sz
    d = math.sqrt(dx * dx + dy * dy + dz * dz)
    if d <= cap:
        return 0
    t = cap / d
    X[i, 0] = sx + t * dx
    X[i, 1] = sy + t * dy
    X[i, 2] = sz + t * dz
    return 1


@nb.njit(cache=True, nogil=True)
def clearance_caps(clear, resolved, share, out):
    """``out[i]``: how far skin may move near another part's, ``share`` of
    its clearance ``clear[i]`` (0 where negative), over ``resolved[i]`` (inf
    where the skin is too coarse, 0, or nothing is near)."""
    for i in range(clear.shape[0]):
        if resolved[i] <= 0.0 or clear[i] == np.inf:
            out[i] = np.inf
        else:
            out[i] = share * max(clear[i], 0.0) / resolved[i]
    return out


@nb.njit(cache=True, nogil=True)
def hold_clear(X, verts, start, cap):
    """Every vertex ``i`` of ``verts`` further than ``cap[i]`` from where it
    started (``start`` (n, 3)) drawn back to that distance along its move
    (inf: no limit). Returns how many were."""
    n = 0
    for k in range(verts.shape[0]):
        i = verts[k]
        if cap[i] < np.inf:
            n += _hold(X, i, start[i, 0], start[i, 1], start[i, 2], cap[i])
    return n


@nb.njit(cache=True, nogil=True, inline="always")
def smoothstep(x):
    """0 below 0, 1 above 1, ``3x^2 - 2x^3`` between."""
    x = min(max(x, 0.0), 1.0)
    return x * x * (3.0 - 2.0 * x)


@nb.njit(cache=True, nogil=True)
def keep_region_volume(X, F, tris, c, corners, verts, mob, free, seg, r0, hold, A, B,
                       limit, vol0, cap, start, near, fade, g, room, share, outer):
    """One joint region's volume back to ``vol0`` (the cone from ``c`` over
    its triangles ``tris``, :func:`cone_volume_gradient`), by even layers
    along the volume's gradient: up to four within the bulge limit's
    envelope (:func:`envelope_room` at ``limit``, each vertex's share fading
    to none as its room runs out), then, if the region is still short (skin
    in contact all round, a coarse mesh), up to four past it, within the
    envelope at ``outer`` the same way. ``mob``
    (len(verts),) is each vertex's share of a layer; where the region is
    short it is also scaled by ``free`` (n,): skin in contact may sink into
    its own flesh, not swell into the other's. Layers move skin both ways
    (contact pushes skin out as well as in), by at most ``cap``; no vertex
    ``i`` ends further than ``near[i]`` from ``start[i]`` (skin near another
    part's, :func:`hold_clear`): its share fades to none over the last
    ``fade[i]`` of that. ``g``
    (len(verts), 3), ``room`` and ``share`` (len(verts),) are scratch.
    Returns the region's volume at the end."""
    vol = cone_volume_gradient(X, F, tris, c, corners, g)
    for it in range(8):
        deficit = vol0 - vol
        if abs(deficit) <= 2e-3 * abs(vol0):
            break
        out = deficit > 0.0
        if not out and it >= 4:
            break
        # within the bulge limit's envelope, then (the last four) the outer one
        env = limit if it < 4 else outer
        if out:
            envelope_room(X, verts, seg, r0, hold, A, B, env, room)
        den = 0.0
        for k in range(verts.shape[0]):
            i = verts[k]
            m = mob[k]
            if out:
                m *= free[i]
                m *= smoothstep(room[k] / max(0.5 * env * r0[i, 0], 1e-12))
            if near[i] < np.inf:
                d = math.sqrt((X[i, 0] - start[i, 0]) ** 2 + (X[i, 1] - start[i, 1]) ** 2
                              + (X[i, 2] - start[i, 2]) ** 2)
                m *= smoothstep((near[i] - d) / max(fade[i], 1e-12))
            share[k] = m
            den += m * math.sqrt(g[k, 0] ** 2 + g[k, 1] ** 2 + g[k, 2] ** 2)
        if den <= 0.0:
            continue
        s = deficit / den
        for k in range(verts.shape[0]):
            i = verts[k]
            step = min(max(s * share[k], -cap), cap)
            if out:
                step = min(step, room[k])
            a = max(math.sqrt(g[k, 0] ** 2 + g[k, 1] ** 2 + g[k, 2] ** 2), 1e-30)
            X[i, 0] += step * g[k, 0] / a
            X[i, 1] += step * g[k, 1] / a
            X[i, 2] += step * g[k, 2] / a
            if near[i] < np.inf:
                _hold(X, i, start[i, 0], start[i, 1], start[i, 2], near[i])
        vol = cone_volume_gradient(X, F, tris, c, corners, g)
    return vol


@nb.njit(cache=True, nogil=True)
def even_layer(X, verts, g, mob, deficit, cap, env, room, r0, limit, held, near, start, fade,
               share):
    """One even layer over ``verts`` towards a volume ``deficit`` along the
    volume's gradient ``g`` (len(verts), 3): vertex ``verts[k]`` moves by its
    share ``mob[k]`` of a step that makes up the deficit to first order, by
    at most ``cap`` either way. With ``env`` its share fades to none as its
    ``room`` (:func:`envelope_room`) falls from half of ``limit`` times its
    rest distance ``r0[i, 0]`` to 0, and it moves no further than that room;
    with ``held`` it fades to none over the last ``fade[i]`` of how far it may
    be from ``start[i]`` (``near[i]``, :func:`hold_clear`). ``share``
    (len(verts),) is scratch. Returns False, moving nothing, when no vertex
    takes any of the layer."""
    den = 0.0
    for k in range(verts.shape[0]):
        i = verts[k]
        m = mob[k]
        if env:
            m *= smoothstep(room[k] / max(0.5 * limit * r0[i, 0], 1e-12))
        if held:
            d = math.sqrt((X[i, 0] - start[i, 0]) ** 2 + (X[i, 1] - start[i, 1]) ** 2
                          + (X[i, 2] - start[i, 2]) ** 2)
            m *= smoothstep((near[i] - d) / max(fade[i], 1e-12))
        share[k] = m
        den += m * math.sqrt(g[k, 0] ** 2 + g[k, 1] ** 2 + g[k, 2] ** 2)
    if den <= 0.0:
        return False
    s = deficit / den
    for k in range(verts.shape[0]):
        i = verts[k]
        step = min(max(s * share[k], -cap), cap)
        if env:
            step = min(step, room[k])
        a = max(math.sqrt(g[k, 0] ** 2 + g[k, 1] ** 2 + g[k, 2] ** 2), 1e-30)
        X[i, 0] += step * (g[k, 0] / a)
        X[i, 1] += step * (g[k, 1] / a)
        X[i, 2] += step * (g[k, 2] / a)
    return True


@nb.njit(cache=True, nogil=True)
def cone_volume_gradient(X, F, tris, c, corners, g):
    """Volume of the cone from ``c`` over triangles ``tris`` of ``X`` and its
    gradient ``g`` with respect to the vertices the triangles' ``corners``
    (len(tris), 3) name: ``corners[r, q]`` is the row of ``g`` that corner
    ``q`` of triangle ``tris[r]`` adds to, -1 for a corner outside them
    (:func:`region_corners`). One pass over the triangles, each adding to
    its corners in turn (so each row sums its triangles in their order)."""
    vol = 0.0
    g[:] = 0.0
    for r in range(tris.shape[0]):
        f = tris[r]
        a, b, d = F[f, 0], F[f, 1], F[f, 2]
        ax, ay, az = X[a, 0] - c[0], X[a, 1] - c[1], X[a, 2] - c[2]
        bx, by, bz = X[b, 0] - c[0], X[b, 1] - c[1], X[b, 2] - c[2]
        dx, dy, dz = X[d, 0] - c[0], X[d, 1] - c[1], X[d, 2] - c[2]
        # d(det)/dp of a corner: the cross product of the two after it in turn
        cx, cy, cz = by * dz - bz * dy, bz * dx - bx * dz, bx * dy - by * dx
        vol += ax * cx + ay * cy + az * cz
        k = corners[r, 0]
        if k >= 0:
            g[k, 0] += cx
            g[k, 1] += cy
            g[k, 2] += cz
        k = corners[r, 1]
        if k >= 0:
            g[k, 0] += dy * az - dz * ay
            g[k, 1] += dz * ax - dx * az
            g[k, 2] += dx * ay - dy * ax
        k = corners[r, 2]
        if k >= 0:
            g[k, 0] += ay * bz - az * by
            g[k, 1] += az * bx - ax * bz
            g[k, 2] += ax * by - ay * bx
    for k in range(g.shape[0]):
        g[k, 0], g[k, 1], g[k, 2] = g[k, 0] / 6.0, g[k, 1] / 6.0, g[k, 2] / 6.0
    return vol / 6.0


@nb.njit(cache=True, nogil=True)
def moved_rows(X, Y):
    """Whether each row of ``X`` (n, 3) differs from ``Y``'s: numpy's
    ``(X != Y).any(axis=1)`` without its (n, 3) temporary and its slow
    reduction over rows of three (0.17 ms a call on 24k rows)."""
    out = np.empty(X.shape[0], dtype=np.bool_)
    for i in range(X.shape[0]):
        out[i] = X[i, 0] != Y[i, 0] or X[i, 1] != Y[i, 1] or X[i, 2] != Y[i, 2]
    return out


@nb.njit(cache=True, nogil=True)
def enclosed_volume(X, F):
    """The volume a closed surface encloses (the signed cones from the origin)."""
    vol = 0.0
    for f in range(F.shape[0]):
        a, b, d = F[f, 0], F[f, 1], F[f, 2]
        vol += (X[a, 0] * (X[b, 1] * X[d, 2] - X[b, 2] * X[d, 1])
                + X[a, 1] * (X[b, 2] * X[d, 0] - X[b, 0] * X[d, 2])
                + X[a, 2] * (X[b, 0] * X[d, 1] - X[b, 1] * X[d, 0]))
    return vol / 6.0


def region_corners(F: np.ndarray, tris: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """For :func:`cone_volume_gradient`: each corner of triangles ``tris``
    as its position in ``verts`` (len(tris), 3), -1 where it is not one."""
    F = np.asarray(F, dtype=np.int64)
    tris = np.asarray(tris, dtype=np.int64)
    verts = np.asarray(verts, dtype=np.int64)
    if not len(tris):
        return np.zeros((0, 3), dtype=np.int64)
    pos = np.full(max(int(F.max()), int(verts.max()) if len(verts) else 0) + 1, -1,
                  dtype=np.int64)
    pos[verts] = np.arange(len(verts))
    return np.ascontiguousarray(pos[F[tris]])


@nb.njit(cache=True, nogil=True)
def split_fade(out, jptr, jverts, jsplit, joint_fade):
    """``out[i] = max_j jsplit * joint_fade[j]`` over the joints ``j`` with
    ``joint_fade[j] > 0`` whose split skin (``jverts[jptr[j]:jptr[j+1]]``,
    CSR, with ``jsplit`` alongside) holds ``i``; ``out`` must be 0 there."""
    for j in range(joint_fade.shape[0]):
        f = joint_fade[j]
        if f <= 0.0:
            continue
        for k in range(jptr[j], jptr[j + 1]):
            i = jverts[k]
            x = jsplit[k] * f
            if x > out[i]:
                out[i] = x


@nb.njit(cache=True, nogil=True, inline="always")
def _dihedral(X, F, f, g):
    """The angle (radians) between the normals of triangles ``f`` and ``g``
    (a right angle where either has no area)."""
    ax, ay, az = _normal(X, F[f, 0], F[f, 1], F[f, 2])
    bx, by, bz = _normal(X, F[g, 0], F[g, 1], F[g, 2])
    la = math.sqrt(ax * ax + ay * ay + az * az)
    lb = math.sqrt(bx * bx + by * by + bz * bz)
    c = (ax * bx + ay * by + az * bz) / (la * lb) if la > 1e-30 and lb > 1e-30 else 0.0
    return math.acos(min(1.0, max(-1.0, c)))


@nb.njit(cache=True, nogil=True)
def bent_edges(X, before, F, fa, fb, moved, limit, hit):
    """Marks in ``hit`` (n,) bool the corners of the triangle pairs ``fa[k]``,
    ``fb[k]`` (sharing an edge) with a corner in ``moved`` whose dihedral
    angle (between their normals) grew by more than ``limit`` radians from
    ``before`` to ``X``; returns how many pairs did."""
    m = 0
    for k in range(fa.shape[0]):
        f, g = fa[k], fb[k]
        if not (moved[F[f, 0]] or moved[F[f, 1]] or moved[F[f, 2]]
                or moved[F[g, 0]] or moved[F[g, 1]] or moved[F[g, 2]]):
            continue
        if _dihedral(X, F, f, g) - _dihedral(before, F, f, g) > limit:
            m += 1
            for r in range(3):
                hit[F[f, r]] = True
                hit[F[g, r]] = True
    return m


@nb.njit(cache=True, nogil=True)
def bent_by_patch(X, before, F, fa, fb, label, limit, count):
    """Adds to ``count[p]`` the triangle pairs ``fa[k]``, ``fb[k]`` with a
    corner on patch ``p`` (``label`` >= 0; the first such corner's) whose
    dihedral angle grew by more than ``limit`` radians from ``before`` to
    ``X``, as :func:`bent_edges` counts them."""
    for k in range(fa.shape[0]):
        f, g = fa[k], fb[k]
        p = -1
        for r in range(3):
            if p < 0 and label[F[f, r]] >= 0:
                p = label[F[f, r]]
            if p < 0 and label[F[g, r]] >= 0:
                p = label[F[g, r]]
        if p < 0:
            continue
        if _dihedral(X, F, f, g) - _dihedral(before, F, f, g) > limit:
            count[p] += 1


@nb.njit(cache=True, nogil=True)
def most_bent(X, before, rest_angle, floor, F, fa, fb, verts, eptr, edges, seen, out):
    """On every corner of the triangle pairs ``fa[k]``, ``fb[k]`` (sharing an
    edge) listed for ``verts`` (``edges[eptr[i]:eptr[i+1]]`` those of vertex
    ``i``, each pair once or more), ``out[i]`` raised to the most their
    dihedral angle (radians) in ``X`` exceeds both its angle in ``before``
    and ``rest_angle[k]``, among the pairs whose angle's cosine in ``X``
    is below ``floor[k]`` (the cosine of the rest angle and the least
    excess that counts: the rest are skipped without an arc cosine).
    ``out`` must hold 0 (or less) there on entry and ``seen`` (one per pair)
    False, as it is left. Returns how many pairs count."""
    m = 0
    for a in range(verts.shape[0]):
        i = verts[a]
        for b in range(eptr[i], eptr[i + 1]):
            k = edges[b]
            if seen[k]:
                continue
            seen[k] = True
            f, g = fa[k], fb[k]
            ax, ay, az = _normal(X, F[f, 0], F[f, 1], F[f, 2])
            bx, by, bz = _normal(X, F[g, 0], F[g, 1], F[g, 2])
            la = math.sqrt(ax * ax + ay * ay + az * az)
            lb = math.sqrt(bx * bx + by * by + bz * bz)
            c = (ax * bx + ay * by + az * bz) / (la * lb) if la > 1e-30 and lb > 1e-30 else 0.0
            if c >= floor[k]:
                continue
            d = math.acos(max(-1.0, c)) - max(_dihedral(before, F, f, g), rest_angle[k])
            if d <= 0.0:
                continue
            m += 1
            for r in range(3):
                out[F[f, r]] = max(out[F[f, r]], d)
                out[F[g, r]] = max(out[F[g, r]], d)
    for a in range(verts.shape[0]):
        i = verts[a]
        for b in range(eptr[i], eptr[i + 1]):
            seen[edges[b]] = False
    return m


@nb.njit(cache=True, nogil=True)
def dihedral_angles(X, F, fa, fb):
    """The angle (radians) between the normals of ``fa[k]`` and ``fb[k]``."""
    out = np.empty(fa.shape[0])
    for k in range(fa.shape[0]):
        out[k] = _dihedral(X, F, fa[k], fb[k])
    return out
