"""Message adapters: round trips, layouts, and every reason a JointState is rejected."""
import array

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState, PointCloud2, PointField
from std_msgs.msg import Header
from visualization_msgs.msg import Marker

from msg_adapters import (ChannelMapper, JointStateError, Reason, channels_to_joint_state,
                          diagnostic_array, diagnostic_values, header_stamp_ns,
                          joint_state_to_arrays,
                          load_name_map, mesh_to_msg, msg_to_mesh, point_cloud2_to_vertices,
                          triangle_list_marker, triangle_list_marker_cdr,
                          vertices_to_point_cloud2)

CHANNELS = ["root_tx", "root_ty", "root_tz", "a_rx", "a_ry", "a_rz", "b_rx", "b_ry", "b_rz"]


def js(names, positions):
    msg = JointState()
    msg.name = list(names)
    msg.position = [float(p) for p in positions]
    return msg


def header(sec=12, nanosec=345, frame="world"):
    h = Header(frame_id=frame)
    h.stamp.sec, h.stamp.nanosec = sec, nanosec
    return h


@pytest.fixture
def mesh():
    rng = np.random.default_rng(0)
    V = rng.normal(size=(500, 3))
    F = rng.integers(0, 500, size=(900, 3))
    return V, F


# ---------------------------------------------------------------- JointState in
def test_valid_joint_state_round_trip():
    q = np.linspace(-1, 1, len(CHANNELS))
    msg = channels_to_joint_state(CHANNELS, q, header(3, 4).stamp)
    names, pos = joint_state_to_arrays(msg)
    assert names == CHANNELS
    np.testing.assert_array_equal(pos, q)
    assert msg.header.stamp.sec == 3 and msg.header.stamp.nanosec == 4


@pytest.mark.parametrize("names, positions, reason", [
    ([], [], Reason.EMPTY),
    (["a_rx", "a_ry"], [0.1], Reason.LENGTH_MISMATCH),
    (["a_rx"], [], Reason.LENGTH_MISMATCH),
    (["a_rx", "a_rx"], [0.1, 0.2], Reason.DUPLICATE_NAMES),
    (["a_rx", "a_ry"], [0.1, float("nan")], Reason.NON_FINITE),
    (["a_rx", "a_ry"], [float("-inf"), 0.0], Reason.NON_FINITE),
    (["a_rx", "a_ry"], [0.1, 1000.5], Reason.OUT_OF_RANGE),
    (["a_rx"], [-1e9], Reason.OUT_OF_RANGE),
])
def test_bad_joint_state_rejected_with_reason(names, positions, reason):
    with pytest.raises(JointStateError) as e:
        joint_state_to_arrays(js(names, positions))
    assert e.value.reason is reason
    assert str(e.value).startswith(reason.value)


def test_limit_is_inclusive():
    _, pos = joint_state_to_arrays(js(["a_rx"], [1000.0]))
    assert pos[0] == 1000.0


# ---------------------------------------------------------------- mapping
def test_mapper_keeps_last_values_for_absent_names():
    m = ChannelMapper(CHANNELS)
    q = m.apply(["a_rx", "b_rz"], np.array([0.5, -0.25])).copy()
    assert q[CHANNELS.index("a_rx")] == 0.5 and q[CHANNELS.index("b_rz")] == -0.25
    q = m.apply(["b_ry"], np.array([0.75]))
    assert q[CHANNELS.index("a_rx")] == 0.5            # kept from the first message
    assert q[CHANNELS.index("b_ry")] == 0.75
    assert np.count_nonzero(q) == 3


def test_mapper_counts_unknown_names_per_message():
    m = ChannelMapper(CHANNELS)
    for _ in range(3):
        m.apply(["a_rx", "wheel", "gripper"], np.array([0.1, 2.0, 3.0]))
    m.apply(["gripper", "b_rx"], np.array([1.0, 0.2]))
    assert m.unknown_counts == {"wheel": 3, "gripper": 4}
    assert m.q[CHANNELS.index("a_rx")] == pytest.approx(0.1)


def test_mapper_rejects_messages_with_no_known_name_and_keeps_state():
    m = ChannelMapper(CHANNELS)
    m.apply(["a_rx"], np.array([0.3]))
    with pytest.raises(JointStateError) as e:
        m.apply(["x", "y"], np.array([1.0, 2.0]))
    assert e.value.reason is Reason.NO_KNOWN_NAMES
    assert m.q[CHANNELS.index("a_rx")] == pytest.approx(0.3)
    assert m.unknown_counts == {"x": 1, "y": 1}


def test_name_map_translates_and_rejects_collisions(tmp_path):
    path = tmp_path / "map.yaml"
    path.write_text("name_map:\n  r_elbow_flex_joint: b_ry\n  elbow_alias: b_ry\n")
    m = ChannelMapper(CHANNELS, load_name_map(path))
    q = m.apply(["r_elbow_flex_joint", "a_rz"], np.array([-0.4, 0.2]))
    assert q[CHANNELS.index("b_ry")] == pytest.approx(-0.4)
    assert q[CHANNELS.index("a_rz")] == pytest.approx(0.2)
    with pytest.raises(JointStateError) as e:
        m.apply(["r_elbow_flex_joint", "elbow_alias"], np.array([0.1, 0.2]))
    assert e.value.reason is Reason.DUPLICATE_NAMES


def test_name_map_to_missing_channel_is_a_config_error():
    with pytest.raises(ValueError, match="unknown channels"):
        ChannelMapper(CHANNELS, {"foo": "no_such_channel"})


@pytest.mark.parametrize("text, problem", [
    ("[1, 2", "not valid YAML"),
    ("", "non-empty mapping"),
    ("- a\n- b\n", "non-empty mapping"),
    ("a: 3\n", "must be strings"),
])
def test_load_name_map_errors_name_the_file(tmp_path, text, problem):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ValueError) as e:
        load_name_map(path)
    assert str(e.value).startswith(str(path)) and problem in str(e.value)
    with pytest.raises(ValueError, match="cannot read"):
        load_name_map(tmp_path / "missing.yaml")


def test_example_name_map_targets_arm_like_channels():
    from pathlib import Path
    path = Path(__file__).resolve().parents[1] / "config" / "name_map_example.yaml"
    nm = load_name_map(path)
    assert "r_shoulder_pan_joint" in nm


# ---------------------------------------------------------------- PointCloud2
def test_point_cloud_round_trip_and_layout(mesh):
    V, _ = mesh
    msg = vertices_to_point_cloud2(V, header())
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (1, 500, 12, 6000)
    assert [f.name for f in msg.fields] == ["x", "y", "z"]
    assert all(f.datatype == PointField.FLOAT32 for f in msg.fields)
    assert msg.is_dense and not msg.is_bigendian and len(msg.data) == 6000
    assert msg.header.stamp.nanosec == 345 and msg.header.frame_id == "world"
    np.testing.assert_allclose(point_cloud2_to_vertices(msg), V, rtol=1e-6, atol=1e-6)


def test_point_cloud_not_dense_with_nan(mesh):
    V = mesh[0].copy()
    V[7, 1] = np.nan
    assert not vertices_to_point_cloud2(V, header()).is_dense


def test_point_cloud_reader_handles_padded_layout():
    # x, y, z plus an intensity field: 16-byte points.
    pts = np.zeros(4, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("i", "<f4")])
    pts["x"], pts["y"], pts["z"], pts["i"] = np.arange(4), 10 + np.arange(4), 20, 99
    msg = PointCloud2(height=1, width=4, point_step=16, row_step=64, is_dense=True,
                      fields=[PointField(name=n, offset=4 * i, datatype=7, count=1)
                              for i, n in enumerate("xyzi")],
                      data=array.array("B", pts.tobytes()))
    V = point_cloud2_to_vertices(msg)
    np.testing.assert_array_equal(V[:, 0], np.arange(4))
    np.testing.assert_array_equal(V[:, 2], 20)


def test_point_cloud_rejects_bad_shape():
    with pytest.raises(ValueError, match=r"\(n, 3\)"):
        vertices_to_point_cloud2(np.zeros((4, 2)), header())


# ---------------------------------------------------------------- Mesh / Marker
def test_mesh_round_trip(mesh):
    V, F = mesh
    V2, F2 = msg_to_mesh(mesh_to_msg(V, F))
    np.testing.assert_array_equal(V2, V)
    np.testing.assert_array_equal(F2, F)


def test_mesh_rejects_out_of_range_faces(mesh):
    V, F = mesh
    with pytest.raises(ValueError, match="outside"):
        mesh_to_msg(V, np.vstack([F, [[0, 1, 500]]]))


def test_triangle_list_marker_matches_corners(mesh):
    V, F = mesh
    m = triangle_list_marker(V, F, header(), ns="skin", marker_id=3)
    P = np.array([(p.x, p.y, p.z) for p in m.points])
    np.testing.assert_array_equal(P, V[F].reshape(-1, 3))
    assert m.type == m.TRIANGLE_LIST and m.action == m.ADD and m.id == 3 and m.ns == "skin"
    assert m.header.stamp.sec == 12 and m.header.frame_id == "world"
    assert m.pose.orientation.w == 1.0 and m.scale.x == 1.0 and m.color.a == 1.0
    assert len(m.colors) == 0 and m.text == ""


def test_triangle_list_marker_bytes_survive_a_reserialization(mesh):
    # Padding bytes are unspecified in CDR, so compare what they decode to.
    V, F = mesh
    for k in (0, 1, 2, 900):  # empty, single and many triangles
        raw = triangle_list_marker_cdr(V, F[:k], header())
        again = serialize_message(deserialize_message(raw, Marker))
        assert len(again) == len(raw) and len(raw) > 72 * k
        assert deserialize_message(again, Marker) == deserialize_message(raw, Marker)


def test_triangle_list_marker_with_long_frame_keeps_alignment(mesh):
    # A frame name of odd length shifts everything after it: padding must follow.
    V, F = mesh
    for frame in ("a", "ab", "abc", "abcd", "base_link_xyz"):
        m = triangle_list_marker(V, F[:5], header(frame=frame))
        np.testing.assert_array_equal(np.array([(p.x, p.y, p.z) for p in m.points]),
                                      V[F[:5]].reshape(-1, 3))


# ---------------------------------------------------------------- diagnostics
def test_diagnostic_array_round_trip():
    msg = diagnostic_array(header(), "skin_node: pipeline", "arm", "warn", "2 rejected",
                           {"frames_processed": 5, "ms_total": 1.23456})
    values = diagnostic_values(msg, "skin_node: pipeline")
    assert values == {"frames_processed": "5", "ms_total": "1.235"}
    assert msg.status[0].level == msg.status[0].WARN
    with pytest.raises(KeyError):
        diagnostic_values(msg, "other")


def test_header_stamp_read_from_cdr_without_deserializing():
    msg = js(CHANNELS, np.arange(9.0))
    msg.header = header(sec=1_700_000_123, nanosec=999_999_999)
    assert header_stamp_ns(serialize_message(msg)) == 1_700_000_123_999_999_999
    cloud = vertices_to_point_cloud2(np.zeros((3000, 3)), header(sec=-2, nanosec=5))
    assert header_stamp_ns(serialize_message(cloud)) == -2 * 10**9 + 5
    big = bytes([0, 0, 0, 0]) + (7).to_bytes(4, "big") + (9).to_bytes(4, "big")
    assert header_stamp_ns(big) == 7 * 10**9 + 9                 # big-endian CDR
    for bad in (b"", b"\x00\x01\x00\x00\x01", b"\x00\x03" + bytes(10)):
        with pytest.raises(ValueError, match="plain CDR"):
            header_stamp_ns(bad)
