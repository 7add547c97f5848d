"""One bag reader for rosbag2 (MCAP, SQLite3, zstd per file or per message) and
ROS 1 bags: the same messages, as CDR, whatever wrote them."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.writer import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import JointState

from skin_node.bag_tool import node_summary, read_joint_states
from skin_node.io.bags import BagReader

JS = "sensor_msgs/msg/JointState"
#: Every way a bag can come: (storage, compression) or "ros1".
KINDS = [("mcap", None), ("sqlite3", None), ("mcap", "file"), ("mcap", "message"),
         ("sqlite3", "file"), ("sqlite3", "message"), "ros1"]


def joint_states(n: int = 7) -> list[tuple[int, JointState]]:
    out = []
    for i in range(n):
        m = JointState()
        m.header.stamp.sec, m.header.stamp.nanosec = 1000 + i, 250_000 * i
        m.header.frame_id = "mocap"
        m.name = ["elbow_rz", "wrist_rx"]
        m.position = [0.1 * i, -0.2 * i]
        out.append((10**9 * (1000 + i) + 17, m))
    return out


def fields(m: JointState) -> tuple:
    return (m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id, list(m.name),
            list(m.position), list(m.velocity), list(m.effort))


def write_ros1_bag(path: Path, stream, topic: str = "/joint_states") -> Path:
    """A ROS 1 bag of (log time ns, rclpy JointState), written by rosbags; ``seq``
    counts up as a ROS 1 publisher's does."""
    ros1 = get_typestore(Stores.ROS1_NOETIC)
    T, H, J = (ros1.types[n] for n in ("builtin_interfaces/msg/Time", "std_msgs/msg/Header", JS))
    with Writer1(path) as w:
        conn = w.add_connection(topic, JS, typestore=ros1)
        for seq, (t, m) in enumerate(stream):
            stamp = T(sec=m.header.stamp.sec, nanosec=m.header.stamp.nanosec)
            msg = J(header=H(seq=seq, stamp=stamp, frame_id=m.header.frame_id),
                    name=list(m.name), position=np.array(m.position, float),
                    velocity=np.array(m.velocity, float), effort=np.array(m.effort, float))
            w.write(conn, t, ros1.serialize_ros1(msg, JS))
    return path


def write_any_bag(path: Path, kind, stream) -> Path:
    """A bag of ``stream`` of the given kind (see :data:`KINDS`); returns what to open."""
    if kind == "ros1":
        return write_ros1_bag(path.with_suffix(".bag"), stream)
    storage, compression = kind
    w = Writer(path, version=8, storage_plugin={"mcap": StoragePlugin.MCAP,
                                                "sqlite3": StoragePlugin.SQLITE3}[storage])
    if compression:
        w.set_compression({"file": CompressionMode.FILE, "message": CompressionMode.MESSAGE}
                          [compression], CompressionFormat.ZSTD)
    with w:
        conn = w.add_connection("/joint_states", JS, typestore=get_typestore(Stores.ROS2_JAZZY))
        other = w.add_connection("/chatter", "std_msgs/msg/String",
                                 typestore=get_typestore(Stores.ROS2_JAZZY))
        for t, msg in stream:
            w.write(conn, t, serialize_message(msg))
            w.write(other, t + 1, bytes([0, 1, 0, 0, 3, 0, 0, 0, 104, 105, 0, 0]))
    return path


@pytest.mark.parametrize("kind", KINDS, ids=lambda k: k if isinstance(k, str) else
                         "-".join(x for x in k if x))
def test_every_kind_of_bag_gives_the_same_joint_states(tmp_path, kind):
    stream = joint_states()
    bag = write_any_bag(tmp_path / "bag", kind, stream)
    got = read_joint_states(str(bag))
    assert [t for t, _ in got] == [t for t, _ in stream]
    # CDR out, whatever the bag's serialisation: the ROS 1 message lost only its seq.
    # (Compared field by field: rclpy leaves CDR's padding bytes uninitialised.)
    assert [fields(deserialize_message(raw, JointState)) for _, raw in got] == \
        [fields(m) for _, m in stream]
    msg = deserialize_message(got[3][1], JointState)
    assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (1003, 750_000)
    assert list(msg.position) == [pytest.approx(0.3), pytest.approx(-0.6)]
    with BagReader(bag) as reader:
        assert reader.ros1 == (kind == "ros1")
        assert ("/joint_states", JS) in reader.connections


def test_a_file_of_a_compressed_rosbag2_folder_opens_its_folder(tmp_path):
    stream = joint_states(3)
    bag = write_any_bag(tmp_path / "bag", ("mcap", "message"), stream)
    (file,) = [p for p in bag.iterdir() if p.suffix == ".mcap"]
    assert [fields(deserialize_message(raw, JointState))
            for _, raw in read_joint_states(str(file))] == [fields(m) for _, m in stream]


def test_bad_bags_say_what_they_are_and_hold(tmp_path):
    with pytest.raises(ValueError, match="no such bag"):
        read_joint_states(str(tmp_path / "missing"))
    junk = tmp_path / "junk.bag"
    junk.write_bytes(b"not a bag at all")
    with pytest.raises(ValueError, match=r"junk.bag: not a readable .*ROS 1 \.bag"):
        read_joint_states(str(junk))
    bag = write_any_bag(tmp_path / "b", ("mcap", None), joint_states(2))
    with pytest.raises(ValueError, match=r"no sensor_msgs/msg/JointState topic /mocap; "
                                         r"it holds \['/chatter \(std_msgs/msg/String\)', "
                                         r"'/joint_states \(sensor_msgs/msg/JointState\)'\]"):
        read_joint_states(str(bag), topic="/mocap")


def test_the_summary_says_why_poses_went_unanswered():
    before = {"frames_processed": "10", "frames_skipped_stale": "2", "rejected_no_known_names":
              "5", "unknown_names": "a"}
    after = {"frames_processed": "10", "frames_skipped_stale": "2",
             "rejected_no_known_names": "1603", "rejected_non_finite": "0",
             "unknown_names": "caster_wheel,fl_caster_rotation_joint,head_pan_joint,torso"}
    text = node_summary(before, after, 1598)
    assert text.startswith("the node answered 0 of 1598, skipped 0 as stale, rejected 1598 "
                           "of 1598 (no_known_names 1598); no name (caster_wheel, "
                           "fl_caster_rotation_joint, head_pan_joint, ...) is a channel"), text
    assert "-p name_map:=" in text
    ok = node_summary(None, {"frames_processed": "40", "frames_skipped_stale": "3"}, 43)
    assert ok == "the node answered 40 of 43, skipped 3 as stale, rejected 0 of 43"
    assert "never arrived" in node_summary(None, None, 5)
    back = node_summary(None, {"rejected_stamp_backwards": "4"}, 4)
    assert "(stamp_backwards 4)" in back and "--topic" in back
