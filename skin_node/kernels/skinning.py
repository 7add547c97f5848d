"""Skinning (numba): linear blend and dual-quaternion skinning with sparse
weights, the dual quaternions of skinning matrices, and the embedding that
carries a tet mesh's correction to the surface."""
from __future__ import annotations

import numba as nb
import numpy as np

from . import FAST


@nb.njit(cache=True, nogil=True, inline="always", fastmath=FAST)
def _lbs_point(V, Widx, Wval, M, out, i):
    """:func:`lbs` of point ``i`` (the one body both loops inline)."""
    K = Widx.shape[1]
    x, y, z = V[i, 0], V[i, 1], V[i, 2]
    ox = oy = oz = 0.0
    for a in range(K):
        wt = Wval[i, a]
        if wt == 0.0:
            continue
        j = Widx[i, a]          # index M directly: a row view costs a refcount
        ox += wt * (M[j, 0, 0] * x + M[j, 0, 1] * y + M[j, 0, 2] * z + M[j, 0, 3])
        oy += wt * (M[j, 1, 0] * x + M[j, 1, 1] * y + M[j, 1, 2] * z + M[j, 1, 3])
        oz += wt * (M[j, 2, 0] * x + M[j, 2, 1] * y + M[j, 2, 2] * z + M[j, 2, 3])
    out[i, 0], out[i, 1], out[i, 2] = ox, oy, oz


@nb.njit(cache=True, nogil=True, parallel=True, fastmath=FAST)
def lbs(V, Widx, Wval, M, out):
    """Linear blend skinning ``v' = sum_j w_j M_j v`` with sparse weights.

    ``V`` (n,3) rest points, ``Widx``/``Wval`` (n,K) bone indices and weights
    (zero-padded), ``M`` (J,4,4) skinning matrices, ``out`` (n,3).
    """
    for i in nb.prange(Widx.shape[0]):
        _lbs_point(V, Widx, Wval, M, out, i)


@nb.njit(cache=True, nogil=True, parallel=True, fastmath=FAST)
def lbs_rows(V, Widx, Wval, M, rows, out):
    """:func:`lbs` of the points ``rows`` only; the rest of ``out`` is left alone."""
    for k in nb.prange(rows.shape[0]):
        _lbs_point(V, Widx, Wval, M, out, rows[k])


@nb.njit(cache=True, nogil=True, inline="always", fastmath=FAST)
def _dq_blend(Widx, Wval, Q, i):
    """Point ``i``'s blended unit dual quaternion as its rotation's unit
    quaternion (w, x, y, z) and its translation (tx, ty, tz)."""
    K = Widx.shape[1]
    j0 = Widx[i, 0]
    b0 = b1 = b2 = b3 = b4 = b5 = b6 = b7 = 0.0
    for a in range(K):
        wt = Wval[i, a]
        if wt == 0.0:
            continue
        j = Widx[i, a]
        dot = Q[j, 0] * Q[j0, 0] + Q[j, 1] * Q[j0, 1] + Q[j, 2] * Q[j0, 2] \
            + Q[j, 3] * Q[j0, 3]
        if dot < 0.0:
            wt = -wt
        b0 += wt * Q[j, 0]
        b1 += wt * Q[j, 1]
        b2 += wt * Q[j, 2]
        b3 += wt * Q[j, 3]
        b4 += wt * Q[j, 4]
        b5 += wt * Q[j, 5]
        b6 += wt * Q[j, 6]
        b7 += wt * Q[j, 7]
    inv = 1.0 / np.sqrt(b0 * b0 + b1 * b1 + b2 * b2 + b3 * b3)
    w0, x0, y0, z0 = b0 * inv, b1 * inv, b2 * inv, b3 * inv
    we, xe, ye, ze = b4 * inv, b5 * inv, b6 * inv, b7 * inv
    # translation t = 2 * dual * conj(real)
    px = 2.0 * (-we * x0 + xe * w0 - ye * z0 + ze * y0)
    py = 2.0 * (-we * y0 + ye * w0 - ze * x0 + xe * z0)
    pz = 2.0 * (-we * z0 + ze * w0 - xe * y0 + ye * x0)
    return w0, x0, y0, z0, px, py, pz


@nb.njit(cache=True, nogil=True, inline="always", fastmath=FAST)
def _turn(w0, x0, y0, z0, vx, vy, vz):
    """Vector ``v`` rotated by unit quaternion ``(w0, x0, y0, z0)``."""
    tx = 2.0 * (y0 * vz - z0 * vy)
    ty = 2.0 * (z0 * vx - x0 * vz)
    tz = 2.0 * (x0 * vy - y0 * vx)
    return (vx + w0 * tx + (y0 * tz - z0 * ty), vy + w0 * ty + (z0 * tx - x0 * tz),
            vz + w0 * tz + (x0 * ty - y0 * tx))


@nb.njit(cache=True, nogil=True, inline="always", fastmath=FAST)
def _dqs_point(V, Widx, Wval, Q, out, i):
    """:func:`dqs` of point ``i`` (the one body both loops inline)."""
    w0, x0, y0, z0, px, py, pz = _dq_blend(Widx, Wval, Q, i)
    rx, ry, rz = _turn(w0, x0, y0, z0, V[i, 0], V[i, 1], V[i, 2])
    out[i, 0], out[i, 1], out[i, 2] = rx + px, ry + py, rz + pz


@nb.njit(cache=True, nogil=True, parallel=True, fastmath=FAST)
def dqs(V, Widx, Wval, Q, out):
    """Dual-quaternion skinning (Kavan et al. 2007) with sparse weights.

    ``Q`` (J,8): per joint the unit real part (w,x,y,z) and dual part of its
    skinning transform. Quaternions are flipped into the first influence's
    hemisphere before blending, so blends never take the long way round.
    """
    for i in nb.prange(Widx.shape[0]):
        _dqs_point(V, Widx, Wval, Q, out, i)


@nb.njit(cache=True, nogil=True, parallel=True, fastmath=FAST)
def dqs_rows(V, Widx, Wval, Q, rows, out):
    """:func:`dqs` of the points ``rows`` only; the rest of ``out`` is left alone."""
    for k in nb.prange(rows.shape[0]):
        _dqs_point(V, Widx, Wval, Q, out, rows[k])


@nb.njit(cache=True, nogil=True, parallel=True, fastmath=FAST)
def dqs_carry(V, Widx, Wval, Q, C, D, a, b, out):
    """:func:`dqs` plus each point's offset ``a C_i + b D_i`` ((n, 3) each)
    turned by the point's own blended rotation: ``out_i = DQS_i + R_i (a C_i
    + b D_i)``; offsets :func:`dqs_offsets` took out of a skin at other poses,
    carried to this one."""
    for i in nb.prange(Widx.shape[0]):
        w0, x0, y0, z0, px, py, pz = _dq_blend(Widx, Wval, Q, i)
        rx, ry, rz = _turn(w0, x0, y0, z0, V[i, 0], V[i, 1], V[i, 2])
        cx, cy, cz = _turn(w0, x0, y0, z0, a * C[i, 0] + b * D[i, 0],
                           a * C[i, 1] + b * D[i, 1], a * C[i, 2] + b * D[i, 2])
        out[i, 0], out[i, 1], out[i, 2] = rx + px + cx, ry + py + cy, rz + pz + cz


@nb.njit(cache=True, nogil=True, parallel=True, fastmath=FAST)
def dqs_offsets(V, Widx, Wval, Q, Y, C):
    """How far skin ``Y`` (n, 3) lies from :func:`dqs`'s, in each point's own
    blended frame: ``C_i = R_i^T (Y_i - DQS_i)``, so that :func:`dqs_carry`
    at the same pose (``a`` = 1, ``b`` = 0) gives ``Y`` back."""
    for i in nb.prange(Widx.shape[0]):
        w0, x0, y0, z0, px, py, pz = _dq_blend(Widx, Wval, Q, i)
        rx, ry, rz = _turn(w0, x0, y0, z0, V[i, 0], V[i, 1], V[i, 2])
        C[i, 0], C[i, 1], C[i, 2] = _turn(w0, -x0, -y0, -z0, Y[i, 0] - rx - px,
                                          Y[i, 1] - ry - py, Y[i, 2] - rz - pz)


@nb.njit(cache=True, nogil=True, parallel=True, fastmath=FAST)
def embed_update(base, X, Xbase, Etet, Ebary, verts, out):
    """Surface = its own stage-1 result plus the barycentric interpolation of
    the tet mesh's correction: ``out_i = base_i + sum_a b_ia (X - Xbase)[t_ia]``
    for ``i`` in ``verts`` (the vertices embedded in tets the solve touched).
    Surface detail finer than the tets is therefore kept."""
    for k in nb.prange(verts.shape[0]):
        i = verts[k]
        for d in range(3):
            s = base[i, d]
            for a in range(4):
                v = Etet[i, a]
                s += Ebary[i, a] * (X[v, d] - Xbase[v, d])
            out[i, d] = s


def matrices_to_dual_quaternions(M: np.ndarray) -> np.ndarray:
    """(J, 8) unit dual quaternions (real w,x,y,z, dual w,x,y,z) of rigid (J,4,4) ``M``."""
    M = np.ascontiguousarray(M, dtype=np.float64)
    return _dual_quaternions(M, np.empty((len(M), 8)))


@nb.njit(cache=True, nogil=True)
def _dual_quaternions(M, q):
    for i in range(M.shape[0]):
        r = M[i]
        tr = r[0, 0] + r[1, 1] + r[2, 2]
        # Shepperd's method: pick the largest pivot for stability.
        if tr >= r[0, 0] and tr >= r[1, 1] and tr >= r[2, 2]:
            s = np.sqrt(1.0 + tr) * 2
            w, x, y, z = 0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, \
                (r[1, 0] - r[0, 1]) / s
        elif r[0, 0] >= r[1, 1] and r[0, 0] >= r[2, 2]:
            s = np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
            w, x, y, z = (r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, \
                (r[0, 2] + r[2, 0]) / s
        elif r[1, 1] >= r[2, 2]:
            s = np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
            w, x, y, z = (r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, \
                (r[1, 2] + r[2, 1]) / s
        else:
            s = np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
            w, x, y, z = (r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, \
                (r[1, 2] + r[2, 1]) / s, 0.25 * s
        n = np.sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w / n, x / n, y / n, z / n
        # dual = 0.5 * (0, t) * real
        tx, ty, tz = r[0, 3], r[1, 3], r[2, 3]
        q[i, 0], q[i, 1], q[i, 2], q[i, 3] = w, x, y, z
        q[i, 4] = 0.5 * (-tx * x - ty * y - tz * z)
        q[i, 5] = 0.5 * (tx * w + ty * z - tz * y)
        q[i, 6] = 0.5 * (-tx * z + ty * w + tz * x)
        q[i, 7] = 0.5 * (tx * y - ty * x + tz * w)
    return q
