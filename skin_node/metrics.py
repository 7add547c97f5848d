"""Measures of a deformed surface: volume, sections, roughness, folds, weight jumps."""
from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components


def mesh_volume(V: np.ndarray, F: np.ndarray) -> float:
    """Signed volume enclosed by a closed triangle mesh (positive when outward), m^3."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def region_volume(V: np.ndarray, F: np.ndarray, faces: np.ndarray, centre: np.ndarray) -> float:
    """Volume of the cone from ``centre`` over the triangles ``faces`` (a region's
    share of the enclosed volume when ``centre`` moves with the region), m^3."""
    a, b, c = (V[F[faces, k]] - centre for k in range(3))
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)


def roughness(V: np.ndarray, verts: np.ndarray, ptr: np.ndarray, nbr: np.ndarray) -> float:
    """Mean length of the umbrella Laplacian ``mean(one ring) - p`` over ``verts``, m."""
    counts = ptr[verts + 1] - ptr[verts]
    rows = np.repeat(np.arange(len(verts)), counts)
    cols = np.concatenate([nbr[ptr[i]:ptr[i + 1]] for i in verts]) if len(verts) else np.zeros(0, int)
    mean = np.zeros((len(verts), 3))
    np.add.at(mean, rows, V[cols])
    mean /= np.maximum(counts, 1)[:, None]
    return float(np.linalg.norm(mean - V[verts], axis=1).mean()) if len(verts) else 0.0


def interior_edges(F: np.ndarray):
    """``(fa, fb, E)``: the two faces and the corners of every edge that
    exactly two faces share."""
    F = np.asarray(F, dtype=np.int64)
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    fid = np.tile(np.arange(len(F)), 3)
    key = np.sort(E, axis=1)
    order = np.lexsort((key[:, 1], key[:, 0]))
    k, f = key[order], fid[order]
    same = np.all(k[1:] == k[:-1], axis=1)
    i = np.flatnonzero(same)
    return f[i], f[i + 1], k[i]


def shells(F: np.ndarray, n: int):
    """``(count, label)``: the connected pieces of the triangles ``F`` over
    ``n`` vertices and each vertex's piece."""
    A = coo_matrix((np.ones(F.size), (F.ravel(), np.roll(F, 1, axis=1).ravel())), shape=(n, n))
    return connected_components(A, directed=False)


def unit_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(m, 3) unit normals of triangles ``F`` over vertices ``V`` (0 for a
    degenerate one)."""
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)


class SurfaceQuality:
    """What a viewer sees of a deformed skin, independently of how it was made.

    * *sharp folds*: interior edges whose dihedral angle (between their two
      faces' normals) grew by more than 90 degrees (``folds90``) or 45
      degrees (``folds45``) from rest. Smooth skinning of a smooth rest
      surface has almost none away from contact; crumpled or torn skin has
      many.
    * *roughness*: the mean length of the umbrella Laplacian (mean of the one
      ring minus the vertex) over the whole surface over the same at rest
      (``roughness``), and the ratio of their 99th percentiles
      (``roughness_p99``).

    Parameters
    ----------
    V0 : (n, 3) rest surface, F : (m, 3) its triangles.
    """

    def __init__(self, V0: np.ndarray, F: np.ndarray) -> None:
        self.F = np.asarray(F, dtype=np.int64)
        self.fa, self.fb, _ = interior_edges(self.F)
        self.turn0 = self._dihedral(V0)
        F = self.F
        E = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1),
                      axis=0)
        n = len(V0)
        self._rows = np.concatenate([E[:, 0], E[:, 1]])
        self._cols = np.concatenate([E[:, 1], E[:, 0]])
        self._count = np.maximum(np.bincount(self._rows, minlength=n), 1)[:, None]
        u0 = self._umbrella(V0)
        self.u0_mean, self.u0_p99 = float(u0.mean()), float(np.percentile(u0, 99))

    def _dihedral(self, V: np.ndarray) -> np.ndarray:
        N = unit_normals(V, self.F)
        c = np.einsum("ij,ij->i", N[self.fa], N[self.fb])
        return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))

    def _umbrella(self, V: np.ndarray) -> np.ndarray:
        S = np.zeros_like(V)
        np.add.at(S, self._rows, V[self._cols])
        return np.linalg.norm(S / self._count - V, axis=1)

    def turns(self, V: np.ndarray) -> np.ndarray:
        """How far each interior edge's dihedral angle grew from rest in ``V``
        (degrees; the edge between faces ``F[fa[k]]`` and ``F[fb[k]]``)."""
        return self._dihedral(np.asarray(V, dtype=np.float64)) - self.turn0

    def __call__(self, V: np.ndarray) -> dict:
        """``folds90``, ``folds45``, ``roughness`` and ``roughness_p99`` of ``V``."""
        V = np.asarray(V, dtype=np.float64)
        turn = self.turns(V)
        u = self._umbrella(V)
        return {"folds90": int(np.count_nonzero(turn > 90.0)),
                "folds45": int(np.count_nonzero(turn > 45.0)),
                "roughness": float(u.mean() / self.u0_mean),
                "roughness_p99": float(np.percentile(u, 99) / self.u0_p99)}


def weight_jumps(F: np.ndarray, Widx: np.ndarray, Wval: np.ndarray, J: int) -> np.ndarray:
    """(e,) the weight jump of every edge of ``F``: the sum over bones of
    ``|w_a - w_b|`` between its two ends (0 for equal weights, 2 for two
    vertices that share no bone). A skin tears where it is large."""
    W = np.zeros((len(Widx), J))
    np.add.at(W, (np.repeat(np.arange(len(Widx)), Widx.shape[1]), Widx.ravel()), Wval.ravel())
    E = np.unique(np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1),
                  axis=0)
    return np.abs(W[E[:, 0]] - W[E[:, 1]]).sum(axis=1)
