"""Walks over a surface's one-ring adjacency (numba)."""
from __future__ import annotations

import numba as nb


@nb.njit(cache=True, nogil=True)
def ring_distance(sources, ptr, nbr, hops, limit, queue):
    """Breadth-first hop counts from ``sources`` over the one-ring CSR, up to
    ``limit``; ``hops`` must hold at least ``limit`` everywhere on entry. Returns the
    number of vertices reached; ``queue[:n]`` lists them (to reset ``hops``)."""
    n = 0
    for a in range(sources.shape[0]):
        i = sources[a]
        if hops[i] != 0:
            hops[i] = 0
            queue[n] = i
            n += 1
    head = 0
    while head < n:
        i = queue[head]
        head += 1
        h = hops[i] + 1
        if h >= limit:
            continue
        for b in range(ptr[i], ptr[i + 1]):
            k = nbr[b]
            if hops[k] > h:
                hops[k] = h
                queue[n] = k
                n += 1
    return n
