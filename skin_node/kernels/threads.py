"""What several threads calling the parallel kernels at once (pipelines in
worker threads, say) need of numba: a threading layer that allows it.

numba's own ``workqueue`` layer aborts the process on concurrent calls; its
``omp`` and ``tbb`` layers do not. The layer is chosen when the first parallel
kernel runs, so :func:`allow_concurrent_calls` must come before that and
:func:`check_concurrent_calls` after it.
"""
from __future__ import annotations

import numba


def allow_concurrent_calls() -> None:
    """Ask numba for a threading layer that takes concurrent calls (``omp``
    or ``tbb``). Call it before any parallel kernel runs."""
    numba.config.THREADING_LAYER = "threadsafe"


def check_concurrent_calls(who: str) -> None:
    """Raise ValueError, naming ``who`` (what needs concurrent calls), when the
    threading layer numba loaded cannot take them. Call it after a parallel
    kernel ran (a warm-up)."""
    if numba.threading_layer() == "workqueue":
        raise ValueError(f"{who} needs numba's omp or tbb threading layer (its workqueue "
                         "layer aborts on concurrent calls); only workqueue could be loaded "
                         "here")
