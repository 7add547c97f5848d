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


@nb.njit(cache=True, nogil=True)
def strongest_within(sources, strength, ptr, nbr, rings, hops, queue, m, nxt, out):
    """On every vertex ``i`` within ``rings`` hops of ``sources``, the
    strongest of them within that reach: ``out[i] = max_j strength_j`` over
    the sources ``j`` at most ``rings`` hops from ``i``. A max of strengths: a
    source whose strength grows from 0 adds nothing at first, so the set it
    reaches grows without a jump, where the reach of a set of sources
    switches ``rings`` rings on at once. ``hops`` as for
    :func:`ring_distance` (reset it on ``queue[:n]`` after); ``m`` (n,) and
    ``nxt`` are scratch. Returns ``n``, the vertices reached, listed in
    ``queue[:n]``."""
    n = ring_distance(sources, ptr, nbr, hops, rings + 1, queue)
    for k in range(n):
        m[queue[k]] = 0.0
    for a in range(sources.shape[0]):
        m[sources[a]] = max(m[sources[a]], strength[a])
    for _ in range(rings):
        for k in range(n):                  # one more ring: the strongest neighbour
            i = queue[k]
            best = m[i]
            for b in range(ptr[i], ptr[i + 1]):
                q = nbr[b]
                if hops[q] <= rings:
                    best = max(best, m[q])
            nxt[k] = best
        for k in range(n):
            m[queue[k]] = nxt[k]
    for k in range(n):
        out[queue[k]] = m[queue[k]]
    return n


@nb.njit(cache=True, nogil=True)
def patches(verts, ptr, nbr, label, queue):
    """Labels the connected patches of ``verts`` (sorted, unique) over the
    one-ring CSR: ``label[i]`` 0, 1, ... on them. ``label`` must hold -1 on
    ``verts`` on entry and anything else off them (it is left so there);
    ``queue`` is scratch. Returns how many patches."""
    m = 0
    for a in range(verts.shape[0]):
        s = verts[a]
        if label[s] != -1:
            continue
        label[s] = m
        queue[0] = s
        n, head = 1, 0
        while head < n:
            i = queue[head]
            head += 1
            for b in range(ptr[i], ptr[i + 1]):
                k = nbr[b]
                if label[k] == -1:
                    label[k] = m
                    queue[n] = k
                    n += 1
        m += 1
    return m
