"""numba kernels: one function per constraint, and the loops that apply them."""

#: Fast-math flags of the hot loops: reassociation, reciprocals, contraction,
#: approximate functions. Not ``nnan``/``ninf``: the finiteness checks stay exact.
FAST = {"nsz", "arcp", "contract", "afn", "reassoc"}
