"""Skinned glTF characters: the real sample files, an independent skinning
reference, file weights in the rig, and one clear error per kind of bad file."""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

pygltflib = pytest.importorskip("pygltflib")

from skin_node.io.character_file import CharacterFileError  # noqa: E402
from skin_node.io.gltf import Y_UP_TO_Z_UP, _quat_to_matrix, load_gltf  # noqa: E402
from skin_node.rigging.build import RigOptions, file_weights, rig_key  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
RIGGED = DATA / "rigged"


def rigged(name: str) -> Path:
    p = RIGGED / name
    if not p.exists():
        pytest.skip(f"test data {p} is absent")
    return p


# --------------------------------------------------------- synthetic files
def box(lo, hi):
    """A closed, outward box: 8 vertices, 12 triangles."""
    x0, y0, z0 = lo
    x1, y1, z1 = hi
    V = np.array([[x0, y0, z0], [x1, y0, z0], [x1, y1, z0], [x0, y1, z0],
                  [x0, y0, z1], [x1, y0, z1], [x1, y1, z1], [x0, y1, z1]], float)
    F = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7], [0, 1, 5], [0, 5, 4],
                  [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6], [3, 0, 4], [3, 4, 7]])
    return V, F


def write_glb(path: Path, V=None, F=None, *, children=None, joints=(0, 1), split_seam=True,
              skin=True, weights=None) -> Path:
    """A two-joint skinned box in glTF's y up (a bar 1 m long along y).

    Node 0 is the root joint (at the origin), node 1 its child (0.5 m up y),
    node 2 the mesh. ``children`` overrides each node's children lists.
    """
    if V is None:
        V, F = box((-0.1, 0.0, -0.1), (0.1, 1.0, 0.1))
    V, F = np.asarray(V, np.float32), np.asarray(F, np.uint32)
    if split_seam:  # duplicate every vertex of the first two triangles, as a UV seam does
        extra = F[:2].ravel()
        F = F.copy()
        F[:2] = (len(V) + np.arange(6)).reshape(2, 3)
        V = np.concatenate([V, V[extra]])
    n = len(V)
    if weights is None:
        w1 = np.clip(V[:, 1].astype(float), 0.0, 1.0)
        weights = np.stack([1.0 - w1, w1, 0 * w1, 0 * w1], axis=1)
    J = np.tile(np.array([0, 1, 0, 0], np.uint16), (n, 1))
    W = np.asarray(weights, np.float32)
    IBM = np.tile(np.eye(4, dtype=np.float32), (2, 1, 1))
    IBM[1, 1, 3] = -0.5
    blobs = [V.tobytes(), F.tobytes(), J.tobytes(), W.tobytes(),
             IBM.transpose(0, 2, 1).tobytes()]
    offs = np.concatenate([[0], np.cumsum([len(b) for b in blobs])]).tolist()
    g = pygltflib.GLTF2()
    g.asset = pygltflib.Asset(version="2.0")
    g.buffers = [pygltflib.Buffer(byteLength=offs[-1])]
    g.bufferViews = [pygltflib.BufferView(buffer=0, byteOffset=offs[i], byteLength=len(b))
                     for i, b in enumerate(blobs)]
    g.accessors = [
        pygltflib.Accessor(bufferView=0, componentType=5126, count=n, type="VEC3",
                           min=np.nanmin(V, 0).tolist(), max=np.nanmax(V, 0).tolist()),
        pygltflib.Accessor(bufferView=1, componentType=5125, count=F.size, type="SCALAR"),
        pygltflib.Accessor(bufferView=2, componentType=5123, count=n, type="VEC4"),
        pygltflib.Accessor(bufferView=3, componentType=5126, count=n, type="VEC4"),
        pygltflib.Accessor(bufferView=4, componentType=5126, count=2, type="MAT4"),
    ]
    attrs = pygltflib.Attributes(POSITION=0, JOINTS_0=2, WEIGHTS_0=3) if skin else \
        pygltflib.Attributes(POSITION=0)
    g.meshes = [pygltflib.Mesh(primitives=[pygltflib.Primitive(attributes=attrs, indices=1)])]
    kids = children if children is not None else [[1], [], []]
    g.nodes = [pygltflib.Node(name="root", children=kids[0]),
               pygltflib.Node(name="tip", translation=[0.0, 0.5, 0.0], children=kids[1]),
               pygltflib.Node(mesh=0, skin=0 if skin else None, children=kids[2])]
    if skin:
        g.skins = [pygltflib.Skin(joints=list(joints), inverseBindMatrices=4)]
    g.scenes = [pygltflib.Scene(nodes=[0, 2])]
    g.scene = 0
    g.set_binary_blob(b"".join(blobs))
    g.save_binary(str(path))
    return path


def test_synthetic_bar_loads_in_z_up_with_seams_merged(tmp_path):
    c = load_gltf(write_glb(tmp_path / "bar.glb"))
    assert c.V.shape == (8, 3) and c.F.shape == (12, 3) and c.n_file_vertices == 14
    # y up (glTF) -> z up (project): the bar stands along +z
    assert np.allclose(c.skeleton.rest_positions, [[0, 0, 0], [0, 0, 0.5]], atol=1e-7)
    assert c.skeleton.names == ["root", "tip"]
    assert np.allclose(c.skeleton.tips[1], [0, 0, 1.0], atol=1e-6)
    # the vertex map carries merged points back to every file vertex
    assert c.to_file_order(c.V).shape == (14, 3)
    assert np.allclose(c.to_file_order(c.V) @ np.linalg.inv(Y_UP_TO_Z_UP).T,
                       _file_positions(tmp_path / "bar.glb"), atol=1e-7)
    # file weights: rows sum to 1, bottom vertices on the root, top ones on the tip
    W = c.dense_weights()
    assert np.allclose(W.sum(1), 1.0)
    assert np.allclose(W[c.V[:, 2] < 1e-6, 0], 1.0) and np.allclose(W[c.V[:, 2] > 0.99, 1], 1.0)


def _file_positions(path: Path) -> np.ndarray:
    g = pygltflib.GLTF2().load(str(path))
    acc = g.accessors[g.meshes[0].primitives[0].attributes.POSITION]
    bv = g.bufferViews[acc.bufferView]
    blob = g.binary_blob()
    return np.frombuffer(blob, np.float32, acc.count * 3, bv.byteOffset or 0).reshape(-1, 3)


# ----------------------------------------------------------- one test per bad case
def _expect(path: Path, *words: str):
    with pytest.raises(CharacterFileError) as e:
        load_gltf(path)
    msg = str(e.value)
    assert msg.startswith(str(path)), msg
    for w in words:
        assert w in msg, msg
    return msg


def test_empty_file(tmp_path):
    p = tmp_path / "empty.glb"
    p.write_bytes(b"")
    _expect(p, "empty")


def test_garbage_file(tmp_path):
    p = tmp_path / "garbage.glb"
    p.write_bytes(b"glTF\x02\x00\x00\x00 not really")
    _expect(p, "not a readable glTF")


def test_missing_file(tmp_path):
    _expect(tmp_path / "nothing.glb", "no such file")


def test_open_surface(tmp_path):
    V, F = box((-0.1, 0.0, -0.1), (0.1, 1.0, 0.1))
    _expect(write_glb(tmp_path / "open.glb", V, F[:-1]), "open")


def test_non_manifold_surface(tmp_path):
    V, F = box((-0.1, 0.0, -0.1), (0.1, 1.0, 0.1))
    V = np.concatenate([V, [[0.0, 0.5, 0.5]]])
    F = np.concatenate([F, [[0, 1, 8], [1, 0, 8]]])   # a fin on an edge: 4 triangles there
    _expect(write_glb(tmp_path / "fin.glb", V, F), "non-manifold")


def test_nan_coordinates(tmp_path):
    V, F = box((-0.1, 0.0, -0.1), (0.1, 1.0, 0.1))
    V[3, 0] = np.nan
    _expect(write_glb(tmp_path / "nan.glb", V, F, split_seam=False), "NaN")


def test_cycle_in_hierarchy(tmp_path):
    _expect(write_glb(tmp_path / "cycle.glb", children=[[1], [0], []]), "cycle")


def test_unknown_parent_link(tmp_path):
    _expect(write_glb(tmp_path / "unknown.glb", children=[[1, 7], [], []]), "unknown parent")


def test_skin_joints_not_one_tree(tmp_path):
    # node 1 detached from node 0: two roots
    _expect(write_glb(tmp_path / "forest.glb", children=[[], [], []]), "exactly one root")


def test_unskinned_file(tmp_path):
    _expect(write_glb(tmp_path / "static.glb", skin=False), "no skin")


def test_zero_weights(tmp_path):
    V, F = box((-0.1, 0.0, -0.1), (0.1, 1.0, 0.1))
    w = np.zeros((8, 4))
    w[1:, 0] = 1.0
    _expect(write_glb(tmp_path / "zero.glb", V, F, split_seam=False, weights=w), "zero weights")


# ------------------------------------------------------------------ real files
@pytest.mark.parametrize("name,file_vertices,merged,joints", [
    ("RiggedSimple.glb", 96, 96, 2), ("RiggedFigure.glb", 370, 130, 19),
    ("CesiumMan.glb", 3273, 2338, 19)])
def test_sample_characters(name, file_vertices, merged, joints):
    with warnings.catch_warnings():
        warnings.simplefilter("error")          # their IBMs agree with the node hierarchy
        c = load_gltf(rigged(name))
    assert c.n_file_vertices == file_vertices and len(c.V) == merged
    assert c.skeleton.n_joints == joints
    assert c.bind_mismatch[0] < 1e-5 and c.bind_mismatch[1] < 1e-4
    s = c.skeleton
    assert np.allclose(s.skinning_matrices(s.rest_pose()), np.eye(4), atol=1e-9)
    assert np.allclose(c.Wval.sum(1), 1.0)
    if joints == 19:
        assert abs(c.V[:, 2].min()) < 1e-6            # z up, standing on z = 0
        assert c.V[:, 2].max() > 1.4


def test_cesiumman_walk_matches_gltf_skinning():
    """The file's walk through our skeleton and LBS against glTF's own formula,
    ``v = sum_j w_j (Cz @ world_j(t) @ IBM_j) v_bind``, evaluated here from the
    node tree directly at the animation's key times."""
    path = rigged("CesiumMan.glb")
    c = load_gltf(path)
    clip = c.clip(fps=24.0)                    # the keys are 1/24 s apart
    g = pygltflib.GLTF2().load(str(path))
    from skin_node.io.gltf import _Reader, _node_matrix, _parents_of_nodes, _topological
    rd = _Reader(path, g)
    parent = _parents_of_nodes(path, g)
    anim = g.animations[0]
    skin_nodes = list(g.skins[0].joints)
    IBM = rd.read(g.skins[0].inverseBindMatrices, "ibm").reshape(-1, 4, 4).transpose(0, 2, 1)
    prim = g.meshes[0].primitives[0]
    Vb = rd.read(prim.attributes.POSITION, "p")
    Ji = rd.read(prim.attributes.JOINTS_0, "j")
    Wv = rd.read(prim.attributes.WEIGHTS_0, "w")
    Wv /= Wv.sum(1, keepdims=True)
    Cz = np.eye(4)
    Cz[:3, :3] = Y_UP_TO_Z_UP
    W_file = c.dense_weights()
    errs = []
    for k in (0, 12, 24, 36, 48):
        local = np.stack([_node_matrix(n) for n in g.nodes])
        T = {i: np.array(n.translation or [0, 0, 0], float) for i, n in enumerate(g.nodes)}
        R = {i: np.array(n.rotation or [0, 0, 0, 1], float) for i, n in enumerate(g.nodes)}
        for ch in anim.channels:
            vals = rd.read(anim.samplers[ch.sampler].output, "o")
            if ch.target.path == "translation":
                T[ch.target.node] = vals[k]
            elif ch.target.path == "rotation":
                R[ch.target.node] = vals[k]
        for i in T:
            if g.nodes[i].matrix is None:
                local[i] = np.eye(4)
                local[i, :3, :3] = _quat_to_matrix(R[i])
                local[i, :3, 3] = T[i]
        world = np.empty_like(local)
        for i in _topological(parent):
            world[i] = local[i] if parent[i] < 0 else world[parent[i]] @ local[i]
        S = Cz @ world[skin_nodes] @ IBM                                   # (19, 4, 4)
        ref = np.einsum("nk,nkij,nj->ni", Wv, S[Ji][..., :3, :3], Vb) + \
            np.einsum("nk,nki->ni", Wv, S[Ji][..., :3, 3])
        M = c.skeleton.skinning_matrices(clip.frames[k])
        ours = np.einsum("nj,jab,nb->na", W_file, M[:, :3, :3], c.V) + W_file @ M[:, :3, 3]
        errs.append(np.linalg.norm(c.to_file_order(ours) - ref, axis=1))
    err = np.concatenate(errs)
    # The skeleton is rigid: the walk's small joint-offset animation (clip.ignored_translation,
    # 3 mm; 1 mm of it on the whole upper body) is the only difference.
    assert clip.ignored_translation < 0.005
    assert err.mean() < 1.5e-3 and err.max() < 2 * clip.ignored_translation + 1e-4, \
        (err.mean(), err.max())


def test_file_weights_in_the_rig(tmp_path, monkeypatch):
    """A file's weights are the character's: the surface keeps them (4 bones
    at most, normalised), the tet lattice takes their smooth extension."""
    monkeypatch.setenv("SKIN_NODE_CACHE", str(tmp_path / "cache"))
    from skin_node import load_character
    path = write_glb(tmp_path / "bar.glb")
    c = load_gltf(path)
    W = file_weights(c.Widx, c.Wval, 2, len(c.V))
    assert W.shape == (8, 2) and np.allclose(W.sum(1), 1.0)
    ref = np.zeros((8, 2))
    np.add.at(ref, (np.repeat(np.arange(8), c.Widx.shape[1]), c.Widx.ravel()), c.Wval.ravel())
    assert np.allclose(W, ref / ref.sum(1, keepdims=True))
    with pytest.raises(ValueError, match="outside 0..1"):
        file_weights(c.Widx + 1, c.Wval, 2, len(c.V))
    ch = load_character(str(path), tet_count=300, weights="file", progress=False)
    r = ch.rig
    dense = np.zeros((len(ch.V), 2))
    np.add.at(dense, (np.repeat(np.arange(len(ch.V)), r.Widx.shape[1]), r.Widx.ravel()),
              r.Wval.ravel())
    assert np.allclose(dense, W, atol=1e-12)            # two bones a vertex: kept as they are
    T = np.zeros((len(r.TV), 2))
    np.add.at(T, (np.repeat(np.arange(len(r.TV)), r.TWidx.shape[1]), r.TWidx.ravel()),
              r.TWval.ravel())
    assert np.allclose(T.sum(1), 1.0)
    z = r.TV[:, 2]                      # the bar runs along z once y-up is turned
    lo, hi = np.argmin(z), np.argmax(z)
    assert T[lo].max() > 0.9 and T[hi].max() > 0.9 and np.argmax(T[lo]) != np.argmax(T[hi])
    # the weights are part of the cache key, only when they are used
    s = c.skeleton
    a, b = RigOptions(), RigOptions(weights="file")
    Wv2 = c.Wval.copy()
    Wv2[0] = Wv2[0][::-1]
    assert rig_key(c.V, c.F, s, a, (c.Widx, c.Wval)) == rig_key(c.V, c.F, s, a)
    assert rig_key(c.V, c.F, s, b, (c.Widx, c.Wval)) != rig_key(c.V, c.F, s, b, (c.Widx, Wv2))
    assert rig_key(c.V, c.F, s, b, (c.Widx, c.Wval)) != rig_key(c.V, c.F, s, a)


def test_load_character_dispatches_on_suffix(tmp_path, monkeypatch):
    monkeypatch.setenv("SKIN_NODE_CACHE", str(tmp_path / "cache"))
    from skin_node import load_character
    path = rigged("RiggedFigure.glb")
    ch = load_character(str(path), tet_count=600, weights="file", progress=False)
    assert ch.name == "RiggedFigure" and ch.options.weights == "file" and len(ch.V) == 130
    assert np.allclose(ch.rig.Wval.sum(1), 1.0) and np.allclose(ch.rig.TWval.sum(1), 1.0)
    auto = load_character(str(path), tet_count=600, progress=False)
    assert auto.options.weights == "automatic"
    assert not np.allclose(auto.rig.TWval, ch.rig.TWval)
    with pytest.raises(ValueError, match="arm: weights 'file'"):
        load_character("arm", weights="file", progress=False)
    with pytest.raises(ValueError, match="weights must be one of"):
        load_character(str(path), tet_count=600, weights="artist", progress=False)
