"""Whole glTF characters: every mesh of a scene posed, in one published surface.

The file is written here with pygltflib: a body of two closed skinned meshes on
two skins (torso, legs), an open skinned skirt and tiny closed skinned teeth,
a rigid eye (under a non-joint node) and an open rigid helmet (with a lines
primitive), a static ground and a mesh of points only. References are taken
from the file by the specification, independently of the loader: a node's
world matrix ``W(t)`` from its own transforms and the file's animation; a
skinned vertex by dual quaternions of ``W_j(t) IBM_j`` with its file weights
(what the character gives a skinned part when no stage runs); a rigid one
``W_node(t) v``.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

pygltflib = pytest.importorskip("pygltflib")
trimesh = pytest.importorskip("trimesh")

from skin_node import Pipeline, load_character  # noqa: E402
from skin_node.io.gltf import Y_UP_TO_Z_UP, load_gltf, load_gltf_scene  # noqa: E402
from test_gltf import box  # noqa: E402
from test_gltf_clips import file_world, trs  # noqa: E402
from test_gltf_scene import Blobs, pose_tracks, quat  # noqa: E402

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"

#: (name, parent, translation, rotation): the armature, five joints, a non-joint face.
#: The joints' rest offsets are exact in float32 and unrotated, so the file's
#: float32 inverse bind matrices are exactly its node hierarchy's and the
#: references hold to 1e-9; the armature and the face turn freely.
SKELETON = [("Armature", -1, [0.1, 0.0, 0.0], quat([0, 1, 0], 20)),
            ("hips", 0, [0.0, 1.0, 0.0], [0, 0, 0, 1]),
            ("spine", 1, [0.0, 0.25, 0.0], [0, 0, 0, 1]),
            ("head", 2, [0.0, 0.375, 0.0], [0, 0, 0, 1]),
            ("l_leg", 1, [0.125, -0.125, 0.0], [0, 0, 0, 1]),
            ("r_leg", 1, [-0.125, -0.125, 0.0], [0, 0, 0, 1]),
            ("face", 3, [0.0, 0.125, 0.0625], quat([0, 1, 0], 30))]
SKINS = [[1, 2, 3], [1, 4, 5]]          # hips in both
ALL = ("torso", "legs", "skirt", "teeth", "eye", "helmet", "ground", "markers")
BODY = ("torso", "legs")
POINTS, LINES, TRIANGLES = 0, 1, 4


def rest_world() -> np.ndarray:
    W = np.zeros((len(SKELETON), 4, 4))
    for i, (_, p, t, r) in enumerate(SKELETON):
        W[i] = trs(t, r) if p < 0 else W[p] @ trs(t, r)
    return W


def armature_space(j: int) -> np.ndarray:
    """Joint ``j``'s rest matrix relative to the armature, from its own chain."""
    M = np.eye(4)
    while j > 0:
        _, p, t, r = SKELETON[j]
        M = trs(t, r) @ M
        j = p
    return M


def fine_box(lo, hi, times: int = 2):
    m = trimesh.creation.box(bounds=[lo, hi])
    for _ in range(times):
        m = m.subdivide()
    return np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)


def tube(radius, y0, y1, around=16, rings=3):
    """An open cylinder about the y axis (no caps), faces outwards."""
    a = 2 * np.pi * np.arange(around) / around
    y = np.linspace(y0, y1, rings)
    V = np.array([[radius * np.cos(t), h, radius * np.sin(t)] for h in y for t in a])
    F = []
    for r in range(rings - 1):
        for k in range(around):
            i, j = r * around + k, r * around + (k + 1) % around
            F += [[i, i + around, j], [j, i + around, j + around]]
    return V, np.array(F)


def meshes(split: bool = False) -> dict:
    """name -> (parent node, translation, primitives [(V, F, mode)], skin): skinned
    points are given in the world at rest, the others in their node's frame."""
    torso = fine_box((-0.15, 1.0, -0.1), (0.15, 1.75, 0.1))
    legs = [fine_box((0.05, 0.1, -0.08), (0.25, 0.9, 0.08), 1),
            fine_box((-0.25, 0.1, -0.08), (-0.05, 0.9, 0.08), 1)]
    hv, hf = box((-0.12, -0.1, -0.12), (0.12, 0.12, 0.12))
    out = {"torso": (-1, [5.0, 5.0, 5.0], [(*torso, TRIANGLES)], 0),  # a skinned node's
           "legs": (-1, [0.0, 0.0, 0.0], [(*m, TRIANGLES) for m in legs], 1),  # place: ignored
           "skirt": (-1, [0.0, 0.0, 0.0], [(*tube(0.32, 0.8, 1.1), TRIANGLES)], 1),
           # a closed cap on the torso's top edge: they share one edge's two
           # vertices, so joined that edge has four triangles
           "cap": (-1, [0.0, 0.0, 0.0],
                   [(*box((0.15, 1.75, -0.1), (0.25, 1.85, -0.05)), TRIANGLES)], 0),
           # two closed plates through each other (a robot's armour): no flesh
           "armour": (-1, [0.0, 0.0, 0.0],
                      [(*box((-0.1, 1.2, 0.12), (0.1, 1.4, 0.16)), TRIANGLES),
                       (*box((-0.05, 1.3, 0.1), (0.05, 1.5, 0.18)), TRIANGLES)], 0),
           # a robot's rigid pieces beside the torso, each wholly on one joint
           "pieces": (-1, [0.0, 0.0, 0.0],
                      [(*box((0.3, 1.2, -0.05), (0.4, 1.4, 0.05)), TRIANGLES),
                       (*box((0.3, 1.5, -0.05), (0.4, 1.7, 0.05)), TRIANGLES)], 0),
           # a closed belt through the torso's sides
           "belt": (-1, [0.0, 0.0, 0.0],
                    [(*box((-0.2, 1.1, -0.12), (0.2, 1.2, 0.12)), TRIANGLES)], 0),
           "teeth": (-1, [0.0, 0.0, 0.0],
                     [(*box((-0.02, 1.6, 0.11), (0.02, 1.61, 0.12)), TRIANGLES)], 0),
           "eye": (6, [0.03, 0.0, 0.05], [(*box((-0.01, -0.01, -0.01), (0.01, 0.01, 0.01)),
                                           TRIANGLES)], None),
           "helmet": (3, [0.0, 0.15, 0.0], [(hv, hf[:-2], TRIANGLES),
                                             (hv[:4], np.array([[0, 1], [1, 2]]), LINES)], None),
           "ground": (-1, [0.0, -0.05, 0.0],
                      [(np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], float),
                        np.array([[0, 2, 1], [0, 3, 2]]), TRIANGLES)], None),
           "markers": (1, [0.0, 0.0, 0.0], [(np.eye(3), None, POINTS)], None)}
    if split:       # the torso as two open halves on two skins, closed only together
        V, F = torso
        up = V[F].mean(1)[:, 1] > 1.4
        for name, half, skin in (("torso", F[up], 0), ("lower", F[~up], 1)):
            used, tri = np.unique(half, return_inverse=True)
            out[name] = (-1, [0, 0, 0], [(V[used], tri.reshape(-1, 3), TRIANGLES)], skin)
    return out


def weights(V_world, skin) -> np.ndarray:
    """(p, 4) weights over a skin's three joints, by inverse squared distance."""
    P = rest_world()[SKINS[skin], :3, 3]
    w = 1.0 / (((V_world[:, None] - P[None]) ** 2).sum(2) + 1e-3)
    return np.c_[w / w.sum(1, keepdims=True), np.zeros(len(w))]


def write_character(path: Path, names=ALL, split: bool = False) -> Path:
    """The test character with the meshes ``names`` (skeleton, skins and the
    animation 'pose' always), as a .glb."""
    A_inv = np.linalg.inv(rest_world()[0])
    buf = Blobs()
    add = buf.add
    nodes = [pygltflib.Node(name=n, translation=t, rotation=r) for n, _, t, r in SKELETON]
    for i, (_, p, _, _) in enumerate(SKELETON):
        if p >= 0:
            nodes[p].children = (nodes[p].children or []) + [i]
    roots = [0]
    gl_meshes = []
    for name, (parent, t, prims, skin) in meshes(split).items():
        if name not in names:
            continue
        out = []
        for k, (V, F, mode) in enumerate(prims):
            Vf = V if skin is None else (np.c_[V, np.ones(len(V))] @ A_inv.T)[:, :3]
            at = {"POSITION": add(Vf, "VEC3", 5126, np.float32)}
            if skin is not None:
                at["JOINTS_0"] = add(np.tile([0, 1, 2, 0], (len(V), 1)), "VEC4", 5123, np.uint16)
                W = weights(V, skin) if name != "pieces" else \
                    np.tile(np.eye(4)[1 + k], (len(V), 1))           # wholly on one joint
                at["WEIGHTS_0"] = add(W, "VEC4", 5126, np.float32)
            idx = None if F is None else add(np.asarray(F).ravel(), "SCALAR", 5125, np.uint32)
            out.append(pygltflib.Primitive(attributes=pygltflib.Attributes(**at), indices=idx,
                                           mode=mode))
        gl_meshes.append(pygltflib.Mesh(name=name, primitives=out))
        nodes.append(pygltflib.Node(name=name, translation=t, mesh=len(gl_meshes) - 1,
                                    skin=skin))
        if parent < 0:
            roots.append(len(nodes) - 1)
        else:
            nodes[parent].children = (nodes[parent].children or []) + [len(nodes) - 1]
    skins = []
    for joints in SKINS:        # the joints' bind in the armature's space, the skins' space
        IBM = np.stack([np.linalg.inv(armature_space(j)) for j in joints])
        skins.append(pygltflib.Skin(joints=joints, inverseBindMatrices=add(
            IBM.transpose(0, 2, 1).reshape(len(joints), 16), "MAT4", 5126, np.float32)))
    pose = buf.animation("pose", pose_tracks([0, 0, 0, 1], [0, 0, 0, 1]))
    g = buf.document()
    g.meshes, g.skins, g.nodes, g.animations = gl_meshes, skins, nodes, [pose]
    g.scenes = [pygltflib.Scene(nodes=roots)]
    g.scene = 0
    g.save_binary(str(path))
    return path


# ------------------------------------------------------------ the references
def dual_quaternion_skinning(V, W, M) -> np.ndarray:
    """Kavan et al. 2007 in numpy: (n, 3) points ``V`` with dense weights ``W``
    (n, J) under rigid matrices ``M`` (J, 4, 4), blended in the hemisphere of
    each point's largest weight."""
    q = Rotation.from_matrix(M[:, :3, :3]).as_quat()[:, [3, 0, 1, 2]]     # w, x, y, z

    def mul(a, b):      # Hamilton products of (..., 4) quaternions, w first
        w1, x1, y1, z1 = np.moveaxis(a, -1, 0)
        w2, x2, y2, z2 = np.moveaxis(b, -1, 0)
        return np.stack([w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
                         w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
                         w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                         w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2], axis=-1)
    d = 0.5 * mul(np.c_[np.zeros(len(M)), M[:, :3, 3]], q)
    sign = np.sign(np.einsum("jk,nk->nj", q, q[np.argmax(W, axis=1)]))
    br, bd = (W * sign) @ q, (W * sign) @ d
    norm = np.linalg.norm(br, axis=1, keepdims=True)
    br, bd = br / norm, bd / norm
    conj = br * [1, -1, -1, -1]
    rotated = mul(mul(br, np.c_[np.zeros(len(V)), V]), conj)[:, 1:]
    return rotated + 2 * mul(bd, conj)[:, 1:]


def reference(path: Path, t: float | None) -> dict:
    """name -> (n_file, 3) points of every triangle mesh of the file at time t (None:
    rest) in the project's z up: skinned ones by dual quaternions."""
    from skin_node.io.gltf import _Reader
    g = pygltflib.GLTF2().load_binary(str(path))
    rd = _Reader(path, g)
    Wt = file_world(g, 0, t if t is not None else 0.0)
    g.animations = [pygltflib.Animation(samplers=[], channels=[])]
    W0 = file_world(g, 0, 0.0)              # the rest: the nodes' own transforms
    Wt = W0 if t is None else Wt
    Cz = np.eye(4)
    Cz[:3, :3] = Y_UP_TO_Z_UP
    to_world = Cz @ W0[0]                   # the skins' space (the armature's) at rest
    out = {}
    for i, node in enumerate(g.nodes):
        if node.mesh is None:
            continue
        pts = []
        for prim in g.meshes[node.mesh].primitives:
            if prim.mode not in (None, TRIANGLES):
                continue
            Vh = np.c_[rd.read(prim.attributes.POSITION, "p"), np.ones(prim_count(g, prim))]
            if node.skin is None:
                pts.append((Vh @ (Cz @ Wt[i]).T)[:, :3])
                continue
            skin = g.skins[node.skin]
            IBM = rd.read(skin.inverseBindMatrices, "ibm").reshape(-1, 4, 4).transpose(0, 2, 1)
            w = rd.read(prim.attributes.WEIGHTS_0, "w")[:, :3]
            M = np.stack([Cz @ Wt[j] @ IBM[k] for k, j in enumerate(skin.joints)])
            pts.append(dual_quaternion_skinning((Vh @ to_world.T)[:, :3],
                                                w / w.sum(1, keepdims=True),
                                                M @ np.linalg.inv(to_world)))
        if pts:
            out[node.name] = np.concatenate(pts)
    return out


def prim_count(g, prim) -> int:
    return g.accessors[prim.attributes.POSITION].count


# ------------------------------------------------------------------- tests
@pytest.fixture(scope="module")
def character(tmp_path_factory):
    """(file, character with the file's weights) of the whole test character."""
    d = tmp_path_factory.mktemp("character")
    path = write_character(d / "character.glb")
    mp = pytest.MonkeyPatch()
    mp.setenv("SKIN_NODE_CACHE", str(d / "cache"))
    ch = load_character(str(path), tet_count=800, weights="file", progress=False)
    yield path, ch
    mp.undo()


def test_every_part_is_read_and_says_what_it_gets(character):
    path, ch = character
    got = {p.name: (p.kind, p.gets, p.vertices, len(p.rows)) for p in ch.parts}
    assert got == {"torso": ("skinned", "solved", 98, 98), "legs": ("skinned", "solved", 52, 52),
                   "skirt": ("skinned", "skinned", 48, 48), "teeth": ("skinned", "skinned", 8, 8),
                   "eye": ("rigid", "rigid", 8, 8), "helmet": ("rigid", "rigid", 8, 8),
                   "ground": ("static", "static", 4, 4)}
    assert list(got) == ["torso", "legs", "skirt", "teeth", "eye", "helmet", "ground"]
    # the body first, then the passengers in node order, each in a block of its own
    assert len(ch.V) == 150 and len(ch.surface_V) == 150 + 48 + 8 + 8 + 8 + 4
    rows = {p.name: p.rows for p in ch.parts}
    assert np.array_equal(np.sort(np.concatenate([rows["torso"], rows["legs"]])),
                          np.arange(150))
    start = 150
    for name in ("skirt", "teeth", "eye", "helmet", "ground"):
        assert np.array_equal(np.sort(rows[name]), start + np.arange(len(rows[name])))
        start += len(rows[name])
    assert len(ch.F) == 192 + 96 and len(ch.surface_F) == len(ch.F) + 64 + 12 + 12 + 10 + 2
    lines = ch.part_lines()
    assert "part 'skirt': 48 vertices, 64 triangles, skinned on skin 1, not a body part: " \
           "surface is open: 32 edges have one triangle" in lines[2]
    assert lines[3].startswith("part 'teeth': 8 vertices, 12 triangles, skinned on skin 0, "
                               "closed but tiny (0.01% of the largest closed part's volume")
    assert lines[4] == ("part 'eye': 8 vertices, 12 triangles, rigid on joint 'head', closed "
                        "-> rigid (carried exactly by its joint)")
    assert lines[1].endswith("-> solved (the body: every stage of the pipeline)")
    # nothing dropped without a line: the helmet's lines, the mesh of points only
    assert any("mesh 5 primitive 1 (node 12) skipped: it is lines, not triangles" in n
               for n in ch.notes), ch.notes
    assert any("part 'markers' (node 14, mesh 7) skipped: it has no triangles" in n
               for n in ch.notes), ch.notes
    assert any("mesh 7 primitive 0 (node 14) skipped: it is points" in n for n in ch.notes)
    assert lines[len(ch.parts):] == ch.notes and len(ch.notes) == 3


@pytest.mark.parametrize("when", [None, 1.0, 0.4])      # rest, the last key, between keys
def test_every_part_sits_where_the_file_puts_it(character, when):
    """Every vertex of every part against the file by the specification: the
    skinned ones (body and skirt, file weights, no stage after skinning) by dual
    quaternions, rigid ones by their node's world matrix to 1e-9."""
    path, ch = character
    fps = 10.0
    q = np.zeros(ch.n_channels) if when is None else \
        load_gltf_scene(path).clip("pose", fps=fps).frames[round(when * fps)]
    X = Pipeline.preset(ch, "dqs").deform(q)
    assert X.shape == ch.surface_V.shape
    want = reference(path, when)
    assert set(want) == {p.name for p in ch.parts}
    for p in ch.parts:
        err = np.abs(X[p.rows] - want[p.name]).max()
        assert err < 1e-9, (p.name, err)
    if when is not None:
        rest = reference(path, None)
        moved = {n: np.abs(want[n] - rest[n]).max() for n in want}
        assert min(v for n, v in moved.items() if n != "ground") > 0.05, moved
        assert moved["ground"] == 0.0
        # rigid parts ride their joint exactly: G_joint B_joint^-1 times the rest points
        fr = Pipeline.preset(ch, "dqs").frame(q)
        j = ch.skeleton.index("head")
        for name in ("eye", "helmet"):
            rows = next(p.rows for p in ch.parts if p.name == name)
            R = np.c_[ch.surface_V[rows], np.ones(len(rows))] @ fr.M[j].T
            assert np.abs(X[rows] - R[:, :3]).max() < 1e-12


def test_the_body_deforms_as_it_would_alone(tmp_path, monkeypatch):
    """Passengers do not touch the body: the default pipeline gives the body of
    the whole character what it gives a file holding only the body's meshes."""
    monkeypatch.setenv("SKIN_NODE_CACHE", str(tmp_path / "cache"))
    whole = load_character(str(write_character(tmp_path / "whole.glb")), tet_count=800,
                           cache=False, progress=False)
    alone = load_character(str(write_character(tmp_path / "alone.glb", BODY)), tet_count=800,
                           cache=False, progress=False)
    assert len(alone.surface_V) == len(alone.V) == len(whole.V) < len(whole.surface_V)
    assert alone.skeleton.names == whole.skeleton.names
    np.testing.assert_array_equal(alone.skeleton.tips, whole.skeleton.tips)
    clip = load_gltf_scene(tmp_path / "whole.glb").clip("pose", fps=4.0)
    a, b = Pipeline.preset(whole, "default"), Pipeline.preset(alone, "default")
    dqs = Pipeline.preset(whole, "dqs")
    solved = 0.0
    for q in clip.frames:
        X, Y = a.deform(q), b.deform(q)
        np.testing.assert_array_equal(X[:len(whole.V)], Y)
        assert set(a.timings) == set(b.timings) | {"passengers"}
        solved = max(solved, float(np.abs(X - dqs.deform(q)).max()))
    assert solved > 1e-4          # the stages did move the body (not only skinning)


def test_a_split_character_is_solved_whole(tmp_path):
    """A torso split into two open meshes on two skins is closed once joined at
    the vertices they share, and solved as one body."""
    whole = load_gltf_scene(write_character(tmp_path / "whole.glb", ("torso",))).split_body()
    split = load_gltf_scene(write_character(tmp_path / "split.glb", ("torso", "lower"),
                                            split=True)).split_body()
    parts = {p.name: p for p in split.parts}
    assert {n: (p.gets, p.shape) for n, p in parts.items()} == {
        "torso": ("solved", "closed (joined with 'lower')"),
        "lower": ("solved", "closed (joined with 'torso')")}
    assert len(split.V) == len(whole.V) == 98 and len(split.passengers) == 0
    assert len(np.intersect1d(parts["torso"].rows, parts["lower"].rows)) > 0   # the seam
    np.testing.assert_allclose(np.sort(split.V, axis=0), np.sort(whole.V, axis=0), atol=1e-12)
    assert len(split.F) == len(whole.F)


def split(tmp_path, names: tuple):
    """The body of a test character of the meshes ``names``, and its parts by name."""
    body = load_gltf_scene(write_character(tmp_path / f"{'-'.join(names)}.glb", names))\
        .split_body()
    return body, {p.name: p for p in body.parts}


def test_parts_that_touch_but_do_not_join_leave_the_largest_solved(tmp_path):
    """A cap set on the torso's edge (a robot's joint cap on its shell): joined
    they are not a surface; the torso, closed alone, is the body and the cap
    rides along skinned, not the whole character posed without the stages."""
    alone, _ = split(tmp_path, ("torso",))
    body, parts = split(tmp_path, ("torso", "cap"))
    assert parts["torso"].gets == "solved" and parts["cap"].gets == "skinned"
    assert parts["torso"].shape == ("closed (alone: joined with the parts it touches, surface "
                                    "is non-manifold: 1 edges have more than two triangles)")
    assert parts["cap"].shape.startswith("not a body part: surface is non-manifold")
    np.testing.assert_array_equal(body.V, alone.V)
    np.testing.assert_array_equal(body.F, alone.F)
    assert len(body.passengers) == 8 and body.notes == []      # the cap's corners


def test_shells_through_each_other_at_rest_are_not_solved(tmp_path):
    """Closed plates that pass through each other at rest have no one skin
    round their flesh: they ride along skinned, the torso beside them is solved;
    of two closed parts through each other, the larger is."""
    alone, _ = split(tmp_path, ("torso",))
    body, parts = split(tmp_path, ("torso", "armour"))
    assert parts["torso"].gets == "solved" and parts["armour"].gets == "skinned"
    assert parts["armour"].shape == ("not a body part: its 2 shells pass through each other "
                                     "at rest (20 intersecting triangle pairs)")
    np.testing.assert_array_equal(body.V, alone.V)
    assert len(body.passengers) == 16
    # a closed part through a larger one: the larger is the body
    body, parts = split(tmp_path, ("torso", "legs", "belt"))
    assert [parts[n].gets for n in ("torso", "legs", "belt")] == ["solved", "solved", "skinned"]
    assert parts["belt"].shape == ("not a body part: passes through 'torso' at rest (68 "
                                   "intersecting triangle pairs)")


def test_rigid_pieces_are_not_solved(tmp_path):
    """Closed pieces each bound wholly to one joint (a robot's) have no skin
    that bends: they ride along skinned beside the solved torso."""
    _, parts = split(tmp_path, ("torso", "pieces"))
    assert parts["torso"].gets == "solved" and parts["pieces"].gets == "skinned"
    assert parts["pieces"].shape == ("not a body part: rigid pieces: each of its 2 shells is "
                                     "bound wholly to one joint (no skin bends)")


def test_no_closed_skinned_part_poses_everything_without_stages(tmp_path, monkeypatch):
    """Half a torso (open) and a skirt, a rigid eye and helmet, the ground: no
    body, no rig; every part is posed as a passenger, where the file puts it."""
    monkeypatch.setenv("SKIN_NODE_CACHE", str(tmp_path / "cache"))
    path = write_character(tmp_path / "open.glb", ("torso", "skirt", "eye", "helmet", "ground"),
                           split=True)
    ch = load_character(str(path), progress=False)
    assert ch.rig is None and len(ch.V) == 0 and len(ch.F) == 0
    assert [p.gets for p in ch.parts] == ["skinned", "skinned", "rigid", "rigid", "static"]
    assert len(ch.surface_V) == sum(p.vertices for p in ch.parts) == ch.parts[0].vertices + 68
    assert ch.notes[-1] == ("no skinned part to solve (each part's line says why): the whole "
                            "character is posed without the pipeline's stages (skinned parts "
                            "by dual quaternions)")
    pipe = Pipeline(ch)                                        # the default stages: none run
    q = load_gltf_scene(path).clip("pose", fps=10.0).frames[-1]
    X = pipe.deform(q)
    assert set(pipe.timings) == {"fk", "passengers", "total"}
    want = reference(path, 1.0)
    for p in ch.parts:
        assert np.abs(X[p.rows] - want[p.name]).max() < 1e-9, p.name
    pipe.set_params(weight_scheme="inverse_distance")         # a rebuild has no stage either
    assert pipe.stages == [] and np.array_equal(pipe.deform(q), X)


def test_one_mesh_files_are_characters_as_before(tmp_path, monkeypatch):
    """A file of one closed skinned mesh: the body is load_gltf's, nothing rides along."""
    monkeypatch.setenv("SKIN_NODE_CACHE", str(tmp_path / "cache"))
    for name in ("RiggedSimple.glb", "RiggedFigure.glb", "CesiumMan.glb"):
        path = DATA / "rigged" / name
        if not path.exists():
            pytest.skip(f"test data {path} is absent")
        g = load_gltf(path)
        body = load_gltf_scene(path).split_body()
        for a, b in ((body.V, g.V), (body.F, g.F), (body.Widx, g.Widx), (body.Wval, g.Wval),
                     (body.skeleton.tips, g.skeleton.tips), (body.file_faces, g.file_faces),
                     (body.file_order, g.vertex_map)):
            np.testing.assert_array_equal(a, b)
        assert len(body.passengers) == 0 and [p.gets for p in body.parts] == ["solved"]
    ch = load_character(str(DATA / "rigged" / "RiggedSimple.glb"), tet_count=600,
                        progress=False)
    assert ch.surface_V is ch.V and ch.surface_F is ch.F


def test_export_writes_every_part_in_the_documented_order(character, tmp_path, capsys):
    from skin_node.io.export import main, read_gltf_morph, read_usd_point_cache
    path, ch = character
    usd, glb = tmp_path / "c.usda", tmp_path / "c.glb"
    assert main(["--character", str(path), "--clip", "pose", "--fps", "4", "--weights", "file",
                 "--pipeline", "dqs", "--float", "-o", str(usd), "-o", str(glb)]) == 0
    n_file = sum(len(p.rows) for p in ch.parts)
    assert f"5 frames of {n_file} points" in capsys.readouterr().out
    clip = load_gltf_scene(path).clip("pose", fps=4.0)
    pipe = Pipeline.preset(ch, "dqs")
    want = np.stack([pipe.deform(q)[ch.file_order] for q in clip.frames])
    # the file's vertices: the body's meshes, then the passengers', each in node order
    order = np.concatenate([p.rows for p in ch.parts if p.gets == "solved"]
                           + [p.rows for p in ch.parts if p.gets != "solved"])
    assert np.array_equal(ch.file_order, order)
    for reader, f in ((read_usd_point_cache, usd), (read_gltf_morph, glb)):
        X, faces, _ = reader(f)
        assert np.array_equal(faces, ch.file_faces) and len(faces) == len(ch.surface_F)
        assert np.abs(X - want).max() < 1e-6          # float32 points


def test_player_and_bench_take_a_multi_skin_file(character, tmp_path, capsys):
    import json
    from skin_node.bench import cli
    from skin_node.motion import character_skeleton, clip_names, load_motion
    path, ch = character
    skel = character_skeleton(str(path))
    assert skel.channel_names == ch.channel_names
    np.testing.assert_array_equal(skel.tips, ch.skeleton.tips)
    assert clip_names(str(path))[0] == "pose"
    assert load_motion(str(path), "pose", fps=10.0).frames.shape == (11, ch.n_channels)
    out = tmp_path / "bench"
    assert cli.main(["run", "--pipelines", "default", "--scenes", str(path), "--stride", "3",
                     "--ref-frames", "0", "--no-charts", "--no-progress", "--out",
                     str(out)]) == 0
    (run,) = json.loads((out / "runs.json").read_text())["runs"]
    assert run["vertices"] == len(ch.V) and run["ms_passengers_p50"] > 0


def test_strips_and_fans_are_triangles_in_the_specifications_order():
    from skin_node.io.gltf import _triangles
    idx = np.array([10, 11, 12, 13, 14])
    assert _triangles(idx, 5).tolist() == [[10, 11, 12], [11, 13, 12], [12, 13, 14]]
    assert _triangles(idx, 6).tolist() == [[11, 12, 10], [12, 13, 10], [13, 14, 10]]
    assert _triangles(idx[:2], 5).shape == (0, 3)


def test_compressed_geometry_is_refused_by_name(tmp_path):
    from skin_node.io.character_file import CharacterFileError
    g = pygltflib.GLTF2().load_binary(str(write_character(tmp_path / "c.glb", BODY)))
    g.extensionsUsed = g.extensionsRequired = ["KHR_draco_mesh_compression"]
    g.save_binary(str(tmp_path / "draco.glb"))
    with pytest.raises(CharacterFileError, match=r"draco.glb: needs KHR_draco_mesh_compression "
                                                 r"\(Draco-compressed meshes\), which is not read"):
        load_character(str(tmp_path / "draco.glb"), progress=False)
