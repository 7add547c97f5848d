"""Stage 1: linear blend skinning and dual-quaternion skinning of both meshes."""
from __future__ import annotations

import numpy as np

from ..kernels import solver
from .base import Frame, Stage


def matrices_to_dual_quaternions(M: np.ndarray) -> np.ndarray:
    """(J, 8) unit dual quaternions (real w,x,y,z, dual w,x,y,z) of rigid (J,4,4) ``M``."""
    R, t = M[:, :3, :3], M[:, :3, 3]
    tr = np.trace(R, axis1=1, axis2=2)
    q = np.empty((len(M), 4))
    # Shepperd's method: pick the largest pivot for stability.
    d = np.stack([tr, R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], axis=1)
    k = np.argmax(d, axis=1)
    for i in range(len(M)):
        r = R[i]
        if k[i] == 0:
            s = np.sqrt(1.0 + tr[i]) * 2
            q[i] = [0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
        elif k[i] == 1:
            s = np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
            q[i] = [(r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, (r[0, 2] + r[2, 0]) / s]
        elif k[i] == 2:
            s = np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
            q[i] = [(r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, (r[1, 2] + r[2, 1]) / s]
        else:
            s = np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
            q[i] = [(r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, (r[1, 2] + r[2, 1]) / s, 0.25 * s]
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    # dual = 0.5 * (0, t) * real
    w, x, y, z = q.T
    tx, ty, tz = t.T
    dual = 0.5 * np.stack([-tx * x - ty * y - tz * z,
                           tx * w + ty * z - tz * y,
                           -tx * z + ty * w + tz * x,
                           tx * y - ty * x + tz * w], axis=1)
    return np.ascontiguousarray(np.concatenate([q, dual], axis=1))


class LBS(Stage):
    """``v' = sum_j w_j M_j v`` on the surface and on the tet mesh."""

    name = "lbs"
    skinning = True

    def __init__(self, character, params):
        super().__init__(character, params)
        r = character.rig
        self.V, self.TV = character.V, r.TV
        self.W = (r.Widx, r.Wval)
        self.TW = (r.TWidx, r.TWval)

    def skin(self, V, W, M, out):
        solver.lbs(V, W[0], W[1], M, out)

    def __call__(self, fr: Frame) -> None:
        M = np.ascontiguousarray(fr.M)
        self.skin(self.V, self.W, M, fr.surface)
        self.skin(self.TV, self.TW, M, fr.tet)
        fr.surface_base[:] = fr.surface
        fr.tet_base[:] = fr.tet


class DQS(LBS):
    """Dual-quaternion skinning (Kavan et al. 2007): no candy-wrapper collapse
    under twist, at the price of a bulge at bent joints (which PBD removes)."""

    name = "dqs"

    def skin(self, V, W, M, out):
        solver.dqs(V, W[0], W[1], self._Q, out)

    def __call__(self, fr: Frame) -> None:
        self._Q = matrices_to_dual_quaternions(fr.M)
        super().__call__(fr)
