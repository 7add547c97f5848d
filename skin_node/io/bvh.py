"""Biovision Hierarchy (BVH) motion files: parsing and forward kinematics.

A BVH file has a ``HIERARCHY`` section (a joint tree with ``OFFSET`` and
``CHANNELS`` per joint, ``End Site`` leaves) and a ``MOTION`` section
(``Frames:``, ``Frame Time:``, then one line of channel values per frame).

Conventions used here:

* Rotation channels are in degrees. The channels of a joint, listed left to
  right, compose as ``R = R_first @ R_second @ R_third`` (so for
  ``Zrotation Yrotation Xrotation``, ``R = Rz @ Ry @ Rx``).
* A joint's local transform is ``T(translation) @ R``; the translation is its
  ``OFFSET`` except for axes that have a position channel, where the channel
  value (an absolute translation in the parent frame) is used instead. This
  matches files whose root ``OFFSET`` is zero (CMU) and files whose root
  ``OFFSET`` repeats the first frame's position.
* Lengths (offsets, positions) are multiplied by ``scale`` when loaded or
  evaluated; raw frame values are kept unchanged in :attr:`Bvh.frames`.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

#: CMU BVH units (about 1/0.45 inch) to metres.
CMU_SCALE = (1.0 / 0.45) * 2.54 / 100.0

_CHANNELS = {
    "xposition": "Xposition", "yposition": "Yposition", "zposition": "Zposition",
    "xrotation": "Xrotation", "yrotation": "Yrotation", "zrotation": "Zrotation",
}
_AXIS = {"X": 0, "Y": 1, "Z": 2}


def axis_rotations(axis: int, angles: np.ndarray) -> np.ndarray:
    """Rotation matrices about one coordinate axis.

    Parameters
    ----------
    axis : int
        0, 1 or 2 for x, y, z.
    angles : (N,) float
        Angles in radians.

    Returns
    -------
    (N, 3, 3) float
    """
    a = np.asarray(angles, dtype=np.float64)
    c, s = np.cos(a), np.sin(a)
    R = np.zeros(a.shape + (3, 3))
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R[..., axis, axis] = 1.0
    R[..., i, i] = c
    R[..., j, j] = c
    R[..., i, j] = -s
    R[..., j, i] = s
    return R


@dataclass
class Bvh:
    """A parsed BVH file.

    Attributes
    ----------
    path : str
        Source file (for messages).
    names : list of str, (J,)
        Joint names in file order (parents before children).
    parents : (J,) int
        Parent index of each joint, -1 for the root.
    offsets : (J, 3) float
        ``OFFSET`` of each joint in its parent's frame, metres (file units
        times ``scale``).
    channels : list of tuple of str, (J,)
        Channel names of each joint in file order, canonical spelling
        (``Xposition`` ... ``Zrotation``); may be empty.
    channel_start : (J,) int
        Column of each joint's first channel in :attr:`frames`.
    frames : (T, C) float
        Raw channel values per frame, as in the file (degrees, file units).
    frame_time : float
        Seconds per frame.
    scale : float
        File length unit to metres.
    end_parents : (E,) int
        Joint index owning each ``End Site``.
    end_offsets : (E, 3) float
        ``End Site`` offsets in the owning joint's frame, metres.
    """

    path: str
    names: list
    parents: np.ndarray
    offsets: np.ndarray
    channels: list
    channel_start: np.ndarray
    frames: np.ndarray
    frame_time: float
    scale: float = 1.0
    end_parents: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    end_offsets: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))

    # ------------------------------------------------------------ basics
    @property
    def n_joints(self) -> int:
        return len(self.names)

    @property
    def n_frames(self) -> int:
        return int(self.frames.shape[0])

    @property
    def n_channels(self) -> int:
        return int(self.frames.shape[1])

    @property
    def fps(self) -> float:
        """Frames per second, ``1 / frame_time``."""
        return 1.0 / self.frame_time

    @property
    def channel_names(self) -> list:
        """``"<joint>_<channel>"`` for every column of :attr:`frames`."""
        return [f"{n}_{c}" for n, chs in zip(self.names, self.channels) for c in chs]

    def index(self, name: str) -> int:
        """Index of the joint called ``name`` (KeyError naming the file if absent)."""
        try:
            return self.names.index(name)
        except ValueError:
            raise KeyError(f"{self.path}: no joint named '{name}'; joints are {self.names}") from None

    def _columns(self, j: int, kind: str) -> list:
        """[(column, axis)] of joint j's channels of ``kind`` ("position"/"rotation"), in order."""
        s = int(self.channel_start[j])
        return [(s + k, _AXIS[c[0]]) for k, c in enumerate(self.channels[j]) if c.endswith(kind)]

    # -------------------------------------------------------- kinematics
    def local_rotations(self) -> np.ndarray:
        """Local rotation of every joint in every frame.

        Returns
        -------
        (T, J, 3, 3) float
            ``R = R_first @ R_second @ R_third`` over each joint's rotation
            channels in file order; identity for joints without any.
        """
        T, J = self.n_frames, self.n_joints
        R = np.tile(np.eye(3), (T, J, 1, 1))
        # Joints sharing a channel order are composed together, so the Python
        # loop runs over distinct orders (usually one), not joints or frames.
        groups: dict = {}
        for j in range(J):
            cols = self._columns(j, "rotation")
            if cols:
                key = tuple(a for _, a in cols)
                groups.setdefault(key, ([], []))
                groups[key][0].append(j)
                groups[key][1].append([c for c, _ in cols])
        for order, (joints, cols) in groups.items():
            ang = np.deg2rad(self.frames[:, np.asarray(cols)])  # (T, Jg, k)
            M = axis_rotations(order[0], ang[..., 0])
            for k in range(1, len(order)):
                M = M @ axis_rotations(order[k], ang[..., k])
            R[:, joints] = M
        return R

    def local_translations(self) -> np.ndarray:
        """(T, J, 3) translation of every joint in its parent's frame, metres."""
        t = np.broadcast_to(self.offsets, (self.n_frames, self.n_joints, 3)).copy()
        for j in range(self.n_joints):
            for col, axis in self._columns(j, "position"):
                t[:, j, axis] = self.frames[:, col] * self.scale
        return t

    def root_positions(self) -> np.ndarray:
        """(T, 3) root joint position in every frame, metres."""
        return self.local_translations()[:, 0].copy()

    def world_matrices(self) -> np.ndarray:
        """(T, J, 4, 4) world transform of every joint in every frame (metres)."""
        T, J = self.n_frames, self.n_joints
        L = np.zeros((T, J, 4, 4))
        L[..., :3, :3] = self.local_rotations()
        L[..., :3, 3] = self.local_translations()
        L[..., 3, 3] = 1.0
        G = np.empty_like(L)
        for j in range(J):  # vectorised over frames
            p = self.parents[j]
            G[:, j] = L[:, j] if p < 0 else G[:, p] @ L[:, j]
        return G

    def end_site_positions(self, G: np.ndarray | None = None) -> np.ndarray:
        """(T, E, 3) world position of every ``End Site``, metres.

        Parameters
        ----------
        G : (T, J, 4, 4) float, optional
            World matrices from :meth:`world_matrices` (computed if omitted).
        """
        if G is None:
            G = self.world_matrices()
        Ge = G[:, self.end_parents]
        return np.einsum("teij,ej->tei", Ge[..., :3, :3], self.end_offsets) + Ge[..., :3, 3]


# ------------------------------------------------------------------ parsing
def _fail(path: str, line: int | None, msg: str) -> ValueError:
    where = f"{path}" if line is None else f"{path}, line {line}"
    return ValueError(f"{where}: {msg}")


def parse_bvh(text: str, path: str = "<string>", scale: float = CMU_SCALE) -> Bvh:
    """Parse BVH text (see :func:`load_bvh`)."""
    lines = text.splitlines()  # \n, \r\n, \r and mixtures
    if not any(ln.strip() for ln in lines):
        raise _fail(path, None, "file is empty")
    motion_at = next((i for i, ln in enumerate(lines)
                      if ln.strip().upper() == "MOTION"), None)
    if motion_at is None:
        raise _fail(path, len(lines), "no MOTION section (the file ends inside or after the HIERARCHY)")

    # Header tokens with their 1-based line numbers.
    toks = [(t, i + 1) for i, ln in enumerate(lines[:motion_at]) for t in ln.split()]
    pos = 0

    def take(what: str):
        nonlocal pos
        if pos >= len(toks):
            last = toks[-1][1] if toks else motion_at + 1
            raise _fail(path, last, f"hierarchy ends early, expected {what}")
        t = toks[pos]
        pos += 1
        return t

    def number(what: str) -> float:
        t, ln = take(what)
        try:
            return float(t)
        except ValueError:
            raise _fail(path, ln, f"expected a number for {what}, got '{t}'") from None

    names, parents, offsets, channels = [], [], [], []
    end_parents, end_offsets = [], []

    def joint_body(j: int) -> None:
        t, ln = take("'{'")
        if t != "{":
            raise _fail(path, ln, f"expected '{{' after joint '{names[j]}', got '{t}'")
        while True:
            t, ln = take("'}'")
            key = t.upper()
            if key == "}":
                return
            if key == "OFFSET":
                offsets[j] = [number(f"OFFSET of '{names[j]}'") for _ in range(3)]
            elif key == "CHANNELS":
                t2, ln2 = take("a channel count")
                try:
                    n = int(t2)
                except ValueError:
                    raise _fail(path, ln2, f"expected a channel count for '{names[j]}', got '{t2}'") from None
                chs = []
                for _ in range(n):
                    c, lc = take(f"{n} channel names for '{names[j]}'")
                    if c.lower() not in _CHANNELS:
                        raise _fail(path, lc, f"unknown channel name '{c}' for joint '{names[j]}' "
                                    f"(expected one of {sorted(set(_CHANNELS.values()))})")
                    chs.append(_CHANNELS[c.lower()])
                if len(set(chs)) != len(chs):
                    raise _fail(path, ln, f"joint '{names[j]}' repeats a channel: {chs}")
                channels[j] = tuple(chs)
            elif key == "JOINT":
                new_joint(take("a joint name")[0], j)
            elif key == "END":
                if pos < len(toks) and toks[pos][0].upper() == "SITE":
                    pos_skip()
                end_site(j, ln)
            else:
                raise _fail(path, ln, f"unexpected '{t}' in joint '{names[j]}' "
                            "(expected OFFSET, CHANNELS, JOINT, End Site or '}')")

    def pos_skip() -> None:
        nonlocal pos
        pos += 1

    def end_site(j: int, ln: int) -> None:
        t, l2 = take("'{'")
        if t != "{":
            raise _fail(path, l2, f"expected '{{' after End Site of '{names[j]}', got '{t}'")
        off = [0.0, 0.0, 0.0]
        while True:
            t, l2 = take("'}'")
            if t == "}":
                break
            if t.upper() == "OFFSET":
                off = [number(f"End Site OFFSET of '{names[j]}'") for _ in range(3)]
            else:
                raise _fail(path, l2, f"unexpected '{t}' in End Site of '{names[j]}'")
        end_parents.append(j)
        end_offsets.append(off)

    def new_joint(name: str, parent: int) -> None:
        names.append(name)
        parents.append(parent)
        offsets.append([0.0, 0.0, 0.0])
        channels.append(())
        joint_body(len(names) - 1)

    t, ln = take("ROOT")
    if t.upper() == "HIERARCHY":
        t, ln = take("ROOT")
    if t.upper() != "ROOT":
        raise _fail(path, ln, f"expected ROOT, got '{t}'")
    new_joint(take("the root name")[0], -1)
    if pos < len(toks):
        t, ln = toks[pos]
        msg = ("more than one ROOT is not supported" if t.upper() == "ROOT"
               else f"unexpected '{t}' after the root joint's closing '}}'")
        raise _fail(path, ln, msg)
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise _fail(path, None, f"duplicate joint names {dup}")

    # MOTION: 'Frames:' and 'Frame Time:' then one line per frame.
    n_declared, frame_time = None, None
    i = motion_at + 1
    while i < len(lines) and (n_declared is None or frame_time is None):
        s = lines[i].strip()
        low = s.lower()
        if not s:
            pass
        elif low.startswith("frames:"):
            try:
                n_declared = int(s.split(":", 1)[1])
            except ValueError:
                raise _fail(path, i + 1, f"bad frame count '{s}'") from None
        elif low.startswith("frame time:"):
            try:
                frame_time = float(s.split(":", 1)[1])
            except ValueError:
                raise _fail(path, i + 1, f"bad frame time '{s}'") from None
            if not frame_time > 0.0:
                raise _fail(path, i + 1, f"frame time must be positive, got {frame_time}")
        else:
            missing = "Frames:" if n_declared is None else "Frame Time:"
            raise _fail(path, i + 1, f"expected '{missing}' line in MOTION, got '{s[:40]}'")
        i += 1
    if n_declared is None or frame_time is None:
        raise _fail(path, len(lines), "MOTION section lacks a 'Frames:' or 'Frame Time:' line")

    C = sum(len(c) for c in channels)
    rows = [(k + 1, ln.split()) for k, ln in enumerate(lines[i:], start=i) if ln.strip()]
    counts = np.fromiter((len(r) for _, r in rows), dtype=np.int64, count=len(rows))
    bad = np.flatnonzero(counts != C)
    if bad.size:
        ln, r = rows[bad[0]]
        raise _fail(path, ln, f"frame {bad[0] + 1} has {len(r)} values, expected {C} "
                    "(the number of channels in the hierarchy)")
    if len(rows) != n_declared:
        raise _fail(path, rows[-1][0] if rows else len(lines),
                    f"'Frames: {n_declared}' but {len(rows)} frame lines follow")
    try:
        frames = np.array([v for _, r in rows for v in r], dtype=np.float64).reshape(len(rows), C)
    except ValueError:
        for ln, r in rows:  # slow path only to name the offending line
            for v in r:
                try:
                    float(v)
                except ValueError:
                    raise _fail(path, ln, f"'{v}' is not a number") from None
        raise
    if not np.all(np.isfinite(frames)):
        k = int(np.flatnonzero(~np.all(np.isfinite(frames), axis=1))[0])
        raise _fail(path, rows[k][0], "frame contains NaN or Inf")

    starts = np.concatenate([[0], np.cumsum([len(c) for c in channels])[:-1]]).astype(np.int64)
    return Bvh(
        path=path,
        names=names,
        parents=np.asarray(parents, dtype=np.int64),
        offsets=np.asarray(offsets, dtype=np.float64) * scale,
        channels=channels,
        channel_start=starts,
        frames=frames,
        frame_time=frame_time,
        scale=float(scale),
        end_parents=np.asarray(end_parents, dtype=np.int64),
        end_offsets=np.asarray(end_offsets, dtype=np.float64).reshape(-1, 3) * scale,
    )


def load_bvh(path: str | Path, scale: float = CMU_SCALE) -> Bvh:
    """Read a BVH file.

    Parameters
    ----------
    path : str or Path
        The file. Line endings may be LF, CRLF, CR or mixed; tabs and blank
        lines are fine.
    scale : float
        File length unit to metres; the default suits CMU files (about
        1/0.45 inch). Use ``1.0`` for files already in metres.

    Returns
    -------
    Bvh

    Raises
    ------
    ValueError
        For a malformed file; the message names the file and, where known,
        the line.
    """
    path = Path(path)
    raw = path.read_bytes()
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = raw.decode("latin-1")  # joint names are ASCII in practice
    return parse_bvh(text, str(path), scale)
