"""Retargeting BVH motion onto a skin_node Skeleton."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from skin_node.io.bvh import load_bvh, parse_bvh  # noqa: E402
from skin_node.retarget import (axis_conversion, continuous_euler, load_mapping,  # noqa: E402
                                retarget_bvh, validate_mapping)
from skin_node.skeleton import Skeleton, euler_xyz_to_matrix, matrix_to_euler_xyz  # noqa: E402

BVH_DIR = REPO.parent / "shared" / "data" / "bvh"
MAPPING = REPO / "config" / "cmu_to_humanoid.yaml"
NAMES = ["pelvis", "spine", "chest", "neck", "head",
         "l_shoulder", "l_elbow", "l_wrist", "r_shoulder", "r_elbow", "r_wrist",
         "l_hip", "l_knee", "l_ankle", "r_hip", "r_knee", "r_ankle"]
HIP_HEIGHT = 0.95


def cmu(name: str):
    p = BVH_DIR / name
    if not p.is_file():
        pytest.skip(f"shared CMU data not found at {p}")
    return load_bvh(p)


def humanoid(arm_drop_deg: float = 0.0) -> Skeleton:
    """17-joint test humanoid: z up, facing +x, left = +y, T-pose (or A-pose)."""
    a = np.deg2rad(arm_drop_deg)
    up_arm = np.array([0.0, np.cos(a), -np.sin(a)])
    sh = np.array([0.0, 0.18, 1.45])
    spec = {
        "pelvis": (None, (0, 0, HIP_HEIGHT)), "spine": ("pelvis", (0, 0, 1.05)),
        "chest": ("spine", (0, 0, 1.25)), "neck": ("chest", (0, 0, 1.5)),
        "head": ("neck", (0, 0, 1.6)),
        "l_hip": ("pelvis", (0, 0.09, 0.9)), "l_knee": ("l_hip", (0, 0.09, 0.5)),
        "l_ankle": ("l_knee", (0, 0.09, 0.08)),
        "r_hip": ("pelvis", (0, -0.09, 0.9)), "r_knee": ("r_hip", (0, -0.09, 0.5)),
        "r_ankle": ("r_knee", (0, -0.09, 0.08)),
    }
    for side, s in (("l", 1.0), ("r", -1.0)):
        m = np.array([1.0, s, 1.0])
        spec[f"{side}_shoulder"] = ("chest", tuple(sh * m))
        spec[f"{side}_elbow"] = (f"{side}_shoulder", tuple((sh + 0.28 * up_arm) * m))
        spec[f"{side}_wrist"] = (f"{side}_elbow", tuple((sh + 0.53 * up_arm) * m))
    parents = [-1 if spec[n][0] is None else NAMES.index(spec[n][0]) for n in NAMES]
    tips = np.full((len(NAMES), 3), np.nan)
    tips[NAMES.index("head")] = (0, 0, 1.8)
    tips[NAMES.index("l_wrist")] = (sh + 0.71 * up_arm) * [1, 1, 1]
    tips[NAMES.index("r_wrist")] = (sh + 0.71 * up_arm) * [1, -1, 1]
    tips[NAMES.index("l_ankle")] = (0.15, 0.09, 0.0)
    tips[NAMES.index("r_ankle")] = (0.15, -0.09, 0.0)
    return Skeleton(NAMES, parents, [spec[n][1] for n in NAMES], tips=tips)


def world(sk: Skeleton, frames: np.ndarray) -> np.ndarray:
    return np.array([sk.world_matrices(q) for q in frames])


def bone_dir(G: np.ndarray, a: int, b: int) -> np.ndarray:
    d = G[..., b, :3, 3] - G[..., a, :3, 3]
    return d / np.linalg.norm(d, axis=-1, keepdims=True)


def rotation_channels(frames: np.ndarray) -> np.ndarray:
    return frames[:, 3:]


# ---------------------------------------------------------- synthetic source
def synthetic_source(rows_deg: dict, n_frames: int = 2):
    """A small CMU-named, y-up, +z-facing BVH (T-pose at zero) with Z X Y channels.

    ``rows_deg[frame][joint] = (z, x, y)`` in channel order.
    """
    tree = [("Hips", None, (0, 0.95, 0)), ("LowerBack", "Hips", (0, 0.1, 0)),
            ("Spine1", "LowerBack", (0, 0.2, 0)), ("Neck", "Spine1", (0, 0.25, 0)),
            ("Head", "Neck", (0, 0.1, 0)),
            ("LeftArm", "Spine1", (0.2, 0.2, 0)), ("LeftForeArm", "LeftArm", (0.3, 0, 0)),
            ("LeftHand", "LeftForeArm", (0.25, 0, 0)),
            ("RightArm", "Spine1", (-0.2, 0.2, 0)), ("RightForeArm", "RightArm", (-0.3, 0, 0)),
            ("RightHand", "RightForeArm", (-0.25, 0, 0)),
            ("LeftUpLeg", "Hips", (0.1, -0.05, 0)), ("LeftLeg", "LeftUpLeg", (0, -0.42, 0)),
            ("LeftFoot", "LeftLeg", (0, -0.42, 0)),
            ("RightUpLeg", "Hips", (-0.1, -0.05, 0)), ("RightLeg", "RightUpLeg", (0, -0.42, 0)),
            ("RightFoot", "RightLeg", (0, -0.42, 0))]
    children = {n: [c for c, p, _ in tree if p == n] for n, _, _ in tree}
    off = {n: o for n, _, o in tree}
    out = ["HIERARCHY"]

    def emit(n, depth, root=False):
        ind = "  " * depth
        out.append(f"{ind}{'ROOT' if root else 'JOINT'} {n}")
        out.append(f"{ind}{{")
        out.append(f"{ind}  OFFSET {off[n][0]} {off[n][1]} {off[n][2]}")
        pos = "Xposition Yposition Zposition " if root else ""
        out.append(f"{ind}  CHANNELS {6 if root else 3} {pos}Zrotation Xrotation Yrotation")
        for c in children[n]:
            emit(c, depth + 1)
        if not children[n]:
            out.extend([f"{ind}  End Site", f"{ind}  {{", f"{ind}    OFFSET 0 -0.05 0.1",
                        f"{ind}  }}"])
        out.append(f"{ind}}}")

    emit("Hips", 0, root=True)
    order = [n for n, _, _ in tree]
    out += ["MOTION", f"Frames: {n_frames}", "Frame Time: 0.0083333"]
    for t in range(n_frames):
        vals = list(rows_deg.get(t, {}).get("_root", (0.0, 0.95, 0.0)))
        for n in order:
            vals += list(rows_deg.get(t, {}).get(n, (0.0, 0.0, 0.0)))
        out.append(" ".join(repr(float(v)) for v in vals))
    return parse_bvh("\n".join(out) + "\n", "synthetic.bvh", scale=1.0)


def cmu_mapping() -> dict:
    return load_mapping(MAPPING)


def test_axis_conversion_cmu():
    C = axis_conversion(cmu_mapping())
    np.testing.assert_allclose(C @ [0, 0, 1], [1, 0, 0])  # forward
    np.testing.assert_allclose(C @ [0, 1, 0], [0, 0, 1])  # up
    np.testing.assert_allclose(C @ [1, 0, 0], [0, 1, 0])  # left
    assert np.isclose(np.linalg.det(C), 1.0)


def test_reference_maps_to_rest_synthetic():
    src = synthetic_source({0: {"LeftForeArm": (30, 10, 5)}, 1: {"LeftLeg": (0, 40, 0)}})
    sk = humanoid()
    for ref in (0, 1):
        names, q, fps = retarget_bvh(src, sk, cmu_mapping(), reference_frame=ref)
        assert names == sk.channel_names and fps == 120.0
        np.testing.assert_allclose(q[ref], 0.0, atol=1e-12)


@pytest.mark.parametrize("axis_src,axis_tgt", [((0, 0, 1), (1, 0, 0)),   # about forward
                                               ((0, 1, 0), (0, 0, 1)),   # about up
                                               ((1, 0, 0), (0, 1, 0))])  # about left
def test_world_rotation_of_forearm_synthetic(axis_src, axis_tgt):
    # Parents are identity at frame 1, so the local Z/X/Y channel is the world rotation.
    k = {(0, 0, 1): 0, (1, 0, 0): 1, (0, 1, 0): 2}[axis_src]
    ang = [0.0, 0.0, 0.0]
    ang[k] = 90.0
    src = synthetic_source({1: {"LeftForeArm": tuple(ang)}})
    sk = humanoid()
    _, q, _ = retarget_bvh(src, sk, cmu_mapping())
    G = world(sk, q)
    el, wr, sh = NAMES.index("l_elbow"), NAMES.index("l_wrist"), NAMES.index("l_shoulder")
    Q = _axis_angle(np.asarray(axis_tgt, float), np.pi / 2)
    np.testing.assert_allclose(bone_dir(G[1], el, wr), Q @ bone_dir(G[0], el, wr), atol=1e-9)
    np.testing.assert_allclose(G[1, el, :3, :3], Q @ G[0, el, :3, :3], atol=1e-9)
    np.testing.assert_allclose(bone_dir(G[1], sh, el), [0, 1, 0], atol=1e-9)
    # Everything but the elbow channels stays at rest.
    others = np.ones(sk.n_channels, bool)
    others[3 + 3 * el: 6 + 3 * el] = False
    np.testing.assert_allclose(q[1, others], 0.0, atol=1e-9)


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def test_rest_offsets_a_pose_target():
    src = synthetic_source({1: {"LeftArm": (0, 0, -90)}})  # left arm swings forward (+z)
    sk = humanoid(arm_drop_deg=45.0)
    m = dict(cmu_mapping())
    m["rest_offsets"] = {"l_shoulder": [45, 0, 0], "r_shoulder": [-45, 0, 0]}
    _, q, _ = retarget_bvh(src, sk, m)
    sh, el = NAMES.index("l_shoulder"), NAMES.index("l_elbow")
    np.testing.assert_allclose(q[0, 3 + 3 * sh: 6 + 3 * sh], [np.pi / 4, 0, 0], atol=1e-12)
    G = world(sk, q)
    np.testing.assert_allclose(bone_dir(G[0], sh, el), [0, 1, 0], atol=1e-9)  # T-pose again
    np.testing.assert_allclose(bone_dir(G[0], NAMES.index("r_shoulder"), NAMES.index("r_elbow")),
                               [0, -1, 0], atol=1e-9)
    np.testing.assert_allclose(bone_dir(G[1], sh, el), [1, 0, 0], atol=1e-9)  # arm forward


def test_root_translation_and_heading_synthetic():
    # Root moves 1 source unit forward (+z) and turns 90 degrees left (about +y).
    src = synthetic_source({1: {"_root": (0.0, 0.95, 1.0), "Hips": (0, 0, 90)}})
    sk = humanoid()
    m = dict(cmu_mapping())
    _, q, _ = retarget_bvh(src, sk, m)
    ratio = HIP_HEIGHT / (0.95 - 0.01)  # source hips above the lowest end site
    np.testing.assert_allclose(q[1, :3], [ratio, 0, 0], atol=1e-12)
    G = world(sk, q)
    np.testing.assert_allclose(G[1, 0, :3, 0], [0, 1, 0], atol=1e-9)  # now faces +y (left turn)
    m["scale"] = 2.0
    _, q2, _ = retarget_bvh(src, sk, m)
    np.testing.assert_allclose(q2[1, :3], [2.0, 0, 0], atol=1e-12)


# ------------------------------------------------------------------- CMU data
def test_cmu_reference_frame_is_rest():
    b = cmu("cmu_02_01_walk.bvh")
    sk = humanoid()
    _, q, fps = retarget_bvh(b, sk, cmu_mapping())
    assert fps == 120.0 and q.shape == (344, sk.n_channels)
    np.testing.assert_allclose(q[0], 0.0, atol=1e-9)
    _, q5, _ = retarget_bvh(b, sk, cmu_mapping(), reference_frame=5)
    np.testing.assert_allclose(q5[5], 0.0, atol=1e-9)


def test_cmu_world_rotation_of_elbow():
    """Rotate the real LeftForeArm by 90 degrees in world (about source up, y)."""
    b = cmu("cmu_02_01_walk.bvh")
    Q = _axis_angle(np.array([0.0, 1.0, 0.0]), np.pi / 2)
    G = b.world_matrices()[0, :, :3, :3]
    j = b.index("LeftForeArm")
    p = b.parents[j]
    L = G[p].T @ G[j]                   # current local rotation
    L_new = G[p].T @ Q @ G[p] @ L       # so that the new world rotation is Q @ G[j]
    zyx = np.rad2deg(matrix_to_euler_xyz(L_new))[::-1]  # channels: Zrotation Yrotation Xrotation
    s = b.channel_start[j]
    b.frames = np.vstack([b.frames[:1], b.frames[:1]])
    b.frames[1, s:s + 3] = zyx
    np.testing.assert_allclose(b.world_matrices()[1, j, :3, :3], Q @ G[j], atol=1e-9)
    sk = humanoid()
    _, q, _ = retarget_bvh(b, sk, cmu_mapping())
    Gt = world(sk, q)
    el, wr = NAMES.index("l_elbow"), NAMES.index("l_wrist")
    Qt = _axis_angle(np.array([0.0, 0.0, 1.0]), np.pi / 2)
    np.testing.assert_allclose(bone_dir(Gt[1], el, wr), Qt @ [0, 1, 0], atol=1e-9)  # -> -x
    np.testing.assert_allclose(q[1, np.r_[0:3 + 3 * el, 6 + 3 * el:sk.n_channels]], 0.0, atol=1e-9)


def test_cmu_walk_plausible():
    b = cmu("cmu_02_01_walk.bvh")
    sk = humanoid()
    _, q, _ = retarget_bvh(b, sk, cmu_mapping())
    assert np.all(np.isfinite(q))
    for side in ("l", "r"):
        knee = NAMES.index(f"{side}_knee")
        flex = q[:, 3 + 3 * knee + 1]   # flexion about the lateral (y) axis
        assert flex.min() > -0.2 and 0.8 < flex.max() < 1.6
        assert np.abs(q[:, 3 + 3 * knee: 6 + 3 * knee:2]).max() < 0.3  # little ab/adduction
    # Root travel: forward (+x) by the source's walked distance (metres, about
    # 3.4 m along +z in the file) times the hip-height ratio.
    src_root = b.root_positions()
    walked = np.linalg.norm((src_root[-1] - src_root[0])[[0, 2]])
    assert 3.0 < walked < 4.0
    G0 = b.world_matrices()[0]
    lowest = min(G0[:, 1, 3].min(), b.end_site_positions(G0[None])[0, :, 1].min())
    ratio = HIP_HEIGHT / (G0[0, 1, 3] - lowest)
    assert 0.9 < ratio < 1.1
    travel = q[-1, :3] - q[0, :3]
    assert travel[0] == pytest.approx(ratio * walked, rel=0.05)
    assert abs(travel[1]) < 0.1 * walked
    # The pelvis stays near hip height and faces the direction of travel.
    G = world(sk, q[::10])
    z = G[:, 0, 2, 3]
    assert np.all(np.abs(z - HIP_HEIGHT) < 0.12)
    fwd = G[:, 0, :3, 0]
    assert np.mean(fwd @ (travel / np.linalg.norm(travel))) > 0.9
    # Feet stay near the floor (pelvis height minus leg length, with the ratio).
    ank = G[:, [NAMES.index("l_ankle"), NAMES.index("r_ankle")], 2, 3]
    assert ank.min() > -0.05 and ank.min(axis=1).max() < 0.35


@pytest.mark.parametrize("name", ["cmu_02_03_run_jog.bvh", "cmu_09_01_run.bvh",
                                  "cmu_02_05_punch_strike.bvh", "cmu_01_01_forward_jumps.bvh"])
def test_cmu_all_files_finite_and_continuous(name):
    b = cmu(name)
    _, q, _ = retarget_bvh(b, humanoid(), cmu_mapping())
    assert q.shape == (b.n_frames, 54) and np.all(np.isfinite(q))
    np.testing.assert_allclose(q[0], 0.0, atol=1e-9)
    # Continuity (frame 0 is the synthetic T-pose, so the step into the capture
    # is skipped): each joint's rotation moves little per frame, and blending the
    # channels of neighbouring frames stays between their rotations, so there are
    # no 2*pi or Euler-branch flips (running knees bend past 90 degrees, the
    # jumping subject turns around). Near ry = +-90 degrees rx and rz may swing
    # together; that is the Euler singularity, harmless to blending.
    a = rotation_channels(q)[1:].reshape(b.n_frames - 1, -1, 3)
    R = euler_xyz_to_matrix(a)
    Rmid = euler_xyz_to_matrix(0.5 * (a[1:] + a[:-1]))
    step = _angle(np.swapaxes(R[:-1], -1, -2) @ R[1:])
    to_mid = np.maximum(_angle(np.swapaxes(R[:-1], -1, -2) @ Rmid),
                        _angle(np.swapaxes(R[1:], -1, -2) @ Rmid))
    assert step.max() < 0.35
    assert np.all(to_mid <= step + 1e-6)


def _angle(R: np.ndarray) -> np.ndarray:
    return np.arccos(np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) * 0.5, -1.0, 1.0))


def test_continuous_euler_branches():
    # A hinge bending about y from 0 to 150 degrees crosses ry = 90 degrees.
    flex = np.linspace(0.0, np.deg2rad(150), 40)
    R = euler_xyz_to_matrix(np.stack([0 * flex, flex, 0 * flex], -1))
    principal = matrix_to_euler_xyz(R)
    assert np.abs(principal[:, 1]).max() <= np.pi / 2 + 1e-12
    cont = continuous_euler(principal[:, None, :], ref=0)[:, 0]
    np.testing.assert_allclose(cont[:, 1], flex, atol=1e-9)
    np.testing.assert_allclose(euler_xyz_to_matrix(cont), R, atol=1e-12)
    # A root yaw turning past 180 degrees stays monotonic, and ref is kept.
    yaw = np.linspace(0.0, 2.5 * np.pi, 50)
    p = matrix_to_euler_xyz(euler_xyz_to_matrix(np.stack([0 * yaw, 0 * yaw, yaw], -1)))
    c = continuous_euler(p[:, None, :], ref=10)[:, 0]
    np.testing.assert_allclose(c[10], p[10])
    np.testing.assert_allclose(np.diff(c[:, 2]), np.diff(yaw), atol=1e-9)


# -------------------------------------------------------------- mapping file
def test_mapping_file_joint_names_check():
    b = cmu("cmu_02_01_walk.bvh")
    m = load_mapping(MAPPING, humanoid(), b)
    assert m["joints"]["l_knee"] == "LeftLeg" and m["_file"] == str(MAPPING)


@pytest.mark.parametrize("edit,pattern", [
    (("l_knee: LeftLeg", "l_kneee: LeftLeg"), r"unknown target joint 'l_kneee'"),
    (("l_knee: LeftLeg", "l_knee: LeftLegg"), r"unknown source joint 'LeftLegg'"),
    (("source_root: Hips", "source_root: Pelvis"), r"unknown source joint 'Pelvis'"),
    (("source_up: +y", "source_up: +w"), r"'source_up' must be one of"),
    (("source_up: +y", "source_up: +z"), r"must be different axes"),
    (("scale: auto", "scale: -1"), r"'scale' must be 'auto' or a positive number"),
    (("rest_offsets: {}", "rest_offsets: {l_elbow: [1, 2]}"), r"rest_offsets of 'l_elbow'"),
    (("rest_offsets: {}", "rest_offsets: {elbow: [1, 2, 3]}"), r"unknown target joint 'elbow'"),
    (("scale: auto", "scael: auto"), r"unknown keys \['scael'\]"),
    (("l_knee: LeftLeg", "l_knee: LeftFoot"), r"mapped more than once: \['LeftFoot'\]"),
    (("joints:", "joints: [\n"), r"not valid YAML"),
])
def test_mapping_errors(tmp_path, edit, pattern):
    p = tmp_path / "bad_mapping.yaml"
    text = MAPPING.read_text()
    assert edit[0] in text
    p.write_text(text.replace(edit[0], edit[1]))
    src = synthetic_source({})
    with pytest.raises(ValueError, match=pattern) as e:
        load_mapping(p, humanoid(), src)
    assert "bad_mapping.yaml" in str(e.value)


def test_unknown_joint_without_file_context():
    m = {"joints": {"nope": "Hips"}}
    with pytest.raises(ValueError, match="unknown target joint 'nope'"):
        retarget_bvh(synthetic_source({}), humanoid(), m)
    validate_mapping({"joints": {"pelvis": "Hips"}})  # structure alone is fine


def test_euler_roundtrip_is_used_consistently():
    # The channels reproduce the intended local rotation (checks the R = Rz Ry Rx convention).
    src = synthetic_source({1: {"LeftLeg": (20, 50, -10)}})
    sk = humanoid()
    _, q, _ = retarget_bvh(src, sk, cmu_mapping())
    k = NAMES.index("l_knee")
    R = euler_xyz_to_matrix(q[1, 3 + 3 * k: 6 + 3 * k])
    C = axis_conversion(cmu_mapping())
    rad = np.deg2rad([20, 50, -10])
    Rs = (_axis_angle(np.array([0, 0, 1.0]), rad[0]) @ _axis_angle(np.array([1.0, 0, 0]), rad[1])
          @ _axis_angle(np.array([0, 1.0, 0]), rad[2]))
    np.testing.assert_allclose(R, C @ Rs @ C.T, atol=1e-9)


def test_a_character_without_a_mapping_is_told_so():
    """A BVH for a character no mapping ships for fails with what to do, not
    with a bare missing-file error; so does a mapping path that is not there."""
    from skin_node.motion import load_motion
    walk = BVH_DIR / "cmu_02_01_walk.bvh"
    simple = REPO.parent / "shared" / "data" / "rigged" / "RiggedSimple.glb"
    if not (walk.is_file() and simple.is_file()):
        pytest.skip("shared data not found")
    with pytest.raises(ValueError, match=r"RiggedSimple.glb: no mapping .*cmu_to_riggedsimple"
                                         r"\.yaml is not in .*shipped: .*cmu_to_humanoid\.yaml"):
        load_motion(str(simple), bvh=str(walk))
    with pytest.raises(ValueError, match="nowhere.yaml: no such mapping file"):
        load_motion(str(simple), bvh=str(walk), mapping="nowhere.yaml")
