"""Pipeline.warm_up, which the node and the benchmark share: it leaves the
parameters as they were and forgets what its frames carried."""
import numpy as np
import pytest

from skin_node import Pipeline, load_character

STAGES = ["dqs", "pbd", "collision", "volume", "smooth"]


@pytest.fixture(scope="module")
def arm():
    return load_character("arm", surface_vertices=2000, tet_count=3000, progress=False)


def test_warm_up_keeps_the_parameters_and_forgets_its_frames(arm):
    """Warm-started, the solve carries its history from frame to frame; after
    the warm-up a pipeline deforms as a fresh one does."""
    pipe = Pipeline(arm, STAGES, warm_start=True, volume_checked_below=0.3)
    q = arm.pose(elbow_rz=np.radians(140))
    seconds = pipe.warm_up([q, arm.pose(elbow_rz=np.radians(60))])
    assert seconds > 0.0
    assert pipe.params["volume_checked_below"] == 0.3 and pipe.params["warm_start"] is True
    fresh = Pipeline(arm, STAGES, warm_start=True, volume_checked_below=0.3)
    for _ in range(2):
        assert np.array_equal(pipe.deform(q), fresh.deform(q))


def test_warm_up_bends_every_joint_to_its_limits(arm, monkeypatch):
    """The poses it deforms: the limits' middle, each channel bent 1 rad within
    its limits and at its upper limit (checked swelling forced), the poses
    given, then rest."""
    pipe = Pipeline(arm, ["lbs"])
    seen = []
    deform = pipe.deform

    def spy(q):
        seen.append((np.array(q), pipe.params["volume_checked_below"]))
        return deform(q)
    monkeypatch.setattr(pipe, "deform", spy)
    extra = arm.pose(elbow_rz=0.5)
    own = pipe.params["volume_checked_below"]
    pipe.warm_up([extra])
    limits = arm.skeleton.limits
    assert [below for _, below in seen] == [0.0, 0.0, 0.0, own, own]
    q = [x for x, _ in seen]
    assert np.array_equal(q[0][3:], limits.mean(axis=-1).ravel())
    assert np.array_equal(q[1][3:], np.clip(1.0, limits[..., 0], limits[..., 1]).ravel())
    assert np.array_equal(q[2][3:], limits[..., 1].ravel())
    assert np.array_equal(q[3], extra) and not q[4].any()
