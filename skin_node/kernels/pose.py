"""What a frame needs of the pose alone (numba): forward kinematics, the joints'
fades and the posed bone segments (conventions: :mod:`skin_node.skeleton`)."""
from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True, nogil=True)
def forward_kinematics(q, parents, offsets, rest_rotations, bind_inv, G, M, angles):
    """World matrices ``G``, skinning matrices ``M = G inv(B)`` and each joint's
    pose rotation angle, in one pass over the joints (parents first)."""
    J = parents.shape[0]
    L = np.zeros((4, 4))
    L[3, 3] = 1.0
    for j in range(J):
        rx, ry, rz = q[3 + 3 * j], q[4 + 3 * j], q[5 + 3 * j]
        cx, cy, cz = np.cos(rx), np.cos(ry), np.cos(rz)
        sx, sy, sz = np.sin(rx), np.sin(ry), np.sin(rz)
        R = np.empty((3, 3))
        R[0, 0], R[0, 1], R[0, 2] = cz * cy, cz * sy * sx - sz * cx, cz * sy * cx + sz * sx
        R[1, 0], R[1, 1], R[1, 2] = sz * cy, sz * sy * sx + cz * cx, sz * sy * cx - cz * sx
        R[2, 0], R[2, 1], R[2, 2] = -sy, cy * sx, cy * cx
        c = (R[0, 0] + R[1, 1] + R[2, 2] - 1.0) * 0.5
        angles[j] = np.arccos(min(1.0, max(-1.0, c)))
        for r in range(3):
            for k in range(3):
                L[r, k] = (R[r, 0] * rest_rotations[j, 0, k] + R[r, 1] * rest_rotations[j, 1, k]
                           + R[r, 2] * rest_rotations[j, 2, k])
            L[r, 3] = offsets[j, r]
        p = parents[j]
        if p < 0:
            for r in range(3):
                L[r, 3] += q[r]
            G[j] = L
        else:
            for r in range(4):
                for k in range(4):
                    G[j, r, k] = (G[p, r, 0] * L[0, k] + G[p, r, 1] * L[1, k]
                                  + G[p, r, 2] * L[2, k] + G[p, r, 3] * L[3, k])
        for r in range(4):
            for k in range(4):
                M[j, r, k] = (G[j, r, 0] * bind_inv[j, 0, k] + G[j, r, 1] * bind_inv[j, 1, k]
                              + G[j, r, 2] * bind_inv[j, 2, k] + G[j, r, 3] * bind_inv[j, 3, k])


@nb.njit(cache=True, nogil=True)
def pose_frame(q, parents, offsets, rest_rotations, bind_inv, threshold, band, seg_joint,
               segA, segB, G, M, angles, fade, A, B):
    """What a frame needs of the pose alone, in one call (a dozen small numpy
    calls cost a quarter of a millisecond between the big kernels): forward
    kinematics, each joint's fade (0 below ``threshold``, rising to 1 over
    ``band`` radians; 0 for roots) and the posed bone segments."""
    forward_kinematics(q, parents, offsets, rest_rotations, bind_inv, G, M, angles)
    for j in range(parents.shape[0]):
        fade[j] = 0.0 if parents[j] < 0 else min(1.0, max(0.0, (angles[j] - threshold) / band))
    for s in range(seg_joint.shape[0]):
        j = seg_joint[s]
        for r in range(3):
            A[s, r] = (M[j, r, 0] * segA[s, 0] + M[j, r, 1] * segA[s, 1]
                       + M[j, r, 2] * segA[s, 2] + M[j, r, 3])
            B[s, r] = (M[j, r, 0] * segB[s, 0] + M[j, r, 1] * segB[s, 1]
                       + M[j, r, 2] * segB[s, 2] + M[j, r, 3])
