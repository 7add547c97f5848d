"""Stage 1: linear blend skinning and dual-quaternion skinning of both meshes."""
from __future__ import annotations

import numba as nb
import numpy as np

from ..kernels import solver
from .base import Frame, Stage


def matrices_to_dual_quaternions(M: np.ndarray) -> np.ndarray:
    """(J, 8) unit dual quaternions (real w,x,y,z, dual w,x,y,z) of rigid (J,4,4) ``M``."""
    M = np.ascontiguousarray(M, dtype=np.float64)
    return _dual_quaternions(M, np.empty((len(M), 8)))


@nb.njit(cache=True, nogil=True)
def _dual_quaternions(M, q):
    for i in range(M.shape[0]):
        r = M[i]
        tr = r[0, 0] + r[1, 1] + r[2, 2]
        # Shepperd's method: pick the largest pivot for stability.
        if tr >= r[0, 0] and tr >= r[1, 1] and tr >= r[2, 2]:
            s = np.sqrt(1.0 + tr) * 2
            w, x, y, z = 0.25 * s, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, \
                (r[1, 0] - r[0, 1]) / s
        elif r[0, 0] >= r[1, 1] and r[0, 0] >= r[2, 2]:
            s = np.sqrt(1.0 + r[0, 0] - r[1, 1] - r[2, 2]) * 2
            w, x, y, z = (r[2, 1] - r[1, 2]) / s, 0.25 * s, (r[0, 1] + r[1, 0]) / s, \
                (r[0, 2] + r[2, 0]) / s
        elif r[1, 1] >= r[2, 2]:
            s = np.sqrt(1.0 + r[1, 1] - r[0, 0] - r[2, 2]) * 2
            w, x, y, z = (r[0, 2] - r[2, 0]) / s, (r[0, 1] + r[1, 0]) / s, 0.25 * s, \
                (r[1, 2] + r[2, 1]) / s
        else:
            s = np.sqrt(1.0 + r[2, 2] - r[0, 0] - r[1, 1]) * 2
            w, x, y, z = (r[1, 0] - r[0, 1]) / s, (r[0, 2] + r[2, 0]) / s, \
                (r[1, 2] + r[2, 1]) / s, 0.25 * s
        n = np.sqrt(w * w + x * x + y * y + z * z)
        w, x, y, z = w / n, x / n, y / n, z / n
        # dual = 0.5 * (0, t) * real
        tx, ty, tz = r[0, 3], r[1, 3], r[2, 3]
        q[i, 0], q[i, 1], q[i, 2], q[i, 3] = w, x, y, z
        q[i, 4] = 0.5 * (-tx * x - ty * y - tz * z)
        q[i, 5] = 0.5 * (tx * w + ty * z - tz * y)
        q[i, 6] = 0.5 * (-tx * z + ty * w + tz * x)
        q[i, 7] = 0.5 * (tx * y - ty * x + tz * w)
    return q


class LBS(Stage):
    """``v' = sum_j w_j M_j v`` on the surface and on the tet mesh.

    Of the tet mesh, only the vertices the later stages use this frame
    (``frame.tet_rows``, see :meth:`Stage.tet_vertices`) are skinned; the rest
    are skinned when the frame is read back (:attr:`Pipeline.last_frame`).
    """

    name = "lbs"
    skinning = True

    def __init__(self, character, params):
        super().__init__(character, params)
        r = character.rig
        self.V, self.TV = character.V, r.TV
        w = self.weights
        self.W = (w.Widx, w.Wval)
        self.TW = (w.TWidx, w.TWval)

    def transforms(self, fr: Frame) -> np.ndarray:
        """The frame's bone transforms in the form :meth:`skin` takes."""
        return np.ascontiguousarray(fr.M)

    def skin(self, V, W, T, out, rows=None):
        if rows is None:
            solver.lbs(V, W[0], W[1], T, out)
        else:
            solver.lbs_rows(V, W[0], W[1], T, rows, out)

    def __call__(self, fr: Frame) -> None:
        T = self.transforms(fr)
        self.skin(self.V, self.W, T, fr.surface)
        fr.surface_base[:] = fr.surface
        rows = fr.tet_rows
        self.skin(self.TV, self.TW, T, fr.tet, rows)
        if rows is None:
            fr.tet_base[:] = fr.tet
            return
        tet, base = fr.tet, fr.tet_base
        base[rows] = tet[rows]

        def the_rest():
            # holds the frame's arrays, not the frame: a frame that held itself
            # would wait for the cycle collector (+34 MB over 1000 walk frames)
            rest = np.ones(len(self.TV), dtype=bool)
            rest[rows] = False
            rest = np.flatnonzero(rest)
            self.skin(self.TV, self.TW, T, tet, rest)
            base[rest] = tet[rest]
        fr.unskinned = the_rest


class DQS(LBS):
    """Dual-quaternion skinning (Kavan et al. 2007): no candy-wrapper collapse
    under twist, at the price of a bulge at bent joints (which PBD removes)."""

    name = "dqs"

    def transforms(self, fr: Frame) -> np.ndarray:
        return matrices_to_dual_quaternions(fr.M)

    def skin(self, V, W, T, out, rows=None):
        if rows is None:
            solver.dqs(V, W[0], W[1], T, out)
        else:
            solver.dqs_rows(V, W[0], W[1], T, rows, out)
