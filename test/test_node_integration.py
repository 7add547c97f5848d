"""The node as a process: bags of joint states in, recorded outputs checked.

Each test starts ``skin_node`` (the installed console script when it is on
PATH, else ``python -m skin_node.node``) on a ROS_DOMAIN_ID it claims for itself
(``skin_node.ros_domain``) with DDS kept on localhost, replays a bag written
here with ``rosbags`` (rosbag2, or ROS 1) through ``skin_bag``, and reads the
bag ``skin_bag`` recorded.
"""
from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore
from sensor_msgs.msg import JointState, PointCloud2
from diagnostic_msgs.msg import DiagnosticArray

import skin_node
from skin_node.player import character_skeleton
from msg_adapters import Reason, diagnostic_values, point_cloud2_to_vertices
from skin_node.io.bags import BagReader
from skin_node.processes import command as _command, stop, wait_for_log
from skin_node.ros_domain import bound_udp_ports, claim_domain, domain_ports, domain_range

REPO = Path(__file__).resolve().parents[1]
PR2_BAG = REPO.parent / "shared" / "data" / "bags" / "pr2_joint_states_mcap"
NAME_MAP = REPO / "config" / "name_map_example.yaml"
ARM_VERTICES = 2000
READY_TIMEOUT = 300.0     # a cold rig cache builds the arm's tets and weights first


def _base_env() -> dict:
    """Environment of the tools: DDS on localhost, unbuffered output, this source tree.

    The source tree comes before the colcon install's copy of it: the installed
    executables then run the code under test, and read the kernels this process
    compiled from numba's cache (kept beside each source file) instead of
    compiling them again for the copy (about 90 s on a fresh clone).
    ``test_install_layout`` starts the install tree alone."""
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1",
               RCUTILS_LOGGING_BUFFERED_STREAM="0")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    return env


@contextlib.contextmanager
def ros_env():
    """Environment of one node + tools, on a domain no other live process holds
    for as long as the block runs."""
    with claim_domain() as claim:
        yield dict(_base_env(), ROS_DOMAIN_ID=str(claim.domain))


@contextlib.contextmanager
def running_node(tmp_path: Path, *ros_args: str):
    """Start skin_node, wait for 'ready', yield (process, env, log path), then stop it
    with SIGTERM and check it exited 0 (documented; an abort would be -6)."""
    with ros_env() as env:
        log = tmp_path / f"node-{env['ROS_DOMAIN_ID']}.log"
        with open(log, "w") as out:
            proc = subprocess.Popen(
                _command("skin_node", "skin_node.node") + ["--ros-args", *ros_args],
                stdout=out, stderr=subprocess.STDOUT, env=env, cwd=REPO)
        try:
            wait_for_log(proc, log, "]: ready in", READY_TIMEOUT)
            yield proc, env, log
        finally:
            stop(proc)
        assert proc.returncode == 0, f"skin_node exited {proc.returncode}:\n{log.read_text()}"


def arm_node(tmp_path: Path, *ros_args: str):
    return running_node(tmp_path, "-p", "character:=arm",
                        "-p", f"surface_vertices:={ARM_VERTICES}", *ros_args)


@contextlib.contextmanager
def ros_client(env: dict, name: str):
    """This test's own node on the running node's domain: yields (node, executor,
    set_params); ``set_params(name=value, ...)`` returns the SetParametersResults."""
    import rclpy
    import rclpy.executors
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(env["ROS_DOMAIN_ID"]))
    try:
        node = rclpy.create_node(name, context=ctx)
        ex = rclpy.executors.SingleThreadedExecutor(context=ctx)
        try:
            ex.add_node(node)
            client = AsyncParameterClient(node, "skin_node")
            assert client.wait_for_services(10.0)

            def set_params(**kw):
                fut = client.set_parameters([Parameter(k, value=v) for k, v in kw.items()])
                ex.spin_until_future_complete(fut, timeout_sec=10.0)
                return fut.result().results

            yield node, ex, set_params
        finally:        # in order: nothing spins, then the node, then the context
            ex.shutdown()
            node.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)


def bag_command(in_bag: Path, out_bag: Path, *args: str) -> list:
    """``skin_bag`` replaying ``in_bag`` into ``out_bag``."""
    return _command("skin_bag", "skin_node.bag_tool") + [str(in_bag), str(out_bag), *args]


def play_and_record(env: dict, in_bag: Path, out_bag: Path, *args: str) -> str:
    cmd = bag_command(in_bag, out_bag, *args)
    res = subprocess.run(cmd, env=env, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stdout + res.stderr
    return res.stdout


def read_outputs(bag: Path) -> tuple[list[PointCloud2], dict]:
    """Recorded point clouds, and the values of the last diagnostics message."""
    clouds, diag = [], None
    with BagReader(bag) as reader:
        for topic, _, raw in reader.messages():
            if topic == "/skin/points":
                clouds.append(deserialize_message(raw, PointCloud2))
            elif topic == "/skin/diagnostics":
                diag = deserialize_message(raw, DiagnosticArray)
    assert diag is not None, "no diagnostics recorded"
    return clouds, diagnostic_values(diag)


def stamp_ns(msg) -> int:
    return msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec


def joint_state(t_ns: int, names, positions) -> JointState:
    msg = JointState()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(t_ns), 1_000_000_000)
    msg.name = list(names)
    msg.position = [float(p) for p in positions]
    return msg


def write_bag(path: Path, storage: str, stream: list[tuple[int, JointState]]) -> None:
    """A rosbag2 bag of ``(log time ns, JointState)`` on /joint_states, written by rosbags."""
    plugin = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}[storage]
    with Writer(path, version=8, storage_plugin=plugin) as writer:
        conn = writer.add_connection("/joint_states", "sensor_msgs/msg/JointState",
                                     typestore=get_typestore(Stores.ROS2_JAZZY))
        for t, msg in stream:
            writer.write(conn, t, serialize_message(msg))


def matched(ex, pub, sub, timeout: float = 10.0) -> None:
    """Spin ``ex`` until ``pub`` sees the node's subscription and ``sub`` its
    publisher (both ways matched: nothing sent after is lost), or ``timeout``."""
    deadline = time.monotonic() + timeout
    while not (pub.get_subscription_count() and sub.get_publisher_count()) \
            and time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.05)


def arm_stream(n_valid: int, hz: float, with_bad: bool = True):
    """Valid arm poses at ``hz``, each followed (when ``with_bad``) by one bad message
    of a rotating kind. Returns (stream, valid stamps, bad stamps by reason)."""
    names = character_skeleton("arm").channel_names
    t0, dt = 1_700_000_000 * 10**9, int(1e9 / hz)
    bad_kinds = [
        (Reason.NON_FINITE, lambda q: (names, np.where(np.arange(len(q)) == 7, np.nan, q))),
        (Reason.LENGTH_MISMATCH, lambda q: (names, q[:-1])),
        (Reason.DUPLICATE_NAMES, lambda q: (names[:4] + names[3:4], q[:5])),
        (Reason.EMPTY, lambda q: ([], [])),
        (Reason.OUT_OF_RANGE, lambda q: (names, q + 5000.0)),
        (Reason.NO_KNOWN_NAMES, lambda q: (["caster_wheel", "gripper"], q[:2])),
        (Reason.STAMP_BACKWARDS, lambda q: (names, q)),
    ]
    stream, valid, bad = [], [], {}
    for i in range(n_valid):
        t = t0 + i * dt
        q = np.zeros(len(names))
        q[names.index("elbow_rz")] = 1.2 * (1 - np.cos(2 * np.pi * i / 40))
        q[names.index("wrist_rx")] = 0.8 * np.sin(2 * np.pi * i / 30)
        stream.append((t, joint_state(t, names, q)))
        valid.append(t)
        if with_bad and i >= 1 and i % 5 == 0:
            reason, make = bad_kinds[(i // 5 - 1) % len(bad_kinds)]
            stamp = t - dt // 2 if reason is Reason.STAMP_BACKWARDS else t + dt // 2
            stream.append((t + dt // 2, joint_state(stamp, *make(q))))
            bad.setdefault(reason, []).append(stamp)
    return stream, valid, bad


# ------------------------------------------------------------------ tests
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_replay_answers_each_valid_message_once_and_counts_bad_ones(tmp_path, storage):
    stream, valid, bad = arm_stream(n_valid=80, hz=20.0)
    assert set(bad) == set(Reason)  # every rejection reason is exercised
    write_bag(tmp_path / "in", storage, stream)
    # In lockstep no valid frame may be skipped as stale; the bad ones are never
    # answered (each waits out the 1 s) but for the backwards stamps, which are
    # older than an answer already given.
    with arm_node(tmp_path, "-p", "pipeline:=[dqs, smooth]") as (proc, env, log):
        out = play_and_record(env, tmp_path / "in", tmp_path / "out", "--storage", storage,
                              "--lockstep", "1")
        assert proc.poll() is None, "node died"
    clouds, diag = read_outputs(tmp_path / "out")
    unanswered = sum(len(v) for v in bad.values()) - len(bad[Reason.STAMP_BACKWARDS])
    assert f"in lockstep ({unanswered} unanswered within 1 s)" in out

    assert [stamp_ns(c) for c in clouds] == valid
    for c in clouds:
        V = point_cloud2_to_vertices(c)
        assert V.shape[0] == c.width and abs(V.shape[0] - ARM_VERTICES) < 0.05 * ARM_VERTICES
        assert c.is_dense and np.isfinite(V).all() and c.header.frame_id == "world"
    assert int(diag["frames_received"]) == len(stream)
    assert int(diag["frames_processed"]) == len(valid)
    assert int(diag["frames_skipped_stale"]) == 0
    assert int(diag["rejected_total"]) == sum(len(v) for v in bad.values())
    for reason, stamps in bad.items():
        assert int(diag[f"rejected_{reason.value}"]) == len(stamps), reason
    assert diag["unknown_names"] == "caster_wheel,gripper"
    assert int(diag["time_jumps_back"]) == 0       # 25 ms back is a reordering, not a restart
    assert "rejected" in log.read_text()  # the throttled warning


def test_a_ros1_bag_replays_like_a_rosbag2_one(tmp_path):
    """A ROS 1 .bag (written here by rosbags) through skin_bag: every valid pose
    answered with its stamp, the unknown names counted, and the summary says so."""
    from test_bags import write_ros1_bag
    stream, valid, _ = arm_stream(n_valid=30, hz=20.0, with_bad=False)
    unknown = [(t + 1000, joint_state(t + 1000, ["caster_wheel"], [0.5]))
               for t, _ in stream[9::10]]
    bag = write_ros1_bag(tmp_path / "in.bag", sorted(stream + unknown, key=lambda x: x[0]))
    with arm_node(tmp_path, "-p", "pipeline:=[dqs, smooth]") as (proc, env, log):
        out = play_and_record(env, bag, tmp_path / "out", "--lockstep", "2")
        assert proc.poll() is None, "node died"
    clouds, diag = read_outputs(tmp_path / "out")
    assert [stamp_ns(c) for c in clouds] == valid
    poses = {t: np.array(m.position) for t, m in stream}
    ch = skin_node.load_character("arm", surface_vertices=ARM_VERTICES, progress=False)
    pipe = skin_node.Pipeline(ch, ["dqs", "smooth"])
    for c in clouds[::7]:
        assert np.abs(point_cloud2_to_vertices(c) - pipe.deform(poses[stamp_ns(c)])).max() < 1e-6
    assert int(diag["rejected_no_known_names"]) == len(unknown) == 3
    assert f"played {len(stream) + 3} joint states" in out
    assert "the node answered 30 of 33, skipped 0 as stale, rejected 3 of 33 " \
           "(no_known_names 3); no name (caster_wheel) is a channel" in out, out


def test_a_gltf_characters_own_clip_through_the_node(tmp_path):
    """A glTF file's animation (cubic, step and linear tracks) named by mocap_player,
    replayed as joint states through the node: each pose's skin is the pipeline's."""
    from test_gltf_clips import write_animated_glb
    from skin_node.motion import load_motion
    glb = write_animated_glb(tmp_path / "leg.glb")
    res = subprocess.run(_command("mocap_player", "skin_node.player")
                         + ["--character", str(glb), "--list-clips"],
                         env=_base_env(), cwd=REPO, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stdout.split() == ["walk", "animation1"], res.stderr
    clip = load_motion(str(glb), "walk", fps=30.0)
    t0, dt = 1_700_000_000 * 10**9, 10**9 // 30
    stream = [(t0 + k * dt, joint_state(t0 + k * dt, clip.channel_names, q))
              for k, q in enumerate(clip.frames)]
    write_bag(tmp_path / "in", "mcap", stream)
    with running_node(tmp_path, "-p", f"character:={glb}", "-p", "weights:=file") \
            as (proc, env, log):
        play_and_record(env, tmp_path / "in", tmp_path / "out", "--lockstep", "5")
        res = subprocess.run(
            _command("mocap_player", "skin_node.player") + [
                "--character", str(glb), "--clip", "walk", "--fps", "30", "--frames", "20"],
            env=env, cwd=REPO, capture_output=True, text=True, timeout=120)
        assert res.returncode == 0, res.stderr
        assert "playing 'walk': 31 frames at 30.0 Hz" in res.stderr
        assert "sent 20 frames" in res.stderr
    clouds, diag = read_outputs(tmp_path / "out")
    assert [stamp_ns(c) for c in clouds] == [t for t, _ in stream]
    pipe = skin_node.Pipeline(skin_node.load_character(str(glb), weights="file",
                                                       progress=False))
    moved = 0.0
    for c, q in zip(clouds, clip.frames):
        X = point_cloud2_to_vertices(c)
        assert np.abs(X - pipe.deform(q)).max() < 1e-6
        moved = max(moved, float(np.abs(X - pipe.character.V).max()))
    assert moved > 0.3                  # the walk moves the leg, root and all


def test_every_part_of_a_gltf_character_is_published(tmp_path):
    """A glTF character of several meshes on two skins, rigid and static parts,
    its own clip replayed through skin_bag: skin/points and skin/mesh cover
    every part (the body, then the passengers), the start-up lines and the
    diagnostics say what each part gets."""
    from shape_msgs.msg import Mesh
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from skin_node.motion import load_motion
    from test_gltf_character import write_character
    glb = write_character(tmp_path / "character.glb")
    ch = skin_node.load_character(str(glb), progress=False)
    clip = load_motion(str(glb), "pose", fps=10.0)
    t0, dt = 1_700_000_000 * 10**9, 10**8
    stream = [(t0 + k * dt, joint_state(t0 + k * dt, clip.channel_names, q))
              for k, q in enumerate(clip.frames)]
    write_bag(tmp_path / "in", "mcap", stream)
    meshes = []
    with running_node(tmp_path, "-p", f"character:={glb}") as (proc, env, log):
        out = play_and_record(env, tmp_path / "in", tmp_path / "out", "--lockstep", "5")
        with ros_client(env, "skin_node_parts_test") as (node, ex, set_params):
            latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
            node.create_subscription(Mesh, "skin/mesh", meshes.append, latched)
            deadline = time.monotonic() + 10.0
            while not meshes and time.monotonic() < deadline:
                ex.spin_once(timeout_sec=0.1)
        text = log.read_text()
    assert f"the node answered {len(stream)} of {len(stream)}" in out, out
    clouds, diag = read_outputs(tmp_path / "out")
    assert [stamp_ns(c) for c in clouds] == [t for t, _ in stream]
    pipe = skin_node.Pipeline(ch)
    for c, q in zip(clouds, clip.frames):
        assert c.width == len(ch.surface_V) > len(ch.V)
        assert np.abs(point_cloud2_to_vertices(c) - pipe.deform(q)).max() < 1e-6
    assert meshes, "no skin/mesh"
    mesh = meshes[0]
    rest = np.array([[p.x, p.y, p.z] for p in mesh.vertices])
    assert len(rest) == len(ch.surface_V) and np.abs(rest - ch.surface_V).max() < 1e-12
    assert np.array_equal([t.vertex_indices for t in mesh.triangles], ch.surface_F)
    assert diag["parts"] == ",".join(p.summary() for p in ch.parts)
    assert diag["parts"].startswith("torso:98:skinned:solved,legs:52:skinned:solved,skirt:48")
    for line in ch.part_lines():        # every part and every skipped mesh, before 'ready'
        assert line in text.split("]: ready in")[0], line
    assert f"character 'character' {len(ch.surface_V)} vertices" in text
    assert "7 parts (vertices 150 solved, 56 skinned, 16 rigid, 4 static)" in text


def _replayed_bag(tmp_path: Path, source: str) -> tuple[Path, list[int], list[str], list[str]]:
    """(bag, its stamps, skin_bag arguments, node arguments) of a generated arm bag
    or of the first 150 messages of the real PR2 one (skipped when absent)."""
    if source == "pr2":
        bag, n = _pr2_or_skip(), 150
        with BagReader(bag) as reader:
            stamps = [stamp_ns(deserialize_message(raw, JointState))
                      for _, _, raw in reader.messages("sensor_msgs/msg/JointState")][:n]
        return bag, stamps, ["--limit", str(n)], ["-p", f"name_map:={NAME_MAP}"]
    stream, valid, _ = arm_stream(n_valid=40, hz=20.0, with_bad=False)
    write_bag(tmp_path / "in", "mcap", stream)
    return tmp_path / "in", valid, [], []


@pytest.mark.parametrize("source", ["generated", "pr2"])
def test_a_bag_replayed_again_is_skinned_again(tmp_path, source):
    """The second replay goes back in time by the bag's length: a restart of the
    source (counted, logged once), not a stream of stamp_backwards."""
    bag, stamps, bag_args, node_args = _replayed_bag(tmp_path, source)
    with arm_node(tmp_path, "-p", "pipeline:=[dqs, smooth]", *node_args) as (proc, env, log):
        outs = [play_and_record(env, bag, tmp_path / f"out{k}", "--lockstep", "1", *bag_args)
                for k in (1, 2)]
        assert proc.poll() is None
        assert log.read_text().count("time jumped back") == 1
    assert "time jumped back" not in outs[0] and "time jumped back 1 time " in outs[1], outs
    for k in (1, 2):
        clouds, diag = read_outputs(tmp_path / f"out{k}")
        assert [stamp_ns(c) for c in clouds] == stamps, f"replay {k}"
        assert int(diag["time_jumps_back"]) == k - 1
    assert int(diag["frames_processed"]) == int(diag["frames_received"]) == 2 * len(stamps)
    assert int(diag["rejected_total"]) == 0


def test_burst_processes_newest_and_counts_stale(tmp_path):
    stream, valid, _ = arm_stream(n_valid=60, hz=2000.0, with_bad=False)
    write_bag(tmp_path / "in", "mcap", stream)
    with arm_node(tmp_path) as (proc, env, log):  # the full default pipeline
        play_and_record(env, tmp_path / "in", tmp_path / "out")
    clouds, diag = read_outputs(tmp_path / "out")
    out = [stamp_ns(c) for c in clouds]
    processed, stale = int(diag["frames_processed"]), int(diag["frames_skipped_stale"])
    assert int(diag["frames_received"]) == len(valid)
    assert processed == len(out) and processed + stale == len(valid)
    assert stale > 0, "a 2 kHz burst must outrun the solver"
    assert out[-1] == valid[-1], "the newest frame must always be processed"
    assert out == sorted(set(out)) and set(out) <= set(valid)


@pytest.mark.parametrize("isolation", ["thread", "process"])
def test_two_workers_publish_in_order_what_one_pipeline_gives(tmp_path, isolation):
    stream, valid, _ = arm_stream(n_valid=60, hz=400.0, with_bad=False)
    write_bag(tmp_path / "in", "mcap", stream)
    with arm_node(tmp_path, "-p", "workers:=2", "-p", f"isolation:={isolation}") as (
            proc, env, log):
        play_and_record(env, tmp_path / "in", tmp_path / "out")
        assert "2 workers" in log.read_text()
        assert ("deform processes" in log.read_text()) == (isolation == "process")
    clouds, diag = read_outputs(tmp_path / "out")
    out = [stamp_ns(c) for c in clouds]
    processed, stale = int(diag["frames_processed"]), int(diag["frames_skipped_stale"])
    assert processed == len(out) and processed + stale == len(valid) == int(diag["frames_received"])
    assert out == sorted(set(out)) and set(out) <= set(valid), "published out of input order"
    assert out[-1] == valid[-1]
    # Each worker's pipeline gives what a single one does: a pose's skin
    # depends on that pose alone, not on which frames a worker took before.
    ch = skin_node.load_character("arm", surface_vertices=ARM_VERTICES, progress=False)
    pipe = skin_node.Pipeline(ch)
    poses = {t: np.array(msg.position) for t, msg in stream}
    for c in clouds[::3]:
        ref = pipe.deform(poses[stamp_ns(c)])
        assert np.abs(point_cloud2_to_vertices(c) - ref).max() < 1e-6


@pytest.mark.parametrize("isolation", ["thread", "process"])
def test_carried_correction_answers_dqs_at_once_then_the_solved_skin(tmp_path, isolation):
    """correction:=carried: the first pose after ready is answered with plain
    DQS (nothing solved yet); the same pose again, once its solve is done, with
    the default pipeline's skin, as the in-process pipeline gives it."""
    names = character_skeleton("arm").channel_names
    q = np.zeros(len(names))
    q[names.index("elbow_rz")] = 2.4
    got, diags = [], []
    with arm_node(tmp_path, "-p", "correction:=carried", "-p", f"isolation:={isolation}") as (
            proc, env, log):
        with ros_client(env, "skin_node_carried_test") as (node, ex, set_params):
            sub = node.create_subscription(PointCloud2, "skin/points", got.append, 10)
            node.create_subscription(DiagnosticArray, "skin/diagnostics",
                                     lambda m: diags.append(diagnostic_values(m)), 10)
            assert not set_params(pipeline=["lbs", "smooth"])[0].successful   # rides on DQS
            pub = node.create_publisher(JointState, "joint_states", 10)
            matched(ex, pub, sub)
            for k in range(2):
                pub.publish(joint_state(10**9 + k * 10**9, names, q))
                # answered, and then (the diagnostics say) the pose solved
                deadline = time.monotonic() + 60.0
                while time.monotonic() < deadline and not (
                        len(got) > k and diags and
                        int(diags[-1]["correction_solves"]) == k + 1):
                    ex.spin_once(timeout_sec=0.05)
        assert "correction carried" in log.read_text()
    assert [stamp_ns(c) for c in got] == [10**9, 2 * 10**9]
    ch = skin_node.load_character("arm", surface_vertices=ARM_VERTICES, progress=False)
    dqs, solved = skin_node.Pipeline.preset(ch, "dqs").deform(q), skin_node.Pipeline(ch).deform(q)
    assert np.abs(dqs - solved).max() > 0.005            # the correction is visible here
    assert np.abs(point_cloud2_to_vertices(got[0]) - dqs).max() < 1e-6
    assert np.abs(point_cloud2_to_vertices(got[1]) - solved).max() < 1e-6
    d = diags[-1]
    assert int(d["frames_processed"]) == 2 and int(d["correction_solves"]) == 2
    assert int(d["correction_solves_failed"]) == 0 and int(d["frames_skipped_stale"]) == 0


@pytest.mark.parametrize("isolation", ["thread", "process"])
def test_two_workers_both_take_a_parameter_change(tmp_path, isolation):
    names = character_skeleton("arm").channel_names
    stages = ["dqs", "pbd", "collision", "smooth", "volume"]      # not the default order
    poses, got, diags = {}, [], []
    with arm_node(tmp_path, "-p", "workers:=2", "-p", f"isolation:={isolation}") as (
            proc, env, log):
        with ros_client(env, "skin_node_workers_test") as (node, ex, set_params):
            sub = node.create_subscription(PointCloud2, "skin/points", got.append, 100)
            node.create_subscription(DiagnosticArray, "skin/diagnostics",
                                     lambda m: diags.append(diagnostic_values(m)), 10)
            assert [r.successful for r in set_params(pipeline=stages, smoothing=0.8)] == \
                [True, True]
            assert not set_params(warm_start=True)[0].successful   # history needs one worker
            pub = node.create_publisher(JointState, "joint_states", 100)
            matched(ex, pub, sub)
            # Bursts of three poses 2 ms apart into frames of several ms: while one
            # worker deforms the first, the other takes the second.
            for burst in range(20):
                for k in range(3):
                    i = 3 * burst + k
                    q = np.zeros(len(names))
                    q[names.index("elbow_rz")] = 0.04 * i
                    poses[10**9 + i * 10**6] = q
                    pub.publish(joint_state(10**9 + i * 10**6, names, q))
                    time.sleep(0.002)
                deadline = time.monotonic() + 10.0
                while time.monotonic() < deadline and (not got or stamp_ns(got[-1]) != max(poses)):
                    ex.spin_once(timeout_sec=0.01)
            # Diagnostics counting every frame sent and every skin received: one
            # taken while the last burst was still being deformed counts fewer.
            deadline = time.monotonic() + 5.0
            while time.monotonic() < deadline and not (
                    diags and int(diags[-1]["frames_received"]) == len(poses)
                    and int(diags[-1]["frames_processed"]) == len(got)):
                ex.spin_once(timeout_sec=0.1)
        assert log.read_text().count("parameters applied") == 1
    out = [stamp_ns(c) for c in got]
    assert out == sorted(set(out)) and out[-1] == max(poses)
    per_worker = [int(n) for n in diags[-1]["frames_per_worker"].split(",")]
    assert len(per_worker) == 2 and min(per_worker) >= 1, per_worker
    assert sum(per_worker) == int(diags[-1]["frames_processed"]) == len(got)
    ch = skin_node.load_character("arm", surface_vertices=ARM_VERTICES, progress=False)
    pipe = skin_node.Pipeline(ch, stages, smoothing=0.8)
    for c in got:           # whichever worker deformed it, the new settings did
        ref = pipe.deform(poses[stamp_ns(c)])
        assert np.abs(point_cloud2_to_vertices(c) - ref).max() < 1e-6


def test_ros_latency_benchmark_measures_the_node(tmp_path):
    """skin_bench ros-latency end to end on the arm: every pose it sends is
    received, answered or counted stale, and it reads stamps, memory and the
    node's parameters back."""
    out = tmp_path / "latency.json"
    cmd = _command("skin_bench", "skin_node.bench.cli") + [
        "ros-latency", "--character", "arm", "--surface-vertices", str(ARM_VERTICES),
        "--seconds", "2", "--rate", "60", "--param", "workers:=2", "--clip", "wrist_twist",
        "--out", str(out)]
    res = subprocess.run(cmd, env=_base_env(), cwd=REPO, capture_output=True, text=True,
                         timeout=400)
    assert res.returncode == 0, res.stdout + res.stderr
    lat = json.loads(out.read_text())
    assert lat["inputs"] in (120, 121) and lat["node_received"] == lat["inputs"]
    assert lat["outputs"] + lat["skipped_stale"] == lat["inputs"]
    assert lat["outputs"] >= lat["inputs"] // 2
    assert 0.0 < lat["latency_ms_p50"] <= lat["latency_ms_p99"] < 1000.0
    assert 0.0 < lat["first_pose_ms"] <= lat["latency_ms_max"]    # the first pose was answered
    assert lat["motion"] == "wrist_twist" and "first pose" in res.stdout
    assert 50.0 < lat["node_rss_mb"] < 1500.0 and lat["params"] == ["workers:=2"]
    assert "(workers:=2)" in res.stdout
    assert lat["domain_id"] in domain_range()     # claimed by the benchmark itself
    assert lat["node_exit_code"] == 0


def _pr2_or_skip() -> Path:
    if not (PR2_BAG / "metadata.yaml").exists():
        pytest.skip(f"real PR2 bag not found at {PR2_BAG}")
    return PR2_BAG


def test_real_pr2_bag_unknown_names_are_counted_not_fatal(tmp_path):
    bag = _pr2_or_skip()
    n = 300   # 3 s of the 100 Hz recording, at the recorded rate
    with BagReader(bag) as reader:
        stamps = [stamp_ns(deserialize_message(raw, JointState))
                  for _, _, raw in reader.messages("sensor_msgs/msg/JointState")][:n]
    # Mapped: 7 PR2 right-arm joints drive the arm, the other 35 names are unknown.
    with arm_node(tmp_path, "-p", f"name_map:={NAME_MAP}") as (proc, env, log):
        play_and_record(env, bag, tmp_path / "mapped", "--limit", str(n))
        assert proc.poll() is None
    clouds, diag = read_outputs(tmp_path / "mapped")
    out = [stamp_ns(c) for c in clouds]
    assert out and out == sorted(set(out)) and set(out) <= set(stamps)
    assert int(diag["frames_received"]) == n and int(diag["rejected_total"]) == 0
    assert int(diag["frames_processed"]) + int(diag["frames_skipped_stale"]) == n
    unknown = diag["unknown_names"].split(",")
    assert {"r_gripper_float_joint", "l_gripper_float_joint"} <= set(unknown)
    assert int(diag["unknown_name_count"]) == 42 - 7 == len(unknown)

    # Unmapped: no PR2 name is an arm channel; every message is rejected, none answered.
    with arm_node(tmp_path) as (proc, env, log):
        out = play_and_record(env, bag, tmp_path / "unmapped", "--limit", "100", "--rate", "2")
        assert proc.poll() is None
    clouds, diag = read_outputs(tmp_path / "unmapped")
    assert clouds == []
    # skin_bag says why nothing came back, and what to do about it.
    assert "recorded skin/points 0," in out
    assert "the node answered 0 of 100, skipped 0 as stale, rejected 100 of 100 " \
           "(no_known_names 100); no name (" in out, out
    assert "pass -p name_map:=MAP.yaml" in out
    assert int(diag["rejected_no_known_names"]) == 100
    assert int(diag["unknown_name_count"]) == 42


def test_parameters_mesh_marker_and_sigterm(tmp_path):
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from shape_msgs.msg import Mesh
    from visualization_msgs.msg import Marker

    with running_node(tmp_path, "--params-file", str(REPO / "config" / "arm.yaml"),
                      "-p", f"surface_vertices:={ARM_VERTICES}") as (proc, env, log):
        with ros_client(env, "skin_node_test") as (node, ex, set_params):
            got = {"mesh": [], "marker": [], "points": []}
            latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                 durability=DurabilityPolicy.TRANSIENT_LOCAL)
            node.create_subscription(Mesh, "skin/mesh", got["mesh"].append, latched)
            node.create_subscription(Marker, "skin/marker", got["marker"].append, 5)
            node.create_subscription(PointCloud2, "skin/points", got["points"].append, 5)

            ok = lambda r: [x.successful for x in r]  # noqa: E731
            assert ok(set_params(stiffness=0.3, iterations=7)) == [True, True]
            assert ok(set_params(iterations=100000)) == [False]          # out of range
            assert ok(set_params(stiffness=2.0)) == [False]
            assert ok(set_params(solver="newton")) == [False]            # not a choice
            r = set_params(pipeline=["dqs", "warp"])
            assert not r[0].successful and "warp" in r[0].reason
            assert ok(set_params(pipeline=["pbd", "smooth"])) == [False]  # no skinning first
            assert ok(set_params(character="humanoid")) == [False]       # read-only
            assert ok(set_params(pipeline=["lbs", "smooth"])) == [True]

            pub = node.create_publisher(JointState, "joint_states", 10)
            channel_names = character_skeleton("arm").channel_names
            deadline = time.monotonic() + 20.0
            i = 0
            while not all(got.values()) and time.monotonic() < deadline:
                if pub.get_subscription_count():
                    q = np.zeros(len(channel_names))
                    q[channel_names.index("elbow_rz")] = 0.05 * i
                    pub.publish(joint_state(10**9 + i * 10**7, channel_names, q))
                    i += 1
                ex.spin_once(timeout_sec=0.1)
            assert all(got.values()), {k: len(v) for k, v in got.items()}
            n_vertices, n_triangles = len(got["mesh"][0].vertices), len(got["mesh"][0].triangles)
            marker = got["marker"][-1]
            assert marker.type == Marker.TRIANGLE_LIST and len(marker.points) == 3 * n_triangles
            assert got["points"] and got["points"][-1].width == n_vertices
            assert "parameters applied" in log.read_text()

        t0 = time.monotonic()
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(5) == 0
        assert time.monotonic() - t0 < 2.0


def test_mocap_player_drives_the_node(tmp_path):
    with arm_node(tmp_path) as (proc, env, log):
        res = subprocess.run(
            _command("mocap_player", "skin_node.player") + ["--character", "arm", "--frames",
                                                            "60", "--rate", "0.5"],
            env=env, cwd=REPO, capture_output=True, text=True, timeout=120)
        assert res.returncode == 0, res.stderr
        assert "playing 'elbow_bend'" in res.stderr and "sent 60 frames" in res.stderr
        deadline = time.monotonic() + 5.0
        while "frames/s" not in log.read_text() and time.monotonic() < deadline:
            time.sleep(0.2)
        assert "frames/s" in log.read_text(), log.read_text()  # the per-second figure line


@pytest.mark.parametrize("sig, isolation", [(signal.SIGINT, "thread"),
                                             (signal.SIGTERM, "thread"),
                                             (signal.SIGINT, "process")])
def test_signal_while_busy_exits_zero_within_2_s(tmp_path, sig, isolation):
    with arm_node(tmp_path, "-p", f"isolation:={isolation}") as (proc, env, log):
        player = subprocess.Popen(
            _command("mocap_player", "skin_node.player") + ["--character", "arm", "--loop"],
            env=env, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            deadline = time.monotonic() + 30.0
            while "frames/s" not in log.read_text() and time.monotonic() < deadline:
                time.sleep(0.2)
            assert "frames/s" in log.read_text(), log.read_text()
            t0 = time.monotonic()
            proc.send_signal(sig)
            assert proc.wait(5) == 0, log.read_text()
            assert time.monotonic() - t0 < 2.0
            if isolation == "process":      # its deform process went with it
                pid = int(log.read_text().split("(deform process ")[1].split(")")[0])
                assert not os.path.exists(f"/proc/{pid}/exe") or \
                    open(f"/proc/{pid}/stat").read().split(")")[-1].split()[0] == "Z"
        finally:
            player.send_signal(sig)
            assert player.wait(5) == 0, player.stderr.read()
            assert "Traceback" not in player.stderr.read()
    assert "Traceback" not in log.read_text(), log.read_text()


def test_a_killed_deform_process_fails_one_frame_and_is_started_again(tmp_path):
    """isolation:=process: a worker's child killed mid-run costs the frame it
    was asked for (counted and logged), the next pose starts it again, and
    the node goes on publishing and exits 0."""
    with arm_node(tmp_path, "-p", "isolation:=process") as (proc, env, log):
        child = int(log.read_text().split("(deform process ")[1].split(")")[0])
        player = subprocess.Popen(
            _command("mocap_player", "skin_node.player") + ["--character", "arm", "--loop"],
            env=env, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        try:
            wait_for_log(proc, log, "frames/s", 30.0)
            os.kill(child, signal.SIGKILL)
            wait_for_log(proc, log, "deform process started again", 120.0)
            text = log.read_text()
            after = text.split("deform process started again")[1]
            deadline = time.monotonic() + 10.0
            while "frames/s" not in after and time.monotonic() < deadline:
                time.sleep(0.2)
                after = log.read_text().split("deform process started again")[1]
            assert "frames/s" in after, text         # publishing again
        finally:
            stop(player, signal.SIGINT)
        text = log.read_text()
        assert text.count("frame failed: RemoteError") == 1, text
        assert "(status -9)" in text
        new = int(text.split("started again (pid ")[1].split(",")[0])
        assert new != child


def _wait_for_line(stream, text: str, seconds: float) -> str:
    """Read ``stream`` until a line holds ``text``; returns what was read."""
    seen, deadline = "", time.monotonic() + seconds
    while text not in seen and time.monotonic() < deadline:
        line = stream.readline()
        if not line:
            break               # the process ended
        seen += line
    assert text in seen, seen
    return seen


def test_tools_started_and_stopped_20_times_exit_0_every_time(tmp_path):
    """skin_bag replays and mocap_player runs, over and over against one node:
    every one exits 0 (an abort on exit would be -6) and says nothing of a crash.
    The player plays its frames out, or loops until SIGINT or SIGTERM, in turn."""
    stream, _, _ = arm_stream(n_valid=10, hz=50.0, with_bad=False)
    write_bag(tmp_path / "in", "mcap", stream)
    player_cmd = _command("mocap_player", "skin_node.player") + ["--character", "arm"]
    codes = []
    with arm_node(tmp_path, "-p", "pipeline:=[dqs]") as (proc, env, log):
        for k in range(20):
            how = ("done", signal.SIGINT, signal.SIGTERM)[k % 3]
            player = subprocess.Popen(
                player_cmd + (["--frames", "30"] if how == "done" else ["--loop"]),
                env=env, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
            # Both start at once (each takes seconds to import and join the
            # domain); the replay ends before a looping player is signalled.
            bag = subprocess.Popen(
                bag_command(tmp_path / "in", tmp_path / f"out{k}", "--record", "skin/points",
                            "--linger", "0.3"),
                env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            try:
                err = _wait_for_line(player.stderr, "playing 'elbow_bend'", 60.0)
                out, bag_err = bag.communicate(timeout=300)
                assert bag.returncode == 0, out + bag_err
                assert "played 10 joint states" in out
                if how != "done":
                    assert player.poll() is None, "the looping player ended unsignalled"
                    player.send_signal(how)
                err += player.communicate(timeout=30)[1]
            finally:
                stop(player, signal.SIGKILL)
                stop(bag, signal.SIGKILL)
            codes.append(player.returncode)
            assert "terminate called" not in err and "Traceback" not in err, err
            assert "terminate called" not in bag_err and "Traceback" not in bag_err, bag_err
            if how == "done":
                assert "sent 30 frames" in err
        assert proc.poll() is None
    assert codes == [0] * 20


def test_skin_bag_interrupted_exits_1_in_order(tmp_path):
    """SIGINT or SIGTERM while skin_bag waits for a node (its spin thread
    running): the documented status 1 and message, no abort, a readable bag."""
    stream, _, _ = arm_stream(n_valid=3, hz=10.0, with_bad=False)
    write_bag(tmp_path / "in", "mcap", stream)
    for k, sig in enumerate([signal.SIGINT, signal.SIGTERM] * 3):
        with ros_env() as env:        # a domain of its own, where no node answers
            bag = subprocess.Popen(
                bag_command(tmp_path / "in", tmp_path / f"out{k}", "--wait", "60"),
                env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
            try:
                # Its participant binds the domain's ports once ROS is up: signal then.
                ports = set(domain_ports(int(env["ROS_DOMAIN_ID"])))
                deadline = time.monotonic() + 60.0
                while not ports & bound_udp_ports() and bag.poll() is None \
                        and time.monotonic() < deadline:
                    time.sleep(0.05)
                time.sleep(0.05 * k)          # now and then a little later
                bag.send_signal(sig)
                out, err = bag.communicate(timeout=30)
            finally:
                stop(bag, signal.SIGKILL)
        assert bag.returncode == 1, (sig, bag.returncode, err)
        assert err.strip() == "skin_bag: interrupted; the bag holds what was recorded so far"
        with BagReader(tmp_path / f"out{k}") as reader:     # a valid bag, with nothing in it
            assert list(reader.messages()) == []


@pytest.mark.parametrize("content, args", [
    (None, ()),                                   # missing file
    ("", ()),                                     # empty file
    ("vertices: [[0, 0\n", ()),                   # malformed
    (None, ("-p", "iterations:=-3")),            # bad parameter, before any file is read
    (None, ("-p", "weights:=artist")),           # neither automatic nor file
    (None, ("-p", "weights:=file")),             # the built-in arm has no file weights
    (None, ("-p", "warm_start:=true", "-p", "workers:=2")),  # history needs one worker
    (None, ("-p", "isolation:=fork")),           # neither thread nor process
    (None, ("-p", "correction:=carried", "-p", "workers:=2")),  # answers on one worker
    (None, ("-p", "correction:=sometimes")),     # neither carried nor inline
])
def test_bad_start_up_is_one_line_and_non_zero(tmp_path, content, args):
    path = tmp_path / "character.yaml"
    if content is not None:
        path.write_text(content)
    spec = "arm" if args else str(path)
    with ros_env() as env:
        res = subprocess.run(
            _command("skin_node", "skin_node.node") + ["--ros-args", "-p", f"character:={spec}",
                                                       *args],
            env=env, cwd=REPO, capture_output=True, text=True, timeout=120)
    assert res.returncode != 0
    lines = res.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in res.stderr, res.stderr
    assert lines[0].startswith("skin_node: error: ")
    assert (str(path) if not args else args[1].split(":=")[0]) in lines[0]


def test_params_files_hold_only_declared_valid_parameters():
    node_params = {"character", "surface_vertices", "weights", "pipeline", "frame_id",
                   "name_map", "workers", "isolation", "correction"}
    for name in ("arm", "humanoid"):
        params = yaml.safe_load((REPO / "config" / f"{name}.yaml").read_text())
        params = params["skin_node"]["ros__parameters"]
        assert params["character"] == name
        assert set(params.get("pipeline", skin_node.DEFAULT_STAGES)) <= set(skin_node.STAGE_NAMES)
        for key, value in params.items():
            if key not in node_params:
                skin_node.PIPELINE_PARAMS[key].check(key, value)


def test_player_loads_builtin_clips_and_retargeted_bvh():
    from skin_node.player import load_motion
    name, names, frames, fps = load_motion("arm")
    assert name == skin_node.default_clip_name("arm") and frames.shape == (len(frames), 12)
    assert names == character_skeleton("arm").channel_names and fps > 0
    bvh = REPO.parent / "shared" / "data" / "bvh" / "cmu_02_01_walk.bvh"
    if not bvh.exists():
        pytest.skip(f"CMU BVH not found at {bvh}")
    name, names, frames, fps = load_motion("humanoid", bvh=str(bvh))
    assert frames.shape == (344, 54) and fps == pytest.approx(120.0)
    assert np.isfinite(frames).all()


def test_skin_bag_refuses_bad_arguments_before_touching_ros(tmp_path, capsys):
    from skin_node import bag_tool
    stream, _, _ = arm_stream(n_valid=3, hz=10.0, with_bad=False)
    write_bag(tmp_path / "in", "mcap", stream)
    for args, problem in (
            (["--lockstep", "2", "--record", "skin/diagnostics"], "waits for skin/points"),
            (["--lockstep", "-1"], "--lockstep must be >= 0"),
            (["--rate", "0"], "--rate must be > 0")):
        with pytest.raises(SystemExit) as e:
            bag_tool.main([str(tmp_path / "in"), str(tmp_path / "out"), *args])
        assert e.value.code == 2 and problem in capsys.readouterr().err
    assert bag_tool.main([str(tmp_path / "none"), str(tmp_path / "out")]) == 1
    assert "skin_bag: error:" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()
