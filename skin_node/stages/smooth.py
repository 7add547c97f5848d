"""Post-processing: Laplacian smoothing of the joint regions."""
from __future__ import annotations

import numpy as np

from ..kernels.solver import laplacian_smooth
from .base import Frame, Stage


class Smooth(Stage):
    """``p_i <- (1 - k) p_i + k mean(one ring of p_i)`` on the regions of bent
    joints only, ``smoothing_iterations`` Jacobi passes of strength ``smoothing``."""

    name = "smooth"

    def __init__(self, character, params):
        super().__init__(character, params)
        r = character.rig
        self.ptr, self.adj = r.adj_ptr, r.adj
        self.region = r.region
        self._key, self._verts = None, None
        self._buf = np.empty_like(character.V)

    def verts(self, bent: np.ndarray) -> np.ndarray:
        key = bent.tobytes()
        if key != self._key:
            js = np.flatnonzero(bent)
            self._key = key
            self._verts = np.flatnonzero(np.isin(self.region, js)).astype(np.int64)
        return self._verts

    def __call__(self, fr: Frame) -> None:
        k = float(self.params["smoothing"])
        n = int(self.params["smoothing_iterations"])
        vs = self.verts(fr.bent)
        if k <= 0 or n <= 0 or len(vs) == 0:
            return
        # strength fades in with the joints' fade (no pop when a joint starts bending)
        kf = k * float(fr.fade[fr.bent].max())
        laplacian_smooth(fr.surface, vs, self.ptr, self.adj, kf, n, self._buf)
