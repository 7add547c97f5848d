"""numba kernels, the per-frame work of the stages, in modules named for what
they hold: pose (forward kinematics), skinning, constraints (one function
each) and solver (the loops that apply them), collision and contact (skin
through skin), volume, shape, smoothing; bvh, raster, intersect and topology
beside them; threads says what several threads calling them at once need."""

#: Fast-math flags of the hot loops: reassociation, reciprocals, contraction,
#: approximate functions. Not ``nnan``/``ninf``: the finiteness checks stay exact.
FAST = {"nsz", "arcp", "contract", "afn", "reassoc"}
