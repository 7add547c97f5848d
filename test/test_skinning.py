"""Stage 1 (LBS, DQS), dual quaternions and the skeleton's kinematics."""
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from skin_node.character import load_character
from skin_node.kernels import skinning as solver
from skin_node.pipeline import Pipeline
from skin_node.skeleton import Skeleton, euler_xyz_to_matrix, matrix_to_euler_xyz
from skin_node.kernels.skinning import matrices_to_dual_quaternions


@pytest.fixture(scope="module")
def arm():
    return load_character("arm", surface_vertices=2000, tet_count=3000, progress=False)


def rigid(R, t):
    M = np.eye(4)
    M[:3, :3] = R
    M[:3, 3] = t
    return M


def rigid_pose(ch, rng):
    """A pose that moves only the root (translation and rotation): a rigid motion."""
    q = ch.skeleton.rest_pose()
    q[:3] = rng.uniform(-0.5, 0.5, 3)
    q[3:6] = rng.uniform(-np.pi, np.pi, 3) * np.array([1.0, 0.45, 1.0])
    return q


def root_motion(skel, q):
    """(R, t) of the root's world matrix applied to rest points: G0 @ inv(B0)."""
    M0 = skel.world_matrices(q)[0] @ np.linalg.inv(skel.bind[0])
    return M0[:3, :3], M0[:3, 3]


# ============================================================ LBS
@pytest.mark.parametrize("stage", ["lbs", "dqs"])
def test_rest_pose_returns_rest_mesh(arm, stage):
    V = Pipeline(arm, [stage]).deform(arm.skeleton.rest_pose())
    assert V.shape == arm.V.shape
    assert np.abs(V - arm.V).max() < 1e-12


def test_rest_skinning_matrices_are_identity(arm):
    M = arm.skeleton.skinning_matrices(arm.skeleton.rest_pose())
    assert np.abs(M - np.eye(4)).max() < 1e-12


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("stage", ["lbs", "dqs"])
def test_root_motion_moves_mesh_rigidly(arm, stage, seed):
    """Root translation plus root rotation, every other channel zero: V' = R V + t."""
    q = rigid_pose(arm, np.random.default_rng(seed))
    R, t = root_motion(arm.skeleton, q)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
    # the root's world matrix is T(root_t) R(q_root) (root at the origin at rest)
    assert np.allclose(R, euler_xyz_to_matrix(q[3:6]), atol=1e-12)
    p0 = arm.skeleton.rest_positions[0]
    assert np.allclose(t, q[:3] + p0 - R @ p0, atol=1e-12)
    V = Pipeline(arm, [stage]).deform(q)
    expect = arm.V @ R.T + t
    assert np.abs(V - expect).max() < 1e-9
    assert np.abs(V - arm.V).max() > 0.01          # it really moved


@pytest.mark.parametrize("seed", [0, 1])
def test_root_motion_moves_tet_mesh_rigidly(arm, seed):
    q = rigid_pose(arm, np.random.default_rng(seed))
    R, t = root_motion(arm.skeleton, q)
    M = np.ascontiguousarray(arm.skeleton.skinning_matrices(q))
    r = arm.rig
    out = np.empty_like(r.TV)
    solver.lbs(r.TV, r.TWidx, r.TWval, M, out)
    assert np.abs(out - (r.TV @ R.T + t)).max() < 1e-9


def test_lbs_matches_numpy_reference(arm):
    """v' = sum_j w_ij M_j v against a dense numpy evaluation, on a bent pose."""
    q = arm.pose(elbow_rz=1.3, wrist_rx=0.7, shoulder_ry=0.2, root_tx=0.1)
    M = np.ascontiguousarray(arm.skeleton.skinning_matrices(q))
    r = arm.rig
    out = np.empty_like(arm.V)
    solver.lbs(arm.V, r.Widx, r.Wval, M, out)
    Vh = np.c_[arm.V, np.ones(len(arm.V))]
    ref = np.einsum("nk,nkij,nj->ni", r.Wval, M[r.Widx], Vh)[:, :3]
    assert np.abs(out - ref).max() < 1e-12


# ============================================================ DQS
def random_rigid(rng, J):
    R = Rotation.random(J, random_state=rng.integers(1 << 31)).as_matrix()
    t = rng.uniform(-1, 1, (J, 3))
    return np.stack([rigid(R[j], t[j]) for j in range(J)])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_dqs_equals_lbs_for_single_bone_vertices(seed):
    rng = np.random.default_rng(seed)
    J, n, K = 5, 200, 3
    M = random_rigid(rng, J)
    V = rng.uniform(-0.5, 0.5, (n, 3))
    Widx = np.zeros((n, K), dtype=np.int64)
    Widx[:, 0] = rng.integers(0, J, n)
    Widx[:, 1] = rng.integers(0, J, n)          # padding indices with zero weight
    Wval = np.zeros((n, K))
    Wval[:, 0] = 1.0
    lb, dq = np.empty((n, 3)), np.empty((n, 3))
    solver.lbs(V, Widx, Wval, M, lb)
    solver.dqs(V, Widx, Wval, matrices_to_dual_quaternions(M), dq)
    assert np.abs(dq - lb).max() < 1e-9
    ref = np.einsum("nij,nj->ni", M[Widx[:, 0], :3, :3], V) + M[Widx[:, 0], :3, 3]
    assert np.abs(dq - ref).max() < 1e-9


def quat_to_matrix(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def qmul(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return np.array([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                     w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                     w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2])


def special_rotations():
    """180-degree turns (trace -1: every Shepperd branch but the first) and near-identity."""
    axes = [[1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, -2, 3], [0, 1, -1]]
    R = [Rotation.from_rotvec(np.pi * np.array(a, float) / np.linalg.norm(a)).as_matrix()
         for a in axes]
    R += [np.eye(3), Rotation.from_rotvec([1e-9, -2e-9, 0.0]).as_matrix(),
          Rotation.from_rotvec([0.0, 0.0, np.pi - 1e-7]).as_matrix()]
    return np.array(R)


def test_dual_quaternion_round_trip():
    rng = np.random.default_rng(5)
    R = np.concatenate([Rotation.random(50, random_state=3).as_matrix(), special_rotations()])
    t = rng.uniform(-2, 2, (len(R), 3))
    M = np.stack([rigid(R[j], t[j]) for j in range(len(R))])
    Q = matrices_to_dual_quaternions(M)
    assert Q.shape == (len(R), 8)
    real, dual = Q[:, :4], Q[:, 4:]
    assert np.allclose(np.linalg.norm(real, axis=1), 1.0, atol=1e-12)
    assert np.abs(np.einsum("ij,ij->i", real, dual)).max() < 1e-12     # unit dual quaternion
    for j in range(len(R)):
        assert np.abs(quat_to_matrix(real[j]) - R[j]).max() < 1e-12, j
        conj = real[j] * np.array([1, -1, -1, -1])
        tt = 2.0 * qmul(dual[j], conj)
        assert abs(tt[0]) < 1e-12
        assert np.abs(tt[1:] - t[j]).max() < 1e-12, j


def test_dqs_applies_transform_of_each_dual_quaternion():
    """Round trip through the kernel: every bone, one vertex each, incl. 180-degree turns."""
    R = special_rotations()
    t = np.random.default_rng(1).uniform(-1, 1, (len(R), 3))
    M = np.stack([rigid(R[j], t[j]) for j in range(len(R))])
    V = np.random.default_rng(2).uniform(-1, 1, (len(R), 3))
    Widx = np.arange(len(R), dtype=np.int64)[:, None]
    Wval = np.ones((len(R), 1))
    out = np.empty_like(V)
    solver.dqs(V, Widx, Wval, matrices_to_dual_quaternions(M), out)
    ref = np.einsum("nij,nj->ni", R, V) + t
    assert np.abs(out - ref).max() < 1e-12


@pytest.mark.parametrize("angle", [np.pi, np.pi - 1e-6, np.pi + 1e-6])
def test_dqs_keeps_radius_at_half_turn_twist_lbs_collapses(angle):
    """Two bones along x, the second twisted by ~180 degrees, weights 50/50:
    LBS maps the ring onto the axis, DQS keeps its radius."""
    r = 0.05
    phi = np.linspace(0, 2 * np.pi, 24, endpoint=False)
    V = np.c_[np.full(len(phi), 0.3), r * np.cos(phi), r * np.sin(phi)]
    M = np.stack([np.eye(4), rigid(Rotation.from_rotvec([angle, 0, 0]).as_matrix(), [0, 0, 0])])
    Widx = np.tile(np.array([0, 1], dtype=np.int64), (len(V), 1))
    Wval = np.full((len(V), 2), 0.5)
    lb, dq = np.empty_like(V), np.empty_like(V)
    solver.lbs(V, Widx, Wval, M, lb)
    solver.dqs(V, Widx, Wval, matrices_to_dual_quaternions(M), dq)
    assert np.hypot(lb[:, 1], lb[:, 2]).max() < 1e-5
    assert np.allclose(np.hypot(dq[:, 1], dq[:, 2]), r, atol=1e-9)
    assert np.allclose(dq[:, 0], 0.3, atol=1e-12)
    # DQS is the quarter turn (half of the twist), with the sign of the shorter way
    ang = np.angle((dq[:, 1] + 1j * dq[:, 2]) / (V[:, 1] + 1j * V[:, 2]))
    expect = angle / 2 if angle <= np.pi else (angle - 2 * np.pi) / 2
    assert np.allclose(ang, expect, atol=1e-6)


def test_arm_wrist_twist_dqs_no_candy_wrapper(arm):
    q = arm.pose(wrist_rx=np.pi)
    ring = (arm.V[:, 0] > 0.48) & (arm.V[:, 0] < 0.52)
    assert ring.sum() > 10
    lb = Pipeline(arm, ["lbs"]).deform(q)
    dq = Pipeline(arm, ["dqs"]).deform(q)
    r_lb = np.hypot(lb[ring, 1], lb[ring, 2])
    r_dq = np.hypot(dq[ring, 1], dq[ring, 2])
    assert r_lb.min() < 0.005                         # LBS collapses towards the axis
    assert np.allclose(r_dq, 0.05, atol=1e-6)         # DQS keeps the arm's radius


# ============================================================ skeleton
def test_euler_round_trip():
    rng = np.random.default_rng(0)
    half = np.pi / 2 - 1e-3
    a = np.c_[rng.uniform(-np.pi, np.pi, 500), rng.uniform(-half, half, 500),
              rng.uniform(-np.pi, np.pi, 500)]
    R = euler_xyz_to_matrix(a)
    assert R.shape == (500, 3, 3)
    assert np.allclose(np.einsum("nij,nkj->nik", R, R), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(R), 1.0, atol=1e-12)
    assert np.abs(matrix_to_euler_xyz(R) - a).max() < 1e-9
    # R = Rz @ Ry @ Rx (x applied first)
    ref = Rotation.from_euler("xyz", a).as_matrix()        # extrinsic x, then y, then z
    assert np.abs(R - ref).max() < 1e-12
    # any rotation matrix (also gimbal lock) comes back as itself
    Rr = np.concatenate([Rotation.random(200, random_state=1).as_matrix(),
                         euler_xyz_to_matrix(np.array([[0.3, np.pi / 2, -0.2],
                                                       [0.1, -np.pi / 2, 0.4]]))])
    assert np.abs(euler_xyz_to_matrix(matrix_to_euler_xyz(Rr)) - Rr).max() < 1e-7


def chain(rest_rotations=None):
    return Skeleton(["a", "b", "c"], [-1, 0, 1], [[0, 0, 0], [1, 0, 0], [2, 0, 0]],
                    rest_rotations=rest_rotations, tips=[[np.nan] * 3, [np.nan] * 3, [3, 0, 0]])


def test_world_matrices_of_a_chain():
    sk = chain()
    assert sk.channel_names == ["root_tx", "root_ty", "root_tz", "a_rx", "a_ry", "a_rz",
                                "b_rx", "b_ry", "b_rz", "c_rx", "c_ry", "c_rz"]
    q = sk.pose(root_tx=0.5, a_rz=np.pi / 2, b_rz=np.pi / 2)
    G = sk.world_matrices(q)
    assert np.allclose(G[:, :3, 3], [[0.5, 0, 0], [0.5, 1, 0], [-0.5, 1, 0]], atol=1e-12)
    Rz = lambda a: euler_xyz_to_matrix(np.array([0, 0, a]))
    assert np.allclose(G[0, :3, :3], Rz(np.pi / 2), atol=1e-12)
    assert np.allclose(G[1, :3, :3], Rz(np.pi), atol=1e-12)
    assert np.allclose(G[2, :3, :3], Rz(np.pi), atol=1e-12)
    # the tip follows the leaf: skinning matrix of c carries (3,0,0) to (-1.5, 1, 0)
    M = sk.skinning_matrices(q)
    assert np.allclose(M[2] @ [3, 0, 0, 1], [-1.5, 1, 0, 1], atol=1e-12)
    # rotation about x of the middle joint turns the last bone about the chain axis only
    G = sk.world_matrices(sk.pose(b_rx=0.7))
    assert np.allclose(G[2, :3, 3], [2, 0, 0], atol=1e-12)


def test_world_matrices_rest_equals_bind_with_rest_rotations():
    rr = Rotation.random(3, random_state=4).as_matrix()
    sk = chain(rr)
    G = sk.world_matrices(sk.rest_pose())
    assert np.abs(G - sk.bind).max() < 1e-12
    assert np.allclose(G[:, :3, 3], sk.rest_positions, atol=1e-12)
    # pose rotations act in the parent's rest frame: b_rz turns c about G_a's z axis
    q = sk.pose(b_rz=0.4)
    G = sk.world_matrices(q)
    axis = G[0, :3, :3][:, 2]                        # a's (the parent's) z axis in world
    d0 = sk.rest_positions[2] - sk.rest_positions[1]
    d1 = G[2, :3, 3] - G[1, :3, 3]
    Rexp = Rotation.from_rotvec(0.4 * axis).as_matrix()
    assert np.allclose(d1, Rexp @ d0, atol=1e-12)


def test_joint_angles():
    sk = chain()
    rv = Rotation.random(3, random_state=2).as_rotvec()
    q = sk.rest_pose()
    q[:3] = [5.0, -3.0, 1.0]                         # root translation is not an angle
    q[3:] = matrix_to_euler_xyz(Rotation.from_rotvec(rv).as_matrix()).ravel()
    assert np.allclose(sk.joint_angles(q), np.linalg.norm(rv, axis=1), atol=1e-9)
    assert np.all(sk.joint_angles(sk.rest_pose()) == 0.0)
    assert sk.joint_angles(sk.pose(b_rz=-1.2))[1] == pytest.approx(1.2, abs=1e-12)
    assert sk.joint_angles(sk.pose(b_rx=np.pi))[1] == pytest.approx(np.pi, abs=1e-7)
    with pytest.raises(ValueError, match="shape"):
        sk.joint_angles(np.zeros(5))


@pytest.mark.parametrize("kwargs, msg", [
    (dict(names=["a", "b", "a"]), "duplicate joint names: \\['a'\\]"),
    (dict(parents=[-1, 2, 1]), "cycle or bad order"),
    (dict(parents=[-1, 1, 1]), "cycle or bad order"),
    (dict(parents=[-1, -1, 1]), "exactly one root"),
    (dict(parents=[0, -1, 1]), "exactly one root"),
    (dict(rest_positions=[[0, 0, 0], [1, np.nan, 0], [2, 0, 0]]), "NaN or Inf"),
    (dict(rest_positions=[[0, 0, 0], [1, np.inf, 0], [2, 0, 0]]), "NaN or Inf"),
    (dict(tips=np.full((3, 3), np.nan)), "leaf joint 'c' needs a finite tip"),
    (dict(parents=[-1, 0, 0], tips=[[np.nan] * 3, [np.nan] * 3, [3, 0, 0]]),
     "leaf joint 'b' needs a finite tip"),
    (dict(parents=[-1, 0]), "skeleton arrays disagree"),
    (dict(names=[], parents=[], rest_positions=np.zeros((0, 3))), "no joints"),
])
def test_skeleton_rejects_bad_input(kwargs, msg):
    base = dict(names=["a", "b", "c"], parents=[-1, 0, 1],
                rest_positions=[[0, 0, 0], [1, 0, 0], [2, 0, 0]],
                tips=[[np.nan] * 3, [np.nan] * 3, [3, 0, 0]])
    base.update(kwargs)
    with pytest.raises(ValueError, match=msg):
        Skeleton(**base)


def test_skeleton_pose_and_index_errors():
    sk = chain()
    with pytest.raises(KeyError, match="unknown channel 'b_rw'"):
        sk.pose(b_rw=1.0)
    with pytest.raises(KeyError, match="no joint named 'x'"):
        sk.index("x")
    with pytest.raises(ValueError, match="expected \\(12,\\)"):
        sk.world_matrices(np.zeros(11))
    assert sk.index("c") == 2
