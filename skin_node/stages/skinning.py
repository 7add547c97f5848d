"""Stage 1: linear blend skinning and dual-quaternion skinning of both meshes."""
from __future__ import annotations

import numpy as np

from ..kernels.skinning import dqs, dqs_rows, lbs, lbs_rows, matrices_to_dual_quaternions
from .base import Frame, Stage


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
            lbs(V, W[0], W[1], T, out)
        else:
            lbs_rows(V, W[0], W[1], T, rows, out)

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
            dqs(V, W[0], W[1], T, out)
        else:
            dqs_rows(V, W[0], W[1], T, rows, out)
