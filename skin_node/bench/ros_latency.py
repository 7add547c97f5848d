"""``skin_bench ros-latency``: input-to-output latency of the skin_node process.

Starts the node (the ``skin_node`` console script if on PATH, else
``python -m skin_node.node``) on a ROS_DOMAIN_ID it claims for the run
(``skin_node.ros_domain``: no other live process holds or uses it) with
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, waits until it has latched
``skin/mesh`` (it does so once set up), then publishes JointState at
``rate`` Hz from the walk clip (``--clip`` another) for ``seconds`` seconds.
Every JointState's ``header.stamp`` is the send time on this process's clock;
the node copies it into ``skin/points``, so latency = receive time - output
stamp. Reports p50 / p99 latency, the first pose's (sent once the node is
ready: whether a cold worker answers within a frame), outputs vs inputs, the
node's ``frames_skipped_stale`` from ``skin/diagnostics``, and its exit status
on SIGINT (0 when it shut down in order).
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import psutil

from ..builtin.characters import BUILTIN_CHARACTERS
from ..character import load_character
from ..motion import load_motion
from ..ros_domain import claim_domain


def _rss_mb(pid: int) -> float:
    """Resident memory of process ``pid`` and its children (a deform process
    of ``isolation:=process``) in MB; NaN where the process is gone."""
    try:
        root = psutil.Process(pid)
        procs = [root, *root.children(recursive=True)]
    except psutil.Error:
        return float("nan")
    total = 0
    for p in procs:
        try:
            total += p.memory_info().rss
        except psutil.Error:
            pass                        # a child that ended meanwhile holds nothing
    return total / 2**20


def measure_latency(seconds: float = 10.0, rate: float = 120.0, character: str = "humanoid",
                    surface_vertices: int = 24000, domain: int | None = None,
                    ready_timeout: float = 300.0, params: list | None = None,
                    weights: str = "automatic", bvh: str = "", clip: str = "",
                    measure_every: int = 0, measure_most: int = 120) -> dict:
    """Run the node and measure it; see the module docstring. Returns a dict.
    ``measure_every`` > 0: every such pose's published skin (at most
    ``measure_most`` of them) is measured after the run against the default
    pipeline's skin solved for that pose and DQS's
    (:func:`skin_node.bench.carried.compare_skins`: exact pairs, folds,
    roughness, distance), so what a subscriber got is graded, not what the
    node meant to send.
    ``params``: more node parameters as ``name:=value`` (``threads:=2``).
    ``character`` may be a character file (``surface_vertices`` then does not
    apply); ``bvh``: play this BVH retargeted to it instead of the built-in clip,
    ``clip``: this clip of the character's (``squat``) instead of its first."""
    # deferred: rclpy, the ROS messages and the modules built on them are optional
    # (skin_bench runs without ROS; this one subcommand needs it)
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.executors import SingleThreadedExecutor
    from sensor_msgs.msg import PointCloud2
    from shape_msgs.msg import Mesh

    from msg_adapters import channels_to_joint_state, diagnostic_values, header_stamp_ns
    from skin_node.node import QOS_JOINT_STATES, QOS_LATCHED, QOS_STREAM
    from skin_node.processes import SpinThread, command, stop

    if domain is None:
        with claim_domain() as claim:           # held until the node is gone
            return measure_latency(seconds, rate, character, surface_vertices, claim.domain,
                                   ready_timeout, params, weights, bvh, clip, measure_every,
                                   measure_most)
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST",
               PYTHONUNBUFFERED="1")
    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    builtin = character in BUILTIN_CHARACTERS
    if builtin:     # a bad request fails here, and the node then reads the rig from the cache
        load_character(character, surface_vertices=surface_vertices, weights=weights,
                       progress=False)
    else:
        surface_vertices = 0
    motion = load_motion(character, clip=clip, bvh=bvh)
    names, frames = list(motion.channel_names), np.asarray(motion.frames)
    log = tempfile.NamedTemporaryFile("w+", suffix=".log", delete=False)
    extra = [a for p in (params or []) for a in ("-p", p)]
    extra += ["-p", f"surface_vertices:={surface_vertices}"] if builtin else []
    proc = subprocess.Popen(command("skin_node", "skin_node.node")
                            + ["--ros-args", "-p", f"character:={character}",
                               "-p", f"weights:={weights}"] + extra,
                            stdout=log, stderr=subprocess.STDOUT, env=env)
    rclpy.init(domain_id=domain)
    node = rclpy.create_node("skin_bench_latency")
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    lat, diag, ready, first, lags = [], {}, [], {}, []
    sent_pose, kept = {}, []              # stamp -> pose of each kept one; (pose, raw cloud)
    clock = node.get_clock()

    def on_points(raw: bytes):
        # Raw CDR: only the stamp is read, not the whole 24k-point cloud.
        now = clock.now().nanoseconds
        stamp = header_stamp_ns(raw)
        lat.append((now - stamp) / 1e6)
        if stamp == first.get("stamp"):
            first["ms"] = lat[-1]
        if stamp in sent_pose and len(kept) < measure_most:
            kept.append((sent_pose.pop(stamp), bytes(raw)))

    def on_diag(msg):
        try:
            vals = diagnostic_values(msg)
        except KeyError:
            return
        if float(vals.get("ms_per_frame", "nan") or "nan") == 0.0:
            vals.pop("ms_per_frame")        # a period without frames (the drain)
        elif "correction_lag_mean" in vals:
            lags.append((float(vals["fps"]), float(vals["correction_lag_mean"]),
                         int(vals["correction_lag_max"])))
        diag.update(vals)

    node.create_subscription(Mesh, "skin/mesh", lambda m: ready.append(1), QOS_LATCHED)
    node.create_subscription(PointCloud2, "skin/points", on_points, QOS_STREAM, raw=True)
    node.create_subscription(DiagnosticArray, "skin/diagnostics", on_diag, 10)
    pub = node.create_publisher(type(channels_to_joint_state(["a"], np.zeros(1))),
                                "joint_states", QOS_JOINT_STATES)
    # The executor spins in its own thread, blocked in its wait set between
    # messages; the feeder below sleeps until each send is due. (Spinning with
    # 2 ms timeouts between sends, and deserializing every cloud, cost this
    # process about a quarter of a core, taken from the node it measures.)
    spinner = SpinThread(ex, "skin_bench_spin").start()
    t_setup = time.monotonic()
    try:
        while not ready:
            if proc.poll() is not None or time.monotonic() - t_setup > ready_timeout:
                log.seek(0)
                raise RuntimeError(f"skin_node did not come up:\n{log.read()[-2000:]}")
            time.sleep(0.1)
        ready_s = time.monotonic() - t_setup
        # both ends matched: the publisher's count says it sees the node, the
        # node's diagnostics that the node sees it (until then a pose may come
        # late, in one burst with the next, and be skipped as stale)
        while pub.get_subscription_count() == 0 or int(diag.get("joint_state_publishers",
                                                                 0)) == 0:
            if proc.poll() is not None or time.monotonic() - t_setup > ready_timeout:
                raise RuntimeError("skin_node did not match the benchmark's publisher")
            time.sleep(0.05)
        period = 1.0 / rate
        sent = 0
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds:
            wait = t0 + sent * period - time.monotonic()
            if wait > 0:
                time.sleep(wait)
            q = frames[sent % len(frames)]
            msg = channels_to_joint_state(names, q, clock.now().to_msg())
            stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            if not sent:
                first["stamp"] = stamp
            if measure_every and sent % measure_every == 0 and sent >= 8:
                sent_pose[stamp] = q
            pub.publish(msg)
            sent += 1
        # drain outputs and wait for a diagnostics message that saw every input
        t_end = time.monotonic()
        while time.monotonic() - t_end < 3.0:
            time.sleep(0.05)
            if int(diag.get("frames_received", 0)) >= sent and time.monotonic() - t_end > 1.2:
                break
        rss_mb = _rss_mb(proc.pid)
    finally:
        spinner.stop()
        node.destroy_node()
        rclpy.try_shutdown()
        stop(proc, signal.SIGINT, 10.0)
        log.close()
        os.unlink(log.name)
    L = np.array(lat) if lat else np.array([np.nan])
    quality = {}
    if kept:
        from rclpy.serialization import deserialize_message

        from msg_adapters import point_cloud2_to_vertices
        from .carried import compare_skins
        skins = [point_cloud2_to_vertices(deserialize_message(raw, PointCloud2)).astype(float)
                 for _, raw in kept]
        quality = compare_skins(f"{character}:{surface_vertices}" if builtin else character,
                                [q for q, _ in kept], skins)
    return {"character": character, "surface_vertices": surface_vertices, "weights": weights,
            "motion": bvh or clip or "built-in", "rate_hz": rate,
            "seconds": seconds, "node_ready_s": ready_s, "inputs": sent, "outputs": len(lat),
            "latency_ms_p50": float(np.percentile(L, 50)),
            "latency_ms_p99": float(np.percentile(L, 99)),
            "latency_ms_max": float(np.max(L)),
            # the first pose after the node said it was ready (NaN: not answered)
            "first_pose_ms": float(first.get("ms", np.nan)),
            "skipped_stale": int(diag.get("frames_skipped_stale", -1)),
            "node_received": int(diag.get("frames_received", -1)),
            "node_ms_per_frame": float(diag.get("ms_per_frame", "nan")),
            "node_rss_mb": rss_mb, "node_exit_code": proc.returncode,
            # correction:=carried: how many poses old the published corrections were
            **({"correction_lag_mean": sum(f * m for f, m, _ in lags)
                / max(sum(f for f, _, _ in lags), 1.0),
                "correction_lag_max": max(x for _, _, x in lags)} if lags else {}),
            "domain_id": domain, "params": list(params or []), **quality}


def latency_line(lat: dict) -> str:
    """One line of a :func:`measure_latency` result (the report's and ``main``'s)."""
    scene = (f"{lat['character']}:{lat['surface_vertices']}" if lat["surface_vertices"] else
             f"{Path(lat['character']).name}, {lat.get('weights', 'automatic')} weights")
    if lat.get("motion", "built-in") != "built-in":
        scene += f", {Path(lat['motion']).name}"
    return (f"ROS latency ({scene}, {lat['rate_hz']:.0f} Hz "
            f"for {lat['seconds']:.0f} s): p50 {lat['latency_ms_p50']:.1f} ms, p99 "
            f"{lat['latency_ms_p99']:.1f} ms, "
            f"first pose {lat.get('first_pose_ms', np.nan):.1f} ms, "
            f"{lat['outputs']} outputs for {lat['inputs']} inputs, "
            f"node skipped {lat['skipped_stale']} as stale"
            + (f", node resident {lat['node_rss_mb']:.0f} MB"
               if np.isfinite(lat.get("node_rss_mb", np.nan)) else "")
            + (f", correction {lat['correction_lag_mean']:.1f} poses old on average "
               f"(at most {lat['correction_lag_max']})" if "correction_lag_mean" in lat else "")
            + (f"; {lat['frames_measured']} published skins measured: exact pairs "
               f"{lat['answer_pairs']} (the solved skin's {lat['solved_pairs']}, DQS's "
               f"{lat['dqs_pairs']}), folds90 {lat['answer_folds90']} ({lat['solved_folds90']}, "
               f"{lat['dqs_folds90']}), roughness {lat['answer_roughness']:.3f} "
               f"({lat['solved_roughness']:.3f}, {lat['dqs_roughness']:.3f}), farthest vertex "
               f"from the solved skin {lat['dev_median_mm']:.1f} mm at the median frame"
               if "frames_measured" in lat else "")
            + (f" ({', '.join(lat['params'])})" if lat.get("params") else ""))


def main(argv: list | None = None) -> int:
    ap = argparse.ArgumentParser(prog="skin_bench ros-latency", description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--rate", type=float, default=120.0)
    ap.add_argument("--character", default="humanoid")
    ap.add_argument("--surface-vertices", type=int, default=24000,
                    help="of a built-in character")
    ap.add_argument("--weights", default="automatic", choices=("automatic", "file"))
    ap.add_argument("--bvh", default="", help="play this BVH, retargeted to the character")
    ap.add_argument("--clip", default="", help="play this clip of the character's "
                    "(default: its first, the walk for the built-in humanoid)")
    ap.add_argument("--domain", type=int, default=None,
                    help="ROS_DOMAIN_ID (default: a free one of $SKIN_NODE_DOMAINS, else 10-99)")
    ap.add_argument("--out", default="", help="write the result as JSON here")
    ap.add_argument("--param", action="append", default=[], metavar="NAME:=VALUE",
                    help="a node parameter, e.g. --param threads:=2 (repeatable)")
    ap.add_argument("--measure-every", type=int, default=0, metavar="N",
                    help="grade every N-th published skin (at most 120) against the solved "
                         "skin and DQS: exact pairs, folds, roughness, distance")
    a = ap.parse_args(argv)
    bad = [p for p in a.param if ":=" not in p]
    if bad:
        ap.error(f"--param takes NAME:=VALUE, got {bad}")
    try:
        res = measure_latency(a.seconds, a.rate, a.character, a.surface_vertices, a.domain,
                              params=a.param, weights=a.weights, bvh=a.bvh, clip=a.clip,
                              measure_every=a.measure_every)
    except (OSError, ValueError, RuntimeError) as e:
        print(f"skin_bench ros-latency: error: {e}", file=sys.stderr)
        return 2
    text = json.dumps(res, indent=1)
    if a.out:
        with open(a.out, "w") as f:
            f.write(text + "\n")
    print(text)
    print(latency_line(res))
    return 0
