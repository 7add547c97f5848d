"""Joint tree, pose channels, forward kinematics and bind matrices.

Conventions (REP-103: metres, radians, right-handed):

* A pose is a flat float vector ``q`` of *channels*, in the order of
  :attr:`Skeleton.channel_names`: ``root_tx, root_ty, root_tz`` (metres) then,
  for every joint ``J`` in joint order, ``J_rx, J_ry, J_rz`` (radians).
* ``J_rx, J_ry, J_rz`` rotate joint ``J`` about the x, y, z axes of its
  parent's frame *at rest*. They compose extrinsically in x, y, z order:
  ``R = Rz(rz) @ Ry(ry) @ Rx(rx)`` (x is applied first).
* Forward kinematics: ``G_j = G_parent @ T(offset_j) @ R(q_j) @ Rrest_j``, with
  the root's parent being ``T(root_t)``. The bind matrix of a joint is its
  world matrix at ``q = 0``; skinning matrices are ``G_j @ inv(B_j)``.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

ROOT_CHANNELS = ("root_tx", "root_ty", "root_tz")
AXES = ("rx", "ry", "rz")


def euler_xyz_to_matrix(angles: np.ndarray) -> np.ndarray:
    """Rotation matrices ``Rz @ Ry @ Rx`` from (..., 3) angles (rx, ry, rz), radians."""
    a = np.asarray(angles, dtype=np.float64)
    cx, cy, cz = np.cos(a[..., 0]), np.cos(a[..., 1]), np.cos(a[..., 2])
    sx, sy, sz = np.sin(a[..., 0]), np.sin(a[..., 1]), np.sin(a[..., 2])
    R = np.empty(a.shape[:-1] + (3, 3))
    R[..., 0, 0] = cz * cy
    R[..., 0, 1] = cz * sy * sx - sz * cx
    R[..., 0, 2] = cz * sy * cx + sz * sx
    R[..., 1, 0] = sz * cy
    R[..., 1, 1] = sz * sy * sx + cz * cx
    R[..., 1, 2] = sz * sy * cx - cz * sx
    R[..., 2, 0] = -sy
    R[..., 2, 1] = cy * sx
    R[..., 2, 2] = cy * cx
    return R


def matrix_to_euler_xyz(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`euler_xyz_to_matrix`: (..., 3, 3) -> (..., 3) (rx, ry, rz)."""
    R = np.asarray(R, dtype=np.float64)
    cy = np.hypot(R[..., 0, 0], R[..., 1, 0])
    ry = np.arctan2(-R[..., 2, 0], cy)        # atan2, not asin: exact near +-90 degrees
    rx = np.arctan2(R[..., 2, 1], R[..., 2, 2])
    rz = np.arctan2(R[..., 1, 0], R[..., 0, 0])
    # At ry = +-90 degrees only rx - rz (or rx + rz) is defined: put it all in rx.
    lock = cy < 1e-9
    if np.any(lock):
        s = np.sign(-R[..., 2, 0])
        rx = np.where(lock, np.arctan2(s * R[..., 0, 1], R[..., 1, 1]), rx)
        rz = np.where(lock, 0.0, rz)
    return np.stack([rx, ry, rz], axis=-1)


@dataclass
class Skeleton:
    """A tree of joints with rest transforms.

    Attributes
    ----------
    names : list of str, (J,)
        Joint names, parents before children.
    parents : (J,) int
        Parent index of each joint, -1 for the root (exactly one root, index 0).
    rest_positions : (J, 3) float
        World position of every joint at rest, metres.
    rest_rotations : (J, 3, 3) float
        Local rest rotation of every joint (identity for the built-ins).
    tips : (J, 3) float
        World rest position of the far end of a leaf joint's bone; NaN for
        joints with children (their bones end at their children).
    limits : (J, 3, 2) float
        Joint limits per rotation channel (min, max), radians; used by clips
        and the stability tests, never enforced on input.
    reference : (J, 3) float, optional
        For a skeleton fitted to a template: the world direction each bone
        (to its only child, or its tip) has in the template's own rest pose,
        the pose its built-in clips start from, where the fitted bone lies
        apart from it (arms lowered in an A-pose); NaN rows
        elsewhere. Built-in clips are turned to it
        (:func:`skin_node.retarget.conform_clip`); None: no such bone.
    """

    names: list
    parents: np.ndarray
    rest_positions: np.ndarray
    rest_rotations: np.ndarray | None = None
    tips: np.ndarray | None = None
    limits: np.ndarray | None = None
    reference: np.ndarray | None = None
    _children: list = field(default=None, init=False, repr=False)

    def __post_init__(self) -> None:
        self.names = [str(n) for n in self.names]
        self.parents = np.asarray(self.parents, dtype=np.int64)
        self.rest_positions = np.asarray(self.rest_positions, dtype=np.float64)
        J = len(self.names)
        if J == 0:
            raise ValueError("skeleton has no joints")
        if self.parents.shape != (J,) or self.rest_positions.shape != (J, 3):
            raise ValueError(
                f"skeleton arrays disagree: {J} names, parents {self.parents.shape}, "
                f"rest_positions {self.rest_positions.shape} (expected ({J},) and ({J}, 3))")
        if len(set(self.names)) != J:
            dup = sorted({n for n in self.names if self.names.count(n) > 1})
            raise ValueError(f"skeleton has duplicate joint names: {dup}")
        if self.parents[0] != -1 or np.any(self.parents[1:] < 0):
            raise ValueError("skeleton must have exactly one root, at index 0")
        if np.any(self.parents[1:] >= np.arange(1, J)):
            raise ValueError("skeleton joints must be ordered parents before children "
                             "(a parent index >= its child's means a cycle or bad order)")
        if not np.all(np.isfinite(self.rest_positions)):
            raise ValueError("skeleton rest positions contain NaN or Inf")
        if self.rest_rotations is None:
            self.rest_rotations = np.tile(np.eye(3), (J, 1, 1))
        self.rest_rotations = np.asarray(self.rest_rotations, dtype=np.float64)
        if self.tips is None:
            self.tips = np.full((J, 3), np.nan)
        self.tips = np.asarray(self.tips, dtype=np.float64)
        if self.limits is None:
            self.limits = np.tile(np.array([-np.pi, np.pi]), (J, 3, 1))
        self.limits = np.asarray(self.limits, dtype=np.float64)
        if self.reference is not None:
            self.reference = np.asarray(self.reference, dtype=np.float64)
            if self.reference.shape != (J, 3):
                raise ValueError(f"skeleton reference has shape {self.reference.shape}, "
                                 f"expected ({J}, 3)")
        self._children = [[] for _ in range(J)]
        for j in range(1, J):
            self._children[self.parents[j]].append(j)
        for j in range(J):
            if not self._children[j] and not np.all(np.isfinite(self.tips[j])):
                raise ValueError(f"leaf joint '{self.names[j]}' needs a finite tip position")
        # Rest world matrices, then local offsets in the parent's rest frame.
        Grest = np.tile(np.eye(4), (J, 1, 1))
        self.offsets = np.zeros((J, 3))
        for j in range(J):
            p = self.parents[j]
            Grest[j, :3, 3] = self.rest_positions[j]
            if p < 0:
                Grest[j, :3, :3] = self.rest_rotations[j]
                self.offsets[j] = self.rest_positions[j]
            else:
                Grest[j, :3, :3] = Grest[p, :3, :3] @ self.rest_rotations[j]
                self.offsets[j] = Grest[p, :3, :3].T @ (self.rest_positions[j] - self.rest_positions[p])
        self.bind = Grest
        self.bind_inv = np.linalg.inv(Grest)

    # ------------------------------------------------------------------ names
    @property
    def n_joints(self) -> int:
        return len(self.names)

    @property
    def channel_names(self) -> list:
        """Every pose channel name, in the order of the pose vector ``q``."""
        return list(ROOT_CHANNELS) + [f"{n}_{a}" for n in self.names for a in AXES]

    @property
    def n_channels(self) -> int:
        return 3 + 3 * self.n_joints

    def children(self, j: int) -> list:
        return list(self._children[j])

    def subtree(self) -> np.ndarray:
        """(J, J) bool: ``[a, b]`` is True when joint ``b`` is ``a`` or below it."""
        J = self.n_joints
        below = np.zeros((J, J), dtype=bool)
        for b in range(J):
            a = b
            while a >= 0:
                below[a, b] = True
                a = self.parents[a]
        return below

    def index(self, name: str) -> int:
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"no joint named '{name}'; joints are {self.names}") from None

    def rest_pose(self) -> np.ndarray:
        """The rest pose as a channel vector (all zeros)."""
        return np.zeros(self.n_channels)

    def pose(self, **channels: float) -> np.ndarray:
        """A channel vector from keyword channels, e.g. ``pose(elbow_rz=1.2)``."""
        q = self.rest_pose()
        lookup = {n: i for i, n in enumerate(self.channel_names)}
        for k, v in channels.items():
            if k not in lookup:
                raise KeyError(f"unknown channel '{k}'")
            q[lookup[k]] = v
        return q

    # ------------------------------------------------------------ kinematics
    def bone_segments(self, G: np.ndarray | None = None):
        """Bone segments of every joint: (seg_joint (S,), A (S,3), B (S,3)).

        A joint's bone runs from the joint to each of its children, or to its
        tip for a leaf. With ``G`` (world matrices) the segments are posed.
        """
        seg_joint, A, B = [], [], []
        for j in range(self.n_joints):
            ends = [self.rest_positions[c] for c in self._children[j]] or [self.tips[j]]
            for e in ends:
                seg_joint.append(j)
                A.append(self.rest_positions[j])
                B.append(e)
        seg_joint = np.asarray(seg_joint, dtype=np.int64)
        A, B = np.asarray(A), np.asarray(B)
        if G is not None:
            M = G @ self.bind_inv
            Ms = M[seg_joint]
            A = np.einsum("sij,sj->si", Ms[:, :3, :3], A) + Ms[:, :3, 3]
            B = np.einsum("sij,sj->si", Ms[:, :3, :3], B) + Ms[:, :3, 3]
        return seg_joint, A, B

    def limited(self) -> np.ndarray:
        """(J,) whether each joint's rotation is limited: some channel of it not
        free over a full turn (a glTF file's skeleton gives no limits)."""
        lim = self.limits
        return ~np.all((lim[:, :, 0] <= -np.pi + 1e-9) & (lim[:, :, 1] >= np.pi - 1e-9), axis=1)

    def local_rotations(self, q: np.ndarray) -> np.ndarray:
        """(J, 3, 3) pose rotations ``R(q_j)`` (without the rest rotation)."""
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (self.n_channels,):
            raise ValueError(f"pose has shape {q.shape}, expected ({self.n_channels},)")
        return euler_xyz_to_matrix(q[3:].reshape(-1, 3))

    def world_matrices(self, q: np.ndarray) -> np.ndarray:
        """(J, 4, 4) world matrices of every joint for pose ``q``."""
        Rq = self.local_rotations(q)
        J = self.n_joints
        G = np.empty((J, 4, 4))
        L = np.zeros((4, 4))
        L[3, 3] = 1.0
        for j in range(J):
            p = self.parents[j]
            L[:3, :3] = Rq[j] @ self.rest_rotations[j]
            L[:3, 3] = self.offsets[j]
            if p < 0:
                L[:3, 3] = self.offsets[j] + q[:3]
                G[j] = L
            else:
                G[j] = G[p] @ L
        return G

    def skinning_matrices(self, q: np.ndarray) -> np.ndarray:
        """(J, 4, 4) matrices ``G_j @ inv(B_j)`` that carry rest points to pose ``q``."""
        return self.world_matrices(q) @ self.bind_inv

    def joint_angles(self, q: np.ndarray) -> np.ndarray:
        """(J,) rotation angle of each joint's pose rotation, radians (0 at rest)."""
        Rq = self.local_rotations(q)
        c = (np.trace(Rq, axis1=1, axis2=2) - 1.0) * 0.5
        return np.arccos(np.clip(c, -1.0, 1.0))
