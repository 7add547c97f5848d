"""Pushing apart triangles of two parts that pass through each other (numba)."""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from .intersect import meets_apart


@nb.njit(cache=True, nogil=True)
def crossing_pairs(X, F, query, inq, fpart, roots, child, first, count, slot, tris, lo, hi,
                   tlo, thi, out):
    """Pairs of intersecting triangles (exactly), one of them from ``query``,
    of two different parts (``fpart``) and sharing no corner, each once,
    found through a tree over all of them (boxes fit to ``X``, see
    :func:`~skin_node.kernels.intersect.intersecting_pairs`); ``inq[f]``
    marks the query triangles. Writes up to len(out) pairs; returns how many
    there are."""
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
                        or lo[nd, 2] > bh2 or hi[nd, 2] < bl2):
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


@nb.njit(cache=True, nogil=True)
def push_apart(X, F, pairs, gap, depth, disp, count, touched):
    """One round of parting the triangle ``pairs`` (k, 2) of surface ``X``.

    For each pair, both ways round: the corners of one triangle that lie
    behind the other's plane, or within ``gap[v]`` in front of it (along its
    normal, outward), are pushed out to ``gap[v]`` in front of it, half the
    way (the other triangle's corners take the other half from the pair the
    other way round). A corner more than ``depth[v]`` behind the plane is
    not pushed: that is flesh through flesh (the contact's business, or rest
    flesh that overlaps), not a triangle's edge run through a neighbour
    between the vertices. A vertex in several pairs moves by the mean of its
    pushes. ``disp`` (n, 3) and ``count`` (n,) must be 0 on entry and are
    left 0; ``touched`` (n,) is scratch. Returns how many vertices moved."""
    m = 0
    for k in range(pairs.shape[0]):
        for side in range(2):
            f, g = pairs[k, side], pairs[k, 1 - side]
            a, b, c = F[g, 0], F[g, 1], F[g, 2]
            ux, uy, uz = X[b, 0] - X[a, 0], X[b, 1] - X[a, 1], X[b, 2] - X[a, 2]
            vx, vy, vz = X[c, 0] - X[a, 0], X[c, 1] - X[a, 1], X[c, 2] - X[a, 2]
            nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
            nn = math.sqrt(nx * nx + ny * ny + nz * nz)
            if nn < 1e-30:
                continue
            nx, ny, nz = nx / nn, ny / nn, nz / nn
            for r in range(3):
                v = F[f, r]
                d = (X[v, 0] - X[a, 0]) * nx + (X[v, 1] - X[a, 1]) * ny + (X[v, 2] - X[a, 2]) * nz
                if d >= gap[v] or d < -depth[v]:
                    continue
                s = 0.5 * (gap[v] - d)
                disp[v, 0] += s * nx
                disp[v, 1] += s * ny
                disp[v, 2] += s * nz
                if count[v] == 0:
                    touched[m] = v
                    m += 1
                count[v] += 1
    for t in range(m):
        v = touched[t]
        for d in range(3):
            X[v, d] += disp[v, d] / count[v]
            disp[v, d] = 0.0
        count[v] = 0
    return m
