"""Kernels that shape the skin around bent joints: bulge limit and inflation (numba)."""
from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True, inline="always")
def _closest_on_segment(px, py, pz, A, B, s):
    dx, dy, dz = B[s, 0] - A[s, 0], B[s, 1] - A[s, 1], B[s, 2] - A[s, 2]
    d2 = dx * dx + dy * dy + dz * dz
    t = ((px - A[s, 0]) * dx + (py - A[s, 1]) * dy + (pz - A[s, 2]) * dz) / max(d2, 1e-30)
    t = min(1.0, max(0.0, t))
    return A[s, 0] + t * dx, A[s, 1] + t * dy, A[s, 2] + t * dz


@nb.njit(cache=True, nogil=True, inline="always")
def _pull(px, py, pz, A, B, s, r0, width):
    """The move that brings ``p`` from ``r0 + e`` to ``r0 + width tanh(e /
    width)`` from segment ``s`` (none when ``e <= 0``)."""
    cx, cy, cz = _closest_on_segment(px, py, pz, A, B, s)
    ux, uy, uz = px - cx, py - cy, pz - cz
    r = math.sqrt(ux * ux + uy * uy + uz * uz)
    e = r - r0
    if e <= 0.0 or r < 1e-12:
        return 0.0, 0.0, 0.0
    k = (r0 + width * math.tanh(e / width)) / r - 1.0
    return ux * k, uy * k, uz * k


@nb.njit(cache=True, nogil=True)
def limit_bulge(X, verts, seg, r0, share, A, B, width, fade):
    """Keep every vertex of ``verts`` near its rest distance from its bone.

    The paper's bind constraint ``C = |p - p'| - d`` (p' the closest point of
    the vertex's bone segment, posed ``A``-``B``; ``d`` its rest distance
    ``r0``), made one-sided and soft: skin further out than at rest by ``e``
    is brought to ``width * tanh(e / width)`` out (never more than ``width``,
    unchanged to first order where ``e`` is small), skin nearer than at rest
    is left to the other stages. ``seg`` (n, 2) and ``r0`` (n, 2) are each
    vertex's two nearest rest segments and distances, ``share`` (n,) the part
    of the pull the second takes: near where the nearest segment changes both
    pull, so the pull changes smoothly across it. ``fade`` (n,) scales the
    pull (0 keeps the vertex). Returns how many vertices moved.
    """
    n = 0
    for k in range(verts.shape[0]):
        i = verts[k]
        f = fade[i]
        if f <= 0.0:
            continue
        px, py, pz = X[i, 0], X[i, 1], X[i, 2]
        ax, ay, az = _pull(px, py, pz, A, B, seg[i, 0], r0[i, 0], width[i])
        b = share[i]
        if b > 0.0:
            bx, by, bz = _pull(px, py, pz, A, B, seg[i, 1], r0[i, 1], width[i])
            ax, ay, az = (1.0 - b) * ax + b * bx, (1.0 - b) * ay + b * by, (1.0 - b) * az + b * bz
        if ax == 0.0 and ay == 0.0 and az == 0.0:
            continue
        X[i, 0] = px + f * ax
        X[i, 1] = py + f * ay
        X[i, 2] = pz + f * az
        n += 1
    return n


@nb.njit(cache=True, nogil=True)
def cone_volume_gradient(X, F, tris, c, inc_ptr, inc, verts, g):
    """Volume of the cone from ``c`` over triangles ``tris`` of ``X`` and its
    gradient ``g`` (len(verts), 3) with respect to each vertex of ``verts``
    (``inc_ptr, inc``: CSR of each of ``verts``' triangles among ``tris``)."""
    vol = 0.0
    for t in range(tris.shape[0]):
        f = tris[t]
        a, b, d = F[f, 0], F[f, 1], F[f, 2]
        ax, ay, az = X[a, 0] - c[0], X[a, 1] - c[1], X[a, 2] - c[2]
        bx, by, bz = X[b, 0] - c[0], X[b, 1] - c[1], X[b, 2] - c[2]
        dx, dy, dz = X[d, 0] - c[0], X[d, 1] - c[1], X[d, 2] - c[2]
        vol += (ax * (by * dz - bz * dy) + ay * (bz * dx - bx * dz) + az * (bx * dy - by * dx))
    for k in range(verts.shape[0]):
        i = verts[k]
        gx = gy = gz = 0.0
        for q in range(inc_ptr[k], inc_ptr[k + 1]):
            f = tris[inc[q]]
            # the other two corners in order after i: d(det)/dp_i = their cross product
            if F[f, 0] == i:
                o1, o2 = F[f, 1], F[f, 2]
            elif F[f, 1] == i:
                o1, o2 = F[f, 2], F[f, 0]
            else:
                o1, o2 = F[f, 0], F[f, 1]
            ux, uy, uz = X[o1, 0] - c[0], X[o1, 1] - c[1], X[o1, 2] - c[2]
            vx, vy, vz = X[o2, 0] - c[0], X[o2, 1] - c[1], X[o2, 2] - c[2]
            gx += uy * vz - uz * vy
            gy += uz * vx - ux * vz
            gz += ux * vy - uy * vx
        g[k, 0], g[k, 1], g[k, 2] = gx / 6.0, gy / 6.0, gz / 6.0
    return vol / 6.0


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


def region_incidence(F: np.ndarray, tris: np.ndarray, verts: np.ndarray):
    """CSR of each of ``verts``' (sorted) triangles among ``tris`` (positions
    into ``tris``, ascending), for :func:`cone_volume_gradient`."""
    if not len(verts) or not len(tris):
        return np.zeros(len(verts) + 1, dtype=np.int64), np.zeros(0, dtype=np.int64)
    return _incidence(np.ascontiguousarray(F, dtype=np.int64),
                      np.ascontiguousarray(tris, dtype=np.int64),
                      np.ascontiguousarray(verts, dtype=np.int64), int(F.max()) + 1)


@nb.njit(cache=True, nogil=True)
def _incidence(F, tris, verts, n):
    # a counting sort by vertex: a zone is rebuilt whenever the set of bent
    # joints changes, so this runs at frame rate, not once
    pos = np.full(max(n, int(verts.max()) + 1), -1, dtype=np.int64)
    for k in range(verts.shape[0]):
        pos[verts[k]] = k
    ptr = np.zeros(verts.shape[0] + 1, dtype=np.int64)
    for r in range(tris.shape[0]):
        for c in range(3):
            k = pos[F[tris[r], c]]
            if k >= 0:
                ptr[k + 1] += 1
    for k in range(verts.shape[0]):
        ptr[k + 1] += ptr[k]
    fill = ptr[:-1].copy()
    rows = np.empty(ptr[-1], dtype=np.int64)
    for r in range(tris.shape[0]):
        for c in range(3):
            k = pos[F[tris[r], c]]
            if k >= 0:
                rows[fill[k]] = r
                fill[k] += 1
    return ptr, rows


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
