"""Delta Mush: smoothing that rounds what a deformation crumpled and keeps the rest
pose's detail (Mancewicz et al., "Delta Mush: smoothing deformations while
preserving detail", DigiPro 2014) (numba).

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


def vertex_faces(F: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """CSR of the faces around every vertex: faces ``vf[vf_ptr[i]:vf_ptr[i+1]]``."""
    flat = F.ravel()
    order = np.argsort(flat, kind="stable")
    vf = (order // 3).astype(np.int64)
    vf_ptr = np.searchsorted(flat[order], np.arange(n + 1)).astype(np.int64)
    return vf_ptr, vf


def adjacency_weights(V: np.ndarray, ptr: np.ndarray, adj: np.ndarray) -> np.ndarray:
    """``1 / |edge|`` at rest for every entry of the one-ring CSR ``ptr``/``adj``
    (what :func:`~skin_node.kernels.solver.edge_weights` gives a layout), once
    per character: :func:`gather_weights` then reads a layout's from it."""
    rows = np.repeat(np.arange(len(ptr) - 1), np.diff(ptr))
    d = np.linalg.norm(V[rows] - V[adj], axis=1)
    if not len(d):
        return d
    return 1.0 / np.maximum(d, 1e-9 * max(float(d.mean()), 1e-30))


@nb.njit(cache=True, nogil=True)
def gather_weights(verts, ptr, w, lptr):
    """The weights of a :func:`~skin_node.kernels.solver.ring_layout` of
    ``verts`` (its ``lptr``) from the per-character :func:`adjacency_weights`."""
    out = np.empty(lptr[-1])
    for k in range(verts.shape[0]):
        i = verts[k]
        o = lptr[k]
        for b in range(ptr[i], ptr[i + 1]):
            out[o + b - ptr[i]] = w[b]
    return out
