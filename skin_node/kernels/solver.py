"""Loops that apply the constraint functions over index arrays.

The Gauss-Seidel sweep visits constraints in the order of the active index
arrays. When those arrays are split into parts that share no vertex, plus a
separator of the constraints that straddle parts, each part runs on its own
thread without races and the separator after them: still Gauss-Seidel, in a
fixed order, so the result does not depend on the thread count's timing.
"""
from __future__ import annotations

import numba as nb
import numpy as np

from . import FAST
from .constraints import (bind_constraint, contact_constraint, energy_step,
                          stretch_constraint, volume_constraint, zone_volume_constraint)

#: The constraint kinds of the solve, by their names in the ``constraints``
#: parameter: :func:`sweep` applies the first four over index arrays,
#: :func:`contact_sweep` the contact planes, :func:`zone_volume_sweep` a zone's
#: total volume.
STRETCH, VOLUME, ENERGY, BIND, CONTACT, ZONE = range(6)
CONSTRAINTS = {"stretch": STRETCH, "volume": VOLUME, "energy": ENERGY, "bind": BIND,
               "contact": CONTACT, "zone_volume": ZONE}


@nb.njit(cache=True, nogil=True, inline="always")
def _apply(X, t, dp):
    for b in range(4):
        for d in range(3):
            X[t[b], d] += dp[b, d]


@nb.njit(cache=True, nogil=True, inline="always")
def _stretch_range(X, w, E, rest, lam, idx, lo, hi, k, alpha, dp):
    for a in range(lo, hi):
        c = idx[a]
        i0, i1 = E[c, 0], E[c, 1]
        dlam = stretch_constraint(X, i0, i1, w[i0], w[i1], rest[c], k, alpha, lam[c], dp)
        lam[c] += dlam
        for d in range(3):
            X[i0, d] += dp[0, d]
            X[i1, d] += dp[1, d]


@nb.njit(cache=True, nogil=True, inline="always")
def _volume_range(X, w, T, rest, lam, idx, lo, hi, k, alpha, dp):
    for a in range(lo, hi):
        c = idx[a]
        t = T[c]
        dlam = volume_constraint(X, t, w, rest[c], k, alpha, lam[c], dp)
        lam[c] += dlam
        _apply(X, t, dp)


@nb.njit(cache=True, nogil=True, inline="always")
def _energy_range(X, w, m, T, ks, rest, lam, idx, lo, hi, k, alpha):
    for a in range(lo, hi):
        c = idx[a]
        t = T[c]
        t0, t1, t2, t3 = t[0], t[1], t[2], t[3]
        (dlam, d0x, d0y, d0z, d1x, d1y, d1z, d2x, d2y, d2z, d3x, d3y,
         d3z) = energy_step(X, t, w, m, ks, rest[c], k, alpha, lam[c])
        lam[c] += dlam
        X[t0, 0] += d0x
        X[t0, 1] += d0y
        X[t0, 2] += d0z
        X[t1, 0] += d1x
        X[t1, 1] += d1y
        X[t1, 2] += d1z
        X[t2, 0] += d2x
        X[t2, 1] += d2y
        X[t2, 2] += d2z
        X[t3, 0] += d3x
        X[t3, 1] += d3y
        X[t3, 2] += d3z


@nb.njit(cache=True, nogil=True, inline="always")
def _bind_range(X, w, seg, A, B, rest, lam, idx, lo, hi, k, alpha, dp):
    for a in range(lo, hi):
        i = idx[a]
        s = seg[i]
        dlam = bind_constraint(X, i, w, A[s, 0], A[s, 1], A[s, 2], B[s, 0], B[s, 1], B[s, 2],
                               rest[i], k, alpha, lam[i], dp)
        lam[i] += dlam
        for d in range(3):
            X[i, d] += dp[0, d]


@nb.njit(cache=True, nogil=True)
def contact_sweep(X, w, idx, planes, plane_of):
    """Project each vertex ``idx[a]`` to the positive side of its plane
    ``planes[plane_of[a]]`` (rows: centre xyz, unit normal xyz)."""
    dp = np.zeros((4, 3))
    for a in range(idx.shape[0]):
        i = idx[a]
        P = planes[plane_of[a]]
        contact_constraint(X, i, w, P[0], P[1], P[2], P[3], P[4], P[5], dp)
        for d in range(3):
            X[i, d] += dp[0, d]


@nb.njit(cache=True, nogil=True)
def zone_volume_sweep(X, T, tets, verts, w, rest, k, g):
    """One projection of :func:`~skin_node.kernels.constraints.zone_volume_constraint`
    over the tets ``tets`` (their vertices ``verts``, each once):
    ``X_i += w_i dlam g_i``. ``g`` (k,3) is scratch and keeps the gradient.
    Returns ``C`` before the projection."""
    dlam, C = zone_volume_constraint(X, T, tets, verts, w, rest, k, g)
    if dlam == 0.0:
        return C
    for a in range(verts.shape[0]):
        i = verts[a]
        f = w[i] * dlam
        X[i, 0] += f * g[i, 0]
        X[i, 1] += f * g[i, 1]
        X[i, 2] += f * g[i, 2]
    return C


@nb.njit(cache=True, nogil=True, inline="always")
def _range(kind, X, w, m, E, T, ks, seg, A, B, rest, erest, lam, idx, lo, hi, k, alpha, dp):
    if kind == STRETCH:
        _stretch_range(X, w, E, rest, lam, idx, lo, hi, k, alpha, dp)
    elif kind == VOLUME:
        _volume_range(X, w, T, rest, lam, idx, lo, hi, k, alpha, dp)
    elif kind == ENERGY:
        _energy_range(X, w, m, T, ks, erest, lam, idx, lo, hi, k, alpha)
    else:
        _bind_range(X, w, seg, A, B, rest, lam, idx, lo, hi, k, alpha, dp)


@nb.njit(cache=True, nogil=True, parallel=True, fastmath=FAST)
def _parallel(kind, X, w, m, E, T, ks, seg, A, B, rest, erest, lam, idx, bounds, k, alpha):
    # Parts (bounds[h], bounds[h+1]) for h < P share no vertex: one thread each.
    # The last range, the separator, touches several parts and runs after them.
    P = bounds.shape[0] - 2
    for h in nb.prange(P):
        dp = np.zeros((4, 3))
        _range(kind, X, w, m, E, T, ks, seg, A, B, rest, erest, lam, idx, bounds[h],
               bounds[h + 1], k, alpha, dp)
    dp = np.zeros((4, 3))
    _range(kind, X, w, m, E, T, ks, seg, A, B, rest, erest, lam, idx, bounds[P], bounds[P + 1],
           k, alpha, dp)


@nb.njit(cache=True, nogil=True, fastmath=FAST)
def _stretch_seq(X, w, E, rest, lam, idx, k, alpha):
    dp = np.zeros((4, 3))
    _stretch_range(X, w, E, rest, lam, idx, 0, idx.shape[0], k, alpha, dp)


@nb.njit(cache=True, nogil=True, fastmath=FAST)
def _volume_seq(X, w, T, rest, lam, idx, k, alpha):
    dp = np.zeros((4, 3))
    _volume_range(X, w, T, rest, lam, idx, 0, idx.shape[0], k, alpha, dp)


@nb.njit(cache=True, nogil=True, fastmath=FAST)
def _energy_seq(X, w, m, T, ks, erest, lam, idx, k, alpha):
    _energy_range(X, w, m, T, ks, erest, lam, idx, 0, idx.shape[0], k, alpha)


@nb.njit(cache=True, nogil=True, fastmath=FAST)
def _bind_seq(X, w, seg, A, B, rest, lam, idx, k, alpha):
    dp = np.zeros((4, 3))
    _bind_range(X, w, seg, A, B, rest, lam, idx, 0, idx.shape[0], k, alpha, dp)


def sweep(kind: int, X, w, m, E, T, ks, seg, A, B, rest, erest, lam, idx, bounds, k, alpha,
          threads: int = 1) -> None:
    """One Gauss-Seidel sweep of one constraint type over ``idx``: 0 stretch,
    1 volume, 2 energy or 3 bind.

    ``bounds`` splits ``idx``: with two entries it is one sequential range;
    with ``P + 2`` entries the first ``P`` ranges are vertex-disjoint parts,
    swept in parallel when ``threads > 1``, and the last is the separator
    between them, swept after (see :func:`skin_node.stages.pbd.partition`).
    Sequentially the parts run one after the other, which gives the same
    result: they share no vertex.

    ``rest`` (1-D) holds the rest values of stretch, volume or bind
    constraints, ``erest`` (t,4) the energy springs' rest lengths."""
    if threads > 1 and bounds.shape[0] > 3:
        _parallel(kind, X, w, m, E, T, ks, seg, A, B, rest, erest, lam, idx, bounds, k, alpha)
    # One kernel per type (a kernel that switches on the type ran the energy
    # sweep about a tenth slower). In sequence, the parts and the separator
    # are just the index array in order.
    elif kind == ENERGY:
        _energy_seq(X, w, m, T, ks, erest, lam, idx, k, alpha)
    elif kind == VOLUME:
        _volume_seq(X, w, T, rest, lam, idx, k, alpha)
    elif kind == BIND:
        _bind_seq(X, w, seg, A, B, rest, lam, idx, k, alpha)
    else:
        _stretch_seq(X, w, E, rest, lam, idx, k, alpha)


@nb.njit(cache=True, nogil=True)
def carry_correction(X, verts, M, dom, corr, apply):
    """Warm start. ``apply``: ``X_i += R_i corr_i``; else ``corr_i = R_i^T X_i``
    (``X`` then holding the correction), with ``R_i`` the rotation of vertex i's
    main bone, so a correction rides with its limb from frame to frame."""
    for a in range(verts.shape[0]):
        i = verts[a]
        R = M[dom[i]]
        if apply:
            for r in range(3):
                X[i, r] += R[r, 0] * corr[i, 0] + R[r, 1] * corr[i, 1] + R[r, 2] * corr[i, 2]
        else:
            for c in range(3):
                corr[i, c] = R[0, c] * X[i, 0] + R[1, c] * X[i, 1] + R[2, c] * X[i, 2]


@nb.njit(cache=True, nogil=True)
def max_move(X, prev, idx):
    m = 0.0
    for a in range(idx.shape[0]):
        i = idx[a]
        d = (X[i, 0] - prev[i, 0]) ** 2 + (X[i, 1] - prev[i, 1]) ** 2 + (X[i, 2] - prev[i, 2]) ** 2
        m = max(m, d)
    return np.sqrt(m)


@nb.njit(cache=True, nogil=True)
def fade_correction(X, base, verts, vzone, fade):
    """``X_i = base_i + z_i (X_i - base_i)`` for ``i`` in ``verts``, ``z_i`` the
    largest ``vzone[a, j] * fade[j]`` over the bent joints ``j`` (row ``a`` of
    ``vzone`` is vertex ``verts[a]``'s zone membership)."""
    for a in range(verts.shape[0]):
        z = vzone[a, 0] * fade[0]
        for j in range(1, fade.shape[0]):
            z = max(z, vzone[a, j] * fade[j])
        i = verts[a]
        for d in range(3):
            X[i, d] = base[i, d] + z * (X[i, d] - base[i, d])
