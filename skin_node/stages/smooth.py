"""Post-processing: Laplacian smoothing of the joint regions."""
from __future__ import annotations

import numpy as np

from ..kernels.smoothing import EVEN, laplacian_smooth, ring_layout
from .base import Frame, KeyedCache, Stage


class Smooth(Stage):
    """Laplacian smoothing of the bent joints' skin, ``smoothing_iterations``
    Jacobi passes of strength ``smoothing`` (faded in with the joints).

    ``smooth_mode: position`` is the paper's ``p_i <- (1 - k) p_i + k mean(one
    ring)`` on the joint regions. ``displacement`` (ours) smooths the
    correction ``d = p - p_stage1`` instead, on every vertex the solve moved:
    the coarse tets' piecewise-linear correction loses its facets while the
    skin's own detail (and its volume) stays, since only ``d`` is averaged.
    """

    name = "smooth"

    def __init__(self, character, params):
        super().__init__(character, params)
        r = character.rig
        self.ptr, self.adj = r.adj_ptr, r.adj
        self.region = r.region
        # surface vertices whose tet touches each joint's zone
        self.szone = character.regions(params["weight_scheme"]).surface_zone
        self._sets = KeyedCache()
        self._ring = np.empty_like(character.V)      # scratch: the gathered ring
        self._buf = np.empty_like(character.V)

    def verts(self, bent: np.ndarray, mode: str) -> np.ndarray:
        """The vertices smoothed for the bent joints ``bent`` in ``mode``."""
        return self.layout(bent, mode)[0]

    def layout(self, bent: np.ndarray, mode: str):
        """:meth:`verts` and their :func:`ring_layout` (cached per bent set)."""
        def make():
            js = np.flatnonzero(bent)
            if mode == "position":
                vs = np.flatnonzero(np.isin(self.region, js)).astype(np.int64)
            else:
                mask = self.szone[:, js].any(axis=1) | np.isin(self.region, js)
                vs = np.flatnonzero(mask).astype(np.int64)
            return (vs, *ring_layout(vs, self.ptr, self.adj))
        return self._sets.get((bent.tobytes(), mode), make)

    def __call__(self, fr: Frame) -> None:
        k = float(self.params["smoothing"])
        n = int(self.params["smoothing_iterations"])
        mode = self.params["smooth_mode"]
        vs, ring, loc, lptr, lnbr = self.layout(fr.bent, mode)
        if k <= 0 or n <= 0 or len(vs) == 0:
            return
        kf = k * float(fr.fade[fr.bent].max())
        laplacian_smooth(fr.surface, fr.surface_base, mode != "position", ring, loc, lptr,
                         lnbr, EVEN, kf, EVEN, n, self._ring[:len(ring)], self._buf[:len(vs)])
