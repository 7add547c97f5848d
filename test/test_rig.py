"""The rig: lattice tets, embedding, edges, weights, cache, parameters."""
from dataclasses import fields

import numpy as np
import pytest
import trimesh

import skin_node.rigging.build as build
from skin_node.character import load_character
from skin_node.metrics import mesh_volume
from skin_node.pipeline import PIPELINE_PARAMS, ParamSpec, Pipeline
from skin_node.rigging.build import Rig
from skin_node.rigging.tetra import lattice_tets, signed_volumes, tet_edges
from skin_node.rigging.weights import (bone_distances, inverse_distance_weights, joint_regions,
                                       point_segment_distance)
from skin_node.skeleton import Skeleton

SPHERE_R, SPHERE_H = 0.05, 0.01


@pytest.fixture(scope="module")
def arm():
    return load_character("arm", surface_vertices=2000, progress=False)


@pytest.fixture(scope="module")
def sphere():
    s = trimesh.creation.icosphere(subdivisions=2, radius=SPHERE_R)
    V, F = np.asarray(s.vertices), np.asarray(s.faces, dtype=np.int64)
    return V, F, lattice_tets(V, F, SPHERE_H)


def meshes(arm, sphere):
    V, F, lat = sphere
    r = arm.rig
    return {"sphere": (V, F, lat),
            "arm": (arm.V, arm.F, (r.TV, r.T, r.Etet, r.Ebary)),
            "arm direct": (arm.V, arm.F, lattice_tets(arm.V, arm.F, float(r.cube)))}


MESHES = ["sphere", "arm", "arm direct"]


# ============================================================ lattice
@pytest.mark.parametrize("which", MESHES)
def test_lattice_tets_orientation_and_volume(arm, sphere, which):
    V, F, (TV, T, _, _) = meshes(arm, sphere)[which]
    sv = signed_volumes(TV, T)
    assert len(T) > 100
    assert np.all(sv > 0) or np.all(sv < 0)
    vol = np.abs(sv).sum()
    body = mesh_volume(V, F)
    assert body > 0
    assert body <= vol <= 1.5 * body, vol / body
    # all tets are Kuhn tets of one cube size: volume h^3 / 6
    assert np.allclose(np.abs(sv), np.abs(sv).mean(), rtol=1e-9)


@pytest.mark.parametrize("which", MESHES)
def test_embedding_reproduces_surface(arm, sphere, which):
    V, _, (TV, T, Etet, Ebary) = meshes(arm, sphere)[which]
    assert Etet.shape == (len(V), 4) and Ebary.shape == (len(V), 4)
    assert np.all(Ebary >= 0.0) and np.all(Ebary <= 1.0)
    assert np.abs(Ebary.sum(1) - 1.0).max() < 1e-12
    P = np.einsum("na,nad->nd", Ebary, TV[Etet])
    assert np.abs(P - V).max() < 1e-12
    # each vertex's 4 tet vertices are an actual tet of the mesh
    tets = {tuple(sorted(t)) for t in T.tolist()}
    assert all(tuple(sorted(e)) in tets for e in Etet.tolist())


def test_lattice_covers_the_deep_interior(sphere):
    """Every point deeper than a cube diagonal inside the surface lies in some tet."""
    _, _, (TV, T, _, _) = sphere
    rng = np.random.default_rng(0)
    P = rng.uniform(-1, 1, (400, 3))
    P = P / np.linalg.norm(P, axis=1, keepdims=True) * rng.uniform(0, 1, (400, 1)) ** (1 / 3)
    P *= 0.049 - SPHERE_H * np.sqrt(3)             # 0.049 < the icosphere's inradius
    X = TV[T]
    Ai = np.linalg.inv(np.stack([X[:, 1] - X[:, 0], X[:, 2] - X[:, 0], X[:, 3] - X[:, 0]], 2))
    for p in P:
        b = np.einsum("tij,tj->ti", Ai, p - X[:, 0])
        assert np.any(np.all(b >= -1e-9, axis=1) & (b.sum(1) <= 1 + 1e-9))


def test_lattice_rejects_bad_cube(sphere):
    V, F, _ = sphere
    for h in (0.0, -0.01, float("nan")):
        with pytest.raises(ValueError, match="cube size must be positive"):
            lattice_tets(V, F, h)


def test_tet_edges_unique_and_complete(arm):
    T = arm.rig.T
    E = tet_edges(T)
    assert E.shape[1] == 2
    assert np.all(E[:, 0] < E[:, 1])
    assert len(np.unique(E, axis=0)) == len(E)
    all_pairs = np.sort(T[:, [[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]]].reshape(-1, 2), 1)
    assert {tuple(e) for e in all_pairs.tolist()} == {tuple(e) for e in E.tolist()}
    assert np.array_equal(E, arm.rig.E)


# ============================================================ weights
@pytest.mark.parametrize("mesh", ["surface", "tets"])
def test_paper_weights_rows(arm, mesh):
    """The paper's weights, kept in the rig for the pipelines that reproduce it."""
    r = arm.rig
    w = r.weights("inverse_distance")
    W, I, region, P = ((w.Wval, w.Widx, r.region, arm.V) if mesh == "surface"
                       else (w.TWval, w.TWidx, r.tregion, r.TV))
    skel = arm.skeleton
    assert W.shape == (len(P), 3) and I.shape == (len(P), 3)
    assert np.all(W >= 0)
    assert np.abs(W.sum(1) - 1).max() < 1e-12
    assert np.all((I >= 0) & (I < skel.n_joints))
    n = (W > 0).sum(1)
    assert np.all(n[region < 0] <= 2)
    assert (region >= 0).sum() > 0 and (region < 0).sum() > 0
    # joint-region points take 3 bones where the nearest bone has 3 tree neighbours
    D, _ = bone_distances(P, skel)
    nearest = np.argmin(D, axis=1)
    cand = np.ones(skel.n_joints, dtype=int)
    for j in range(1, skel.n_joints):
        cand[j] += 1
        cand[skel.parents[j]] += 1
    jr = region >= 0
    assert np.array_equal(n[jr], np.minimum(3, cand[nearest[jr]]))
    assert np.any(n[jr] == 3)
    # the bones used are distinct
    for i in np.flatnonzero(n > 1):
        assert len(set(I[i, :n[i]])) == n[i]


@pytest.mark.parametrize("mesh", ["surface", "tets"])
def test_paper_weights_follow_inverse_fourth_power(arm, mesh):
    r = arm.rig
    w = r.weights("inverse_distance")
    W, I, P = (w.Wval, w.Widx, arm.V) if mesh == "surface" else (w.TWval, w.TWidx, r.TV)
    D, _ = bone_distances(P, arm.skeleton)
    d = np.maximum(np.take_along_axis(D, I, axis=1), 1e-6)
    two = np.flatnonzero(((W > 1e-3).sum(1) == 2) & (W[:, 2] == 0))
    assert len(two) > 10
    i = two
    assert np.allclose(W[i, 0] / W[i, 1], (d[i, 1] / d[i, 0]) ** 4, rtol=1e-9)
    inv = np.where(W > 0, d ** -4.0, 0.0)
    assert np.allclose(W, inv / inv.sum(1, keepdims=True), rtol=1e-9, atol=1e-15)
    # the largest weight goes to the nearest bone
    assert np.array_equal(I[np.arange(len(P)), np.argmax(W, 1)], np.argmin(D, 1))


def test_regions_follow_thresholds(arm):
    r, skel = arm.rig, arm.skeleton
    d = np.linalg.norm(arm.V[:, None, :] - skel.rest_positions[None], axis=2)
    inside = (d < r.threshold[None]) & (skel.parents >= 0)[None]
    assert np.array_equal(r.region >= 0, inside.any(1))
    j = r.region[r.region >= 0]
    assert np.all(inside[r.region >= 0, j])
    assert np.all(r.region != 0)                   # the root has no region
    assert np.array_equal(joint_regions(arm.V, skel, r.threshold), r.region)


def test_a_joint_detached_from_the_skin_has_no_region(sphere):
    """A hand alone on a whole arm's skeleton (a robot whose hands alone are
    skin): the elbow and the wrist lie outside, far from the skin, and take
    none of it; the knuckle inside, and a joint set just outside its skin,
    keep theirs."""
    V, F, _ = sphere
    R = SPHERE_R
    P = [[-12 * R, 0, 0], [-8 * R, 0, 0], [-4 * R, 0, 0], [0.5 * R, 0, 0], [1.1 * R, 0, 0]]
    sk = Skeleton(["shoulder", "elbow", "wrist", "knuckle", "nail"], [-1, 0, 1, 2, 3], P,
                  tips=[[np.nan] * 3] * 4 + [[1.5 * R, 0, 0]])
    rig = build.build_rig(V, F, sk, build.RigOptions(tet_count=500))
    counts = np.bincount(rig.region + 1, minlength=6)[1:]
    assert counts[1] == counts[2] == 0                  # elbow, wrist: outside and far
    assert counts[3] > 0 and counts[4] > 0              # knuckle inside, nail 0.1 R outside
    assert rig.threshold[1] == rig.threshold[2] == 0.0


def test_inverse_distance_weights_paper_counts():
    """Without the tree restriction: 3 bones in a joint region, 2 elsewhere, (1/d)^4."""
    sk = Skeleton(["a", "b", "c", "d"], [-1, 0, 1, 2],
                  [[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]],
                  tips=[[np.nan] * 3] * 3 + [[4, 0, 0]])
    rng = np.random.default_rng(0)
    D = rng.uniform(0.05, 2.0, (50, 4))
    region = np.where(np.arange(50) % 2 == 0, 1, -1)
    Widx, Wval = inverse_distance_weights(D, region, sk, 4.0, neighbours_only=False)
    n = (Wval > 0).sum(1)
    assert np.all(n[region >= 0] == 3) and np.all(n[region < 0] == 2)
    order = np.argsort(D, 1)
    for i in range(50):
        k = n[i]
        assert set(Widx[i, :k]) == set(order[i, :k])
        inv = D[i, order[i, :k]] ** -4.0
        assert np.allclose(Wval[i, :k], inv / inv.sum(), rtol=1e-12)
    # with the tree restriction, a bone two steps away from the nearest one never weighs
    D = np.array([[1.0, 0.1, 0.5, 0.2]])           # nearest b; d is near but not a neighbour
    Widx, Wval = inverse_distance_weights(D, np.array([2]), sk, 4.0, neighbours_only=True)
    assert set(Widx[0][Wval[0] > 0]) == {0, 1, 2}
    Widx, Wval = inverse_distance_weights(D, np.array([2]), sk, 4.0, neighbours_only=False)
    assert set(Widx[0][Wval[0] > 0]) == {1, 2, 3}


def test_point_segment_distance():
    A = np.array([[0.0, 0, 0]])
    B = np.array([[1.0, 0, 0]])
    P = np.array([[0.5, 0.3, 0.4], [-1.0, 0, 0], [2.0, 1.0, 0], [0.2, 0, 0]])
    assert np.allclose(point_segment_distance(P, A, B)[:, 0],
                       [0.5, 1.0, np.sqrt(2), 0.0], atol=1e-15)


# ============================================================ cache
def test_rig_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SKIN_NODE_CACHE", str(tmp_path))
    kw = dict(surface_vertices=2000, tet_count=1500, progress=False)
    a = load_character("arm", **kw)
    rigs = list(tmp_path.glob("rig-*.npz"))
    assert len(rigs) == 1 and len(list(tmp_path.glob("mesh-arm-*.npz"))) == 1

    def no_build(*args, **kwargs):
        raise AssertionError("rig rebuilt instead of read from the cache")

    monkeypatch.setattr(build, "build_rig", no_build)
    b = load_character("arm", **kw)
    assert np.array_equal(a.V, b.V) and np.array_equal(a.F, b.F)
    for f in fields(Rig):
        x, y = getattr(a.rig, f.name), getattr(b.rig, f.name)
        assert x.dtype == y.dtype and np.array_equal(x, y), f.name
    assert a.skeleton.names == b.skeleton.names
    # a different option is a different key, so it is built (and fails here)
    with pytest.raises(AssertionError, match="rebuilt"):
        load_character("arm", surface_vertices=2000, tet_count=1600, progress=False)


def test_corrupt_rig_cache_is_rebuilt(tmp_path, monkeypatch):
    monkeypatch.setenv("SKIN_NODE_CACHE", str(tmp_path))
    kw = dict(surface_vertices=2000, tet_count=1500, progress=False)
    a = load_character("arm", **kw)
    (path,) = tmp_path.glob("rig-*.npz")
    path.write_bytes(b"not a zip file")
    b = load_character("arm", **kw)
    assert np.array_equal(a.rig.T, b.rig.T) and np.array_equal(a.rig.Wval, b.rig.Wval)
    assert np.array_equal(Rig.load(path).TV, a.rig.TV)      # rewritten


def test_no_cache_writes_nothing(tmp_path, monkeypatch):
    d = tmp_path / "cache"
    monkeypatch.setenv("SKIN_NODE_CACHE", str(d))
    ch = load_character("arm", surface_vertices=2000, tet_count=1500, cache=False,
                        progress=False)
    assert len(ch.rig.T) > 0
    assert not d.exists()


# ============================================================ parameters
BAD_PARAMS = [
    ("iterations", -1, "outside"),
    ("iterations", 201, "outside"),
    ("iterations", 2.5, "integer"),
    ("iterations", "5", "number"),
    ("iterations", True, "number"),
    ("iterations", None, "number"),
    ("stiffness", 2.0, "outside"),
    ("stiffness", -0.1, "outside"),
    ("stiffness", float("nan"), "outside"),
    ("stiffness", float("inf"), "outside"),
    ("stretch_compliance", -1e-9, "outside"),
    ("threads", 0, "outside"),
    ("solver", "newton", "one of"),
    ("solver", 1, "one of"),
    ("constraints", "stretch", "list of strings"),
    ("constraints", ["stretch", 3], "list of strings"),
    ("constraints", ["stretch", "gravity"], "unknown \\['gravity'\\]"),
    ("active_regions", 1, "bool"),
    ("active_regions", "yes", "bool"),
]


@pytest.mark.parametrize("name, value, msg", BAD_PARAMS)
def test_paramspec_rejects(name, value, msg):
    with pytest.raises(ValueError, match=msg) as e:
        PIPELINE_PARAMS[name].check(name, value)
    assert name in str(e.value)


@pytest.mark.parametrize("name, value, msg", BAD_PARAMS)
def test_set_params_rejects_and_keeps_old_values(arm, name, value, msg):
    p = Pipeline(arm, ["lbs"])
    before = dict(p.params)
    with pytest.raises(ValueError, match=msg) as e:
        p.set_params(smoothing=0.9, **{name: value})
    assert name in str(e.value)
    assert p.params == before                      # nothing applied, not even smoothing=0.9
    with pytest.raises(ValueError, match=name):
        Pipeline(arm, ["lbs"], **{name: value})


def test_set_params_unknown_name(arm):
    p = Pipeline(arm, ["lbs"])
    with pytest.raises(ValueError, match="unknown parameter 'itterations'"):
        p.set_params(itterations=3)
    with pytest.raises(ValueError, match="unknown parameter 'foo'"):
        Pipeline(arm, ["lbs"], foo=1)


def test_set_params_accepts_and_converts(arm):
    p = Pipeline(arm, ["lbs"])
    p.set_params(iterations=np.int64(12), stiffness=1, active_regions=np.bool_(False),
                 constraints=("stretch", "bind"), solver="pbd", tolerance=np.float32(0.5))
    assert p.params["iterations"] == 12 and type(p.params["iterations"]) is int
    assert p.params["stiffness"] == 1.0 and type(p.params["stiffness"]) is float
    assert p.params["active_regions"] is False
    assert p.params["constraints"] == ["stretch", "bind"]
    assert p.params["solver"] == "pbd"
    p.set_params(iterations=3.0)
    assert p.params["iterations"] == 3 and type(p.params["iterations"]) is int
    for k, s in PIPELINE_PARAMS.items():              # every default passes its own check
        assert s.check(k, s.default) == s.default


def test_paramspec_bounds_inclusive():
    s = ParamSpec(float, 0.5, 0.0, 1.0)
    assert s.check("x", 0.0) == 0.0 and s.check("x", 1.0) == 1.0
    with pytest.raises(ValueError, match="x = 1.0000001 is outside \\[0.0, 1.0\\]"):
        s.check("x", 1.0000001)


@pytest.mark.parametrize("stages, msg", [
    (["lbs", "wobble"], "unknown stage\\(s\\) \\['wobble'\\]"),
    (["pbd"], "first stage must be 'lbs' or 'dqs'"),
    (["pbd", "lbs"], "first stage must be 'lbs' or 'dqs'"),
    ([], "first stage must be 'lbs' or 'dqs'"),
    (["lbs", "dqs"], "only the first stage may skin"),
    (["dqs", "pbd", "lbs"], "only the first stage may skin"),
    (["lbs", "lbs"], "only the first stage may skin"),
])
def test_pipeline_rejects_bad_stage_lists(arm, stages, msg):
    with pytest.raises(ValueError, match=msg):
        Pipeline(arm, stages)


def test_pipeline_rejects_bad_pose(arm):
    p = Pipeline(arm, ["lbs"])
    with pytest.raises(ValueError, match="pose has shape"):
        p.deform(np.zeros(arm.n_channels + 1))
    q = arm.skeleton.rest_pose()
    q[4] = np.nan
    with pytest.raises(ValueError, match="NaN or Inf"):
        p.deform(q)


def test_weights_with_fewer_than_three_bones():
    """A two-joint skeleton (a bent tube like RiggedSimple) still gets valid weights."""
    from skin_node.rigging.weights import bone_distances, inverse_distance_weights, joint_regions
    skel = Skeleton(["a", "b"], np.array([-1, 0]), np.array([[0, 0, 0], [1.0, 0, 0]]),
                    tips=np.array([[np.nan] * 3, [2.0, 0, 0]]))
    P = np.array([[0.5, 0.1, 0], [1.0, 0.1, 0], [1.5, 0.1, 0]])
    D, _ = bone_distances(P, skel)
    region = joint_regions(P, skel, np.array([0.0, 0.3]))
    Widx, Wval = inverse_distance_weights(D, region, skel)
    assert Widx.shape == (3, 3) and np.allclose(Wval.sum(1), 1.0)
    assert Widx.max() <= 1 and np.all(Wval >= 0)
    assert abs(Wval[1, 0] - 0.5) < 1e-9          # on the joint: half and half
