"""A quadruped walk for skeletons embedded with the ``quadruped`` template.

Channels follow the template frame (the root's rest rotation has the body's
forward, left and up axes as columns): ``*_ry`` > 0 swings a leg's lower end
backward, so the clip is the same whatever way the mesh faces.
"""
from __future__ import annotations

import numpy as np

from ..skeleton import Skeleton
from .channels import FPS, channel_setter

#: Footfall order of a lateral-sequence walk (left hind, left fore, right hind,
#: right fore), as fractions of the stride.
PHASES = {"l_ankle": 0.0, "l_wrist": 0.25, "r_ankle": 0.5, "r_wrist": 0.75}


def quadruped_walk(skel: Skeleton, seconds: float = 2.0, cadence: float = 1.0,
                   swing: float = 0.35, speed: float = 0.6) -> np.ndarray:
    """A four-beat walk: each leg swings fore and aft, flexing its middle joint
    while it swings forward; the neck nods twice a stride.

    Parameters
    ----------
    skel : Skeleton
        A skeleton with the quadruped template's joint names.
    seconds : float
        Clip length.
    cadence : float
        Strides per second.
    swing : float
        Hip and shoulder swing amplitude, radians.
    speed : float
        Forward speed of the root along the body's rest forward axis, m/s.

    Returns
    -------
    (T, C) float
        One pose per frame at :data:`~skin_node.builtin.channels.FPS` (120) frames
        per second, ``T = seconds * 120``, over ``skel.channel_names``.
    """
    T = int(round(seconds * FPS))
    frames = np.zeros((T, skel.n_channels))
    put = channel_setter(skel, frames)
    ph = 2.0 * np.pi * cadence * np.arange(T) / FPS
    legs = {"l_ankle": ("l_hip", "l_knee"), "r_ankle": ("r_hip", "r_knee"),
            "l_wrist": ("l_shoulder", "l_elbow"), "r_wrist": ("r_shoulder", "r_elbow")}
    for foot, (upper, middle) in legs.items():
        p = ph - 2.0 * np.pi * PHASES[foot]
        # Stance: the foot moves back (ry > 0); swing: forward, lifting it by
        # flexing the middle joint (knee or elbow) and the lower one back.
        put(f"{upper}_ry", swing * np.sin(p))
        lift = np.clip(-np.cos(p), 0.0, None) ** 2
        hind = foot.endswith("ankle")
        put(f"{middle}_ry", (0.5 if hind else -0.4) * lift)
        put(f"{foot}_ry", (-0.35 if hind else 0.5) * lift)
    put("spine_rz", 0.05 * np.sin(ph))
    put("neck_ry", 0.08 * np.sin(2.0 * ph))
    forward = skel.rest_rotations[0][:, 0]
    frames[:, :3] = np.outer(speed * np.arange(T) / FPS, forward)
    return frames
