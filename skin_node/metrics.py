"""Measures of a deformed surface: volume, sections, roughness, crossings."""
from __future__ import annotations

import numpy as np


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
