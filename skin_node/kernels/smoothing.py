"""Smoothing kernels (numba): Laplacian smoothing of a vertex set gathered into a
compact ring layout, and Delta Mush.

Delta Mush: smoothing that rounds what a deformation crumpled and keeps the rest
pose's detail (Mancewicz et al., "Delta Mush: smoothing deformations while
preserving detail", DigiPro 2014).

Smoothing the posed skin ``X`` rounds its creases and crumples but also melts
its detail; the detail is the rest skin's difference from the same smoothing of
it, ``d = V - S(V)``. Carried in each vertex's frame (its normal and a tangent
towards one neighbour), the smoothed rest skin's frame to the smoothed posed
skin's, it comes back: ``X' = S(X) + R d``. Where the neighbourhood moved
rigidly, ``S`` commutes with the motion and ``X' = X`` exactly.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from . import FAST

#: no weights or factors: :func:`laplacian_smooth`'s ``lw`` or ``kw`` for an even step
EVEN = np.empty(0)


@nb.njit(cache=True, nogil=True, inline="always")
def _frame(S, F, vf_ptr, vf, first, i):
    """Vertex ``i``'s frame on surface ``S``: tangent ``t``, bitangent ``n x t``
    and ``n``, the sum of its faces' normals, unit length; tangent towards
    neighbour ``first[i]`` in its tangent plane. Zero where degenerate."""
    nx = ny = nz = 0.0
    for k in range(vf_ptr[i], vf_ptr[i + 1]):
        f = vf[k]
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        ux, uy, uz = S[b, 0] - S[a, 0], S[b, 1] - S[a, 1], S[b, 2] - S[a, 2]
        vx, vy, vz = S[c, 0] - S[a, 0], S[c, 1] - S[a, 1], S[c, 2] - S[a, 2]
        nx += uy * vz - uz * vy
        ny += uz * vx - ux * vz
        nz += ux * vy - uy * vx
    s = np.sqrt(nx * nx + ny * ny + nz * nz)
    if s < 1e-30:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    nx, ny, nz = nx / s, ny / s, nz / s
    j = first[i]
    tx, ty, tz = S[j, 0] - S[i, 0], S[j, 1] - S[i, 1], S[j, 2] - S[i, 2]
    d = tx * nx + ty * ny + tz * nz
    tx, ty, tz = tx - d * nx, ty - d * ny, tz - d * nz
    s = np.sqrt(tx * tx + ty * ty + tz * tz)
    if s < 1e-30:
        return 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0
    tx, ty, tz = tx / s, ty / s, tz / s
    bx, by, bz = ny * tz - nz * ty, nz * tx - nx * tz, nx * ty - ny * tx
    return tx, ty, tz, bx, by, bz, nx, ny, nz


@nb.njit(cache=True, nogil=True, parallel=True)
def restore_detail(X, V0, SX, SV, verts, F, vf_ptr, vf, first, fade):
    """``X[i] <- S(X)[i] + R_i (V0[i] - S(V0)[i])`` for every vertex of
    ``verts``, blended with ``X[i]`` by ``fade[i]`` (0 keeps it): ``SX`` and
    ``SV`` are the smoothed posed and rest skin, ``R_i`` takes vertex ``i``'s
    frame on ``SV`` to its frame on ``SX`` (:func:`_frame`). A vertex whose
    frame is degenerate on either keeps its place."""
    for k in nb.prange(verts.shape[0]):
        i = verts[k]
        f = fade[i]
        if f <= 0.0:
            continue
        t0x, t0y, t0z, b0x, b0y, b0z, n0x, n0y, n0z = _frame(SV, F, vf_ptr, vf, first, i)
        t1x, t1y, t1z, b1x, b1y, b1z, n1x, n1y, n1z = _frame(SX, F, vf_ptr, vf, first, i)
        if (n0x == 0.0 and n0y == 0.0 and n0z == 0.0) or \
                (n1x == 0.0 and n1y == 0.0 and n1z == 0.0):
            continue
        dx, dy, dz = V0[i, 0] - SV[i, 0], V0[i, 1] - SV[i, 1], V0[i, 2] - SV[i, 2]
        ct = dx * t0x + dy * t0y + dz * t0z
        cb = dx * b0x + dy * b0y + dz * b0z
        cn = dx * n0x + dy * n0y + dz * n0z
        yx = SX[i, 0] + ct * t1x + cb * b1x + cn * n1x
        yy = SX[i, 1] + ct * t1y + cb * b1y + cn * n1y
        yz = SX[i, 2] + ct * t1z + cb * b1z + cn * n1z
        X[i, 0] += f * (yx - X[i, 0])
        X[i, 1] += f * (yy - X[i, 1])
        X[i, 2] += f * (yz - X[i, 2])


@nb.njit(cache=True, nogil=True, inline="always")
def _ring_mean_offset(X, ptr, adj, i):
    """The mean of vertex ``i``'s one ring on ``X`` less its own position
    (the even umbrella Laplacian); zeros for a vertex with no neighbour."""
    m = ptr[i + 1] - ptr[i]
    if m == 0:
        return 0.0, 0.0, 0.0
    cx = cy = cz = 0.0
    for b in range(ptr[i], ptr[i + 1]):
        q = adj[b]
        cx += X[q, 0]
        cy += X[q, 1]
        cz += X[q, 2]
    return cx / m - X[i, 0], cy / m - X[i, 1], cz / m - X[i, 2]


@nb.njit(cache=True, nogil=True, inline="always")
def _face_cos(ax, ay, az, bx, by, bz, cx, cy, cz, nx, ny, nz):
    """The cosine between triangle ``abc``'s normal and ``n`` (-1 if degenerate)."""
    ux, uy, uz = bx - ax, by - ay, bz - az
    vx, vy, vz = cx - ax, cy - ay, cz - az
    fx, fy, fz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    s = np.sqrt(fx * fx + fy * fy + fz * fz)
    return (fx * nx + fy * ny + fz * nz) / s if s > 1e-300 else -1.0


@nb.njit(cache=True, nogil=True, inline="always")
def _turns_a_face_over(X, F, vf_ptr, vf, i, mx, my, mz, nx, ny, nz):
    """Whether moving vertex ``i`` by ``m`` turns the worst of its faces on
    ``X`` further from normal ``n`` (the least cosine between them falls)."""
    before = after = 1.0
    for q in range(vf_ptr[i], vf_ptr[i + 1]):
        f = vf[q]
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        ax, ay, az = X[a, 0], X[a, 1], X[a, 2]
        bx, by, bz = X[b, 0], X[b, 1], X[b, 2]
        cx, cy, cz = X[c, 0], X[c, 1], X[c, 2]
        before = min(before, _face_cos(ax, ay, az, bx, by, bz, cx, cy, cz, nx, ny, nz))
        if a == i:
            ax, ay, az = ax + mx, ay + my, az + mz
        elif b == i:
            bx, by, bz = bx + mx, by + my, bz + mz
        else:
            cx, cy, cz = cx + mx, cy + my, cz + mz
        after = min(after, _face_cos(ax, ay, az, bx, by, bz, cx, cy, cz, nx, ny, nz))
    return after < before


@nb.njit(cache=True, nogil=True, parallel=True)
def rest_tangents(V0, F, vf_ptr, vf, first, ptr, adj, out):
    """``out[i]`` (n, 2): the tangential part of vertex ``i``'s umbrella
    Laplacian on the rest skin ``V0``, in its rest frame (:func:`_frame`):
    where its one ring's mean lies beside it, along the tangent and the
    bitangent (what :func:`relax_tangents` slides it back towards)."""
    for i in nb.prange(V0.shape[0]):
        tx, ty, tz, bx, by, bz, nx, ny, nz = _frame(V0, F, vf_ptr, vf, first, i)
        dx, dy, dz = _ring_mean_offset(V0, ptr, adj, i)
        out[i, 0] = dx * tx + dy * ty + dz * tz
        out[i, 1] = dx * bx + dy * by + dz * bz
    return out


@nb.njit(cache=True, nogil=True, parallel=True)
def relax_tangents(X, verts, weight, F, vf_ptr, vf, first, ptr, adj, rest, step, passes, guard,
                   buf):
    """Tangential relaxation of ``verts`` on ``X``, in place, ``passes``
    Jacobi passes: each vertex slides in its tangent plane (its faces'
    normal) by ``step * weight[k]`` of the way to where its one ring's mean
    puts it at rest (``rest``, :func:`rest_tangents`, carried in its frame),
    never along its normal: the shape stays, the triangles regain their rest
    shape. Where the neighbourhood moved rigidly nothing moves (to rounding).
    With ``guard``, a vertex keeps its place where its move would turn the
    worst of its faces further from its normal (:func:`_turns_a_face_over`):
    on skin crushed flat its frame can point anywhere, and unguarded, a 3 mm
    slide on CesiumMan's head at a pose far past its joints' reach turned
    regular 15 mm triangles over.
    ``buf`` (len(verts), 3) is scratch; the result does not depend on the
    threads."""
    for _ in range(passes):
        for k in nb.prange(verts.shape[0]):
            i = verts[k]
            buf[k, 0] = buf[k, 1] = buf[k, 2] = 0.0
            s = step * weight[k]
            if s <= 0.0:
                continue
            tx, ty, tz, bx, by, bz, nx, ny, nz = _frame(X, F, vf_ptr, vf, first, i)
            if nx == 0.0 and ny == 0.0 and nz == 0.0:
                continue
            dx, dy, dz = _ring_mean_offset(X, ptr, adj, i)
            d = dx * nx + dy * ny + dz * nz
            u, v = rest[i, 0], rest[i, 1]
            mx = s * (dx - d * nx - u * tx - v * bx)
            my = s * (dy - d * ny - u * ty - v * by)
            mz = s * (dz - d * nz - u * tz - v * bz)
            if guard and _turns_a_face_over(X, F, vf_ptr, vf, i, mx, my, mz, nx, ny, nz):
                continue
            buf[k, 0], buf[k, 1], buf[k, 2] = mx, my, mz
        for k in nb.prange(verts.shape[0]):
            i = verts[k]
            X[i, 0] += buf[k, 0]
            X[i, 1] += buf[k, 1]
            X[i, 2] += buf[k, 2]


def vertex_faces(F: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """CSR of the faces around every vertex: faces ``vf[vf_ptr[i]:vf_ptr[i+1]]``."""
    flat = F.ravel()
    order = np.argsort(flat, kind="stable")
    vf = (order // 3).astype(np.int64)
    vf_ptr = np.searchsorted(flat[order], np.arange(n + 1)).astype(np.int64)
    return vf_ptr, vf


def ring_layout(verts: np.ndarray, ptr: np.ndarray, nbr: np.ndarray):
    """The compact layout :func:`laplacian_smooth` works in: ``verts`` (sorted)
    and their one ring gathered into ``ring`` (sorted), ``loc`` the position of
    each of ``verts`` in it, and the verts' adjacency as CSR ``lptr``/``lnbr``
    into ``ring``. Gathered, a joint region's few thousand vertices stay in
    cache through the passes, where the whole surface and its adjacency would
    not."""
    verts = np.ascontiguousarray(verts, dtype=np.int64)
    return _ring_layout(verts, ptr, nbr, np.full(len(ptr) - 1, -1, dtype=np.int64))


@nb.njit(cache=True, nogil=True)
def _ring_layout(verts, ptr, nbr, pos):
    n = 0
    for k in range(verts.shape[0]):
        i = verts[k]
        if pos[i] < 0:
            pos[i] = 0
            n += 1
        for b in range(ptr[i], ptr[i + 1]):
            q = nbr[b]
            if pos[q] < 0:
                pos[q] = 0
                n += 1
    ring = np.empty(n, dtype=np.int64)
    m = 0
    for v in range(pos.shape[0]):
        if pos[v] >= 0:
            pos[v] = m
            ring[m] = v
            m += 1
    loc = np.empty(verts.shape[0], dtype=np.int64)
    lptr = np.zeros(verts.shape[0] + 1, dtype=np.int64)
    for k in range(verts.shape[0]):
        i = verts[k]
        loc[k] = pos[i]
        lptr[k + 1] = lptr[k] + ptr[i + 1] - ptr[i]
    lnbr = np.empty(lptr[-1], dtype=np.int32)
    for k in range(verts.shape[0]):
        i = verts[k]
        for b in range(ptr[i], ptr[i + 1]):
            lnbr[lptr[k] + b - ptr[i]] = pos[nbr[b]]
    return ring, loc, lptr, lnbr


@nb.njit(cache=True, nogil=True, parallel=True, fastmath=FAST)
def laplacian_smooth(X, base, relative, ring, loc, lptr, lnbr, lw, k, kw, iterations, L, buf):
    """Jacobi Laplacian smoothing of the vertices of a :func:`ring_layout`, in
    place: ``p <- (1-k) p + k mean(one ring)``, ``iterations`` times, of the
    positions ``X`` or, with ``relative``, of the displacements ``X - base``
    (``X = base + smoothed``). ``L`` (len(ring), 3) and ``buf`` (len(loc), 3)
    are scratch. The ring is read, only the vertices themselves move. With
    ``lw`` (one weight per ``lnbr`` entry; empty for an even mean) the mean is
    weighted (:func:`edge_weights`: a sliver's two close corners move
    together). With ``kw`` (one factor per vertex of ``loc``; empty for none)
    vertex ``a`` takes the step ``k kw[a]``: a factor of 0 holds it."""
    weighted = lw.shape[0] > 0
    scaled = kw.shape[0] > 0
    for a in nb.prange(ring.shape[0]):
        i = ring[a]
        for c in range(3):
            L[a, c] = X[i, c] - base[i, c] if relative else X[i, c]
    for _ in range(iterations):
        for a in nb.prange(loc.shape[0]):
            lo, hi = lptr[a], lptr[a + 1]
            sx = sy = sz = 0.0
            sw = 0.0
            for b in range(lo, hi):
                q = lnbr[b]
                w = lw[b] if weighted else 1.0
                sx += w * L[q, 0]
                sy += w * L[q, 1]
                sz += w * L[q, 2]
                sw += w
            ka = k * kw[a] if scaled else k
            c = ka / max(sw, 1e-30)
            i = loc[a]
            buf[a, 0] = (1.0 - ka) * L[i, 0] + c * sx
            buf[a, 1] = (1.0 - ka) * L[i, 1] + c * sy
            buf[a, 2] = (1.0 - ka) * L[i, 2] + c * sz
        for a in nb.prange(loc.shape[0]):
            i = loc[a]
            L[i, 0], L[i, 1], L[i, 2] = buf[a, 0], buf[a, 1], buf[a, 2]
    for a in nb.prange(loc.shape[0]):
        i, v = loc[a], ring[loc[a]]
        for c in range(3):
            X[v, c] = base[v, c] + L[i, c] if relative else L[i, c]


def edge_weights(V: np.ndarray, ring: np.ndarray, loc: np.ndarray, lptr: np.ndarray,
                 lnbr: np.ndarray) -> np.ndarray:
    """Weights ``1 / |edge|`` at rest for the neighbours of a :func:`ring_layout`
    (``lw`` of :func:`laplacian_smooth`): a displacement smoothed with them
    keeps the two corners of a short edge together, where an even mean moves
    them apart by its change over the whole ring and flips the triangle."""
    rows = np.repeat(ring[loc], np.diff(lptr))
    d = np.linalg.norm(V[rows] - V[ring[lnbr]], axis=1)
    if not len(d):
        return d
    return 1.0 / np.maximum(d, 1e-9 * max(float(d.mean()), 1e-30))


def adjacency_weights(V: np.ndarray, ptr: np.ndarray, adj: np.ndarray) -> np.ndarray:
    """``1 / |edge|`` at rest for every entry of the one-ring CSR ``ptr``/``adj``
    (what :func:`edge_weights` gives a layout), once
    per character: :func:`gather_weights` then reads a layout's from it."""
    rows = np.repeat(np.arange(len(ptr) - 1), np.diff(ptr))
    d = np.linalg.norm(V[rows] - V[adj], axis=1)
    if not len(d):
        return d
    return 1.0 / np.maximum(d, 1e-9 * max(float(d.mean()), 1e-30))


@nb.njit(cache=True, nogil=True)
def gather_weights(verts, ptr, w, lptr):
    """The weights of a :func:`ring_layout` of
    ``verts`` (its ``lptr``) from the per-character :func:`adjacency_weights`."""
    out = np.empty(lptr[-1])
    for k in range(verts.shape[0]):
        i = verts[k]
        o = lptr[k]
        for b in range(ptr[i], ptr[i + 1]):
            out[o + b - ptr[i]] = w[b]
    return out


@nb.njit(cache=True, nogil=True)
def cap_relief(X, base, verts, ptr, nbr, limit, passes):
    """Limit how far a stage's displacement ``D = X - base`` of each of
    ``verts`` stands out from its neighbours': ``|D_i - mean_ring(D)|`` at
    most ``limit[i]``, the excess taken off along the difference, in place on
    ``X``, Gauss-Seidel (a vertex sees its neighbours' capped moves), up to
    ``passes`` sweeps, stopping after one that changed nothing. A spike (one
    vertex moved far more than the skin around it) is cut to a bump of
    ``limit``; a layer moving evenly is left as it is. Returns how many
    vertices the sweeps changed (a vertex changed in two sweeps counts twice).

    A sweep after the first visits only vertices a neighbour of which
    changed since they were visited: the others would find what they found
    then (their ring is as it was, and a cut leaves a vertex at its limit),
    so the skin is the same as with every vertex visited every sweep, at
    the cost of the vertices near the cuts.
    """
    changed = 0
    # stale[i]: vertex i's ring changed since i was last visited
    stale = np.ones(X.shape[0], dtype=np.bool_)
    for _ in range(passes):
        now = 0
        for a in range(verts.shape[0]):
            i = verts[a]
            if not stale[i]:
                continue
            stale[i] = False
            k = ptr[i + 1] - ptr[i]
            if k == 0:
                continue
            mx = 0.0
            my = 0.0
            mz = 0.0
            for b in range(ptr[i], ptr[i + 1]):
                u = nbr[b]
                mx += X[u, 0] - base[u, 0]
                my += X[u, 1] - base[u, 1]
                mz += X[u, 2] - base[u, 2]
            mx /= k
            my /= k
            mz /= k
            rx = X[i, 0] - base[i, 0] - mx
            ry = X[i, 1] - base[i, 1] - my
            rz = X[i, 2] - base[i, 2] - mz
            r = np.sqrt(rx * rx + ry * ry + rz * rz)
            if r > limit[i] * (1.0 + 1e-9):
                s = limit[i] / r
                X[i, 0] = base[i, 0] + mx + rx * s
                X[i, 1] = base[i, 1] + my + ry * s
                X[i, 2] = base[i, 2] + mz + rz * s
                now += 1
                for b in range(ptr[i], ptr[i + 1]):
                    stale[nbr[b]] = True
        changed += now
        if now == 0:
            break
    return changed


@nb.njit(cache=True, nogil=True, parallel=True, fastmath=FAST)
def ring_means(X, ptr, adj, passes, buf):
    """``passes`` times, each row of ``X`` (n, 3) replaced by the mean of
    itself and its one-ring's (the CSR ``ptr``/``adj``), in place; ``buf``
    (n, 3) scratch. A field's smooth part stays, what changes from vertex to
    vertex is averaged away."""
    for _ in range(passes):
        for i in nb.prange(X.shape[0]):
            sx, sy, sz = X[i, 0], X[i, 1], X[i, 2]
            for b in range(ptr[i], ptr[i + 1]):
                j = adj[b]
                sx += X[j, 0]
                sy += X[j, 1]
                sz += X[j, 2]
            k = 1.0 / (ptr[i + 1] - ptr[i] + 1)
            buf[i, 0], buf[i, 1], buf[i, 2] = sx * k, sy * k, sz * k
        X[:] = buf
