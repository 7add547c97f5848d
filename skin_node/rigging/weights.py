"""Joint regions and the paper's automatic inverse-distance skin weights."""
from __future__ import annotations

import numpy as np

from ..skeleton import Skeleton


def segment_distance(P: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Distance of points ``P`` to segments ``A``-``B``, (..., 3) arrays that
    broadcast (row-wise for three (n,3)); shape the broadcast's, without its
    last axis. A segment of no length is its point ``A``."""
    AB = B - A
    AP = P - A
    ab2 = np.maximum(np.einsum("...k,...k->...", AB, AB), 1e-18)
    t = np.clip(np.einsum("...k,...k->...", AP, AB) / ab2, 0.0, 1.0)
    D = AP - t[..., None] * AB
    return np.sqrt(np.einsum("...k,...k->...", D, D))


def point_segment_distance(P: np.ndarray, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(n, S) distances from points ``P`` (n,3) to segments ``A``-``B`` (S,3)."""
    return segment_distance(P[:, None, :], A[None, :, :], B[None, :, :])


def bone_distances(P: np.ndarray, skel: Skeleton):
    """(n, J) distance of every point to every joint's bone, and the nearest segment.

    Returns
    -------
    D : (n, J) float
        Distance to the closest segment of each joint's bone, metres.
    nearest_seg : (n,) int
        Index (into :meth:`Skeleton.bone_segments`) of the closest segment overall.
    """
    seg_joint, A, B = skel.bone_segments()
    Ds = point_segment_distance(P, A, B)
    D = np.full((len(P), skel.n_joints), np.inf)
    for s, j in enumerate(seg_joint):
        D[:, j] = np.minimum(D[:, j], Ds[:, s])
    return D, np.argmin(Ds, axis=1)


def joint_radii(V: np.ndarray, skel: Skeleton) -> np.ndarray:
    """(J,) distance from each joint to the nearest surface vertex: the local
    limb radius that scales the joint's region."""
    P = skel.rest_positions
    r = np.empty(len(P))
    for j in range(len(P)):
        r[j] = np.sqrt(((V - P[j]) ** 2).sum(1).min())
    return r


def joint_regions(P: np.ndarray, skel: Skeleton, thresholds: np.ndarray) -> np.ndarray:
    """(n,) joint whose region holds each point, -1 for a bone region.

    A point belongs to joint ``j``'s region when it is closer to ``j`` than
    ``thresholds[j]`` (the root, where no two bones articulate, has none); of
    several such joints the nearest wins.
    """
    d = np.sqrt(((P[:, None, :] - skel.rest_positions[None]) ** 2).sum(-1))   # (n,J)
    d[:, skel.parents < 0] = np.inf
    d = np.where(d < thresholds[None, :], d, np.inf)
    region = np.argmin(d, axis=1)
    region[~np.isfinite(d[np.arange(len(P)), region])] = -1
    return region


def inverse_distance_weights(D: np.ndarray, region: np.ndarray, skel: Skeleton,
                             power: float = 4.0, neighbours_only: bool = True):
    """The paper's weights ``w_ij = (1/d_ij)^p / sum_k (1/d_ik)^p``.

    A joint-region point takes its 3 nearest bones, any other point its 2.

    Parameters
    ----------
    D : (n, J) float
        Point-to-bone distances (:func:`bone_distances`).
    region : (n,) int
        Joint region per point, -1 outside every region.
    neighbours_only : bool
        Past the paper: candidate bones are the nearest bone and its neighbours
        in the joint tree (parent, children), so a thigh never takes weight from
        the other thigh just because it is near in space.

    Returns
    -------
    Widx, Wval : (n, 3) int, (n, 3) float
        Bone indices and weights, zero-padded, non-negative, rows summing to 1.
    """
    n, J = D.shape
    Dm = D.copy()
    if neighbours_only:
        adj = np.eye(J, dtype=bool)
        for j in range(1, J):
            adj[j, skel.parents[j]] = adj[skel.parents[j], j] = True
        nearest = np.argmin(D, axis=1)
        Dm[~adj[nearest]] = np.inf
    if J < 3:                          # pad so there are always 3 candidate columns
        Dm = np.hstack([Dm, np.full((n, 3 - J), np.inf)])
    order = np.argsort(Dm, axis=1, kind="stable")[:, :3]
    d = np.take_along_axis(Dm, order, axis=1)
    k = np.where(region >= 0, 3, 2)
    valid = (np.arange(3)[None, :] < k[:, None]) & np.isfinite(d)
    inv = np.where(valid, 1.0 / np.maximum(d, 1e-6) ** power, 0.0)
    Wval = inv / inv.sum(1, keepdims=True)
    Widx = np.where(valid, order, 0)
    return Widx.astype(np.int64), Wval


#: Bone segments whose bulge limit a vertex is under: skin can be about as
#: near three (the buttocks: two of the pelvis's and a thigh's), and a limit
#: must fade out before its segment leaves the set.
NEAREST = 4


def nearest_segments(V: np.ndarray, skel, k: int = NEAREST):
    """Each vertex's ``k`` nearest rest bone segments ``seg`` (n, k), their
    distances ``r0`` (n, k) and ``hold`` (n, k): how far each one's bulge
    limit holds (1 for the nearest, falling smoothly to 0 once a segment is
    30% further than it)."""
    _, A, B = skel.bone_segments()
    D = point_segment_distance(V, A, B)
    k = min(k, D.shape[1])
    seg = np.argsort(D, axis=1, kind="stable")[:, :k]
    r0 = np.ascontiguousarray(np.take_along_axis(D, seg, axis=1))
    gap = (r0 - r0[:, :1]) / np.maximum(0.3 * r0[:, :1], 1e-9)
    x = np.clip(1.0 - gap, 0.0, 1.0)
    hold = np.ascontiguousarray(x * x * (3.0 - 2.0 * x))
    return np.ascontiguousarray(seg, dtype=np.int64), r0, hold
