"""Volume constraints on the surface (numba): the enclosed volume of the whole
mesh or of a joint region's cone, their gradients, moves along the unit
normals, and the region swell that keeps only the moves that cross no skin
(:mod:`skin_node.stages.volume` says what each is for)."""
from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from .collision import crossed_at, in_box, longest_edge, near_points, seg_dist


@nb.njit(cache=True, nogil=True)
def volume_and_gradient(X, F, inc_ptr, inc, verts, g):
    """Enclosed volume of the whole mesh, and ``g_i = dV/dp_i`` for ``verts`` only:
    ``(1/6) sum over the faces (i, b, c) around i of p_b x p_c``."""
    vol = 0.0
    for f in range(F.shape[0]):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        vol += (X[a, 0] * (X[b, 1] * X[c, 2] - X[b, 2] * X[c, 1])
                + X[a, 1] * (X[b, 2] * X[c, 0] - X[b, 0] * X[c, 2])
                + X[a, 2] * (X[b, 0] * X[c, 1] - X[b, 1] * X[c, 0])) / 6.0
    for k in range(verts.shape[0]):
        i = verts[k]
        gx = gy = gz = 0.0
        for q in range(inc_ptr[i], inc_ptr[i + 1]):
            f = inc[q]
            e = 0
            while F[f, e] != i:
                e += 1
            b, c = F[f, (e + 1) % 3], F[f, (e + 2) % 3]
            gx += X[b, 1] * X[c, 2] - X[b, 2] * X[c, 1]
            gy += X[b, 2] * X[c, 0] - X[b, 0] * X[c, 2]
            gz += X[b, 0] * X[c, 1] - X[b, 1] * X[c, 0]
        g[k, 0], g[k, 1], g[k, 2] = gx / 6.0, gy / 6.0, gz / 6.0
    return vol


@nb.njit(cache=True, nogil=True, inline="always")
def flesh_ramp(d, R):
    """0 within the other side's flesh radius ``R`` of its bone, rising to 1 at 1.5 ``R``."""
    return min(1.0, max(0.0, (d / max(R, 1e-9) - 1.0) / 0.5))


@nb.njit(cache=True, nogil=True)
def zone_mobility(X, mob, Z, ZJ, ZL, ZS, fade, A, B, R, m):
    """``m[ZL] = max over entries of mob[Z, j] * fade[j] * ramp``, with ramp 0
    within the other side's flesh radius ``R`` of its bone, 1 past 1.5 R."""
    for e in range(Z.shape[0]):
        i, j, o = Z[e], ZJ[e], 1 - ZS[e]
        ramp = flesh_ramp(seg_dist(X[i, 0], X[i, 1], X[i, 2], A[j, o], B[j, o]), R[j, o])
        val = mob[e] * fade[j] * ramp
        if val > m[ZL[e]]:
            m[ZL[e]] = val


@nb.njit(cache=True, nogil=True)
def region_volume_gradient(X, F, tris, cx, cy, cz, g):
    """Volume of the cone from ``c`` over the triangles ``tris`` and its gradient,
    written into ``g`` at their vertices (other rows of ``g`` are left alone)."""
    for a in range(tris.shape[0]):
        for e in range(3):
            v = F[tris[a], e]
            g[v, 0] = g[v, 1] = g[v, 2] = 0.0
    vol = 0.0
    for a in range(tris.shape[0]):
        i, j, k = F[tris[a], 0], F[tris[a], 1], F[tris[a], 2]
        ax, ay, az = X[i, 0] - cx, X[i, 1] - cy, X[i, 2] - cz
        bx, by, bz = X[j, 0] - cx, X[j, 1] - cy, X[j, 2] - cz
        qx, qy, qz = X[k, 0] - cx, X[k, 1] - cy, X[k, 2] - cz
        # b x q, q x a, a x b: the gradients at i, j, k (times 6)
        ux, uy, uz = by * qz - bz * qy, bz * qx - bx * qz, bx * qy - by * qx
        vx, vy, vz = qy * az - qz * ay, qz * ax - qx * az, qx * ay - qy * ax
        wx, wy, wz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
        vol += (ax * ux + ay * uy + az * uz) / 6.0
        g[i, 0] += ux / 6.0
        g[i, 1] += uy / 6.0
        g[i, 2] += uz / 6.0
        g[j, 0] += vx / 6.0
        g[j, 1] += vy / 6.0
        g[j, 2] += vz / 6.0
        g[k, 0] += wx / 6.0
        g[k, 1] += wy / 6.0
        g[k, 2] += wz / 6.0
    return vol


@nb.njit(cache=True, nogil=True)
def move_along_normals(X, verts, m, g, C, budget):
    """Project ``C = 0`` to first order by moving ``verts`` along their unit
    normals ``g / |g|`` by ``lam * m_i``; ``dV = sum g . dp = lam sum m |g|``.
    ``|lam|`` is clipped to ``budget``; returns the ``lam`` applied and the
    first-order volume change ``lam sum m |g|``."""
    den = 0.0
    for a in range(verts.shape[0]):
        i = verts[a]
        den += m[a] * math.sqrt(g[i, 0] ** 2 + g[i, 1] ** 2 + g[i, 2] ** 2)
    if den <= 1e-30:
        return 0.0, 0.0
    lam = min(max(-C / den, -budget), budget)
    for a in range(verts.shape[0]):
        i = verts[a]
        L = math.sqrt(g[i, 0] ** 2 + g[i, 1] ** 2 + g[i, 2] ** 2)
        if L > 1e-30:
            f = lam * m[a] / L
            X[i, 0] += f * g[i, 0]
            X[i, 1] += f * g[i, 1]
            X[i, 2] += f * g[i, 2]
    return lam, lam * den


class RegionSwell(NamedTuple):
    """One joint region's volume constraint, as :func:`restore_region` and
    :func:`swell_checked` read it."""

    F: np.ndarray           # (m, 3) the surface's triangles
    tris: np.ndarray        # the region's triangles
    c: np.ndarray           # (3,) the posed joint centre, the cones' apex
    verts: np.ndarray       # the region's vertices that may move
    mob: np.ndarray         # their mobility
    side: np.ndarray        # their side
    fade: float             # the joint's fade
    A: np.ndarray           # (2, 3) starts of the posed bones (parent side's, child side's)
    B: np.ndarray           # (2, 3) their ends
    R: np.ndarray           # (2,) each side's flesh radius about its bone
    hops: np.ndarray        # (n,) rings from skin in contact, per surface vertex
    ring_width: float       # rings over which skin next to a contact comes free
    vol0: float             # the region's rest volume
    max_move: float         # the most any vertex moves
    g: np.ndarray           # (n, 3) scratch: the volume's gradient
    m: np.ndarray           # (>= len(verts),) scratch: the mobilities applied
    passes: int             # projections


@nb.njit(cache=True, nogil=True)
def restore_region(X, swell, guarded):
    """Give the joint region ``swell.tris`` (:class:`RegionSwell`) its rest
    volume ``vol0`` back (cone from the posed joint centre ``c``), moving
    ``verts`` along their normals by at most ``max_move``. Mobility: ``mob *
    fade``; with ``guarded``, times a ramp from 0 within the other side's flesh
    radius ``R`` of its bone (``A``-``B``) to 1 at 1.5 ``R``, times ``min(1,
    hops / ring_width)`` (rings from skin in contact). Returns the region's
    volume ratio after the ``passes`` projections, to first order."""
    F, tris, c, verts, mob, side, fade = (swell.F, swell.tris, swell.c, swell.verts, swell.mob,
                                          swell.side, swell.fade)
    A, B, R, hops, ring_width, vol0 = (swell.A, swell.B, swell.R, swell.hops, swell.ring_width,
                                       swell.vol0)
    max_move, g, m, passes = swell.max_move, swell.g, swell.m, swell.passes
    mmax = 0.0
    for a in range(verts.shape[0]):
        i, o = verts[a], 1 - side[a]
        m[a] = mob[a] * fade
        if guarded:
            ramp = flesh_ramp(seg_dist(X[i, 0], X[i, 1], X[i, 2], A[o], B[o]), R[o])
            m[a] *= ramp * min(1.0, hops[i] / ring_width)
        mmax = max(mmax, m[a])
    if vol0 == 0.0:
        return 1.0
    budget = max_move / max(mmax, 1e-30)
    vol = vol0
    for _ in range(passes):
        vol = region_volume_gradient(X, F, tris, c[0], c[1], c[2], g)
        if mmax <= 0.0:
            break
        lam, dv = move_along_normals(X, verts, m, g, vol - vol0, budget)
        budget -= abs(lam)
        vol += dv
    return vol / vol0


@nb.njit(cache=True, nogil=True)
def new_crossings(X, test, fit, refit, hint, pos, nth, v, keep):
    """Of ``pos`` (positions into the region's vertices ``test.verts``, a
    :class:`~skin_node.kernels.collision.RegionTest`), those whose vertex
    crosses skin now but did not with ``v`` at ``keep``, and the triangles they
    cross (-2: none, deep in the other side's flesh). Both tests are
    :func:`~skin_node.kernels.collision.crossed_at`'s, the first fitting the
    tree afresh with ``refit``."""
    hit = crossed_at(X, test, fit, refit, hint, pos, nth)
    now = np.flatnonzero(hit != -1)
    if now.shape[0] == 0:
        return pos[now], hit[now]
    # the same test of those, with v back at keep
    moved = np.empty((v.shape[0], 3))
    for a in range(v.shape[0]):
        for d in range(3):
            moved[a, d] = X[v[a], d]
            X[v[a], d] = keep[a, d]
    before = crossed_at(X, test, fit, False, hint, pos[now], nth)
    for a in range(v.shape[0]):
        for d in range(3):
            X[v[a], d] = moved[a, d]
    new = now[before == -1]
    return pos[new], hit[new]


@nb.njit(cache=True, nogil=True)
def swell_checked(X, swell, ratio, m_guarded, test, fit, refit, hint, edge, emax, nth):
    """:meth:`skin_node.stages.volume.Volume._checked`'s swell and check of one
    joint region: :func:`restore_region` of ``swell`` unguarded, after the
    guarded one gave ``ratio`` with the mobilities ``m_guarded``, then the
    crossing test ``test`` (:class:`~skin_node.kernels.collision.RegionTest`
    over the region's vertices; its ``reach`` the detection cell) with its
    tree boxes ``fit``, ``refit`` and ``hint`` as in
    :func:`~skin_node.kernels.collision.crossed_at`; ``edge`` and ``emax`` the
    median and longest rest edges. Returns the region's volume ratio."""
    F, tris, c, v, max_move = swell.F, swell.tris, swell.c, swell.verts, swell.max_move
    g, m, vol0 = swell.g, swell.m, swell.vol0
    verts, cell = test.verts, test.reach
    nv = v.shape[0]
    keep = np.empty((nv, 3))
    for a in range(nv):
        for d in range(3):
            keep[a, d] = X[v[a], d]
    new = restore_region(X, swell, False)
    freed = np.flatnonzero(m[:nv] > m_guarded + 1e-9)
    if freed.shape[0] == 0:
        return new
    reach = cell + 2.0 * emax
    retest = max(reach, cell + longest_edge(X, F, tris) + 2.0 * max_move)
    P = np.empty((2 * freed.shape[0], 3))
    for b in range(freed.shape[0]):
        for d in range(3):
            P[b, d] = X[v[freed[b]], d]
            P[freed.shape[0] + b, d] = keep[freed[b], d]
    sub = in_box(X, verts, np.arange(verts.shape[0]), P, retest)
    bad, tri = new_crossings(X, test, fit, refit, hint, sub, nth, v, keep)
    every = np.arange(nv)
    for r in (1.5 * edge, 3.0 * edge, reach, reach, reach):
        if bad.shape[0] == 0:
            return region_volume_gradient(X, F, tris, c[0], c[1], c[2], g) / vol0
        # Put back the skin near each new crossing, then or now, and the corners
        # of the triangle it crosses; test again around it.
        P = np.empty((bad.shape[0], 3))
        for b in range(bad.shape[0]):
            for d in range(3):
                P[b, d] = X[verts[bad[b]], d]
        mark = np.zeros(nv, dtype=np.bool_)
        for near_now in (near_points(X, v, P, r), near_points(keep, every, P, r)):
            for b in range(near_now.shape[0]):
                mark[near_now[b]] = True
        for b in range(tri.shape[0]):
            if tri[b] < 0:
                continue
            for e in range(3):
                corner = F[tri[b], e]
                at = min(np.searchsorted(v, corner), nv - 1)
                if v[at] == corner:
                    mark[at] = True
        back = np.flatnonzero(mark)
        if back.shape[0] == 0:
            break
        P = np.empty((2 * back.shape[0], 3))
        for b in range(back.shape[0]):
            for d in range(3):
                P[b, d] = X[v[back[b]], d]
                P[back.shape[0] + b, d] = keep[back[b], d]
                X[v[back[b]], d] = keep[back[b], d]
        near = in_box(X, verts, sub, P, retest)
        bad, tri = new_crossings(X, test, fit, False, hint, near, nth, v, keep)
    for a in range(nv):
        for d in range(3):
            X[v[a], d] = keep[a, d]
    return ratio
