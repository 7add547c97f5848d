"""Lattice tet meshes and the surface embedding.

Like the simulation meshes of PhysX (which the paper used), the volume is a
regular lattice of cubes, each split into six Kuhn tets, keeping every cube
that holds a surface vertex or whose centre lies inside the surface. Why a
lattice rather than a conforming tetrahedraliser:

* the density is one number (the cube size) chosen independently of the
  surface, so "model no more than the scene needs" is a parameter;
* every tet is well shaped (no slivers to make volume constraints explode);
* every surface vertex lies in a kept cube, so the embedding never fails and
  its barycentric coordinates are exact and non-negative;
* no extra dependency, deterministic, and fast (numba).
"""
from __future__ import annotations

import itertools

import numba as nb
import numpy as np

# Kuhn decomposition: the tet for permutation s holds points with u[s0] >= u[s1] >= u[s2].
_PERMS = np.array(list(itertools.permutations(range(3))), dtype=np.int64)


def _kuhn_corners() -> np.ndarray:
    """(6, 4) corner codes (bit0 = x, bit1 = y, bit2 = z) of the six Kuhn tets."""
    out = np.zeros((6, 4), dtype=np.int64)
    for t, s in enumerate(_PERMS):
        code = 0
        out[t, 0] = 0
        for a in range(3):
            code |= 1 << s[a]
            out[t, a + 1] = code
    return out


def _oriented(corners: np.ndarray):
    """Swap the last two corners of the Kuhn tets whose signed volume (the
    METHOD formula) is negative, so every tet of the lattice has the same
    orientation; return the corners and the barycentric column order."""
    pos = np.array([[(b >> 0) & 1, (b >> 1) & 1, (b >> 2) & 1] for b in range(8)], float)
    cols = np.tile(np.arange(4), (len(corners), 1))
    out = corners.copy()
    for t in range(len(corners)):
        p1, p2, p3, p4 = pos[corners[t]]
        if np.dot(np.cross(p1 - p2, p1 - p3), p1 - p4) < 0:
            out[t, [2, 3]] = out[t, [3, 2]]
            cols[t, [2, 3]] = cols[t, [3, 2]]
    return out, cols


_KUHN, _BARY_COLS = _oriented(_kuhn_corners())


@nb.njit(cache=True)
def _column_crossings(V, F, ox, oy, h, nx, ny):
    """z of every crossing of the vertical line through each cell-centre column."""
    counts = np.zeros(nx * ny, dtype=np.int64)
    for pass_ in range(2):
        if pass_ == 1:
            ptr = np.zeros(nx * ny + 1, dtype=np.int64)
            for c in range(nx * ny):
                ptr[c + 1] = ptr[c] + counts[c]
            zs = np.empty(ptr[-1])
            fill = ptr[:-1].copy()
        for f in range(F.shape[0]):
            a, b, c = F[f, 0], F[f, 1], F[f, 2]
            x0, y0 = V[a, 0], V[a, 1]
            x1, y1 = V[b, 0], V[b, 1]
            x2, y2 = V[c, 0], V[c, 1]
            det = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2)
            if abs(det) < 1e-30:
                continue
            i0 = max(0, int(np.floor((min(x0, x1, x2) - ox) / h - 0.5)))
            i1 = min(nx - 1, int(np.ceil((max(x0, x1, x2) - ox) / h - 0.5)))
            j0 = max(0, int(np.floor((min(y0, y1, y2) - oy) / h - 0.5)))
            j1 = min(ny - 1, int(np.ceil((max(y0, y1, y2) - oy) / h - 0.5)))
            for i in range(i0, i1 + 1):
                px = ox + (i + 0.5) * h
                for j in range(j0, j1 + 1):
                    py = oy + (j + 0.5) * h
                    l0 = ((y1 - y2) * (px - x2) + (x2 - x1) * (py - y2)) / det
                    l1 = ((y2 - y0) * (px - x2) + (x0 - x2) * (py - y2)) / det
                    l2 = 1.0 - l0 - l1
                    if l0 < 0.0 or l1 < 0.0 or l2 < 0.0:
                        continue
                    col = i * ny + j
                    if pass_ == 0:
                        counts[col] += 1
                    else:
                        zs[fill[col]] = l0 * V[a, 2] + l1 * V[b, 2] + l2 * V[c, 2]
                        fill[col] += 1
    return ptr, zs


@nb.njit(cache=True)
def _inside_cells(ptr, zs, oz, h, nx, ny, nz):
    inside = np.zeros((nx, ny, nz), dtype=np.bool_)
    for i in range(nx):
        for j in range(ny):
            col = i * ny + j
            z = np.sort(zs[ptr[col]:ptr[col + 1]])
            for k in range(nz):
                pz = oz + (k + 0.5) * h
                n = 0
                for q in range(z.shape[0]):
                    if z[q] < pz:
                        n += 1
                inside[i, j, k] = (n % 2) == 1
    return inside


def lattice_tets(V: np.ndarray, F: np.ndarray, h: float):
    """Tet mesh of the volume of a closed surface on a cube lattice of size ``h``.

    Parameters
    ----------
    V : (n, 3) float
        Surface vertices, metres.
    F : (m, 3) int
        Closed surface triangles.
    h : float
        Cube edge, metres.

    Returns
    -------
    TV : (k, 3) float
        Tet vertices (lattice nodes of kept cubes).
    T : (t, 4) int
        Tets.
    Etet : (n, 4) int
        For each surface vertex, the 4 tet vertices of the tet it lies in.
    Ebary : (n, 4) float
        Its barycentric coordinates in that tet (non-negative, summing to 1).
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if not h > 0:
        raise ValueError(f"lattice cube size must be positive, got {h}")
    # A tiny irrational shift keeps column rays off surface vertices and edges.
    lo = V.min(0) - h * (0.5 + 1e-3 * np.array([np.sqrt(2), np.sqrt(3), np.sqrt(5)]))
    dims = np.ceil((V.max(0) - lo) / h + 0.5).astype(np.int64) + 1
    nx, ny, nz = (int(d) for d in dims)
    ptr, zs = _column_crossings(V, F, lo[0], lo[1], h, nx, ny)
    keep = _inside_cells(ptr, zs, lo[2], h, nx, ny, nz)
    # Cubes holding a surface vertex are kept too: the embedding always finds a tet.
    cell = np.clip(np.floor((V - lo) / h).astype(np.int64), 0, dims - 1)
    keep[cell[:, 0], cell[:, 1], cell[:, 2]] = True
    cells = np.argwhere(keep)                                  # (c, 3)
    corner = np.array([[(b >> 0) & 1, (b >> 1) & 1, (b >> 2) & 1] for b in range(8)])
    node = cells[:, None, :] + corner[None, :, :]              # (c, 8, 3)
    nid = (node[..., 0] * (ny + 1) + node[..., 1]) * (nz + 1) + node[..., 2]
    used, inv = np.unique(nid.ravel(), return_inverse=True)
    inv = inv.reshape(nid.shape)
    TV = np.stack([used // ((ny + 1) * (nz + 1)), (used // (nz + 1)) % (ny + 1),
                   used % (nz + 1)], axis=1) * h + lo
    T = inv[:, _KUHN].reshape(-1, 4)                           # cube c -> tets 6c..6c+5
    # Embedding: cube of the vertex, then the Kuhn tet from the order of its local coords.
    cube_of = -np.ones(dims, dtype=np.int64)
    cube_of[cells[:, 0], cells[:, 1], cells[:, 2]] = np.arange(len(cells))
    c = cube_of[cell[:, 0], cell[:, 1], cell[:, 2]]
    u = np.clip((V - lo) / h - cell, 0.0, 1.0)
    order = np.argsort(-u, axis=1, kind="stable")              # s0, s1, s2
    perm_id = _perm_index(order)
    us = np.take_along_axis(u, order, axis=1)
    Ebary = np.stack([1.0 - us[:, 0], us[:, 0] - us[:, 1], us[:, 1] - us[:, 2], us[:, 2]], axis=1)
    Ebary = np.take_along_axis(Ebary, _BARY_COLS[perm_id], axis=1)
    Etet = T[6 * c + perm_id]
    return TV, T, Etet, Ebary


def _perm_index(order: np.ndarray) -> np.ndarray:
    code = order[:, 0] * 9 + order[:, 1] * 3 + order[:, 2]
    table = np.full(27, -1, dtype=np.int64)
    for i, s in enumerate(_PERMS):
        table[s[0] * 9 + s[1] * 3 + s[2]] = i
    return table[code]


def lattice_for_count(V: np.ndarray, F: np.ndarray, target_tets: int, volume: float):
    """:func:`lattice_tets` with the cube size that gives about ``target_tets`` tets."""
    if target_tets < 6:
        raise ValueError(f"target tet count must be at least 6, got {target_tets}")
    h = (6.0 * volume / target_tets) ** (1.0 / 3.0)
    best = None
    for _ in range(4):
        out = lattice_tets(V, F, h)
        n = len(out[1])
        if best is None or abs(n - target_tets) < abs(len(best[1]) - target_tets):
            best = out + (h,)
        if abs(n - target_tets) <= 0.03 * target_tets:
            break
        h *= (n / target_tets) ** (1.0 / 3.0)
    return best


def tet_edges(T: np.ndarray) -> np.ndarray:
    """(e, 2) unique edges of a tet mesh, smaller index first."""
    pairs = np.array([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)])
    E = np.sort(T[:, pairs].reshape(-1, 2), axis=1)
    return np.unique(E, axis=0)


def signed_volumes(X: np.ndarray, T: np.ndarray) -> np.ndarray:
    """(t,) ``(1/6) [(p1 - p2) x (p1 - p3)] . (p1 - p4)`` of every tet."""
    p1, p2, p3, p4 = (X[T[:, a]] for a in range(4))
    return np.einsum("ij,ij->i", np.cross(p1 - p2, p1 - p3), p1 - p4) / 6.0
