"""A glTF character's own animations as pose channels.

The reference here evaluates the file independently of the loader (its own
TRS per node, scipy's slerp, the specification's cubic Hermite, the node
hierarchy walked by hand) and checks that the skeleton posed from the
published JointState channels has the file's joint transforms at sampled
times, between keys as well as on them. Tolerances: rotations 1e-9 rad and
positions 1e-9 m where the rigid skeleton can follow the file exactly; where
the file moves a joint away from its parent (CesiumMan's walk, 3 mm), the
positions are held to the offset change the clip reports.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

pygltflib = pytest.importorskip("pygltflib")

from msg_adapters import ChannelMapper, channels_to_joint_state  # noqa: E402
from skin_node.io.gltf import Y_UP_TO_Z_UP, load_gltf  # noqa: E402
from skin_node.motion import clip_names, file_clip, load_motion  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
RIGGED = DATA / "rigged"


def quat(axis, degrees) -> list:
    return Rotation.from_rotvec(np.radians(degrees) * np.asarray(axis, float)
                                / np.linalg.norm(axis)).as_quat().tolist()   # x, y, z, w


def trs(t=(0, 0, 0), r=(0, 0, 0, 1), s=(1, 1, 1)) -> np.ndarray:
    M = np.eye(4)
    M[:3, :3] = Rotation.from_quat(r).as_matrix() * np.asarray(s, float)
    M[:3, 3] = t
    return M


# ------------------------------------------------------------ the test file
#: Nodes: (name, parent, translation, rotation); joints are hip, knee, ankle.
NODES = [("Armature", -1, [0.3, 0.0, -0.2], quat([0, 1, 0], 30)),
         ("hip", 0, [0.0, 0.2, 0.0], quat([1, 0, 1], 20)),
         ("twist", 1, [0.0, 0.0, 0.0], quat([0, 1, 0], 10)),      # not a joint
         ("knee", 2, [0.0, 0.5, 0.0], quat([0, 0, 1], -15)),
         ("ankle", 3, [0.0, 0.4, 0.0], quat([1, 0, 0], 5)),
         ("mesh", -1, [0.0, 0.0, 0.0], [0, 0, 0, 1])]
JOINT_NODES = [1, 3, 4]
ANKLE_SHIFT = 0.01      # the ankle's animated offset change, m: the rigid skeleton ignores it


def animations() -> list:
    """(name, [(node, path, interpolation, times, values)]) of the test file."""
    t3 = np.array([0.0, 0.5, 1.0])
    hip_r = np.array([quat([1, 0, 1], 20), quat([1, 0, 0.2], 70), quat([0.3, 0, 1], -40)])
    # Twist about the bone (its own y), so the knee's offset from the hip stays put.
    twist_r = np.array([quat([0, 1, 0], 10), quat([0, 1, 0], 50), quat([0, 1, 0], -30)])
    knee_v = np.array([quat([0, 0, 1], -15), quat([0, 0, 1], -95), quat([0.2, 0, 1], -60)])
    knee_tan = np.array([[0.1, -0.2, 0.3, 0.05], [0.4, 0.1, -0.3, 0.2], [0.0, 0.3, 0.1, -0.1]])
    knee = np.stack([-knee_tan, knee_v, knee_tan], axis=1).reshape(-1, 4)  # in, value, out
    root_t = np.array([[0.3, 0.0, -0.2], [0.5, 0.1, 0.0], [0.8, 0.0, 0.3]])
    hip_t = np.array([[0.0, 0.2, 0.0], [0.0, 0.25, 0.05]])
    ankle_t = np.array([[0.0, 0.4, 0.0], [0.0, 0.4 + ANKLE_SHIFT, 0.0]])
    ankle_s = np.array([[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]])
    walk = [(0, "translation", "LINEAR", t3, root_t),
            (1, "rotation", "LINEAR", t3, hip_r),
            (1, "translation", "LINEAR", t3[[0, 2]], hip_t),
            (2, "rotation", "STEP", t3, twist_r),
            (3, "rotation", "CUBICSPLINE", t3, knee),
            (4, "translation", "LINEAR", t3[[0, 2]], ankle_t),
            (4, "scale", "LINEAR", t3[[0, 2]], ankle_s)]
    wave = [(3, "rotation", "LINEAR", np.array([0.0, 0.25]),
             np.array([quat([0, 0, 1], -15), quat([0, 0, 1], -45)]))]
    return [("walk", walk), ("", wave)]


def rest_world() -> np.ndarray:
    W = np.zeros((len(NODES), 4, 4))
    for i, (_, p, t, r) in enumerate(NODES):
        W[i] = trs(t, r) if p < 0 else W[p] @ trs(t, r)
    return W


def write_animated_glb(path: Path) -> Path:
    """A three-joint leg (a closed bar) under a rotated armature, with two animations."""
    from test_gltf import box
    W = rest_world()
    A = W[0]
    P = W[JOINT_NODES, :3, 3]
    Vw, F = box(P.min(0) - 0.15, P.max(0) + 0.15)     # a closed box around the leg
    # Vertices in the armature's space, bound to the joints' rest pose there.
    V = (np.c_[Vw, np.ones(len(Vw))] @ np.linalg.inv(A).T)[:, :3]
    nearest = np.argmin(((Vw[:, None] - P[None]) ** 2).sum(2), axis=1)
    J = np.tile(np.array([0, 1, 2, 0], np.uint16), (len(V), 1))
    Wt = np.zeros((len(V), 4), np.float32)
    Wt[np.arange(len(V)), nearest] = 1.0
    IBM = np.stack([np.linalg.inv(np.linalg.inv(A) @ W[j]) for j in JOINT_NODES])
    blobs = [np.asarray(V, np.float32).tobytes(), np.asarray(F, np.uint32).tobytes(),
             J.tobytes(), Wt.tobytes(), IBM.transpose(0, 2, 1).astype(np.float32).tobytes()]
    acc = [pygltflib.Accessor(bufferView=0, componentType=5126, count=len(V), type="VEC3",
                              min=V.min(0).tolist(), max=V.max(0).tolist()),
           pygltflib.Accessor(bufferView=1, componentType=5125, count=F.size, type="SCALAR"),
           pygltflib.Accessor(bufferView=2, componentType=5123, count=len(V), type="VEC4"),
           pygltflib.Accessor(bufferView=3, componentType=5126, count=len(V), type="VEC4"),
           pygltflib.Accessor(bufferView=4, componentType=5126, count=3, type="MAT4")]
    anims = []
    for name, tracks in animations():
        samplers, channels = [], []
        for node, what, interp, times, values in tracks:
            for arr, kind in ((times, "SCALAR"), (values, {3: "VEC3", 4: "VEC4"}[values.shape[1]])):
                blobs.append(np.asarray(arr, np.float32).tobytes())
                extra = {"min": [float(arr.min())], "max": [float(arr.max())]} if kind == "SCALAR" \
                    else {}
                acc.append(pygltflib.Accessor(bufferView=len(blobs) - 1, componentType=5126,
                                              count=len(arr), type=kind, **extra))
            samplers.append(pygltflib.AnimationSampler(input=len(acc) - 2, output=len(acc) - 1,
                                                       interpolation=interp))
            channels.append(pygltflib.AnimationChannel(
                sampler=len(samplers) - 1,
                target=pygltflib.AnimationChannelTarget(node=node, path=what)))
        anims.append(pygltflib.Animation(name=name or None, samplers=samplers, channels=channels))
    offs = np.concatenate([[0], np.cumsum([len(b) for b in blobs])]).tolist()
    g = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0"))
    g.buffers = [pygltflib.Buffer(byteLength=offs[-1])]
    g.bufferViews = [pygltflib.BufferView(buffer=0, byteOffset=offs[i], byteLength=len(b))
                     for i, b in enumerate(blobs)]
    g.accessors = acc
    g.meshes = [pygltflib.Mesh(primitives=[pygltflib.Primitive(
        attributes=pygltflib.Attributes(POSITION=0, JOINTS_0=2, WEIGHTS_0=3), indices=1)])]
    kids = {i: [k for k, n in enumerate(NODES) if n[1] == i] for i in range(len(NODES))}
    g.nodes = [pygltflib.Node(name=n, translation=t, rotation=r, children=kids[i] or None)
               for i, (n, _, t, r) in enumerate(NODES[:-1])]
    g.nodes.append(pygltflib.Node(name="mesh", mesh=0, skin=0))
    g.skins = [pygltflib.Skin(joints=JOINT_NODES, inverseBindMatrices=4)]
    g.animations = anims
    g.scenes = [pygltflib.Scene(nodes=[0, 5])]
    g.scene = 0
    g.set_binary_blob(b"".join(blobs))
    g.save_binary(str(path))
    return path


# ------------------------------------------------ an independent evaluation
def sample_track(interp, times, values, t, rotation):
    """One track at time t, written from the glTF 2.0 specification."""
    if interp == "CUBICSPLINE":
        a, v, b = values[0::3], values[1::3], values[2::3]
    else:
        v = values
    if t <= times[0]:
        out = v[0]
    elif t >= times[-1]:
        out = v[-1]
    else:
        k = int(np.searchsorted(times, t, side="right") - 1)
        d = times[k + 1] - times[k]
        s = (t - times[k]) / d
        if interp == "STEP":
            out = v[k]
        elif interp == "LINEAR" and rotation:
            out = Slerp([0, 1], Rotation.from_quat([v[k], v[k + 1]]))(s).as_quat()
        elif interp == "LINEAR":
            out = (1 - s) * v[k] + s * v[k + 1]
        else:
            out = ((2 * s**3 - 3 * s**2 + 1) * v[k] + (s**3 - 2 * s**2 + s) * d * b[k]
                   + (-2 * s**3 + 3 * s**2) * v[k + 1] + (s**3 - s**2) * d * a[k + 1])
    return out / np.linalg.norm(out) if rotation else out


def file_world(g, anim: int, t: float) -> np.ndarray:
    """(N, 4, 4) world matrix of every node of pygltflib document ``g`` at time t."""
    from skin_node.io.gltf import _Reader
    rd = _Reader(Path("."), g)
    T = [list(n.translation or [0, 0, 0]) for n in g.nodes]
    R = [list(n.rotation or [0, 0, 0, 1]) for n in g.nodes]
    S = [list(n.scale or [1, 1, 1]) for n in g.nodes]
    a = g.animations[anim]
    for ch in a.channels:
        smp = a.samplers[ch.sampler]
        times = rd.read(smp.input, "t").ravel()
        vals = rd.read(smp.output, "v")
        x = sample_track(smp.interpolation or "LINEAR", times, vals, t,
                         ch.target.path == "rotation")
        {"translation": T, "rotation": R, "scale": S}[ch.target.path][ch.target.node] = x
    parent = {c: i for i, n in enumerate(g.nodes) for c in (n.children or [])}
    W = {}

    def world(i):
        if i not in W:
            L = trs(T[i], R[i], S[i]) if g.nodes[i].matrix is None else \
                np.asarray(g.nodes[i].matrix, float).reshape(4, 4).T
            W[i] = L if i not in parent else world(parent[i]) @ L
        return W[i]
    return np.stack([world(i) for i in range(len(g.nodes))])


def posed_from_joint_states(skel, clip) -> np.ndarray:
    """(T, J, 4, 4): the skeleton posed from each frame as a JointState carries it."""
    mapper = ChannelMapper(skel.channel_names)
    out = []
    for q in clip.frames:
        msg = channels_to_joint_state(clip.channel_names, q)
        qq = mapper.apply(list(msg.name), np.asarray(msg.position)).copy()
        out.append(skel.world_matrices(qq))
    return np.stack(out)


def compare(path: Path, anim: int, fps: float):
    """(rotation error rad, position error m, clip) of the clip against the file."""
    c = load_gltf(path)
    clip = c.clip(anim, fps=fps)
    G = posed_from_joint_states(c.skeleton, clip)
    Cz = np.eye(4)
    Cz[:3, :3] = Y_UP_TO_Z_UP
    rot, pos = 0.0, 0.0
    for k in range(len(clip.frames)):
        Wf = Cz @ file_world(c._gltf, anim, k / fps)[c.joint_nodes]
        U, _, Vt = np.linalg.svd(Wf[:, :3, :3])      # scaled nodes: their rotation
        Rf = U @ Vt
        d = np.einsum("jik,jil->jkl", Rf, G[k, :, :3, :3])
        rot = max(rot, float(np.arccos(np.clip((np.trace(d, axis1=1, axis2=2) - 1) / 2,
                                               -1, 1)).max()))
        pos = max(pos, float(np.abs(Wf[:, :3, 3] - G[k, :, :3, 3]).max()))
    return rot, pos, clip


# -------------------------------------------------------------------- tests
@pytest.mark.parametrize("fps", [2.0, 7.0, 120.0])    # on the keys only, and between them
def test_channels_reproduce_the_files_joint_transforms(tmp_path, fps):
    path = write_animated_glb(tmp_path / "leg.glb")
    rot, pos, clip = compare(path, 0, fps)
    assert len(clip.frames) == int(np.floor(1.0 * fps + 1e-6)) + 1 and clip.fps == fps
    assert rot < 1e-6, rot           # float32 keys: the same numbers on both sides
    # The hip and knee follow exactly; the ankle's offset grows by ANKLE_SHIFT, which
    # the rigid skeleton reports instead of following.
    assert clip.ignored_translation == pytest.approx(ANKLE_SHIFT, rel=1e-4)
    assert pos <= ANKLE_SHIFT * (1 + 1e-4)
    c = load_gltf(path)
    G = posed_from_joint_states(c.skeleton, clip)
    Cz = np.eye(4)
    Cz[:3, :3] = Y_UP_TO_Z_UP
    for k in range(len(clip.frames)):
        Wf = Cz @ file_world(c._gltf, 0, k / fps)[c.joint_nodes]
        assert np.abs(Wf[:2, :3, 3] - G[k, :2, :3, 3]).max() < 1e-6      # hip, knee


def test_cubic_spline_uses_the_files_tangents(tmp_path):
    """The knee's cubic track between keys differs from a slerp of its key values
    by degrees, and the clip follows the cubic (STEP and LINEAR: above)."""
    path = write_animated_glb(tmp_path / "leg.glb")
    c = load_gltf(path)
    clip = c.clip("walk", fps=40.0)
    k = c.skeleton.index("knee")
    knee = c.skeleton.world_matrices(clip.frames[10])[k, :3, :3]   # t = 0.25
    Cz = Y_UP_TO_Z_UP
    W = file_world(c._gltf, 0, 0.25)
    np.testing.assert_allclose(knee, Cz @ W[3, :3, :3], atol=1e-6)
    # what the old key-values-only reading gave: a slerp of the values
    tracks = dict(((n, p), (i, tt, v)) for n, p, i, tt, v in animations()[0][1])
    _, tt, v = tracks[(3, "rotation")]
    lin = Slerp([0, 1], Rotation.from_quat(v[1::3][:2]))(0.5).as_matrix()
    W_lin = W[2, :3, :3] @ lin
    assert np.degrees(np.arccos((np.trace((Cz @ W_lin).T @ knee) - 1) / 2)) > 1.0


@pytest.mark.parametrize("name", ["CesiumMan.glb", "RiggedFigure.glb", "RiggedSimple.glb"])
def test_sample_files_own_walks(name):
    path = RIGGED / name
    if not path.exists():
        pytest.skip(f"test data {path} is absent")
    rot, pos, clip = compare(path, 0, 60.0)
    assert rot < 1e-5, rot
    # A joint's position error adds up its ancestors' offset changes: measured
    # 4.0 mm against 3.0 mm a joint on CesiumMan, 2.2 against 2.6 um on
    # RiggedFigure, 0.27 um on RiggedSimple.
    assert pos <= 2 * clip.ignored_translation + 1e-5, (pos, clip.ignored_translation)


def test_clip_names_and_the_default_clip(tmp_path):
    path = str(write_animated_glb(tmp_path / "leg.glb"))
    assert clip_names(path) == ["walk", "animation1"]         # no built-in clip fits a leg
    first = load_motion(path)                                 # a glTF plays its first
    assert first.name == "walk" and first.fps == 120.0 and len(first.frames) == 121
    wave = load_motion(path, "gltf:1", fps=8)
    assert wave.name == "animation1" and len(wave.frames) == 3
    assert file_clip(path, "animation1", fps=8).frames.tolist() == wave.frames.tolist()
    assert file_clip(path, "squat") is None                   # not the file's: a built-in
    with pytest.raises(ValueError, match=r"clip 'squat'.*clips for this character: "
                                         r"\['walk', 'animation1'\]"):
        load_motion(path, "squat")
    with pytest.raises(ValueError, match="no animation named 'run'"):
        load_motion(path, "gltf:run")
    with pytest.raises(ValueError, match="not a glTF file"):
        load_motion("humanoid", "gltf:walk")
    assert "walk" in clip_names("humanoid") and "elbow_bend" in clip_names("arm")
