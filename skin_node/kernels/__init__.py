"""numba kernels: one function per constraint, and the loops that apply them."""
