"""Stress the ROS side: repeated integration test runs and replays into one node.

Two parts, each optional:

1. ``--test-runs N`` (default 10): ``pytest test/test_node_integration.py``
   N times in a row; counts failed runs, failed tests and aborts
   ("terminate called" in the output, or an exit status of -6 / 134).
2. ``--replays N`` (default 100): one ``skin_node`` (the arm, the example name
   map), and N consecutive ``skin_bag`` replays of the same bag into it; counts
   aborts, non-zero exits, and the skins each replay recorded. Every replay
   after the first goes back in time by the bag's length, so the node must
   take each one for a restart (``time_jumps_back``). The node must then stop
   with status 0 on SIGTERM.

Not part of the default test run: it takes about an hour on two cores. Run it
after set-up, from the repository root::

    bash tools/setup.sh && . tools/env.sh
    python tools/stress.py                       # both parts
    python tools/stress.py --test-runs 0 --replays 20

The bag defaults to the shared PR2 recording (first ``--limit`` 150
messages); without it, a generated arm bag is replayed. The last line is the
summary; the exit status is 0 only when nothing aborted, every process exited
as documented and every replay was skinned.
"""
from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PR2_BAG = REPO.parent / "shared" / "data" / "bags" / "pr2_joint_states_mcap"
NAME_MAP = REPO / "config" / "name_map_example.yaml"
ABORTED = (-6, 134)          # SIGABRT, as Popen and as a shell report it
sys.path.append(str(REPO))


def _env(domain: int | None = None) -> dict:
    env = dict(os.environ, ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST", PYTHONUNBUFFERED="1",
               RCUTILS_LOGGING_BUFFERED_STREAM="0")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [env.get("PYTHONPATH"), str(REPO)]))
    if domain is not None:
        env["ROS_DOMAIN_ID"] = str(domain)
    return env


def run_tests(runs: int) -> dict:
    """The node integration tests ``runs`` times in a row."""
    failed_runs, failed_tests, aborts = 0, {}, 0
    for k in range(runs):
        t0 = time.monotonic()
        res = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                              "test/test_node_integration.py"], cwd=REPO, env=_env(),
                             capture_output=True, text=True)
        out = res.stdout + res.stderr
        n_abort = out.count("terminate called") + len(re.findall(r"exited -6\b", out))
        aborts += n_abort
        names = re.findall(r"^FAILED (\S+)", out, re.M)
        for name in names:
            failed_tests[name] = failed_tests.get(name, 0) + 1
        failed_runs += res.returncode != 0
        tail = out.strip().splitlines()[-1] if out.strip() else "(no output)"
        print(f"stress: test run {k + 1}/{runs}: exit {res.returncode}, {tail.strip('= ')}"
              f" ({time.monotonic() - t0:.0f} s){f', {n_abort} aborts' if n_abort else ''}",
              flush=True)
        for name in names:
            print(f"stress:   failed {name}", flush=True)
    return {"runs": runs, "failed_runs": failed_runs, "failed_tests": failed_tests,
            "aborts": aborts}


def _generated_bag(path: Path) -> Path:
    """150 arm poses at 100 Hz, like the PR2 excerpt, when the PR2 bag is absent."""
    import numpy as np
    from rclpy.serialization import serialize_message
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from msg_adapters import channels_to_joint_state
    from skin_node.player import character_skeleton

    names = character_skeleton("arm").channel_names
    with Writer(path, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection("/joint_states", "sensor_msgs/msg/JointState",
                                     typestore=get_typestore(Stores.ROS2_JAZZY))
        for i in range(150):
            t = 10**9 + i * 10**7
            q = np.zeros(len(names))
            q[names.index("elbow_rz")] = 1.2 * (1 - np.cos(2 * np.pi * i / 60))
            msg = channels_to_joint_state(names, q)
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(t, 10**9)
            writer.write(conn, t, serialize_message(msg))
    return path


def _last_diagnostics(bag: Path) -> dict:
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.serialization import deserialize_message
    from rosbags.rosbag2 import Reader

    from msg_adapters import diagnostic_values

    last = None
    with Reader(bag) as reader:
        for conn, _, raw in reader.messages():
            if conn.topic == "/skin/diagnostics":
                last = raw
    return diagnostic_values(deserialize_message(bytes(last), DiagnosticArray)) if last else {}


def run_replays(replays: int, bag: Path | None, limit: int, work: Path) -> dict:
    """``replays`` skin_bag replays of one bag into one node."""
    from skin_node.processes import command as _command, stop, wait_for_log
    from skin_node.ros_domain import claim_domain

    node_args = ["--ros-args", "-p", "character:=arm", "-p", "surface_vertices:=2000"]
    if bag is None:
        bag = _generated_bag(work / "arm_bag")
        print(f"stress: {PR2_BAG} not found; replaying a generated arm bag", flush=True)
    else:
        node_args += ["-p", f"name_map:={NAME_MAP}"]
    codes, skins, aborts, diag = [], [], 0, {}
    with claim_domain() as claim:
        env = _env(claim.domain)
        log = work / "node.log"
        with open(log, "w") as out:
            node = subprocess.Popen(_command("skin_node", "skin_node.node") + node_args,
                                    stdout=out, stderr=subprocess.STDOUT, env=env, cwd=REPO)
        try:
            wait_for_log(node, log, "]: ready in", 300.0)
            print(f"stress: skin_node ready on domain {claim.domain}; {replays} replays of "
                  f"{bag} (first {limit} messages)", flush=True)
            for k in range(replays):
                out_bag = work / f"replay{k}"
                res = subprocess.run(
                    _command("skin_bag", "skin_node.bag_tool")
                    + [str(bag), str(out_bag), "--limit", str(limit), "--linger", "1.2"],
                    env=env, cwd=REPO, capture_output=True, text=True, timeout=300)
                m = re.search(r"recorded skin/points (\d+)", res.stdout)
                n = int(m[1]) if m else 0
                codes.append(res.returncode)
                skins.append(n)
                aborted = res.returncode in ABORTED or "terminate called" in res.stderr
                aborts += aborted
                print(f"stress: replay {k + 1}/{replays}: exit {res.returncode}, {n} skins"
                      f"{' ABORTED' if aborted else ''}"
                      f"{'' if res.returncode == 0 else ': ' + res.stderr.strip()[-300:]}",
                      flush=True)
                if k == replays - 1 and out_bag.exists():
                    diag = _last_diagnostics(out_bag)
                shutil.rmtree(out_bag, ignore_errors=True)
        finally:
            stop(node, signal.SIGTERM, 10.0)
    print(f"stress: skin_node exited {node.returncode} on SIGTERM", flush=True)
    return {"replays": replays, "aborts": aborts,
            "nonzero": sum(c != 0 for c in codes), "unskinned": sum(n == 0 for n in skins),
            "skins_min": min(skins, default=0), "skins_median": statistics.median(skins or [0]),
            "skins_max": max(skins, default=0), "skins_total": sum(skins),
            "node_exit": node.returncode,
            "time_jumps_back": diag.get("time_jumps_back", "?"),
            "rejected_total": diag.get("rejected_total", "?")}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="tools/stress.py", description=__doc__.splitlines()[0])
    ap.add_argument("--test-runs", type=int, default=10, metavar="N")
    ap.add_argument("--replays", type=int, default=100, metavar="N")
    ap.add_argument("--bag", type=Path, default=None,
                    help=f"bag to replay (default: {PR2_BAG}, else a generated arm bag)")
    ap.add_argument("--limit", type=int, default=150, help="messages of the bag per replay")
    a = ap.parse_args(argv)
    if a.test_runs < 0 or a.replays < 0 or a.limit <= 0:
        ap.error("--test-runs and --replays must be >= 0, --limit > 0")
    bag = a.bag or (PR2_BAG if (PR2_BAG / "metadata.yaml").exists() else None)
    t0 = time.monotonic()
    summary, ok = [], True
    if a.test_runs:
        t = run_tests(a.test_runs)
        ok &= t["failed_runs"] == 0 and t["aborts"] == 0
        summary.append(f"tests: {a.test_runs - t['failed_runs']}/{a.test_runs} runs passed, "
                       f"{t['aborts']} aborts, failed tests {t['failed_tests'] or 'none'}")
    if a.replays:
        with tempfile.TemporaryDirectory(prefix="skin_stress_") as work:
            r = run_replays(a.replays, bag, a.limit, Path(work))
        ok &= r["aborts"] == r["nonzero"] == r["unskinned"] == 0 and r["node_exit"] == 0
        summary.append(
            f"replays: {r['replays']}, {r['aborts']} aborts, {r['nonzero']} non-zero exits, "
            f"{r['unskinned']} unskinned; skins per replay min {r['skins_min']} median "
            f"{r['skins_median']:g} max {r['skins_max']} (total {r['skins_total']}); node "
            f"time_jumps_back {r['time_jumps_back']}, rejected {r['rejected_total']}, "
            f"exit {r['node_exit']}")
    print(f"stress: {'PASS' if ok else 'FAIL'} in {time.monotonic() - t0:.0f} s | "
          + " | ".join(summary), flush=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
