"""Whole glTF scenes: skinned meshes on two skins joined into one skeleton, rigid
meshes carried by joints (through a non-joint node), a static mesh and open parts.

The reference evaluates the file by the specification, independently of the
loader: a skinned vertex is ``sum_j w_j (W_j IBM_j) v`` with ``W_j`` the joint
node's world matrix, a rigid one ``W_node v``; every part's vertices are
checked against it at rest and in a pose given by the file's own animation
(within 1e-6 m: float32 data on both sides).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

pygltflib = pytest.importorskip("pygltflib")

from skin_node.io.character_file import CharacterFileError  # noqa: E402
from skin_node.io.gltf import Y_UP_TO_Z_UP, load_gltf, load_gltf_scene  # noqa: E402
from test_gltf import box  # noqa: E402
from test_gltf_clips import file_world, trs  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def quat(axis, degrees):
    a = np.asarray(axis, float)
    return Rotation.from_rotvec(np.radians(degrees) * a / np.linalg.norm(a)).as_quat().tolist()


#: (name, parent, translation, rotation, mesh); meshes: body, legs (skinned),
#: eye, helmet (rigid), ground (static).
NODES = [("Armature", -1, [0.1, 0.0, 0.0], quat([0, 1, 0], 20), None),
         ("hips", 0, [0.0, 1.0, 0.0], [0, 0, 0, 1], None),
         ("spine", 1, [0.0, 0.3, 0.0], quat([1, 0, 0], 5), None),
         ("head", 2, [0.0, 0.3, 0.0], quat([0, 0, 1], 10), None),
         ("l_leg", 1, [0.15, -0.1, 0.0], [0, 0, 0, 1], None),
         ("r_leg", 1, [-0.15, -0.1, 0.0], [0, 0, 0, 1], None),
         ("body", -1, [5.0, 5.0, 5.0], [0, 0, 0, 1], "body"),    # its transform is ignored
         ("legs", -1, [0.0, 0.0, 0.0], [0, 0, 0, 1], "legs"),
         ("face", 3, [0.0, 0.1, 0.05], quat([0, 1, 0], 30), None),  # not a joint
         ("eye", 8, [0.03, 0.0, 0.05], quat([1, 1, 0], 15), "eye"),
         ("helmet", 3, [0.0, 0.15, 0.0], [0, 0, 0, 1], "helmet"),
         ("ground", -1, [0.0, -0.05, 0.0], [0, 0, 0, 1], "ground")]
SKINS = [[1, 2, 3], [1, 4, 5]]          # hips is in both


def rest_world() -> np.ndarray:
    W = np.zeros((len(NODES), 4, 4))
    for i, (_, p, t, r, _) in enumerate(NODES):
        W[i] = trs(t, r) if p < 0 else W[p] @ trs(t, r)
    return W


def meshes():
    """name -> (list of (V, F) primitives in mesh space, skin or None)."""
    W = rest_world()
    A_inv = np.linalg.inv(W[0])

    def arm(V):          # world points into the armature's space (the skins' space)
        return (np.c_[V, np.ones(len(V))] @ A_inv.T)[:, :3]
    body = box((-0.15, 0.9, -0.1), (0.15, 1.75, 0.1))
    l_leg, r_leg = box((0.05, 0.1, -0.08), (0.25, 0.95, 0.08)), box((-0.25, 0.1, -0.08),
                                                                  (-0.05, 0.95, 0.08))
    hv, hf = box((-0.12, -0.1, -0.12), (0.12, 0.12, 0.12))
    return {"body": ([(arm(body[0]), body[1])], 0),
            "legs": ([(arm(l_leg[0]), l_leg[1]), (arm(r_leg[0]), r_leg[1])], 1),  # 2 primitives
            "eye": ([box((-0.01, -0.01, -0.01), (0.01, 0.01, 0.01))], None),
            "helmet": ([(hv, hf[:-2])], None),                   # a box without its last side
            "ground": ([(np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], float),
                         np.array([[0, 2, 1], [0, 3, 2]]))], None)}


def pose_tracks(spine_rest, head_rest) -> list:
    """(node, path, values at 0 and 1 s): hips turned and moved, spine, head and
    left leg turned (nodes 1 to 4 of both test files)."""
    return [(1, "rotation", [[0, 0, 0, 1], quat([0, 0, 1], 35)]),
            (1, "translation", [[0, 1, 0], [0.2, 1.1, -0.3]]),
            (2, "rotation", [spine_rest, quat([1, 0, 0.3], 40)]),
            (3, "rotation", [head_rest, quat([0, 1, 1], -50)]),
            (4, "rotation", [[0, 0, 0, 1], quat([1, 0, 0], -60)])]


def smooth_weights(V_world, joints) -> np.ndarray:
    """(p, 4) weights over a skin's three joints, by inverse squared distance."""
    P = rest_world()[joints, :3, 3]
    w = 1.0 / (((V_world[:, None] - P[None]) ** 2).sum(2) + 1e-3)
    return np.c_[w / w.sum(1, keepdims=True), np.zeros(len(w))]


class Blobs:
    """Accessors over one binary chunk, collected while a .glb is written."""

    def __init__(self) -> None:
        self.blobs, self.accessors = [], []

    def add(self, arr, kind, comp, dtype) -> int:
        """A new accessor (and buffer view) of ``arr``; its index."""
        arr = np.ascontiguousarray(arr, dtype)
        self.blobs.append(arr.tobytes())
        extra = {}
        if kind == "VEC3" and comp == 5126:
            extra = {"min": arr.min(0).tolist(), "max": arr.max(0).tolist()}
        if kind == "SCALAR" and comp == 5126:
            extra = {"min": [float(arr.min())], "max": [float(arr.max())]}
        self.accessors.append(pygltflib.Accessor(bufferView=len(self.blobs) - 1,
                                                 componentType=comp, count=len(arr), type=kind,
                                                 **extra))
        return len(self.accessors) - 1

    def animation(self, name: str, tracks, t=(0.0, 1.0)) -> "pygltflib.Animation":
        """A LINEAR animation of ``(node, path, values at t)`` tracks."""
        samplers, channels = [], []
        for node, what, values in tracks:
            ti = self.add(np.asarray(t), "SCALAR", 5126, np.float32)
            vi = self.add(np.asarray(values, float), "VEC4" if what == "rotation" else "VEC3",
                          5126, np.float32)
            samplers.append(pygltflib.AnimationSampler(input=ti, output=vi))
            channels.append(pygltflib.AnimationChannel(
                sampler=len(samplers) - 1,
                target=pygltflib.AnimationChannelTarget(node=node, path=what)))
        return pygltflib.Animation(name=name, samplers=samplers, channels=channels)

    def document(self) -> "pygltflib.GLTF2":
        """A glTF 2.0 document holding the accessors in one buffer (its binary chunk)."""
        offs = np.concatenate([[0], np.cumsum([len(b) for b in self.blobs])]).tolist()
        g = pygltflib.GLTF2(asset=pygltflib.Asset(version="2.0"))
        g.buffers = [pygltflib.Buffer(byteLength=offs[-1])]
        g.bufferViews = [pygltflib.BufferView(buffer=0, byteOffset=offs[i], byteLength=len(b))
                         for i, b in enumerate(self.blobs)]
        g.accessors = self.accessors
        g.set_binary_blob(b"".join(self.blobs))
        return g


def write_scene(path: Path) -> Path:
    W = rest_world()
    buf = Blobs()
    add = buf.add
    gl_meshes, mesh_index = [], {}
    for name, (prims, skin) in meshes().items():
        out = []
        for V, F in prims:
            at = {"POSITION": add(V, "VEC3", 5126, np.float32)}
            if skin is not None:
                Vw = (np.c_[V, np.ones(len(V))] @ W[0].T)[:, :3]
                at["JOINTS_0"] = add(np.tile([0, 1, 2, 0], (len(V), 1)), "VEC4", 5123, np.uint16)
                at["WEIGHTS_0"] = add(smooth_weights(Vw, SKINS[skin]), "VEC4", 5126, np.float32)
            out.append(pygltflib.Primitive(attributes=pygltflib.Attributes(**at),
                                           indices=add(np.asarray(F).ravel(), "SCALAR", 5125,
                                                       np.uint32)))
        mesh_index[name] = len(gl_meshes)
        gl_meshes.append(pygltflib.Mesh(name=name, primitives=out))
    skins = []
    for joints in SKINS:
        IBM = np.stack([np.linalg.inv(np.linalg.inv(W[0]) @ W[j]) for j in joints])
        skins.append(pygltflib.Skin(joints=joints, inverseBindMatrices=add(
            IBM.transpose(0, 2, 1).reshape(len(joints), 16), "MAT4", 5126, np.float32)))
    # The pose: one animation with keys at 0 and 1 s.
    pose = buf.animation("pose", pose_tracks(NODES[2][3], NODES[3][3]))
    g = buf.document()
    g.meshes, g.skins = gl_meshes, skins
    kids = {i: [k for k, n in enumerate(NODES) if n[1] == i] or None for i in range(len(NODES))}
    g.nodes = [pygltflib.Node(name=n, translation=tt, rotation=r, children=kids[i],
                              mesh=mesh_index.get(m), skin=meshes()[m][1] if m else None)
               for i, (n, _, tt, r, m) in enumerate(NODES)]
    g.animations = [pose]
    g.scenes = [pygltflib.Scene(nodes=[i for i, n in enumerate(NODES) if n[1] < 0])]
    g.scene = 0
    g.save_binary(str(path))
    return path


def reference(g, t: float | None) -> dict:
    """name -> (n_file, 3) points of every mesh at time t (None: rest), project z up."""
    W = file_world(g, 0, t) if t is not None else rest_world()
    Cz = np.eye(4)
    Cz[:3, :3] = Y_UP_TO_Z_UP
    out = {}
    for name, (prims, skin) in meshes().items():
        node = next(i for i, n in enumerate(NODES) if n[4] == name)
        pts = []
        for V, _ in prims:
            Vh = np.c_[V, np.ones(len(V))]
            if skin is None:
                pts.append((Vh @ (Cz @ W[node]).T)[:, :3])
                continue
            joints = SKINS[skin]
            IBM = [np.linalg.inv(np.linalg.inv(rest_world()[0]) @ rest_world()[j])
                   for j in joints]
            w = smooth_weights((Vh @ rest_world()[0].T)[:, :3], joints)
            M = np.stack([Cz @ W[j] @ IBM[k] for k, j in enumerate(joints)])
            pts.append(np.einsum("nk,kij,nj->ni", w[:, :3], M, Vh)[:, :3])
        out[name] = np.concatenate(pts)
    return out


def test_every_part_is_read_with_its_skin_or_joint(tmp_path):
    sc = load_gltf_scene(write_scene(tmp_path / "scene.glb"))
    parts = {p.name: p for p in sc.parts}
    assert list(parts) == ["body", "legs", "eye", "helmet", "ground"]
    # both skins' joints joined, the shared hips once, the skins' common root on top
    assert sc.skeleton.names == ["hips", "spine", "l_leg", "r_leg", "head"]
    assert sc.warnings == []
    kinds = {n: (p.kind, p.skin, sc.skeleton.names[p.joint] if p.joint >= 0 else None)
             for n, p in parts.items()}
    assert kinds == {"body": ("skinned", 0, None), "legs": ("skinned", 1, None),
                     "eye": ("rigid", None, "head"), "helmet": ("rigid", None, "head"),
                     "ground": ("static", None, None)}
    # vertex counts: a box has 8 corners; the legs are two boxes in two primitives
    counts = {n: (len(p.V), p.n_file_vertices, len(p.F), p.closed) for n, p in parts.items()}
    assert counts == {"body": (8, 8, 12, True), "legs": (16, 16, 24, True),
                      "eye": (8, 8, 12, True), "helmet": (8, 8, 10, False),
                      "ground": (4, 4, 2, False)}
    assert parts["helmet"].open_edges == 4 and parts["ground"].open_edges == 4
    report = sc.report()
    assert report[3] == ("part 'helmet' (node 10, mesh 3): rigid on joint 'head', 8 vertices "
                         "(8 in the file), 10 triangles, open (4 edges with one triangle)")
    assert report[1].startswith("part 'legs' (node 7, mesh 1): skinned on skin 1, 16 vertices")


@pytest.mark.parametrize("when", [None, 1.0, 0.4])      # rest, the last key, between keys
def test_every_part_sits_where_the_file_puts_it(tmp_path, when):
    sc = load_gltf_scene(write_scene(tmp_path / "scene.glb"))
    fps = 10.0
    q = np.zeros(sc.skeleton.n_channels) if when is None else \
        sc.clip("pose", fps=fps).frames[int(round(when * fps))]
    want = reference(sc._gltf, when)
    for p, X in zip(sc.parts, sc.posed(q)):
        err = np.abs(X[p.vertex_map] - want[p.name]).max()
        assert err < 1e-6, (p.name, err)
    if when is not None:        # the pose moves every part but the static ground
        rest = reference(sc._gltf, None)
        moved = {n: np.abs(want[n] - rest[n]).max() for n in want}
        assert min(v for n, v in moved.items() if n != "ground") > 0.05 and moved["ground"] == 0


def test_one_skin_files_load_as_the_single_mesh_loader_does():
    for name in ("CesiumMan.glb", "RiggedFigure.glb", "RiggedSimple.glb"):
        path = DATA / "rigged" / name
        if not path.exists():
            pytest.skip(f"test data {path} is absent")
        sc, one = load_gltf_scene(path), load_gltf(path)
        (part,) = sc.parts
        assert sc.skeleton.names == one.skeleton.names
        np.testing.assert_allclose(sc.skeleton.rest_positions, one.skeleton.rest_positions,
                                   atol=1e-9)
        np.testing.assert_allclose(part.V, one.V, atol=1e-9)
        assert np.array_equal(part.vertex_map, one.vertex_map)


def test_skins_with_no_common_root_are_refused(tmp_path):
    path = write_scene(tmp_path / "scene.glb")
    g = pygltflib.GLTF2().load_binary(str(path))
    # cut the legs' skeleton off the armature: two trees, nothing above both
    g.nodes[1].children = [2]
    g.nodes[4].translation = [0.15, 0.9, 0.0]
    g.nodes.append(pygltflib.Node(name="other", children=[4, 5]))
    g.scenes[0].nodes.append(len(g.nodes) - 1)
    g.save_binary(str(tmp_path / "split.glb"))
    with pytest.raises(CharacterFileError, match=r"split.glb: the joints form 3 trees .* no "
                                                 "common ancestor node"):
        load_gltf_scene(tmp_path / "split.glb")
