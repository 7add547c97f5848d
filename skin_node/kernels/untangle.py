"""Pushing apart triangles of two parts that pass through each other (numba)."""
from __future__ import annotations

import math

import numba as nb


@nb.njit(cache=True, nogil=True)
def push_apart(X, F, pairs, gap, depth, spread, ptr, adj, disp, count, touched):
    """One round of parting the triangle ``pairs`` (k, 2) of surface ``X``.

    For each pair, both ways round: the corners of one triangle that lie
    behind the other's plane, or within ``gap[v]`` in front of it (along its
    normal, outward), are pushed out to ``gap[v]`` in front of it, half the
    way (the other triangle's corners take the other half from the pair the
    other way round). A corner more than ``depth[v]`` behind the plane is
    not pushed: that is flesh through flesh (the contact's business, or rest
    flesh that overlaps), not a triangle's edge run through a neighbour
    between the vertices. A vertex in several pairs moves by the mean of its
    pushes. Each unpushed neighbour of a pushed vertex (one ring, CSR
    ``ptr``, ``adj``) moves by ``spread`` times the mean of its pushed
    neighbours' moves: a 40 mm triangle's corner pushed alone past a
    neighbour's still lying one bent their edge into a sharp fold.
    ``disp`` (n, 3) and ``count`` (n,) must be 0 on entry and are left 0;
    ``touched`` (n,) is scratch; on return it lists the pushed vertices,
    then their neighbours moved with them. Returns how many were pushed and
    how many moved in all."""
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
            disp[v, d] /= count[v]
    # the ring: count < 0 marks a neighbour by how many pushed vertices it has
    moved = m
    if spread > 0.0:
        for t in range(m):
            v = touched[t]
            for e in range(ptr[v], ptr[v + 1]):
                u = adj[e]
                if count[u] > 0:
                    continue
                if count[u] == 0:
                    touched[moved] = u
                    moved += 1
                count[u] -= 1
                for d in range(3):
                    disp[u, d] += disp[v, d]
    for t in range(moved):
        v = touched[t]
        s = 1.0 if count[v] > 0 else spread / -count[v]
        for d in range(3):
            X[v, d] += s * disp[v, d]
            disp[v, d] = 0.0
        count[v] = 0
    return m, moved
