"""Bags in, whatever recorded them: rosbag2 and ROS 1, through one reader.

:class:`BagReader` opens

* a **rosbag2** bag: its folder (``metadata.yaml`` plus MCAP or SQLite3
  files, compressed per file or per message with zstd or not), or one
  ``.mcap`` / ``.db3`` file of it (its folder is opened when it has the
  metadata, so compression is undone);
* a **ROS 1** bag: a ``.bag`` file, or several given together.

Reading is ``rosbags.highlevel.AnyReader``'s. Every message comes out as CDR,
the ROS 2 serialisation, so the rest of the tools see one format: a ROS 1
message is converted with the ROS 2 Jazzy message definitions (its header's
``seq`` is dropped; a type Jazzy does not define cannot be converted and says
so). Messages are read lazily, in log-time order across topics.
"""
from __future__ import annotations

from pathlib import Path
from typing import Iterator, Sequence

#: Message definitions CDR is written and read with.
_TYPESTORE = None


def typestore():
    """The ROS 2 Jazzy typestore (made once)."""
    global _TYPESTORE
    if _TYPESTORE is None:
        from rosbags.typesys import Stores, get_typestore   # deferred: only bags need rosbags
        _TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
    return _TYPESTORE


def _bag_paths(path: str | Path | Sequence) -> list[Path]:
    paths = [Path(p) for p in path] if isinstance(path, (list, tuple)) else [Path(path)]
    if not paths:
        raise ValueError("no bag given")
    out = []
    for p in paths:
        if not p.exists():
            raise ValueError(f"{p}: no such bag")
        if p.is_file() and p.suffix != ".bag" and (p.parent / "metadata.yaml").exists():
            p = p.parent          # a file of a rosbag2 folder: the folder knows its compression
        out.append(p)
    return out


class BagReader:
    """A rosbag2 or ROS 1 bag, opened for reading (a context manager).

    Parameters
    ----------
    path : str, Path or sequence of them
        A rosbag2 folder or one of its files, or ROS 1 ``.bag`` file(s).

    Raises
    ------
    ValueError
        ``"<path>: <problem>"`` for a missing path or a file that is not a bag.
    """

    def __init__(self, path) -> None:
        self.paths = _bag_paths(path)
        self.name = ", ".join(str(p) for p in self.paths)
        self._reader = None

    def __enter__(self) -> "BagReader":
        from rosbags.highlevel import AnyReader         # deferred: only bags need rosbags
        try:
            self._reader = AnyReader(self.paths, default_typestore=typestore())
            self._reader.open()
        except Exception as e:  # noqa: BLE001 - rosbags raises several types for a bad bag
            self._reader = None
            raise ValueError(f"{self.name}: not a readable rosbag2 folder, .mcap/.db3 file or "
                             f"ROS 1 .bag ({type(e).__name__}: {e})") from None
        return self

    def __exit__(self, *exc) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None

    @property
    def ros1(self) -> bool:
        """True for a ROS 1 bag (its messages are converted to CDR)."""
        return not self._reader.is2

    @property
    def connections(self) -> list[tuple[str, str]]:
        """(topic, message type) of every connection, ``"sensor_msgs/msg/JointState"`` style."""
        return [(c.topic, c.msgtype) for c in self._reader.connections]

    def describe(self) -> list[str]:
        """``"topic (type)"`` of every topic, sorted: what a bag holds, for error messages."""
        return sorted({f"{t} ({m})" for t, m in self.connections})

    def messages(self, msgtype: str | None = None,
                 topic: str | None = None) -> Iterator[tuple[str, int, bytes]]:
        """(topic, log time ns, CDR bytes) of the messages of one type and/or topic
        (leading slashes ignored), in log-time order."""
        want = None if topic is None else topic.lstrip("/")
        conns = [c for c in self._reader.connections
                 if (msgtype is None or c.msgtype == msgtype)
                 and (want is None or c.topic.lstrip("/") == want)]
        if not conns:
            return
        ts = typestore()
        for conn, t, raw in self._reader.messages(connections=conns):
            if self._reader.is2:
                yield conn.topic, int(t), bytes(raw)
                continue
            try:
                cdr = ts.ros1_to_cdr(raw, conn.msgtype)
            except Exception as e:  # noqa: BLE001 - an unknown type or a definition mismatch
                raise ValueError(f"{self.name}: a ROS 1 {conn.msgtype} message on {conn.topic} "
                                 f"cannot be converted to ROS 2 ({type(e).__name__}: {e})") \
                    from None
            yield conn.topic, int(t), bytes(cdr)

    @staticmethod
    def deserialize(cdr: bytes, msgtype: str):
        """A CDR message as a ``rosbags`` message object (no rclpy needed)."""
        return typestore().deserialize_cdr(cdr, msgtype)
