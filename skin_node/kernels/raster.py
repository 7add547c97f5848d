"""A small z-buffer rasterizer for pictures of skin that a viewer can trust.

Every pixel shows the triangle nearest the eye at that pixel (a depth per
pixel), so skin passing through skin is drawn as it is: where one sheet
pierces another, the picture shows the cut. Faces seen from behind (skin
turned inside out, or the inside of a surface seen through a hole) are drawn
in their own colour. A painter's sort of whole faces by mean depth cannot do
either.
"""
from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def rasterize(P, F, width, height, depth, face):
    """Fill ``depth`` (height, width) with the nearest depth and ``face`` with
    the id of the nearest triangle (-1 where none) of the projected vertices
    ``P`` (n, 3): x, y in pixels, z the depth (smaller is nearer)."""
    for f in range(F.shape[0]):
        a, b, c = F[f, 0], F[f, 1], F[f, 2]
        x0, y0, z0 = P[a, 0], P[a, 1], P[a, 2]
        x1, y1, z1 = P[b, 0], P[b, 1], P[b, 2]
        x2, y2, z2 = P[c, 0], P[c, 1], P[c, 2]
        area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
        if abs(area) < 1e-12:
            continue
        i0 = max(0, int(np.floor(min(x0, x1, x2))))
        i1 = min(width - 1, int(np.ceil(max(x0, x1, x2))))
        j0 = max(0, int(np.floor(min(y0, y1, y2))))
        j1 = min(height - 1, int(np.ceil(max(y0, y1, y2))))
        for j in range(j0, j1 + 1):
            py = j + 0.5
            for i in range(i0, i1 + 1):
                px = i + 0.5
                w0 = ((x1 - px) * (y2 - py) - (x2 - px) * (y1 - py)) / area
                w1 = ((x2 - px) * (y0 - py) - (x0 - px) * (y2 - py)) / area
                w2 = 1.0 - w0 - w1
                if w0 < 0.0 or w1 < 0.0 or w2 < 0.0:
                    continue
                z = w0 * z0 + w1 * z1 + w2 * z2
                if z < depth[j, i]:
                    depth[j, i] = z
                    face[j, i] = f


def look_at(eye: np.ndarray, target: np.ndarray, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """(3, 3) camera rotation: rows right, up, forward (towards the target)."""
    fwd = np.asarray(target, float) - np.asarray(eye, float)
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, up)
    if np.linalg.norm(right) < 1e-9:
        right = np.cross(fwd, (0.0, 1.0, 0.0))
    right /= np.linalg.norm(right)
    return np.stack([right, np.cross(right, fwd), fwd])


def render(V: np.ndarray, F: np.ndarray, eye, target, size=(400, 400), fov: float = 30.0,
           up=(0.0, 0.0, 1.0), front=(0.80, 0.62, 0.52), back=(0.15, 0.35, 0.95),
           background=(1.0, 1.0, 1.0), mark: np.ndarray | None = None,
           mark_colour=(0.9, 0.1, 0.1), clip=None) -> np.ndarray:
    """(height, width, 3) float image of the surface ``V, F`` seen from
    ``eye`` towards ``target`` in perspective (vertical field of view ``fov``
    degrees), shaded by a head light; faces seen from behind in ``back``,
    faces flagged in ``mark`` (m,) bool in ``mark_colour``. ``clip = (point,
    normal)`` leaves out the faces whose centre lies on the normal's side of
    that plane: a section through the body, where skin that passes through
    skin shows as crossing outlines."""
    w, h = size
    R = look_at(np.asarray(eye, float), np.asarray(target, float), up)
    C = (np.asarray(V, float) - np.asarray(eye, float)) @ R.T       # x right, y up, z depth
    f = 0.5 * h / np.tan(np.radians(fov) / 2)
    z = np.maximum(C[:, 2], 1e-6)
    P = np.stack([w / 2 + f * C[:, 0] / z, h / 2 - f * C[:, 1] / z, C[:, 2]], axis=1)
    P = np.ascontiguousarray(P)
    depth = np.full((h, w), np.inf)
    face = np.full((h, w), -1, dtype=np.int64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    drawn = np.arange(len(F))
    if clip is not None:
        cen = np.asarray(V, float)[F].mean(axis=1)
        drawn = np.flatnonzero((cen - np.asarray(clip[0], float)) @ np.asarray(clip[1], float) <= 0)
    rasterize(P, np.ascontiguousarray(F[drawn]), w, h, depth, face)
    face = np.where(face >= 0, drawn[np.maximum(face, 0)], -1)
    # shading: the world normal against the direction to the eye
    X = np.asarray(V, float)
    n = np.cross(X[F[:, 1]] - X[F[:, 0]], X[F[:, 2]] - X[F[:, 0]])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)
    view = np.asarray(eye, float) - X[F].mean(axis=1)
    view /= np.maximum(np.linalg.norm(view, axis=1, keepdims=True), 1e-20)
    cos = np.einsum("ij,ij->i", n, view)
    img = np.empty((h, w, 3))
    img[:] = background
    hit = face >= 0
    fid = face[hit]
    c = cos[fid]
    base = np.where((c >= 0)[:, None], np.asarray(front), np.asarray(back))
    if mark is not None:
        base = np.where(mark[fid][:, None], np.asarray(mark_colour), base)
    img[hit] = base * (0.25 + 0.75 * np.abs(c))[:, None]
    return np.clip(img, 0.0, 1.0)
