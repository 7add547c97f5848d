"""sensor_msgs/JointState <-> numpy channel vectors.

The node accepts a JointState only when it can be trusted as a whole: every
check below rejects the message with a :class:`Reason` rather than repairing
it, so a bad frame is answered by nothing and counted.
"""
from __future__ import annotations

import array
import enum
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np
import yaml
from sensor_msgs.msg import JointState

#: Largest accepted |position|. Radians and metres both stay far below this;
#: larger values are unit mix-ups (degrees, millimetres) or garbage.
MAX_ABS_POSITION = 1000.0

#: Default of :class:`StampOrder`'s tolerance (the node's ``time_jump_tolerance``):
#: a stamp this much or less older than the last accepted one is a reordering
#: (two publishers, a late packet) and rejected; one older by more is a restart of
#: the source. Reorderings are milliseconds; a restart goes back by a bag's or a
#: clip's length, or to a simulator's zero.
TIME_JUMP_TOLERANCE_S = 0.5


class Reason(str, enum.Enum):
    """Why a JointState was rejected; the value is the diagnostics key."""

    EMPTY = "empty"
    LENGTH_MISMATCH = "length_mismatch"
    NON_FINITE = "non_finite"
    OUT_OF_RANGE = "out_of_range"
    DUPLICATE_NAMES = "duplicate_names"
    NO_KNOWN_NAMES = "no_known_names"
    STAMP_BACKWARDS = "stamp_backwards"


class JointStateError(ValueError):
    """A rejected JointState; ``reason`` says which check failed."""

    def __init__(self, reason: Reason, detail: str) -> None:
        super().__init__(f"{reason.value}: {detail}")
        self.reason = reason


def joint_state_to_arrays(msg: JointState,
                          max_abs: float = MAX_ABS_POSITION) -> tuple[list[str], np.ndarray]:
    """Names and positions of a JointState, validated.

    Parameters
    ----------
    msg : sensor_msgs.msg.JointState
    max_abs : float
        Largest accepted absolute position (radians or metres).

    Returns
    -------
    names : list of str, (k,)
    positions : (k,) float64

    Raises
    ------
    JointStateError
        With ``reason`` EMPTY, LENGTH_MISMATCH, DUPLICATE_NAMES, NON_FINITE or
        OUT_OF_RANGE.
    """
    names = list(msg.name)
    positions = np.asarray(msg.position, dtype=np.float64)
    if not names:
        raise JointStateError(Reason.EMPTY, "message has no joint names")
    if positions.shape != (len(names),):
        raise JointStateError(Reason.LENGTH_MISMATCH,
                              f"{len(names)} names but {positions.size} positions")
    if len(set(names)) != len(names):
        seen, dup = set(), set()
        for n in names:
            (dup if n in seen else seen).add(n)
        raise JointStateError(Reason.DUPLICATE_NAMES, f"repeated names {sorted(dup)}")
    finite = np.isfinite(positions)
    if not finite.all():
        raise JointStateError(Reason.NON_FINITE,
                              f"NaN/Inf position for {names[int(np.argmin(finite))]}")
    too_big = np.abs(positions) > max_abs
    if too_big.any():
        i = int(np.argmax(too_big))
        raise JointStateError(Reason.OUT_OF_RANGE,
                              f"|{names[i]}| = {abs(positions[i]):g} > {max_abs:g}")
    return names, positions


class StampOrder:
    """Header stamps of one JointState stream, in order, with restarts.

    Like robot_state_publisher, which takes a jump back in time for a restart
    of its source, a stamp older than the last accepted one by more than
    ``tolerance_s`` restarts the stream's time there: a looped or replayed
    bag, a restarted mocap source, a simulator resetting its clock. A smaller
    step back is a reordering and rejected (STAMP_BACKWARDS), as ever.

    :meth:`check` a stamp before the rest of the message, and :meth:`accept`
    it once the whole message was accepted, so a message rejected for another
    reason neither moves time nor counts as a restart.

    Parameters
    ----------
    tolerance_s : float
        Seconds, >= 0 (0: every step back is a restart).
    """

    def __init__(self, tolerance_s: float = TIME_JUMP_TOLERANCE_S) -> None:
        self.tolerance_s = tolerance_s
        self.last_ns: int | None = None     # newest accepted stamp
        self.jumps_back = 0                 # restarts accepted so far

    @property
    def tolerance_s(self) -> float:
        return self._tolerance_ns * 1e-9

    @tolerance_s.setter
    def tolerance_s(self, seconds: float) -> None:
        if not seconds >= 0.0:
            raise ValueError(f"time jump tolerance must be >= 0 s, got {seconds}")
        self._tolerance_ns = round(seconds * 1e9)

    def check(self, stamp_ns: int) -> bool:
        """True when ``stamp_ns`` would restart time, False when it is in order.

        Raises
        ------
        JointStateError
            STAMP_BACKWARDS when it is older than the last accepted stamp by
            the tolerance or less.
        """
        if self.last_ns is None or stamp_ns >= self.last_ns:
            return False
        if self.last_ns - stamp_ns > self._tolerance_ns:
            return True
        raise JointStateError(
            Reason.STAMP_BACKWARDS,
            f"stamp {stamp_ns} ns < previous {self.last_ns} ns, by "
            f"{(self.last_ns - stamp_ns) * 1e-6:.1f} ms: within the "
            f"{self.tolerance_s * 1e3:g} ms of a reordering")

    def accept(self, stamp_ns: int, restart: bool) -> None:
        """Make ``stamp_ns`` (checked: ``restart`` is what :meth:`check` said) the newest."""
        self.jumps_back += restart
        self.last_ns = stamp_ns


def load_name_map(path: str | Path) -> dict[str, str]:
    """Read a name map (incoming joint name -> character channel name) from YAML.

    The file holds either the mapping itself or a mapping under the key
    ``name_map``.

    Raises
    ------
    ValueError
        ``"<path>: <what is wrong>"`` when the file is unreadable or malformed.
    """
    try:
        data = yaml.safe_load(Path(path).read_text())
    except OSError as e:
        raise ValueError(f"{path}: cannot read name map ({e.strerror})") from None
    except yaml.YAMLError as e:
        raise ValueError(f"{path}: not valid YAML ({str(e).splitlines()[0]})") from None
    if isinstance(data, dict) and isinstance(data.get("name_map"), dict):
        data = data["name_map"]
    if not isinstance(data, dict) or not data:
        raise ValueError(f"{path}: expected a non-empty mapping 'incoming_name: channel_name'")
    bad = [k for k, v in data.items() if not isinstance(k, str) or not isinstance(v, str)]
    if bad:
        raise ValueError(f"{path}: names must be strings, not {bad[:3]}")
    return dict(data)


@dataclass(frozen=True)
class _Layout:
    """How one ordered tuple of incoming names lands on the channel vector."""

    src: np.ndarray        # positions in the message that map to a channel
    dst: np.ndarray        # the channel each of those lands on
    unknown: tuple         # incoming names that map to no channel


class ChannelMapper:
    """Maps JointState names onto a character's channel vector.

    Channels absent from a message keep their last value (rest pose, zero, at
    first), so several publishers may each send a subset. The layout of each
    distinct name list is computed once and cached: per message the work is one
    fancy-indexed assignment.

    Parameters
    ----------
    channel_names : sequence of str
        The character's channels, in pose-vector order.
    name_map : mapping, optional
        Incoming name -> channel name, for sources with their own vocabulary.
        Names not in the map are looked up as channel names directly.
    """

    def __init__(self, channel_names: Sequence[str],
                 name_map: Mapping[str, str] | None = None) -> None:
        self.channel_names = list(channel_names)
        self._channel_index = {n: i for i, n in enumerate(self.channel_names)}
        self.name_map = dict(name_map or {})
        wrong = sorted(v for v in self.name_map.values() if v not in self._channel_index)
        if wrong:
            raise ValueError(f"name map targets unknown channels {wrong[:5]}; "
                             f"channels are {self.channel_names[:6]}...")
        self.q = np.zeros(len(self.channel_names))
        self._layouts: dict[tuple, _Layout] = {}
        self._unknown_messages: dict[tuple, int] = {}

    def _layout(self, key: tuple) -> _Layout:
        layout = self._layouts.get(key)
        if layout is None:
            idx = np.array([self._channel_index.get(self.name_map.get(n, n), -1) for n in key],
                           dtype=np.int64)
            known = idx >= 0
            dst = idx[known]
            if np.unique(dst).size != dst.size:
                raise JointStateError(Reason.DUPLICATE_NAMES,
                                      "several names map onto the same channel")
            layout = _Layout(np.flatnonzero(known), dst,
                             tuple(n for n, k in zip(key, known) if not k))
            self._layouts[key] = layout
        return layout

    def apply(self, names: Sequence[str], positions: np.ndarray) -> np.ndarray:
        """Write a validated message into the channel vector and return it.

        Returns
        -------
        q : (C,) float64
            The mapper's own vector (copy it to keep it).

        Raises
        ------
        JointStateError
            NO_KNOWN_NAMES when no name maps onto a channel (nothing changes),
            DUPLICATE_NAMES when two names map onto one channel.
        """
        key = tuple(names)
        layout = self._layout(key)
        if layout.unknown:
            self._unknown_messages[layout.unknown] = \
                self._unknown_messages.get(layout.unknown, 0) + 1
        if layout.dst.size == 0:
            raise JointStateError(Reason.NO_KNOWN_NAMES,
                                  f"none of {len(key)} names is a channel, e.g. {key[0]!r}")
        self.q[layout.dst] = positions[layout.src]
        return self.q

    @property
    def unknown_counts(self) -> dict[str, int]:
        """Unknown incoming name -> number of messages that carried it."""
        counts: dict[str, int] = {}
        for unknown, n in self._unknown_messages.items():
            for name in unknown:
                counts[name] = counts.get(name, 0) + n
        return counts


def channels_to_joint_state(names: Sequence[str], q: np.ndarray,
                            stamp=None) -> JointState:
    """A JointState carrying the channel vector ``q`` under ``names``.

    Parameters
    ----------
    names : sequence of str, (C,)
    q : (C,) float
        Positions, radians or metres.
    stamp : builtin_interfaces.msg.Time, optional
    """
    q = np.asarray(q, dtype=np.float64)
    if q.shape != (len(names),):
        raise ValueError(f"{len(names)} names but q has shape {q.shape}")
    msg = JointState()
    if stamp is not None:
        msg.header.stamp = stamp
    msg.name = list(names)
    msg.position = array.array("d", q.tobytes())
    return msg
