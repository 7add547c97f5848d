"""skin_node: real-time skinning of articulated characters.

Linear or dual-quaternion skinning, then an extended Position Based Dynamics
solve over a tet mesh (Chen & Pan 2017), then self-collision handling and
Laplacian smoothing of the joint regions. The core never imports rclpy: a DCC
plug-in, a benchmark or a notebook uses it alone::

    from skin_node import load_character, Pipeline
    ch = load_character("arm")
    pipe = Pipeline(ch)                        # default stages
    V = pipe.deform(ch.pose(elbow_rz=2.6))     # (n, 3) surface, metres
    pipe.timings                               # ms per stage
"""
import os as _os

# A per-frame deformer shares two cores with DDS threads and its feeders: OpenMP
# threads that spin while waiting would steal them (measured: 10x slower
# parallel kernels under load). Waiting threads sleep instead, unless told otherwise,
# after a short spin (30000 rounds, about 1 ms here): waking a sleeping thread for
# every kernel of a frame cost more than the second thread saved (threads: 2).
_os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
_os.environ.setdefault("GOMP_SPINCOUNT", "30000")

from .builtin.clips import CLIP_NAMES, Clip, default_clip_name, make_clip
from .character import Character, load_character
from .pipeline import (DEFAULT_STAGES, PIPELINE_PARAMS, PRESETS, STAGE_NAMES, ParamSpec,
                       Pipeline)
from .skeleton import Skeleton

__version__ = "0.1.0"

__all__ = ["Character", "Clip", "CLIP_NAMES", "DEFAULT_STAGES", "PIPELINE_PARAMS", "PRESETS",
           "ParamSpec", "Pipeline", "STAGE_NAMES", "Skeleton", "default_clip_name",
           "load_character", "make_clip", "__version__"]
