"""A pipeline in a process of its own (``skin_node.remote``): the same skin as
in this process, bitwise, and a child that never outlives its caller."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from skin_node import DEFAULT_STAGES, Pipeline, load_character, make_clip
from skin_node.remote import RemoteError, RemotePipeline

ARM = {"spec": "arm", "surface_vertices": 2000}


@pytest.fixture(scope="module")
def arm():
    return load_character("arm", surface_vertices=2000, progress=False)


@pytest.fixture(scope="module")
def remote(arm):
    with RemotePipeline(arm, ARM, DEFAULT_STAGES) as pipe:
        yield pipe


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def _wait_gone(pid: int, seconds: float) -> bool:
    deadline = time.monotonic() + seconds
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    return not _alive(pid)


def test_the_child_deforms_bitwise_what_this_process_does(arm, remote):
    local = Pipeline(arm)
    frames = make_clip("elbow_bend", arm.skeleton).frames[::6]
    moved = 0.0
    for q in frames:
        V = remote.deform(q)
        assert V.shape == (len(arm.surface_V), 3)
        assert np.array_equal(V, local.deform(q))
        moved = max(moved, float(np.abs(V - arm.surface_V).max()))
    assert moved > 0.05, "the clip must bend the arm for the comparison to mean anything"
    assert set(remote.timings) >= {"fk", "dqs", "contact", "total"}
    assert remote.timings["total"] > 0.0


def test_bad_requests_are_value_errors_and_the_child_answers_on(arm, remote):
    q = arm.skeleton.rest_pose()
    with pytest.raises(ValueError, match="NaN"):
        remote.deform(np.full_like(q, np.nan))
    with pytest.raises(ValueError, match="shape"):
        remote.deform(q[:-1])
    with pytest.raises(ValueError, match="contact_rounds"):
        remote.set_params(contact_rounds=-1)
    with pytest.raises(ValueError, match="unknown stage"):
        remote.set_stages(["dqs", "wobble"], **remote.params)
    assert remote.stage_names == list(DEFAULT_STAGES)
    assert np.array_equal(remote.deform(q), Pipeline(arm).deform(q))
    assert remote.restarts == 0


def test_parameters_and_stages_change_in_the_child(arm, remote):
    q = arm.pose(elbow_rz=2.4)
    try:
        remote.set_params(contact_rounds=1, bulge_limit=0.3)
        assert np.array_equal(remote.deform(q),
                              Pipeline(arm, contact_rounds=1, bulge_limit=0.3).deform(q))
        params = dict(remote.params)
        remote.set_stages(["dqs", "bulge"], **params)
        assert np.array_equal(remote.deform(q), Pipeline(arm, ["dqs", "bulge"], **params).deform(q))
        assert set(remote.timings) == {"fk", "dqs", "bulge", "total"}
    finally:
        remote.set_stages(DEFAULT_STAGES, **{**remote.params, "contact_rounds": 4,
                                             "bulge_limit": 0.1})


def test_a_child_killed_mid_run_fails_one_frame_and_is_started_again(arm):
    q = arm.pose(elbow_rz=2.0)
    with RemotePipeline(arm, ARM, ["dqs", "bulge"]) as pipe:
        pipe.set_params(bulge_limit=0.2)
        first = pipe.deform(q)
        pid = pipe.pid
        os.kill(pid, signal.SIGKILL)
        assert _wait_gone(pid, 5.0)
        with pytest.raises(RemoteError, match="exited"):
            pipe.deform(q)
        again = pipe.deform(q)            # a new child, with the settings the old one had
        assert pipe.restarts == 1 and pipe.pid != pid
        assert np.array_equal(again, first)
        child = pipe.pid
    assert _wait_gone(child, 5.0), "close() must end the child"


def test_the_child_ends_when_its_caller_dies():
    code = (
        "import os, sys\n"
        "from skin_node import load_character\n"
        "from skin_node.remote import RemotePipeline\n"
        "ch = load_character('arm', surface_vertices=2000, progress=False)\n"
        "pipe = RemotePipeline(ch, {'spec': 'arm', 'surface_vertices': 2000}, ['dqs'])\n"
        "print(pipe.pid, flush=True)\n"
        "os._exit(0)\n")          # no close(), no atexit: as if killed
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=600, cwd=os.path.dirname(__file__))
    assert res.returncode == 0, res.stderr
    child = int(res.stdout.split()[-1])
    assert _wait_gone(child, 10.0), "an orphaned deform process kept running"


def test_a_bad_set_up_in_the_child_is_an_error_here(arm):
    with pytest.raises(ValueError, match="unknown parameter"):
        RemotePipeline(arm, ARM, ["dqs"], wobble=1)
    with pytest.raises(ValueError, match=r"5982 vertices here, 12 and 2018 in the calling"):
        RemotePipeline(arm, {"spec": "arm"}, ["dqs"])     # not the character given
