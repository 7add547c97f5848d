"""skin_bag: replay a bag of joint states into skin_node and record what it says.

Reads a bag (rosbag2: MCAP or SQLite3, compressed or not; or a ROS 1
``.bag``; :mod:`skin_node.io.bags`), publishes its ``sensor_msgs/msg/JointState``
messages on ``joint_states`` at the recorded rate (their header stamps
untouched), and records the node's outputs into a new rosbag2 bag. Messages
pass through as serialized CDR in both directions (a ROS 1 message is
converted once, on reading), so the tool neither parses nor re-encodes them::

    skin_bag in_bag out_bag --storage mcap --record skin/points skin/diagnostics

At the recorded rate the node, like on live mocap, skips a pose that a newer
one overtook while it was busy. ``--lockstep SECONDS`` instead sends each joint
state once the node has answered the one before on ``skin/points`` (a cloud
with that stamp or a later one), or after SECONDS without an answer (a message
the node rejects is never answered): every pose is deformed however slow the
machine, which is what reprocessing a bag for measurement wants.

The summary line says what the node made of the poses, from its
``skin/diagnostics`` (the counters' change over the replay): how many it
received, answered, skipped as stale and rejected, by reason, with a hint for
the usual cause (names that are no channel of the character: a name map).

SIGINT or SIGTERM stops it with status 1, after writing what was recorded so
far into a valid bag.
"""
from __future__ import annotations

import argparse
import contextlib
import importlib
import queue
import signal
import sys
import threading
import time

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import JointState

from msg_adapters import Reason, diagnostic_values, header_stamp_ns
from skin_node.io.bags import BagReader
from skin_node.node import QOS_JOINT_STATES
from skin_node.processes import SpinThread

JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
POINTS_TOPIC = "skin/points"
DIAGNOSTICS_TOPIC = "skin/diagnostics"
#: Seconds to wait for the node's first diagnostics (1 Hz), the counters' baseline.
BASELINE_WAIT = 1.5
#: Message type of each topic the node publishes; other topics need "topic=pkg/msg/Type".
KNOWN_TOPICS = {
    "skin/points": "sensor_msgs/msg/PointCloud2",
    "skin/diagnostics": "diagnostic_msgs/msg/DiagnosticArray",
    "skin/mesh": "shape_msgs/msg/Mesh",
    "skin/marker": "visualization_msgs/msg/Marker",
}
# Deep enough that a recording never drops a frame the node sent.
QOS_RECORD = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)


def _message_class(type_name: str):
    """``"sensor_msgs/msg/PointCloud2"`` -> the rclpy message class."""
    pkg, sub, name = type_name.split("/")
    return getattr(importlib.import_module(f"{pkg}.{sub}"), name)


def read_joint_states(path: str, topic: str | None = None) -> list[tuple[int, bytes]]:
    """(log time ns, CDR bytes) of every JointState in a rosbag2 or ROS 1 bag,
    in log-time order.

    Raises
    ------
    ValueError
        When the path is no bag, or the bag holds no JointState message (on
        ``topic``, if given).
    """
    with BagReader(path) as reader:
        messages = [(t, raw) for _, t, raw in reader.messages(JOINT_STATE_TYPE, topic)]
        if not messages:
            has_topic = any(m == JOINT_STATE_TYPE and (topic is None or
                                                       t.lstrip("/") == topic.lstrip("/"))
                            for t, m in reader.connections)
            if has_topic:
                raise ValueError(f"{path}: no JointState messages")
            raise ValueError(f"{path}: no {JOINT_STATE_TYPE} topic"
                             f"{' ' + topic if topic else ''}; it holds {reader.describe()}")
    return messages


def node_summary(before: dict | None, after: dict | None, sent: int) -> str:
    """What the node made of the ``sent`` poses, from its diagnostics values
    before and after the replay (:func:`msg_adapters.diagnostic_values`), e.g.
    ``"the node answered 0 of 100, skipped 0 as stale, rejected 100 of 100
    (no_known_names 100); no name (a, b, ...) is a channel of the character:
    pass -p name_map:=MAP.yaml to skin_node (incoming: channel)"``.

    ``before`` None means the node had counted nothing yet.
    """
    if after is None:
        return "the node's diagnostics never arrived: rejections unknown"

    def delta(key: str) -> int:
        try:
            return int(after.get(key, 0)) - (int(before.get(key, 0)) if before else 0)
        except ValueError:
            return 0

    answered, stale = delta("frames_processed"), delta("frames_skipped_stale")
    rejected = {r.value: delta(f"rejected_{r.value}") for r in Reason}
    rejected = {k: n for k, n in rejected.items() if n > 0}
    n_rej = sum(rejected.values())
    text = (f"the node answered {answered} of {sent}, skipped {stale} as stale, "
            f"rejected {n_rej} of {sent}")
    if rejected:
        text += " (" + ", ".join(f"{k} {n}" for k, n in rejected.items()) + ")"
    hints = []
    if "no_known_names" in rejected:
        unknown = [n for n in str(after.get("unknown_names", "")).split(",") if n]
        shown = ", ".join(unknown[:3]) + (", ..." if len(unknown) > 3 else "")
        hints.append(f"no name ({shown}) is a channel of the character: pass "
                     "-p name_map:=MAP.yaml to skin_node (incoming: channel)")
    jumps = delta("time_jumps_back")
    if jumps > 0:
        text += (f"; time jumped back {jumps} time{'s' if jumps > 1 else ''} "
                 "(a replay or restart: skinned on)")
    if "stamp_backwards" in rejected:
        hints.append("header stamps step back by less than the node's time_jump_tolerance "
                     "(interleaved sources?): play one topic (--topic)")
    return text + ("; " + "; ".join(hints) if hints else "")


class BagRecorder(Node):
    """Publishes raw joint states; queues raw recordings for the writer.

    Only the main thread touches the bag (an SQLite connection belongs to
    the thread that opened it), so callbacks just queue what they receive.
    """

    def __init__(self, writer: Writer, topics: dict[str, str]) -> None:
        super().__init__("skin_bag")
        typestore = get_typestore(Stores.ROS2_JAZZY)
        self.counts = {t: 0 for t in topics}
        self._writer, self._queue = writer, queue.SimpleQueue()
        #: Newest stamp (ns) seen on skin/points: what the node has answered.
        self.answered_ns = None
        self.answered = threading.Condition()
        #: The node's diagnostics values: before playback (the baseline; None when
        #: none came in time: a fresh node) and the newest.
        self.diagnostics_before = self.diagnostics_last = None
        self._matched_at, self._playing = None, False
        self.pub = self.create_publisher(JointState, "joint_states", QOS_JOINT_STATES)
        self.subs = []
        if not any(t.lstrip("/") == DIAGNOSTICS_TOPIC for t in topics):
            # Not recorded, but read: the summary says why poses went unanswered.
            self.subs.append(self.create_subscription(
                DiagnosticArray, DIAGNOSTICS_TOPIC, self._diagnostics, QOS_RECORD))
        for topic, type_name in topics.items():
            conn = writer.add_connection("/" + topic.lstrip("/"), type_name, typestore=typestore)
            self.subs.append(self.create_subscription(
                _message_class(type_name), topic,
                lambda raw, t=topic, c=conn: self._received(t, c, raw),
                QOS_RECORD, raw=True))

    def _diagnostics(self, msg) -> None:
        try:
            values = diagnostic_values(msg)
        except KeyError:                # an empty array: nothing to count
            return
        if not self._playing:
            self.diagnostics_before = values
        self.diagnostics_last = values

    def _received(self, topic: str, conn, raw: bytes) -> None:
        self._queue.put((topic, conn, self.get_clock().now().nanoseconds, raw))
        if topic.lstrip("/") == DIAGNOSTICS_TOPIC:
            self._diagnostics(deserialize_message(raw, DiagnosticArray))
        if topic.lstrip("/") == POINTS_TOPIC:
            try:
                stamp = header_stamp_ns(raw)
            except ValueError:          # recorded as it came; answers nothing
                return
            with self.answered:
                if self.answered_ns is None or stamp > self.answered_ns:
                    self.answered_ns = stamp
                self.answered.notify_all()

    def write_pending(self) -> None:
        """Write everything received so far (main thread only)."""
        while not self._queue.empty():
            topic, conn, t, raw = self._queue.get()
            self._writer.write(conn, t, raw)
            self.counts[topic] += 1

    def matched(self) -> bool:
        """True once the node listens to us, we listen to each of its topics, and its
        first diagnostics came (the counters' baseline; at most
        :data:`BASELINE_WAIT` s after matching)."""
        if not (self.pub.get_subscription_count() > 0
                and all(s.get_publisher_count() > 0 for s in self.subs)):
            return False
        if self._matched_at is None:
            self._matched_at = time.monotonic()
        self._playing = (self.diagnostics_before is not None
                         or time.monotonic() - self._matched_at > BASELINE_WAIT)
        return self._playing


class Interrupted(Exception):
    """SIGINT or SIGTERM arrived."""


_SIGNALLED = threading.Event()


def _on_signal(signum, frame) -> None:
    _SIGNALLED.set()


def _check() -> None:
    """Raise :class:`Interrupted` once SIGINT or SIGTERM arrived.

    The signal only sets a flag, which the main thread polls between its short
    waits: neither an exception nor a context shut down under it can land in
    the middle of making the node or of joining the spin thread.
    """
    if _SIGNALLED.is_set():
        raise Interrupted


def _send_and_wait(node: BagRecorder, raw: bytes, seconds: float) -> bool:
    """Publish one joint state and wait up to ``seconds`` for a cloud with its
    stamp or a later one, writing what arrives meanwhile. True when it came."""
    node.pub.publish(raw)
    try:
        stamp_ns = header_stamp_ns(raw)
    except ValueError:                  # no stamp: nothing to wait for
        return False
    end = time.monotonic() + seconds
    while True:
        node.write_pending()
        _check()
        with node.answered:
            if node.answered_ns is not None and node.answered_ns >= stamp_ns:
                return True
            left = end - time.monotonic()
            if left <= 0:
                return False
            node.answered.wait(min(left, 0.02))


def _sleep_writing(node: BagRecorder, seconds: float) -> None:
    """Sleep ``seconds`` while writing what arrives."""
    end = time.monotonic() + seconds
    while True:
        node.write_pending()
        _check()
        left = end - time.monotonic()
        if left <= 0:
            return
        time.sleep(min(left, 0.02))


def _wait_for_node(node: BagRecorder, seconds: float) -> bool:
    """Wait up to ``seconds`` until the node and we are matched both ways."""
    deadline = time.monotonic() + seconds
    while not node.matched():
        _check()
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    # Matching is not symmetric in time: give the node's reader a moment to
    # match our writer too, or the first messages can be lost.
    _sleep_writing(node, 0.5)
    return True


def _play(node: BagRecorder, messages: list[tuple[int, bytes]],
          args: argparse.Namespace) -> tuple[float, int]:
    """Publish ``messages`` at the recorded rate or in lockstep; returns
    (seconds played, messages left unanswered in lockstep)."""
    t0, start, unanswered = messages[0][0], time.monotonic(), 0
    for i, (t, raw) in enumerate(messages):
        if not args.lockstep:
            _sleep_writing(node, start + (t - t0) * 1e-9 / args.rate - time.monotonic())
            node.pub.publish(raw)
            continue
        unanswered += not _send_and_wait(node, raw, args.lockstep)
        if (i + 1) % 500 == 0:
            print(f"skin_bag: {i + 1}/{len(messages)} sent, {unanswered} unanswered",
                  flush=True)
    return time.monotonic() - start, unanswered


def _record(node: BagRecorder, executor, messages: list[tuple[int, bytes]],
            args: argparse.Namespace) -> tuple[str, float, int]:
    """Spin ``executor`` while ``node`` plays ``messages`` and records.

    Returns (outcome, seconds played, unanswered in lockstep); outcome is
    "played", "no node" or "interrupted". An interrupted recording ends like a
    finished one: whatever arrived is written, and the caller closes a valid bag.
    """
    outcome, played_s, unanswered = "interrupted", 0.0, 0
    try:
        with SpinThread(executor, "skin_bag_spin"):
            if _wait_for_node(node, args.wait):
                played_s, unanswered = _play(node, messages, args)
                _sleep_writing(node, args.linger)
                outcome = "played"
            else:
                outcome = "no node"
    except Interrupted:
        pass
    finally:
        node.write_pending()            # the spin has stopped: nothing more comes in
    return outcome, played_s, unanswered


def _parse(argv: list[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="skin_bag", description=__doc__.splitlines()[0])
    ap.add_argument("in_bag", help="bag of JointState: rosbag2 folder (or its .mcap/.db3 "
                    "file), or ROS 1 .bag")
    ap.add_argument("out_bag", help="new bag folder to record into (must not exist)")
    ap.add_argument("--topic", help="JointState topic to play (default: every JointState topic)")
    ap.add_argument("--record", nargs="+", default=["skin/points", "skin/diagnostics"],
                    metavar="TOPIC[=TYPE]", help="topics to record (default: %(default)s)")
    ap.add_argument("--storage", choices=["mcap", "sqlite3"], default="mcap")
    ap.add_argument("--rate", type=float, default=1.0, help="playback speed factor")
    ap.add_argument("--limit", type=int, default=0, help="play only the first N messages")
    ap.add_argument("--lockstep", type=float, default=0.0, metavar="SECONDS",
                    help="send each message once skin/points answered the one before, "
                         "or after SECONDS without an answer (0: the recorded rate)")
    ap.add_argument("--wait", type=float, default=30.0,
                    help="seconds to wait for skin_node to appear")
    ap.add_argument("--linger", type=float, default=2.5,
                    help="seconds to keep recording after the last message (>1 catches "
                         "the final 1 Hz diagnostics)")
    args = ap.parse_args(argv)
    if args.rate <= 0:
        ap.error("--rate must be > 0")
    if args.lockstep < 0:
        ap.error("--lockstep must be >= 0")
    if args.lockstep and POINTS_TOPIC not in [t.partition("=")[0].lstrip("/")
                                              for t in args.record]:
        ap.error(f"--lockstep waits for {POINTS_TOPIC}: record it")
    return args


def main(argv: list[str] | None = None) -> int:
    """Console script ``skin_bag``; exit 0 when played and recorded, 1 otherwise."""
    args_ros = sys.argv if argv is None else ["skin_bag", *argv]
    args = _parse(rclpy.utilities.remove_ros_args(args_ros)[1:])
    topics = {}
    for spec in args.record:
        topic, _, type_name = spec.partition("=")
        if not type_name and topic.lstrip("/") not in KNOWN_TOPICS:
            print(f"skin_bag: error: give the type of {topic} as {topic}=pkg/msg/Type",
                  file=sys.stderr)
            return 1
        topics[topic] = type_name or KNOWN_TOPICS[topic.lstrip("/")]
    try:
        messages = read_joint_states(args.in_bag, args.topic)[:args.limit or None]
    except Exception as e:  # noqa: BLE001 - rosbags raises several types for a bad bag
        print(f"skin_bag: error: {e}", file=sys.stderr)
        return 1
    storage = StoragePlugin.MCAP if args.storage == "mcap" else StoragePlugin.SQLITE3
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _on_signal)
    rclpy.init(args=args_ros, signal_handler_options=SignalHandlerOptions.NO)
    with contextlib.ExitStack() as done:        # unwinds in reverse: node, bag, context
        done.callback(rclpy.try_shutdown)
        try:
            writer = done.enter_context(Writer(args.out_bag, version=8, storage_plugin=storage))
        except WriterError as e:
            print(f"skin_bag: error: {e}", file=sys.stderr)
            return 1
        node = BagRecorder(writer, topics)
        done.callback(node.destroy_node)
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        outcome, played_s, unanswered = _record(node, executor, messages, args)
        counts = dict(node.counts)
    if outcome == "no node":
        print(f"skin_bag: error: no skin_node on joint_states/{list(topics)} "
              f"after {args.wait:.0f} s", file=sys.stderr)
        return 1
    if outcome == "interrupted":
        print("skin_bag: interrupted; the bag holds what was recorded so far", file=sys.stderr)
        return 1
    lockstep = (f" in lockstep ({unanswered} unanswered within {args.lockstep:g} s)"
                if args.lockstep else "")
    print(f"skin_bag: played {len(messages)} joint states in {played_s:.2f} s{lockstep}; "
          "recorded " + ", ".join(f"{t} {n}" for t, n in counts.items())
          + f" into {args.out_bag}; "
          + node_summary(node.diagnostics_before, node.diagnostics_last, len(messages)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
