"""Procedural built-in characters: counts, closedness, determinism, rigs."""
import numpy as np
import pytest
import trimesh

from skin_node.builtin.characters import (BUILTIN_CHARACTERS, DEFAULT_SURFACE_VERTICES,
                                          make_arm, make_humanoid)

HUMANOID_JOINTS = ["pelvis", "spine", "chest", "neck", "head",
                   "l_shoulder", "l_elbow", "l_wrist", "r_shoulder", "r_elbow", "r_wrist",
                   "l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle"]


def winding_number(V: np.ndarray, F: np.ndarray, P: np.ndarray) -> np.ndarray:
    """Generalized winding number (k,) of points P (k, 3) w.r.t. mesh (V, F)."""
    out = np.empty(len(P))
    for i, p in enumerate(P):
        a, b, c = (V[F[:, k]] - p for k in range(3))
        la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
        det = np.einsum("ij,ij->i", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("ij,ij->i", a, b) * lc
               + np.einsum("ij,ij->i", b, c) * la + np.einsum("ij,ij->i", c, a) * lb)
        out[i] = np.arctan2(det, den).sum() / (2.0 * np.pi)
    return out


def assert_closed_genus0(V, F):
    assert V.dtype == np.float64 and V.ndim == 2 and V.shape[1] == 3
    assert F.dtype == np.int64 and F.ndim == 2 and F.shape[1] == 3
    m = trimesh.Trimesh(V, F, process=False)
    assert m.is_watertight
    assert m.is_winding_consistent
    assert m.volume > 0
    assert m.euler_number == 2
    assert len(np.unique(F)) == len(V)          # no unreferenced vertices


@pytest.fixture(scope="module")
def humanoid():
    return make_humanoid()


# ------------------------------------------------------------------- arm
@pytest.mark.parametrize("target", [500, 2000, 6000, 24000])
def test_arm_vertex_count_and_closed(target):
    V, F, _ = make_arm(target)
    assert abs(len(V) / target - 1.0) < 0.05
    assert_closed_genus0(V, F)


def test_arm_shape_and_determinism():
    V, F, sk = make_arm()
    V2, F2, _ = make_arm()
    assert np.array_equal(V, V2) and np.array_equal(F, F2)
    assert V[:, 0].min() == pytest.approx(0.0, abs=1e-12)
    assert V[:, 0].max() == pytest.approx(0.6, abs=1e-12)
    mid = (V[:, 0] >= 0.05) & (V[:, 0] <= 0.55)
    assert mid.sum() > 0.8 * len(V)
    r = np.hypot(V[mid, 1], V[mid, 2])
    assert np.allclose(r, 0.05, rtol=0.01)
    assert np.hypot(V[:, 1], V[:, 2]).max() <= 0.05 + 1e-12
    m = trimesh.Trimesh(V, F, process=False)
    # Close to a 0.6 m cylinder minus the rounding of the ends.
    assert 0.95 * np.pi * 0.05 ** 2 * 0.6 < m.volume < np.pi * 0.05 ** 2 * 0.6


def test_arm_skeleton():
    V, F, sk = make_arm(2000)
    assert sk.names == ["shoulder", "elbow", "wrist"]
    assert list(sk.parents) == [-1, 0, 1]
    assert np.allclose(sk.rest_positions, [[0, 0, 0], [0.27, 0, 0], [0.5, 0, 0]])
    assert np.allclose(sk.tips[2], [0.6, 0, 0])
    e, w = sk.index("elbow"), sk.index("wrist")
    assert sk.limits[e, 2, 0] == 0.0 and 2.5 <= sk.limits[e, 2, 1] <= 2.8
    assert np.allclose(sk.limits[w, 0], [-np.pi, np.pi])
    # Elbow and wrist are inside; the shoulder and the hand tip sit on the poles.
    assert np.all(winding_number(V, F, sk.rest_positions[1:]) > 0.99)
    for p in (sk.rest_positions[0], sk.tips[2]):
        assert np.linalg.norm(V - p, axis=1).min() < 1e-12


# -------------------------------------------------------------- humanoid
def test_humanoid_default(humanoid):
    V, F, sk = humanoid
    assert abs(len(V) / DEFAULT_SURFACE_VERTICES["humanoid"] - 1.0) < 0.05
    assert_closed_genus0(V, F)
    assert V[:, 2].min() == pytest.approx(0.0, abs=1e-12)
    assert 1.70 < V[:, 2].max() < 1.80
    # T-pose: arms reach out along +-y about as far as the body is tall.
    assert 0.8 < V[:, 1].max() < 0.95 and -0.95 < V[:, 1].min() < -0.8
    # Facing +x: the toes stick out in front.
    assert V[:, 0].max() > 0.15 and V[:, 0].min() > -0.15


def test_humanoid_skeleton(humanoid):
    V, F, sk = humanoid
    assert sk.names == HUMANOID_JOINTS
    assert sk.n_joints == 17
    P = {n: sk.rest_positions[sk.index(n)] for n in sk.names}
    assert P["l_shoulder"][1] > 0.1 and P["r_shoulder"][1] < -0.1      # left = +y
    assert P["pelvis"][2] == pytest.approx(P["l_hip"][2], abs=0.05)     # root at hip height
    leg = P["l_hip"][2] - P["l_ankle"][2]
    assert abs(P["l_knee"][2] - (P["l_ankle"][2] + 0.5 * leg)) < 0.05 * leg
    assert P["l_elbow"][1] < P["l_wrist"][1] and P["r_elbow"][1] > P["r_wrist"][1]
    leaves = [j for j in range(17) if not sk.children(j)]
    assert sorted(sk.names[j] for j in leaves) == sorted(
        ["head", "l_wrist", "r_wrist", "l_ankle", "r_ankle"])
    knee = sk.index("l_knee")
    assert sk.limits[knee, 1, 0] == 0.0 and sk.limits[knee, 1, 1] >= 2.5
    # Positive knee ry folds the shin backward: the ankle moves toward -x.
    G = sk.world_matrices(sk.pose(l_knee_ry=1.0))
    assert G[sk.index("l_ankle"), 0, 3] < P["l_knee"][0] - 0.2
    # Every joint and leaf tip is inside the body; tips are near its ends.
    tips = sk.tips[leaves]
    w = winding_number(V, F, np.vstack([sk.rest_positions, tips]))
    assert np.all(w > 0.99)
    dist = np.array([np.linalg.norm(V - t, axis=1).min() for t in tips])
    assert np.all(dist < 0.06)


@pytest.mark.parametrize("target", [3000, 12000])
def test_humanoid_vertex_count(target):
    V, F, sk = make_humanoid(target)
    assert abs(len(V) / target - 1.0) < 0.05
    assert_closed_genus0(V, F)
    assert np.all(winding_number(V, F, sk.rest_positions) > 0.99)


def test_humanoid_deterministic():
    a = make_humanoid(3000)
    b = make_humanoid(3000)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert np.array_equal(a[2].rest_positions, b[2].rest_positions)


def test_registry():
    assert set(BUILTIN_CHARACTERS) == set(DEFAULT_SURFACE_VERTICES) == {"arm", "humanoid"}
    assert BUILTIN_CHARACTERS["arm"] is make_arm
    assert BUILTIN_CHARACTERS["humanoid"] is make_humanoid
    with pytest.raises(ValueError):
        make_humanoid(100)
