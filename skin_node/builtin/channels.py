"""What every built-in clip is made with: its frame rate and a writer of
channel columns by name."""
from __future__ import annotations

import numpy as np

from ..skeleton import Skeleton

FPS = 120.0


def channel_setter(skel: Skeleton, frames: np.ndarray):
    """``put(name, values)``: write ``values`` into the column of ``frames``
    (T, C) of the channel ``name`` of ``skel``; raises ValueError for a
    channel the skeleton lacks."""
    index = {n: i for i, n in enumerate(skel.channel_names)}

    def put(name: str, values) -> None:
        if name not in index:
            raise ValueError(f"clip needs channel '{name}', which this skeleton lacks")
        frames[:, index[name]] = values
    return put
