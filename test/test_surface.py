"""The skin as a viewer sees it: smooth weights, a clean contact crease, and
the measures and pictures that judge them (none of them a stage's own rule)."""
from __future__ import annotations

import numpy as np
import pytest
import trimesh
import yaml

from skin_node import Pipeline, load_character
from skin_node.bench.measure import SceneMetrics
from skin_node.kernels.bvh import closest, crossings, inside, mesh_tree
from skin_node.kernels.contact import field_at, skinned_field
from skin_node.kernels.intersect import SelfIntersections
from skin_node.kernels.raster import render
from skin_node.kernels.smoothing import (laplacian_smooth, relax_tangents, rest_tangents,
                                        restore_detail, ring_layout, vertex_faces)
from skin_node.metrics import SurfaceQuality, weight_jumps
from skin_node.kernels.skinning import matrices_to_dual_quaternions


@pytest.fixture(scope="module")
def humanoid():
    return load_character("humanoid", progress=False)


@pytest.fixture(scope="module")
def small_arm():
    return load_character("arm", surface_vertices=2000, progress=False)


def grid(n=11, h=0.01):
    """A flat n x n grid in z = 0, two triangles a cell."""
    x, y = np.meshgrid(np.arange(n) * h, np.arange(n) * h, indexing="ij")
    V = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            a, b, c, d = i * n + j, (i + 1) * n + j, (i + 1) * n + j + 1, i * n + j + 1
            F += [[a, b, c], [a, c, d]]
    return V, np.array(F)


# ------------------------------------------------------------------ measures
def test_surface_quality_counts_the_edges_of_a_fold():
    """A flat sheet folded along a grid line by 120 degrees: exactly the edges
    on that line turn by 120 (folds90 and folds45); by 60, only folds45."""
    V, F = grid()
    sq = SurfaceQuality(V, F)
    assert sq(V) == {"folds90": 0, "folds45": 0, "roughness": 1.0, "roughness_p99": 1.0}
    for angle, f90 in ((120, 10), (60, 0)):
        a = np.radians(angle)
        X = V.copy()
        far = V[:, 0] > 0.05 + 1e-9
        d = V[far, 0] - 0.05
        X[far, 0] = 0.05 + d * np.cos(a)
        X[far, 2] = d * np.sin(a)
        s = sq(X)
        assert s["folds90"] == f90 and s["folds45"] == 10, (angle, s)
    # noise on the sheet is roughness
    rng = np.random.default_rng(1)
    X = V + rng.normal(0.0, 0.002, V.shape)
    assert sq(X)["roughness"] > 1.5


def test_weight_jumps_read_a_seam():
    F = np.array([[0, 1, 2]])
    Widx = np.array([[0, 1], [0, 1], [1, 0]])
    Wval = np.array([[1.0, 0.0], [0.5, 0.5], [1.0, 0.0]])
    j = weight_jumps(F, Widx, Wval, 2)            # edges (0,1), (0,2), (1,2)
    assert np.allclose(np.sort(j), [1.0, 1.0, 2.0])


# ------------------------------------------------------------------- weights
@pytest.mark.parametrize("name", ["arm", "humanoid"])
def test_built_ins_have_smooth_weights(name, humanoid):
    """No edge of a built-in character jumps by more than 0.5 in weight; the
    paper's inverse-distance weights tear the humanoid along hundreds."""
    ch = humanoid if name == "humanoid" else load_character("arm", progress=False)
    r = ch.rig
    J = ch.skeleton.n_joints
    assert r.Widx.shape[1] == 4 and np.all(r.Wval >= 0)
    assert np.abs(r.Wval.sum(1) - 1).max() < 1e-9 and np.abs(r.TWval.sum(1) - 1).max() < 1e-9
    assert weight_jumps(ch.F, r.Widx, r.Wval, J).max() < 0.5
    if name == "humanoid":
        paper = r.weights("inverse_distance")
        assert (weight_jumps(ch.F, paper.Widx, paper.Wval, J) > 0.5).sum() > 100


def test_lbs_folds_no_skin_at_arms_lowered(humanoid):
    """Arms lowered 70 degrees from the T-pose, nothing else: nothing touches,
    so plain LBS should fold nothing; on the paper's weights it folds the
    chest and shoulders along the weights' seams."""
    q = humanoid.pose(l_shoulder_rx=-1.2, r_shoulder_rx=1.2)
    sq = SurfaceQuality(humanoid.V, humanoid.F)
    ours = sq(Pipeline(humanoid, ["lbs"]).deform(q))["folds90"]
    paper = sq(Pipeline(humanoid, ["lbs"], weight_scheme="inverse_distance").deform(q))["folds90"]
    assert ours <= 10, ours
    assert paper > 100, paper


def test_no_upper_arm_weight_under_the_armpit_where_it_is_out_of_sight(humanoid):
    """Bone heat weighs a vertex by the bones it sees through the body: the
    torso's side below the armpit sees the chest, not the upper arm (the air
    under the armpit is in between), so it barely follows the arm."""
    ch, skel = humanoid, humanoid.skeleton
    r = ch.rig
    sh = skel.rest_positions[skel.index("l_shoulder")]
    side = np.flatnonzero((np.abs(ch.V[:, 1] - (sh[1] - 0.06)) < 0.015)
                          & (ch.V[:, 2] < sh[2] - 0.12) & (ch.V[:, 2] > sh[2] - 0.2))
    assert len(side) > 5
    w = (r.Wval[side] * (r.Widx[side] == skel.index("l_shoulder"))).sum(1)
    assert w.max() < 0.15, w.max()


# ---------------------------------------------------------------- the crease
def test_default_beats_dqs_on_a_small_arm_at_150(small_arm):
    """The arm at 150 degrees against DQS on the same weights: no more than a
    tenth of its intersecting triangle pairs, no more sharp folds, roughness
    within 5%, the elbow's region within 3%, the whole arm's volume within 3%,
    the bulge at most half of DQS's; and the contact stage is what parts the
    skin."""
    ch = small_arm
    q = ch.pose(elbow_rz=np.radians(150))
    si, sq, sm = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F), SceneMetrics(ch)
    out = {}
    for name, pipe in (("dqs", Pipeline.preset(ch, "dqs")), ("ours", Pipeline.preset(ch, "default")),
                       ("no contact", Pipeline(ch, ["dqs", "bulge", "inflate"]))):
        X = pipe.deform(q)
        fr = pipe.last_frame
        out[name] = {"pairs": len(si.pairs(X)), **sq(X),
                     "bulge": float(sm.deviation_mm(X, fr.seg_A, fr.seg_B).max()),
                     "region": sm.region_ratio(X, fr.G, ch.skeleton.index("elbow")),
                     "volume": sm.measure(X, fr, crossings=False)["volume_ratio"]}
    d, o = out["dqs"], out["ours"]
    assert d["pairs"] > 50 and o["pairs"] <= 0.1 * d["pairs"], out
    assert o["folds90"] <= d["folds90"], out
    assert o["roughness"] <= 1.05 * d["roughness"], out
    assert abs(o["region"] - 1.0) <= 0.03 and o["volume"] >= 0.97, out
    assert o["bulge"] <= 0.5 * d["bulge"], out
    assert out["no contact"]["pairs"] > 50, out


def test_inflation_gives_volume_back_inside_the_bulge_envelope(small_arm):
    """At 150 degrees the bulge limit draws the elbow's outer skin in and the
    region loses a tenth of its volume; inflation gives it back from skin
    with room under the envelope: the region within 1% of rest, the bulge
    no more than a millimetre past what the bulge limit left."""
    ch = small_arm
    q = ch.pose(elbow_rz=np.radians(150))
    sm, elbow = SceneMetrics(ch), ch.skeleton.index("elbow")
    res = {}
    for name, stages in (("bulge", ["dqs", "bulge"]), ("inflated", ["dqs", "bulge", "contact", "inflate"])):
        pipe = Pipeline(ch, stages)
        X = pipe.deform(q)
        fr = pipe.last_frame
        res[name] = (float(sm.deviation_mm(X, fr.seg_A, fr.seg_B).max()), sm.region_ratio(X, fr.G, elbow))
    assert res["bulge"][1] < 0.93, res
    assert abs(res["inflated"][1] - 1.0) <= 0.01, res
    assert res["inflated"][0] <= res["bulge"][0] + 1.0, res


def test_region_volume_kernel_follows_its_numpy_reference(small_arm):
    """The joint region's layers in one kernel (a speed lever) move the
    skin as the same layers written in numpy do, to 1e-12 m, at the elbow
    bent to 150 degrees after the bulge limit and contact, where both
    phases (inside the bulge envelope, then past it within the outer one)
    run."""
    from skin_node.kernels.shape import (cone_volume_gradient, envelope_room,
                                         keep_region_volume)
    ch = small_arm
    pipe = Pipeline(ch, ["dqs", "bulge", "contact", "inflate"])
    pipe.deform(ch.pose(elbow_rz=np.radians(150)))
    fr, st = pipe.last_frame, pipe.stages[3]
    j = ch.skeleton.index("elbow")
    v, t, corners, F = st.verts[j], st.tris[j], st.corners[j], st.F
    X0 = fr.surface.copy()
    X0[v] -= 0.08 * (X0[v] - fr.G[j, :3, 3])        # a region short of its volume
    free = np.ones(len(X0))
    free[v[::3]] = 0.5
    # a small cap: the region is still short after four layers, so the last four run too
    c, limit, cap, outer = fr.G[j, :3, 3].copy(), 0.1, 0.01 * st.radius[j], 0.35
    mob = st.mob[j] * fr.fade[j]
    # the reference: the layers as numpy arrays
    X, g = X0.copy(), np.empty((len(v), 3))
    vol = cone_volume_gradient(X, F, t, c, corners, g)
    steps = 0
    for it in range(8):
        deficit = st.vol0[j] - vol
        if abs(deficit) <= 2e-3 * abs(st.vol0[j]) or (deficit <= 0.0 and it >= 4):
            break
        m, room = mob.copy(), None
        if deficit > 0.0:
            m = m * free[v]
            env = limit if it < 4 else outer
            room = np.empty(len(v))
            envelope_room(X, v, st.seg, st.r0, st.hold, fr.seg_A, fr.seg_B, env, room)
            x = np.clip(room / np.maximum(0.5 * env * st.r0[v, 0], 1e-12), 0.0, 1.0)
            m = m * x * x * (3.0 - 2.0 * x)
        a = np.linalg.norm(g, axis=1)
        den = float((m * a).sum())
        if den <= 0.0:
            continue
        step = np.clip((deficit / den) * m, -cap, cap)
        if room is not None:
            step = np.minimum(step, room)
        X[v] += step[:, None] * (g / np.maximum(a, 1e-30)[:, None])
        vol = cone_volume_gradient(X, F, t, c, corners, g)
        steps += 1
    Y = X0.copy()
    got = keep_region_volume(Y, F, t, c, corners, v, mob, free, st.seg, st.r0, st.hold,
                             fr.seg_A, fr.seg_B, limit, st.vol0[j], cap, Y.copy(),
                             np.full(len(Y), np.inf), st._edge, np.empty((len(v), 3)),
                             np.empty(len(v)), np.empty(len(v)), outer)
    assert steps == 8, steps
    assert np.abs(Y - X).max() <= 1e-12, np.abs(Y - X).max()
    assert abs(got - vol) <= 1e-12 * abs(vol)
    assert np.abs(Y - X0).max() > 1e-4           # it did move skin


def capsule(path, r=0.045, length=0.5, h=0.008):
    """A capsule limb along +x meshed by marching cubes (not one of ours),
    with a two-bone character file: root at one end, a hinge in the middle."""
    from skimage.measure import marching_cubes
    lo = np.array([-0.01, -r - 0.01, -r - 0.01])
    hi = np.array([length + 2 * r + 0.01, r + 0.01, r + 0.01])
    n = np.ceil((hi - lo) / h).astype(int) + 1
    g = np.stack(np.meshgrid(*[lo[k] + h * np.arange(n[k]) for k in range(3)], indexing="ij"), -1)
    x = np.clip(g[..., 0], r, length + r)
    sdf = np.sqrt((g[..., 0] - x) ** 2 + g[..., 1] ** 2 + g[..., 2] ** 2) - r
    V, F, _, _ = marching_cubes(sdf, 0.0, spacing=(h, h, h), method="lewiner")
    m = trimesh.Trimesh(V + lo, F, process=True)
    if m.volume < 0:
        m.invert()
    m.export(path.parent / "limb.obj")
    joints = [{"name": "root", "position": [r, 0, 0]},
              {"name": "hinge", "parent": "root", "position": [r + length / 2, 0, 0],
               "tip": [r + length, 0, 0]}]
    path.write_text(yaml.safe_dump({"mesh": "limb.obj", "joints": joints}))
    return path


def test_a_capsule_limb_folded_to_150_meets_itself_cleanly(tmp_path, monkeypatch):
    """A two-bone capsule we did not make (marching cubes, slivers and all)
    folded to 150 degrees: DQS passes skin through skin; ours leaves no
    intersecting pair and no more sharp folds than DQS."""
    monkeypatch.setenv("SKIN_NODE_CACHE", str(tmp_path / "cache"))
    ch = load_character(str(capsule(tmp_path / "limb.yaml")), progress=False)
    q = ch.pose(hinge_rz=np.radians(150))
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    dqs, ours = Pipeline.preset(ch, "dqs").deform(q), Pipeline.preset(ch, "default").deform(q)
    assert len(si.pairs(dqs)) > 50
    assert len(si.pairs(ours)) == 0
    assert sq(ours)["folds90"] <= sq(dqs)["folds90"], (sq(ours), sq(dqs))
    assert sq(ours)["roughness"] <= 1.05 * sq(dqs)["roughness"]


def test_a_coarse_limb_folded_keeps_its_triangles_apart_too(tmp_path, monkeypatch):
    """The same capsule meshed at 21 mm around its 45 mm radius (CesiumMan's
    resolution): folded to 150 degrees, every vertex can stay out of the other
    side's flesh while the flat triangles between them still cross. The
    default leaves no intersecting pair. Two things keep it so, each enough
    here: contact that starts a couple of chord sagittas outside the flesh
    (started at the flesh's surface, inflation's layers swell 11 pairs back
    through), and inflation withheld where its layers run coarse skin through
    another part's or undone where they still fold it (with those, started at
    the surface leaves none either). No more sharp folds than DQS (3
    against 9): the contact's easing of coarse skin, smoothing the opposite
    pushes on the two sides of the fold, left 12 where it kept the smoothing
    even where that creased more."""
    import skin_node.stages.shape as shape
    monkeypatch.setenv("SKIN_NODE_CACHE", str(tmp_path / "cache"))
    ch = load_character(str(capsule(tmp_path / "limb.yaml", h=0.021)), progress=False)
    q = ch.pose(hinge_rz=np.radians(150))
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    dqs, ours = Pipeline.preset(ch, "dqs").deform(q), Pipeline.preset(ch, "default").deform(q)
    at_surface = Pipeline.preset(ch, "default", contact_onset=0.0).deform(q)
    assert len(si.pairs(dqs)) > 40
    assert len(si.pairs(ours)) == 0
    assert len(si.pairs(at_surface)) == 0
    assert sq(ours)["folds90"] <= sq(dqs)["folds90"], (sq(ours), sq(dqs))
    assert sq(ours)["roughness"] <= 1.05 * sq(dqs)["roughness"]
    monkeypatch.setattr(shape, "WITHHOLD_ROUNDS", 0)
    monkeypatch.setattr(shape, "FINAL_BEND", 1e9)
    assert len(si.pairs(Pipeline.preset(ch, "default").deform(q))) == 0
    assert len(si.pairs(Pipeline.preset(ch, "default", contact_onset=0.0).deform(q))) >= 5


def _mush(X, V, F, verts, passes):
    """Delta Mush of ``verts`` of ``X`` (rest ``V``), even weights, by hand."""
    m = trimesh.Trimesh(V, F, process=False)
    ptr = np.r_[0, np.cumsum([len(n) for n in m.vertex_neighbors])].astype(np.int64)
    adj = np.concatenate(m.vertex_neighbors).astype(np.int64)
    ring, loc, lptr, lnbr = ring_layout(np.sort(verts), ptr, adj)
    L, buf = np.empty((len(ring), 3)), np.empty((len(loc), 3))
    SX, SV = X.copy(), V.copy()
    for S in (SX, SV):
        laplacian_smooth(S, S, False, ring, loc, lptr, lnbr, np.empty(0), 0.5, np.empty(0), passes, L, buf)
    out = X.copy()
    restore_detail(out, V, SX, SV, np.sort(verts).astype(np.int64), F.astype(np.int64),
                   *vertex_faces(F, len(V)), adj[ptr[:-1]], np.ones(len(V)))
    return out


def test_mush_leaves_a_rigidly_moved_surface_where_it_is():
    """Smoothing commutes with a rigid motion, and the rest detail turns with
    its frame: a bumpy sphere turned and moved comes out of the mush as it
    went in, though the same mush of a squashed one moves it."""
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    rng = np.random.default_rng(3)
    V = m.vertices * (1.0 + 0.05 * rng.standard_normal((len(m.vertices), 1)))
    F = m.faces
    R = trimesh.transformations.rotation_matrix(1.1, [0.3, -0.5, 0.8])[:3, :3]
    X = V @ R.T + [0.4, -0.2, 1.0]
    verts = np.flatnonzero(V[:, 2] > 0.0)
    assert np.abs(_mush(X, V, F, verts, 8) - X).max() < 1e-12
    squashed = X * [1.0, 1.0, 0.5]
    assert np.abs(_mush(squashed, V, F, verts, 8) - squashed).max() > 1e-3


def test_mush_rounds_a_crease_and_keeps_its_bumps():
    """A grid folded to a sharp V: the mush rounds the fold line (its sharpest
    dihedral turn falls) while a bump away from it keeps its height."""
    V, F = grid(21, 0.01)
    V[:, 2] = 0.004 * np.exp(-((V[:, 0] - 0.05) ** 2 + (V[:, 1] - 0.1) ** 2) / 2e-4)
    X = V.copy()
    x = V[:, 0] - 0.1
    X[:, 0] = 0.1 + np.where(x > 0, x * np.cos(2.0), x)     # fold along x = 0.1
    X[:, 2] = V[:, 2] + np.where(x > 0, x * np.sin(2.0), 0.0)
    sq = SurfaceQuality(V, F)
    verts = np.flatnonzero(np.abs(x) < 0.05)
    Y = _mush(X, V, F, verts, 8)
    assert sq(Y)["folds45"] < sq(X)["folds45"], (sq(Y), sq(X))
    bump = int(np.argmax(V[:, 2]))
    assert abs((Y[bump] - X[bump])[2]) < 2e-4      # the bump (4 mm) is kept to 0.2 mm


def _relax(X, V, F, verts, passes, step=0.5):
    """:func:`relax_tangents` of ``verts`` of ``X`` (rest ``V``), full strength."""
    m = trimesh.Trimesh(V, F, process=False)
    ptr = np.r_[0, np.cumsum([len(n) for n in m.vertex_neighbors])].astype(np.int64)
    adj = np.concatenate(m.vertex_neighbors).astype(np.int64)
    F = F.astype(np.int64)
    vf_ptr, vf = vertex_faces(F, len(V))
    first = adj[ptr[:-1]]
    rest = rest_tangents(V, F, vf_ptr, vf, first, ptr, adj, np.empty((len(V), 2)))
    out = X.copy()
    verts = np.sort(verts).astype(np.int64)
    relax_tangents(out, verts, np.ones(len(verts)), F, vf_ptr, vf, first, ptr, adj, rest, step,
                   passes, True, np.empty((len(verts), 3)))
    return out


def test_tangential_relaxation_reshapes_a_crushed_triangle_and_keeps_the_shape():
    """The relaxation slides a vertex along the surface towards where its
    ring puts it at rest: a bumpy sphere turned and moved does not move; a
    vertex slid 80% of the way onto its neighbour (its triangles crushed into
    slivers) goes most of the way back, and no vertex leaves the sphere by
    more than a tenth of the slide (a move along the tangent plane leaves a
    curved surface by its sagitta: 0.56 mm of an 11 mm slide here)."""
    m = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    rng = np.random.default_rng(5)
    V = m.vertices * (1.0 + 0.02 * rng.standard_normal((len(m.vertices), 1)))
    F = m.faces
    R = trimesh.transformations.rotation_matrix(0.7, [0.2, 0.9, -0.4])[:3, :3]
    X = V @ R.T + [0.1, 0.3, -0.5]
    verts = np.flatnonzero(V[:, 2] > 0.0)
    assert np.abs(_relax(X, V, F, verts, 4) - X).max() < 1e-12
    # a smooth sphere: crush one vertex's triangles by sliding it along the surface
    V = m.vertices.copy()
    i = int(np.argmax(V[:, 2]))
    j = int(m.vertex_neighbors[i][0])
    X = V.copy()
    p = V[i] + 0.8 * (V[j] - V[i])
    X[i] = 0.1 * p / np.linalg.norm(p)
    slid = np.linalg.norm(X[i] - V[i])
    Y = _relax(X, V, F, verts, 4)
    assert np.linalg.norm(Y[i] - V[i]) < 0.3 * slid, (np.linalg.norm(Y[i] - V[i]), slid)
    assert np.abs(np.linalg.norm(Y, axis=1) - 0.1).max() < 0.1 * slid


def test_the_raised_thighs_groin_crease_keeps_no_crushed_triangle(humanoid):
    """A thigh raised 108 degrees and turned in (``random_poses`` of seed 13,
    number 21, a pose no setting was chosen on): the contact projects the
    thigh's skin at the groin out of the pelvis's flesh and the mush rounds
    the crease, but the triangles at its bottom stay crushed into slivers,
    which turn their edges past 90 degrees: 6 sharp folds where DQS has none.
    The mush's tangential relaxation (``mush_relax``) gives them their shape
    back: 0 folds, and still no intersecting pair."""
    from skin_node.bench.measure import random_poses
    ch = humanoid
    n = len(ch.V)
    q = random_poses(ch.skeleton, seed=13)[21]
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    dqs = Pipeline.preset(ch, "dqs").deform(q)[:n].copy()
    ours = Pipeline(ch).deform(q)[:n].copy()
    crushed = Pipeline(ch, mush_relax=0).deform(q)[:n].copy()
    assert sq(dqs)["folds90"] == 0
    assert sq(ours)["folds90"] <= sq(dqs)["folds90"], sq(ours)
    assert sq(crushed)["folds90"] >= 3, sq(crushed)
    assert len(si.pairs(ours)) == 0


def test_mush_leaves_a_limb_too_coarse_for_it_alone(tmp_path, monkeypatch):
    """Smoothing a few rings of a limb only two edges across its radius would
    reach across the whole joint: such skin takes next to none of the mush; a
    fine limb takes all of it."""
    monkeypatch.setenv("SKIN_NODE_CACHE", str(tmp_path / "cache"))
    coarse = load_character(str(capsule(tmp_path / "coarse.yaml", h=0.03)), progress=False)
    fine = load_character(str(capsule(tmp_path / "fine.yaml", h=0.008)), progress=False)
    resolved = Pipeline(coarse, ["dqs", "mush"]).stages[1].resolved
    assert np.median(resolved) == 0.0 and resolved.max() < 0.25, resolved.max()
    assert np.median(Pipeline(fine, ["dqs", "mush"]).stages[1].resolved) == 1.0


def test_a_finer_arm_at_150_keeps_its_crease_clean(monkeypatch):
    """The arm at twice the default resolution (about 12 edges across its
    radius) at 150 degrees: the smoothing's rings and passes and the contact's
    margin grow with the resolution, so the crease is rounded over as many
    millimetres as at the default; at the counts given for 8 edges across it
    kept 50 intersecting pairs and 14 sharp folds (DQS 355 and 8)."""
    ch = load_character("arm", surface_vertices=12000, progress=False)
    assert 1.3 < ch.smoothing_scale < 1.6, ch.smoothing_scale
    q = ch.pose(elbow_rz=np.radians(150))
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    d = Pipeline.preset(ch, "dqs").deform(q)
    o = Pipeline.preset(ch, "default").deform(q)
    d, o = {"pairs": len(si.pairs(d)), **sq(d)}, {"pairs": len(si.pairs(o)), **sq(o)}
    assert d["pairs"] > 100 and o["pairs"] <= 0.1 * d["pairs"], (o, d)
    assert o["folds90"] <= d["folds90"] and o["roughness"] <= 1.05 * d["roughness"], (o, d)
    # the scale is the feature: at the given counts the crease crosses itself
    monkeypatch.setattr(type(ch), "smoothing_scale", property(lambda self: 1.0))
    u = Pipeline.preset(ch, "default").deform(q)
    assert len(si.pairs(u)) > 0.1 * d["pairs"] or sq(u)["folds90"] > d["folds90"]


def test_mush_fades_the_rest_detail_that_folds_a_fine_crease(monkeypatch):
    """The humanoid at 90k vertices (14 edges across a limb's radius) at the
    squat's deepest frame: crushed into the crease between the thighs and
    the belly, each vertex's rest offset, turned into its own frame, folds
    the skin between them. Faded out where it bends an edge beyond both the
    smoothed and the rest skin (the tangential relaxation off, to see the
    fade alone): no more sharp folds than DQS (measured 21 against 27; 85
    with the detail kept too), at most a tenth of its intersecting pairs (0
    against 1,202; 26 kept), roughness no higher. With the relaxation as
    well (the default) the triangles crushed at the crease's bottom get
    their shape back: 6 folds, no pair (the relaxation alone: 11 and 7)."""
    import skin_node.stages.mush as mush
    from skin_node import make_clip
    ch = load_character("humanoid", surface_vertices=90000, progress=False)
    assert ch.smoothing_scale > 1.6, ch.smoothing_scale
    clip = make_clip("squat", ch.skeleton).frames
    q = clip[int(np.argmax([ch.skeleton.joint_angles(f).max() for f in clip]))]
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    out = {}
    for name, bend, relax in (("dqs", None, 0), ("ours", mush.DETAIL_BEND, 0),
                              ("kept", 1e9, 0), ("default", mush.DETAIL_BEND, 2)):
        monkeypatch.setattr(mush, "DETAIL_BEND", bend or 0.0)
        X = (Pipeline.preset(ch, "dqs") if bend is None
             else Pipeline.preset(ch, "default", mush_relax=relax)).deform(q)
        out[name] = {"pairs": len(si.pairs(X)), **sq(X)}
    d, o, k, f = out["dqs"], out["ours"], out["kept"], out["default"]
    assert d["pairs"] > 500 and o["pairs"] <= 0.1 * d["pairs"], out
    assert o["folds90"] <= d["folds90"] < k["folds90"], out
    assert o["roughness"] <= k["roughness"], out
    assert f["pairs"] <= 0.1 * d["pairs"] and f["folds90"] < o["folds90"], out


def test_the_deepest_squat_meets_dqs_on_every_measure(humanoid):
    """The humanoid's deepest squat, where thighs, belly and groin meet:
    against DQS on the same weights, at most a tenth of its intersecting
    pairs, no more sharp folds, roughness within 5%, every bent joint's
    region within 3% of rest, and at most half of its bulge (the buttocks,
    between the pelvis's and the thighs' bones, held by both limits); without
    the mush the crease keeps its folds."""
    from skin_node import make_clip
    ch = humanoid
    clip = make_clip("squat", ch.skeleton).frames
    q = clip[int(np.argmax([ch.skeleton.joint_angles(f).max() for f in clip]))]
    si, sq, sm = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F), SceneMetrics(ch)
    out = {}
    for name, pipe in (("dqs", Pipeline.preset(ch, "dqs")), ("ours", Pipeline.preset(ch, "default")),
                       ("no mush", Pipeline(ch, ["dqs", "bulge", "contact", "inflate"]))):
        X = pipe.deform(q)
        fr = pipe.last_frame
        bent = [j for j in sm.region_joints if fr.angles[j] > 0.35]
        out[name] = {"pairs": len(si.pairs(X)), **sq(X),
                     "bulge": float(sm.deviation_mm(X, fr.seg_A, fr.seg_B).max()),
                     "regions": [round(sm.region_ratio(X, fr.G, j), 3) for j in bent]}
    d, o = out["dqs"], out["ours"]
    assert o["bulge"] <= 0.5 * d["bulge"], out
    assert d["pairs"] > 100 and o["pairs"] <= 0.1 * d["pairs"], out
    assert o["folds90"] <= d["folds90"] < out["no mush"]["folds90"], out
    assert o["roughness"] <= 1.05 * d["roughness"], out
    assert all(abs(r - 1.0) <= 0.03 for r in o["regions"]), out


#: Poses of no built-in clip (radians; the walk's arms-lowered shoulders
#: where the arms hang): the issue's measures must hold beyond the clips.
HOLD_OUT = {
    "sit": dict(l_hip_ry=-1.57, r_hip_ry=-1.57, l_knee_ry=1.57, r_knee_ry=1.57,
                l_shoulder_rx=-1.2, r_shoulder_rx=1.2),
    "kneel": dict(l_hip_ry=-0.3, r_hip_ry=-0.3, l_knee_ry=2.6, r_knee_ry=2.6, l_ankle_ry=0.6,
                  r_ankle_ry=0.6, l_shoulder_rx=-1.2, r_shoulder_rx=1.2),
    "lunge": dict(l_hip_ry=-1.5, l_knee_ry=1.7, r_hip_ry=0.4, r_knee_ry=0.4,
                  l_shoulder_rx=-1.2, r_shoulder_rx=1.2),
    "high kick": dict(l_hip_ry=-1.9, l_shoulder_rx=-1.2, r_shoulder_rx=1.2),
    "hands on head": dict(l_shoulder_rx=0.6, r_shoulder_rx=-0.6, l_elbow_rz=-2.5,
                          r_elbow_rz=2.5),
    "arms up": dict(l_shoulder_rx=1.4, r_shoulder_rx=-1.4),
    "bent at the hips": dict(spine_ry=0.6, chest_ry=0.5, l_hip_ry=-0.9, r_hip_ry=-0.9,
                             l_shoulder_rx=-1.2, r_shoulder_rx=1.2),
    "elbows to 160": dict(l_elbow_rz=-2.8, r_elbow_rz=2.8, l_shoulder_rx=-1.2,
                          r_shoulder_rx=1.2),
    "knee to chest": dict(l_hip_ry=-2.3, l_knee_ry=2.4, l_shoulder_rx=-1.2, r_shoulder_rx=1.2),
    "chin to chest": dict(neck_ry=0.6, head_ry=0.5, l_shoulder_rx=-1.2, r_shoulder_rx=1.2),
    "deep crouch": dict(l_hip_ry=-2.0, r_hip_ry=-2.0, l_knee_ry=2.5, r_knee_ry=2.5,
                        l_ankle_ry=-0.6, r_ankle_ry=-0.6, spine_ry=0.4, l_shoulder_rx=-1.2,
                        r_shoulder_rx=1.2),
    "fists to shoulders": dict(l_shoulder_rx=-1.2, r_shoulder_rx=1.2, l_shoulder_rz=0.8,
                               r_shoulder_rz=-0.8, l_elbow_rz=-2.4, r_elbow_rz=2.4),
    "boxing guard": dict(l_shoulder_rx=-0.9, r_shoulder_rx=0.9, l_shoulder_rz=1.0,
                         r_shoulder_rz=-1.0, l_elbow_rz=-2.0, r_elbow_rz=2.0),
    "legs crossed": dict(l_hip_rx=-0.35, r_hip_rx=0.2, l_hip_ry=-0.3, l_shoulder_rx=-1.2,
                         r_shoulder_rx=1.2),
    "arms out, elbows at 120": dict(l_elbow_rz=-2.1, r_elbow_rz=2.1),
    "heel to buttock": dict(r_hip_ry=0.9, r_knee_ry=1.9, l_shoulder_rx=-1.2, r_shoulder_rx=1.2),
}


@pytest.mark.parametrize("pose", list(HOLD_OUT))
def test_poses_beyond_the_clips_meet_dqs_on_every_measure(humanoid, pose):
    """Poses no clip holds, against DQS on the same weights: at most a tenth
    of its intersecting pairs (kneeling 0 against 399, the elbows at 160
    degrees 0 against 577, a knee to the chest 0 against 200, a deep crouch
    0 against 360, legs crossed 0 against 259), no more sharp folds (2
    against 9 at the elbows, 0 against 16 at the knee, 0 against 27 in the
    crouch, 0 against 16 in a boxing guard), roughness
    within 5%, no more bulge, every bent joint's region within 3% of rest and
    the whole mesh within 3% of its volume. (Limbs driven deep into each
    other's rest flesh, arms crossed or curled up tight, are a known limit.)"""
    from skin_node.metrics import mesh_volume
    ch = humanoid
    q = ch.pose(**HOLD_OUT[pose])
    si, sq, sm = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F), SceneMetrics(ch)
    v0 = mesh_volume(ch.V, ch.F)
    out = {}
    for name, pipe in (("dqs", Pipeline.preset(ch, "dqs")), ("ours", Pipeline(ch))):
        X = pipe.deform(q)[:len(ch.V)]
        fr = pipe.last_frame
        bent = [j for j in sm.region_joints if fr.angles[j] > 0.35]
        out[name] = {"pairs": len(si.pairs(X)), **sq(X),
                     "bulge": float(sm.deviation_mm(X, fr.seg_A, fr.seg_B).max()),
                     "volume": mesh_volume(X, ch.F) / v0,
                     "regions": [round(sm.region_ratio(X, fr.G, j), 3) for j in bent]}
    d, o = out["dqs"], out["ours"]
    assert o["pairs"] <= 0.1 * d["pairs"], out
    assert o["folds90"] <= d["folds90"], out
    assert o["roughness"] <= 1.05 * d["roughness"], out
    assert o["bulge"] <= d["bulge"] + 0.5, out
    assert o["regions"] and all(abs(r - 1.0) <= 0.03 for r in o["regions"]), out
    assert o["volume"] >= 0.97, out


def test_a_hand_pressed_into_the_hip_leaves_no_spikes(humanoid):
    """Arms lowered 75 degrees, the spine and chest bent 40 degrees sideways
    towards one hand: the hand reaches deeper into the pelvis's rest flesh
    than the contact can move skin out of it, and its projections alone
    leave spikes and one-vertex creases (measured 824 intersecting pairs and
    129 sharp folds with the relief cap off; DQS 317 and 0). With the cap:
    no sharp fold to speak of, fewer pairs than DQS's, roughness within 10%
    of DQS's (280 pairs, 3 folds, 1.122 against 1.038)."""
    ch = humanoid
    a, b = np.radians(75.0), np.radians(20.0)
    q = ch.pose(l_shoulder_rx=-a, r_shoulder_rx=a, spine_rx=b, chest_rx=b)
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    out = {}
    # the turn off in both: it turns the arm out of the hip here (see the
    # next test), which is not what this one measures
    for name, pipe in (("dqs", Pipeline.preset(ch, "dqs")), ("ours", Pipeline(ch, turn_depth=0.0)),
                       ("uncapped", Pipeline(ch, relief_limit=0.0, turn_depth=0.0))):
        X = pipe.deform(q)[:len(ch.V)]
        out[name] = {"pairs": len(si.pairs(X)), **sq(X)}
    d, o, u = out["dqs"], out["ours"], out["uncapped"]
    assert d["pairs"] > 100 and o["pairs"] < d["pairs"] and o["pairs"] <= 0.5 * u["pairs"], out
    assert u["folds90"] > 50 and o["folds90"] <= 5, out
    assert o["roughness"] <= 1.1 * d["roughness"], out


#: Arms at the sides (shoulders lowered by the first number, radians) and
#: the spine and chest leaning sideways (by the second, degrees, in all):
#: the pose drives a forearm and hand into the hip and thigh.
LEANS = {"arms down, leaning 20": (1.4, 20.0), "arms down, leaning 30": (1.4, 30.0),
         "arms down, leaning 40": (1.4, 40.0), "arms lowered, leaning 40": (1.2, 40.0),
         "arms lowered, leaning 50": (1.2, 50.0), "arms straight down, leaning 20": (1.5, 20.0)}


def _lean(ch, arms, degrees):
    b = np.radians(0.5 * degrees)
    return ch.pose(spine_rx=b, chest_rx=b, l_shoulder_rx=-arms, r_shoulder_rx=arms)


@pytest.mark.parametrize("pose", list(LEANS))
def test_a_lean_with_the_arms_down_turns_the_arm_out_of_the_hip(humanoid, pose):
    """The forearm and hand driven into the hip and thigh deeper than the
    contact can crease: without the turn it flattens them onto one surface
    inside the body and keeps most of DQS's intersecting pairs (237, 217,
    237, 188, 304 and 227 against 328, 324, 477, 214, 381 and 477) with
    rougher skin (1.075 to 1.134 against 1.034 to 1.041) and sharp folds
    DQS does not have (2, 12, 9 and 30 where it has none); turned out about
    the shoulder, none of either, roughness within 5% of DQS's (within
    1.7%). Each turn moves no skin further than its cap; the forearm's and
    then the hand's turn about the shoulder add up, and the skin moved
    (DQS on the turned bones against DQS, measured 44, 138, 239, 99, 208
    and 115 mm) stays within two caps (144 mm each), with the stage's
    ``turn_mm`` count no less than it. Capped at 3 limb radii (the default
    before), leaning 40 degrees kept 142 pairs."""
    ch = humanoid
    q = _lean(ch, *LEANS[pose])
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    out = {}
    for name, pipe in (("dqs", Pipeline.preset(ch, "dqs")), ("ours", Pipeline(ch)),
                       ("unturned", Pipeline(ch, turn_depth=0.0))):
        X = pipe.deform(q)[:len(ch.V)]
        out[name] = {"pairs": len(si.pairs(X)), **sq(X), "turned": pipe.counts.get("turned"),
                     "turn_mm": pipe.counts.get("turn_mm")}
    d, o, u = out["dqs"], out["ours"], out["unturned"]
    assert u["pairs"] >= 0.4 * d["pairs"] > 0, out
    assert o["turned"] > 0 and o["pairs"] <= 0.1 * d["pairs"], out
    assert o["folds90"] <= d["folds90"], out
    assert o["roughness"] <= 1.05 * d["roughness"], out
    radius = ch.nearest_segments[1][:, 0][ch.rig.part == ch.skeleton.index("r_elbow")]
    cap = 1e3 * float(Pipeline(ch).params["turn_shift"]) * np.median(radius)
    turned = Pipeline(ch, ("turn", "dqs")).deform(q)[:len(ch.V)]
    moved = 1e3 * np.sqrt(((turned - Pipeline(ch, ("dqs",)).deform(q)[:len(ch.V)]) ** 2)
                          .sum(axis=1)).max()
    assert 0.0 < moved <= 2.0 * cap and o["turn_mm"] >= moved - 1e-6, (moved, cap, out)


def test_the_turn_comes_in_and_holds_without_a_jump(humanoid):
    """Leaning from 14 to 60 degrees a degree a step, arms down: the turn
    starts from nothing, grows to 119 mm at the hand by 28 degrees and holds
    from 45, the forearm's and then the hand's turn about the shoulder each
    at its cap (291 mm in all; it never falls back by more than the
    bisection's 0.01 mm), while the default's correction of
    DQS changes by at most 11 mm a step up to 46 degrees (no intersecting
    pair there), and by at most 36 mm beyond, where the contact flattens the
    hand into the hip. Turned each its own least way out about a pivot that
    followed where the hand lay deep, it jumped by up to 207 mm a step past
    its cap; before a contact pair came in over a turn, the step onto 41
    degrees, where the spine and chest start being tested, was 22 mm."""
    ch = humanoid
    dq, ours = Pipeline.preset(ch, "dqs"), Pipeline(ch)
    last, steps, turned = None, [], []
    for deg in np.arange(14.0, 60.5, 1.0):
        q = _lean(ch, 1.4, deg)
        C = ours.deform(q)[:len(ch.V)] - dq.deform(q)[:len(ch.V)]
        turned.append(ours.counts["turn_mm"])
        if last is not None:
            steps.append(float(np.sqrt(((C - last) ** 2).sum(axis=1)).max()) * 1e3)
        last = C
    turned, steps = np.array(turned), np.array(steps)
    assert turned[0] == 0.0 and turned[28 - 14] >= 90.0, turned
    assert np.all(np.diff(turned) >= -0.01), turned
    # steps[i] is the step onto 15 + i degrees
    assert steps[:46 - 14].max() <= 15.0, steps
    assert steps.max() <= 40.0, steps


def test_the_turn_changes_no_faster_than_the_pose(humanoid):
    """A thigh turned in from 15 to 23 degrees a quarter degree a step
    (``r_hip_rx``, nothing else). Each pose's turn is found for that pose
    alone, and it changes which limb turns twice: the left foot until 18.25
    degrees, the right shin about the right hip at 18.5 and 18.75, the left
    thigh about its own from 19. With no rate (``turn_rate`` 0) the
    correction of DQS jumps 123 and 126 mm in those two steps (measured),
    against 4-5 mm a step before them. Held to the pose's own change, the
    largest step is 16 mm (measured), each new turn coming in over the next
    steps. A fresh pipeline (its first frame) is turned as the pose alone;
    stepped from 18.75 to 19 degrees and held there, it starts from the last
    turn and reaches what 19 degrees alone gets, to the bit."""
    ch = humanoid
    n = len(ch.V)
    dq = Pipeline.preset(ch, "dqs")
    poses = [ch.pose(r_hip_rx=np.radians(d)) for d in np.arange(15.0, 23.01, 0.25)]

    def steps(pipe):
        C = [pipe.deform(q)[:n] - dq.deform(q)[:n] for q in poses]
        return np.array([1e3 * np.sqrt(((b - a) ** 2).sum(axis=1)).max()
                         for a, b in zip(C, C[1:])])
    held, free = Pipeline(ch), Pipeline(ch, turn_rate=0.0)
    a, b = steps(held), steps(free)
    assert b.max() >= 100.0 and a.max() <= 20.0, (a.round(1), b.round(1))
    # from 18.75 to 19 degrees, then held there
    alone = Pipeline(ch, turn_rate=0.0).deform(poses[16])[:n].copy()
    held = Pipeline(ch)
    assert np.array_equal(held.deform(poses[15])[:n], free.deform(poses[15])[:n])
    X = held.deform(poses[16])[:n]
    assert 1e3 * np.sqrt(((X - alone) ** 2).sum(axis=1)).max() >= 50.0
    for _ in range(40):
        X = held.deform(poses[16])[:n]
    assert np.array_equal(X, alone)


def test_a_contact_pair_comes_in_without_a_jump(humanoid):
    """Leaning 40 then 40.5 degrees (arms down), the spine and chest pass
    the contact's active_threshold against each other, with skin of the
    chest already in the spine's flesh. Their contact comes in over
    active_fade: the correction of DQS changes by at most 6 mm between the
    two poses (measured 5.4, as between 39 and 40). Pushed out all at once
    (no allowance while the pair comes in), a chest vertex moved 23 mm.
    With no active_threshold there is nothing to come in over: every pair
    tested is tested in full."""
    ch = humanoid
    dq = Pipeline.preset(ch, "dqs")

    def step(pipe):
        C = [pipe.deform(q)[:len(ch.V)] - dq.deform(q)[:len(ch.V)]
             for q in (_lean(ch, 1.4, 40.0), _lean(ch, 1.4, 40.5))]
        return float(np.sqrt(((C[1] - C[0]) ** 2).sum(axis=1)).max()) * 1e3

    ours = Pipeline(ch)
    at_once = Pipeline(ch)
    contact = next(s for s in at_once.stages if s.name == "contact")
    contact._deep[:] = 0.0
    assert step(ours) <= 6.0 and step(at_once) >= 15.0, (step(ours), step(at_once))
    # with no threshold every pair is tested, and in full
    every = Pipeline(ch, active_threshold=0.0)
    every.deform(_lean(ch, 1.4, 40.0))
    fade = next(s for s in every.stages if s.name == "contact")._fade
    assert fade.max() == 1.0 and set(np.unique(fade)) <= {0.0, 1.0}, np.unique(fade)


def test_knees_pressed_together_below_the_joint_threshold_meet_on_a_crease(humanoid):
    """A thigh turned 15 degrees in towards the other (standing with the
    knees together): the two legs, which meet at no joint, have turned less
    than ``active_threshold`` (20 degrees) from each other. Tested from that
    threshold on, as a joint's two sides are, the legs kept 617 of DQS's 771
    exact intersecting pairs; with the shins and knees tested at any turn
    (``contact_apart_threshold`` 0), 52 (measured), no sharp fold, and
    roughness 1.4% over DQS's (asserted within 3%)."""
    ch = humanoid
    n = len(ch.V)
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    q = ch.pose(r_hip_rx=np.radians(15.0))
    out = {}
    for name, pipe in (("dqs", Pipeline.preset(ch, "dqs")), ("ours", Pipeline(ch)),
                       ("gated", Pipeline(ch, contact_apart_threshold=0.35))):
        X = pipe.deform(q)[:n].copy()
        out[name] = (len(si.pairs(X)), sq(X))
    (d, qd), (o, qo), (g, _) = out["dqs"], out["ours"], out["gated"]
    assert d > 500 and o <= 0.1 * d and g >= 0.5 * d, (d, o, g)
    assert qo["folds90"] <= qd["folds90"], (qo["folds90"], qd["folds90"])
    assert qo["roughness"] <= 1.03 * qd["roughness"], (qo["roughness"], qd["roughness"])


def test_a_thigh_crossed_over_the_other_turns_out_of_it_within_the_hips_limits(humanoid):
    """Sitting with one thigh crossed over the other (``random_poses``
    number 16: both hips bent 87 degrees, the left turned in 39): a limb's
    top part turns out of its sibling about its own joint. Exact intersecting
    pairs: measured 0 against DQS's 346 (285 unturned), no sharp fold more
    than DQS's, and the hip's channels as turned still within its limits."""
    from skin_node.bench.measure import random_poses
    from skin_node.skeleton import matrix_to_euler_xyz
    ch = humanoid
    sk = ch.skeleton
    n = len(ch.V)
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    q = random_poses(sk)[16]
    out = {}
    for name, pipe in (("dqs", Pipeline.preset(ch, "dqs")), ("ours", Pipeline(ch)),
                       ("unturned", Pipeline(ch, turn_depth=0.0))):
        X = pipe.deform(q)[:n].copy()
        out[name] = (len(si.pairs(X)), sq(X)["folds90"], pipe.last_frame)
    (d, fd, _), (o, fo, fr), (u, _, _) = out["dqs"], out["ours"], out["unturned"]
    assert fr.counts["turned"] >= 1
    assert d > 200 and o <= 0.1 * d and u >= 0.5 * d, (d, o, u)
    assert fo <= fd, (fo, fd)
    k = sk.index("l_hip")
    R = fr.G[sk.parents[k], :3, :3].T @ fr.G[k, :3, :3] @ sk.rest_rotations[k].T
    x = matrix_to_euler_xyz(R)
    assert np.abs(x - q[3 + 3 * k:6 + 3 * k]).max() > np.radians(3.0), x   # it turned
    assert np.all(x >= sk.limits[k, :, 0]) and np.all(x <= sk.limits[k, :, 1]), x


def test_a_thigh_its_turn_would_drive_deeper_is_not_turned(humanoid):
    """``random_poses`` of seed 43, number 17: a knee bent 108 degrees, its
    thigh turned in 39 and lying 33 mm into the other (its turn starts at
    26 mm). No turn within the hip's limits takes it out, and along the
    other thigh's field gradients the turn drives it deeper (52 mm at the
    cap), taking the bent shin into the other thigh: turned to the cap it
    kept 214 exact intersecting pairs and 6 sharp folds where DQS has 5 and
    6. Left as posed, the contact creases it: measured 0 and 0."""
    from skin_node.bench.measure import random_poses
    ch = humanoid
    n = len(ch.V)
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    q = random_poses(ch.skeleton, seed=43)[17]
    ours = Pipeline(ch)
    X, D = ours.deform(q)[:n].copy(), Pipeline.preset(ch, "dqs").deform(q)[:n].copy()
    assert ours.counts["turned"] == 0, ours.counts
    assert len(si.pairs(X)) <= len(si.pairs(D)), (len(si.pairs(X)), len(si.pairs(D)))
    assert sq(X)["folds90"] <= sq(D)["folds90"]


def test_the_turn_crosses_less_on_random_poses(humanoid):
    """Poses no clip has (half the humanoid's joints turned at random, each
    channel up to 92 degrees, seeded): with the turn, fewer exact
    intersecting pairs and no more sharp folds summed than without it
    (measured over these 30: 3,028 against 3,561 pairs, 473 against 478
    folds; DQS 6,775 and 321), the skin finite."""
    ch = humanoid
    sk = ch.skeleton
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    on, off = Pipeline(ch), Pipeline(ch, turn_depth=0.0)
    rng = np.random.default_rng(7)
    pairs, folds, turned = np.zeros(2, dtype=int), np.zeros(2, dtype=int), 0
    for _ in range(30):
        q = sk.rest_pose().copy()
        n = len(q) - 3
        q[3:] = rng.uniform(-1.6, 1.6, n) * (rng.random(n) < 0.5)
        a, b = on.deform(q)[:len(ch.V)].copy(), off.deform(q)[:len(ch.V)].copy()
        turned += on.counts["turned"] > 0
        assert np.isfinite(a).all()
        pairs += (len(si.pairs(a)), len(si.pairs(b)))
        folds += (sq(a)["folds90"], sq(b)["folds90"])
    assert turned >= 3, turned
    assert pairs[0] <= 0.9 * pairs[1], pairs
    assert folds[0] <= folds[1], folds


def test_poses_within_the_joint_limits_that_no_clip_has(humanoid):
    """Thirty poses drawn within the humanoid's joint limits
    (:func:`~skin_node.bench.measure.random_poses`, the benchmark's
    ``random_poses``; number 16 chose the turn's ``SIBLING_DEPTH``, the
    defaults were tuned on none of the others), against DQS: measured 415
    exact intersecting pairs against 2,889 summed, 28 poses within 10% of
    DQS's pairs (the other two drive a thigh through the other, the pelvis
    tilted 41 degrees and the turn at its cap, or a hand through the neck:
    243 and 172 pairs against 485 and 304), 1 sharp fold against 133,
    roughness at most 1.039 times DQS's (median 1.016)."""
    from skin_node.bench.measure import random_poses
    ch = humanoid
    n = len(ch.V)
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    ours, dqs = Pipeline(ch), Pipeline.preset(ch, "dqs")
    rows = []
    for q in random_poses(ch.skeleton):
        a, b = ours.deform(q)[:n].copy(), dqs.deform(q)[:n].copy()
        assert np.isfinite(a).all()
        qa, qb = sq(a), sq(b)
        rows.append((len(si.pairs(a)), len(si.pairs(b)), qa["folds90"], qb["folds90"],
                     qa["roughness"] / qb["roughness"]))
    r = np.array(rows)
    assert len(r) == 30
    assert r[:, 0].sum() <= 0.35 * r[:, 1].sum(), r[:, :2].sum(axis=0)
    assert (r[:, 0] <= 0.1 * r[:, 1]).sum() >= 26, r[:, :2]
    assert r[:, 2].sum() <= 0.15 * r[:, 3].sum(), r[:, 2:4].sum(axis=0)
    assert r[:, 4].max() <= 1.08 and np.median(r[:, 4]) <= 1.03, r[:, 4]


def test_carried_back_a_skinned_vertex_reads_its_rest_field(humanoid):
    """A part's flesh is where skinning puts it: carrying a DQS-skinned vertex
    back through its part's blend lands it where it was at rest, so its own
    field reads its rest value (within a millimetre for 99% of vertices at
    the deepest squat), where its bone alone would misplace it by centimetres."""
    from skin_node import make_clip
    ch = humanoid
    squat = make_clip("squat", ch.skeleton).frames
    q = squat[len(squat) // 2]
    pipe = Pipeline.preset(ch, "dqs")
    X = pipe.deform(q)
    M = pipe.last_frame.M
    Q, Minv = matrices_to_dual_quaternions(M), np.linalg.inv(M)
    r, pf = ch.rig, ch.rig.fields
    err, rigid = [], []
    for i in range(0, len(X), 13):
        a = r.part[i]
        rest = field_at(pf[4], pf[3], pf[0], pf[1], pf[2], a, *ch.V[i], True)[0]
        err.append(abs(skinned_field(pf, Q, a, *X[i], *ch.V[i], 3, True, -1)[0] - rest))
        x = Minv[a, :3, :3] @ X[i] + Minv[a, :3, 3]
        rigid.append(abs(field_at(pf[4], pf[3], pf[0], pf[1], pf[2], a, *x, True)[0] - rest))
    assert np.percentile(err, 99) < 1e-3, np.percentile(err, 99)
    assert np.percentile(rigid, 90) > 1e-2


def test_contact_chunks_keep_every_vertex_a_box_holds(humanoid):
    """The contact's first pass tests only chunks of skin whose box meets a
    candidate part's box: at the deepest squat that is a fraction of the
    skin, and every vertex that the per-vertex box test would keep is among
    them (the chunks change the time, never the skin)."""
    from skin_node import make_clip
    from skin_node.kernels.contact import boxed_vertices
    ch = humanoid
    clip = make_clip("squat", ch.skeleton).frames
    q = clip[int(np.argmax([ch.skeleton.joint_angles(f).max() for f in clip]))]
    pipe = Pipeline(ch, ["dqs"])
    X = pipe.deform(q)
    st = Pipeline(ch, ["dqs", "contact"]).stages[1]
    fr = pipe.last_frame
    cand_ptr, cand, Minv, box = st.pairs(fr)
    out, clear = np.empty(len(X), dtype=np.int64), np.full(len(X), np.inf)
    kept = set(out[:boxed_vertices(X, st._order, st._pptr, st._cptr, cand_ptr, cand, Minv,
                                   box, st._reach(), st._apart, clear, out)].tolist())
    inside = set()
    for a in np.flatnonzero(np.diff(cand_ptr)):
        vs = np.flatnonzero(ch.rig.part == a)
        for b in cand[cand_ptr[a]:cand_ptr[a + 1]]:
            x = X[vs] @ Minv[b, :3, :3].T + Minv[b, :3, 3]
            hit = np.all((x >= box[b, 0]) & (x <= box[b, 1]), axis=1)
            inside.update(vs[hit].tolist())
    assert len(inside) > 1000, len(inside)
    assert inside <= kept, len(inside - kept)
    assert len(kept) < 0.7 * len(X), (len(kept), len(X))


#: A guard: the left arm down and the forearm folded across the chest, the
#: torso turned (a held-out CMU punch, 02_05 frame 872, arms and torso only).
GUARD = dict(spine_ry=0.25, chest_rx=-0.18, chest_ry=0.19, chest_rz=0.18, l_shoulder_rx=-1.44,
             l_shoulder_rz=-0.7, l_elbow_rx=0.76, l_elbow_ry=0.49, l_elbow_rz=-1.59)


def test_contact_clearance_is_a_lower_bound_of_the_distance_to_other_skin(humanoid):
    """What the contact reports as each vertex's clearance (how far, at
    least, it is from the flesh of the parts it tests against the vertex's
    part, those that meet it at no joint) is never more than its distance to
    those parts' skin, measured on the triangles themselves (give or take
    2 mm and 10%: the fields are read on a grid, the flesh carried without
    the vertex's bone), at the guard and at the deepest squat; and it is
    finite for the skin that matters (within 5 cm of such a part)."""
    from skin_node import make_clip
    ch = humanoid
    clip = make_clip("squat", ch.skeleton).frames
    deepest = clip[int(np.argmax([ch.skeleton.joint_angles(f).max() for f in clip]))]
    part, parents = ch.rig.part, ch.skeleton.parents
    # each part's own triangles (all three corners its own)
    fpart = np.where((part[ch.F] == part[ch.F[:, :1]]).all(axis=1), part[ch.F[:, 0]], -1)
    checked = 0
    for q in (ch.pose(**GUARD), deepest):
        pipe = Pipeline(ch, ["dqs", "contact"])
        dqs = Pipeline.preset(ch, "dqs").deform(q).copy()
        pipe.deform(q)
        clear = pipe.last_frame.clearance.copy()
        cand_ptr, cand = pipe.stages[1].pairs(pipe.last_frame)[:2]
        for a in np.unique(part):
            apart = [b for b in cand[cand_ptr[a]:cand_ptr[a + 1]]
                     if parents[b] != a and parents[a] != b]
            if not apart:
                assert np.all(clear[part == a] == np.inf)
                continue
            tris = ch.F[np.isin(fpart, apart)]
            vs = np.flatnonzero(part == a)[::3]
            used, local = np.unique(tris, return_inverse=True)
            d = closest(mesh_tree(dqs[used], local.reshape(-1, 3)), dqs[vs])[0]
            assert np.all(clear[vs] <= 1.1 * d + 2e-3), (a, float((clear[vs] - d).max()))
            assert np.isfinite(clear[vs][d < 0.05]).all(), a
            checked += int((d < 0.05).sum())
    assert checked > 200, checked


def test_skin_near_another_part_does_not_swell_into_it(humanoid):
    """At the guard, contact parts the forearm from the chest, but inflation
    swelled the chest and the mush rounded the flattened skin back out through
    the forearm (34 intersecting pairs, where contact alone left none): skin
    near a part that meets its own at no joint now moves at most half its
    clearance. The default has no intersecting pair there (DQS: over 50), no
    more sharp folds than DQS, and every bent joint's region within 3%."""
    ch = humanoid
    q = ch.pose(**GUARD)
    si, sq, sm = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F), SceneMetrics(ch)
    dqs = Pipeline.preset(ch, "dqs").deform(q).copy()
    pipe = Pipeline.preset(ch, "default")
    X = pipe.deform(q)
    fr = pipe.last_frame
    assert len(si.pairs(dqs)) > 50
    assert len(si.pairs(X)) == 0, len(si.pairs(X))
    assert sq(X)["folds90"] <= sq(dqs)["folds90"], (sq(X)["folds90"], sq(dqs)["folds90"])
    regions = [sm.region_ratio(X, fr.G, j) for j in sm.region_joints if fr.angles[j] > 0.35]
    assert regions and all(abs(r - 1.0) <= 0.03 for r in regions), regions
    assert fr.counts["mush_held"] > 0


#: Legs that part: a high kick (the left hip flexed 110 degrees) and the side
#: splits (each leg out 52 degrees). No built-in clip or tuning pose does either.
PARTING = {"kick": dict(l_hip_ry=-1.9, l_knee_ry=0.3),
           "splits": dict(l_hip_rx=0.9, r_hip_rx=-0.9)}


@pytest.mark.parametrize("pose", sorted(PARTING))
def test_skin_between_parting_legs_spans_them_without_crumpling(humanoid, pose):
    """The crotch's skin is about as near either thigh's bone, and the bulge
    limit held it to both: as the legs part it cannot stay near both, and
    held to each it crumpled (6 and 3 sharp folds where DQS has none; 12 at
    the kick after the bulge stage alone). Loosened by how far the bones parted, it
    spans the gap: no sharp fold, no intersecting pair, roughness within 8%
    of DQS's, and the bulge stage alone adds no fold either."""
    ch = humanoid
    q = ch.pose(**PARTING[pose])
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    dqs = Pipeline.preset(ch, "dqs").deform(q).copy()
    X = Pipeline.preset(ch, "default").deform(q).copy()
    bulged = Pipeline(ch, ["dqs", "bulge"]).deform(q).copy()
    d, o = sq(dqs), sq(X)
    assert d["folds90"] == 0 and o["folds90"] == 0, (d, o)
    assert sq(bulged)["folds90"] == 0, sq(bulged)
    assert len(si.pairs(X)) == 0
    assert o["roughness"] <= 1.08 * d["roughness"], (o, d)


def test_the_bulge_limit_loosens_by_how_far_the_bones_parted(humanoid):
    """What the bulge limit loosens by (the bones' parting around a vertex)
    is 0 at rest and wherever the body moved rigidly (a root turn and shift);
    at the splits it is, at the crotch, of the order of how far the thighs'
    points near it parted; folding an elbow to 150 degrees (bones that meet
    at a joint close on each other) gives its skin none."""
    from skin_node.kernels.shape import parting
    from skin_node.stages.shape import Bulge
    ch = humanoid
    pipe = Pipeline(ch, ["dqs", "bulge"])
    pairs = next(s for s in pipe.stages if isinstance(s, Bulge)).pairs
    verts = np.arange(len(ch.V), dtype=np.int64)

    def parted(**channels):
        pipe.deform(ch.pose(**channels))
        fr = pipe.last_frame
        return parting(np.empty(len(verts)), verts, *pairs, fr.seg_A, fr.seg_B)

    assert np.abs(parted()).max() < 1e-9
    assert np.abs(parted(root_tx=0.3, root_ty=-0.2, pelvis_rz=1.1, pelvis_rx=0.4)).max() < 1e-9
    skel = ch.skeleton
    at = {n: skel.rest_positions[skel.index(n)] for n in ("l_hip", "r_hip", "l_knee", "l_elbow")}
    # the crotch: between the thighs (within 3 cm of the middle), below the hips
    crotch = np.flatnonzero((np.abs(ch.V[:, 1] - 0.5 * (at["l_hip"][1] + at["r_hip"][1])) < 0.03)
                            & (ch.V[:, 2] < at["l_hip"][2]) & (ch.V[:, 2] > at["l_knee"][2]))
    assert len(crotch) > 10
    s = parted(l_hip_rx=0.9, r_hip_rx=-0.9)[crotch]
    # each leg swings out 0.9 rad about its hip: a point a tenth of the thigh
    # down moves 0.1 * thigh * 2 sin(0.45) sideways, a point at the knee ten times that
    thigh = float(np.linalg.norm(at["l_knee"] - at["l_hip"]))
    swing = 2.0 * np.sin(0.45) * thigh
    assert 0.1 * swing < s.max() < 2.0 * swing, (s.max(), swing)
    near = np.linalg.norm(ch.V - at["l_elbow"], axis=1) < 0.08
    assert parted(l_elbow_rz=-2.6)[near].max() < 1e-9


def test_far_bones_that_part_loosen_the_bulge_limit_without_a_groove(humanoid):
    """A pose within the joint limits (``random_poses`` number 25: the left
    knee bent 115 degrees, the thigh out, the other leg back): the other
    thigh, 300 mm further from the skin above the knee than at rest, counted
    in full through its small weight, loosened that skin's bulge limit by
    centimetres more on one vertex than on the next, and the skin drawn in
    showed a groove along the thigh. Each pair's growth saturating at 1.5
    rest distances (``PARTING_SPAN``) leaves fewer of the thigh's edges
    bent more than 5 degrees beyond rest (measured 213 against 246; DQS 55,
    with a 106-degree fold at the knee) and the side splits' crotch, which
    the loosening is for, as smooth as counted in full (roughness 1.0210
    against 1.0211)."""
    from skin_node.bench.measure import random_poses
    from skin_node.kernels.shape import parting_pairs
    from skin_node.stages.shape import Bulge
    ch = humanoid
    n = len(ch.V)
    sq = SurfaceQuality(ch.V, ch.F)
    seg_joint, A, B = ch.skeleton.bone_segments()
    full = Pipeline(ch)
    next(s for s in full.stages if isinstance(s, Bulge)).pairs = parting_pairs(
        ch.V, A, B, seg_joint, span=1e9)
    ours = Pipeline(ch)
    thigh = ch.rig.part == ch.skeleton.index("l_hip")
    on_thigh = thigh[sq.F[sq.fa]].all(axis=1) & thigh[sq.F[sq.fb]].all(axis=1)

    def bent(X):
        return int(np.count_nonzero(sq.turns(X)[on_thigh] > 5.0))

    q = random_poses(ch.skeleton)[25]
    a, b = bent(ours.deform(q)[:n]), bent(full.deform(q)[:n])
    assert a <= 0.92 * b, (a, b)
    splits = ch.pose(**PARTING["splits"])
    ra, rb = sq(ours.deform(splits)[:n])["roughness"], sq(full.deform(splits)[:n])["roughness"]
    assert abs(ra - rb) <= 0.002 * rb, (ra, rb)


def test_a_joint_regions_layers_fade_where_it_meets_the_next_region(humanoid, monkeypatch):
    """Inflation's layers over a joint region fade with the distance from its
    joint and towards the next joint's region: where the head's region meets
    the neck's, faded by the distance alone the head's layer stopped at up
    to 0.8 of its full move, a seam round the base of the neck at a pose
    within the joint limits (``random_poses`` number 3, the head turned 40
    degrees). Edges of the neck, head and chest bent more than 10 degrees
    beyond rest: measured 16 with the fade, 53 without it (DQS 0)."""
    import skin_node.stages.shape as shape
    from skin_node.bench.measure import random_poses
    ch = humanoid
    n = len(ch.V)
    sk = ch.skeleton
    sq = SurfaceQuality(ch.V, ch.F)
    ours = Pipeline(ch)
    monkeypatch.setattr(shape, "REGION_BORDER_RINGS", 0)
    unfaded = Pipeline(ch)
    part = ch.rig.part
    sel = np.isin(part, [sk.index(j) for j in ("neck", "head", "chest")])
    on = sel[sq.F[sq.fa]].all(axis=1) & sel[sq.F[sq.fb]].all(axis=1)

    def bent(X):
        return int(np.count_nonzero(sq.turns(X)[on] > 10.0))

    q = random_poses(sk)[3]
    a, b = bent(ours.deform(q)[:n]), bent(unfaded.deform(q)[:n])
    assert b >= 20 and a <= 0.4 * b, (a, b)


# ------------------------------------------------------------------ kernels
def test_push_apart_parts_two_crossing_triangles_and_leaves_deep_ones():
    """Two triangles of two parts, one through the other's edge by 3 mm: a few
    rounds of :func:`push_apart` leave them apart (the exact test says so)
    with the pushed corners within a millimetre or two of where they were;
    a corner 3 cm behind the other's plane (flesh through flesh) is not
    pushed at all."""
    from skin_node.kernels.intersect import triangles_intersect
    from skin_node.kernels.untangle import push_apart
    # a flat triangle (z = 0, normal +z) and one standing through it from below
    X = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0],
                  [0.02, 0.02, -0.003], [0.05, 0.02, 0.08], [0.02, 0.05, 0.08]])
    F = np.array([[0, 1, 2], [3, 4, 5]])
    pairs = np.array([[0, 1]])
    n = len(X)
    gap, depth = np.full(n, 0.001), np.full(n, 0.01)
    ptr, adj = np.zeros(n + 1, dtype=np.int64), np.zeros(0, dtype=np.int64)
    disp, count, touched = np.zeros((n, 3)), np.zeros(n, dtype=np.int64), np.empty(n, np.int64)
    assert triangles_intersect(X, 0, 1, 2, 3, 4, 5)
    Y = X.copy()
    for _ in range(4):
        if not triangles_intersect(Y, 0, 1, 2, 3, 4, 5):
            break
        assert push_apart(Y, F, pairs, gap, depth, 0.5, ptr, adj, disp, count, touched)[0] > 0
    assert not triangles_intersect(Y, 0, 1, 2, 3, 4, 5)
    assert np.abs(Y - X).max() < 0.006, np.abs(Y - X).max()
    assert not disp.any() and not count.any()
    deep = X.copy()
    deep[3, 2] = -0.03
    D = deep.copy()
    push_apart(D, F, pairs, gap, depth, 0.5, ptr, adj, disp, count, touched)
    assert D[3, 2] == deep[3, 2]


def test_push_apart_takes_the_pushed_corners_neighbours_along_by_the_spread():
    """Each unpushed neighbour of a pushed corner moves by ``spread`` times
    the mean of its pushed neighbours' moves; with no spread only pushed
    corners move, by the same amounts."""
    from skin_node.kernels.untangle import push_apart
    from skin_node.rigging.build import one_ring
    # a flat triangle (z = 0) and a fan of three standing through it from below
    X = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0],
                  [0.02, 0.02, -0.003], [0.05, 0.02, 0.08], [0.02, 0.05, 0.08],
                  [0.06, 0.06, 0.09]])
    F = np.array([[0, 1, 2], [3, 4, 5], [4, 6, 5]])
    n = len(X)
    ptr, adj = one_ring(F, n)
    pairs = np.array([[0, 1]])
    gap, depth = np.full(n, 0.001), np.full(n, 0.01)
    disp, count, touched = np.zeros((n, 3)), np.zeros(n, dtype=np.int64), np.empty(n, np.int64)
    alone = X.copy()
    p0, m0 = push_apart(alone, F, pairs, gap, depth, 0.0, ptr, adj, disp, count, touched)
    assert p0 == m0 > 0
    pushed = set(touched[:p0].tolist())
    Y = X.copy()
    p, m = push_apart(Y, F, pairs, gap, depth, 0.5, ptr, adj, disp, count, touched)
    assert p == p0 and set(touched[:p].tolist()) == pushed and m > p
    np.testing.assert_array_equal(Y[list(pushed)], alone[list(pushed)])
    for u in touched[p:m]:
        nb = [v for v in adj[ptr[u]:ptr[u + 1]] if v in pushed]
        assert u not in pushed and nb
        want = 0.5 * np.mean([Y[v] - X[v] for v in nb], axis=0)
        np.testing.assert_allclose(Y[u] - X[u], want, atol=1e-15)
    untouched = [v for v in range(n) if v not in set(touched[:m].tolist())]
    np.testing.assert_array_equal(Y[untouched], X[untouched])
    assert (Y[6] == X[6]).all() and not disp.any() and not count.any()


def test_mesh_tree_queries_agree_with_brute_force():
    m = trimesh.creation.icosphere(3, radius=0.1)
    V, F = np.asarray(m.vertices), np.asarray(m.faces)
    tree = mesh_tree(V, F)
    rng = np.random.default_rng(0)
    P = rng.uniform(-0.15, 0.15, (300, 3))
    d, C, face, _ = closest(tree, P)
    # brute force over every triangle
    from skin_node.kernels.collision import _closest_on_triangle
    for k in range(0, 300, 7):
        best = min(np.linalg.norm(np.array(_closest_on_triangle(*P[k], *V[a], *V[b], *V[c])[:3])
                                  - P[k]) for a, b, c in F)
        assert abs(best - d[k]) < 1e-12
    # inside the sphere <=> nearer the centre than the (faceted) surface
    ins = inside(tree, P, 1.0)
    r = np.linalg.norm(P, axis=1)
    clear = np.abs(r - 0.1) > 0.01
    assert np.array_equal(ins[clear], (r < 0.1)[clear])
    # a segment through the centre crosses the surface twice
    n = crossings(tree, np.array([[-0.2, 0.001, 0.002]]), np.array([[0.2, 0.001, 0.002]]))
    assert n[0] == 2


def test_rasterizer_draws_the_nearest_face_and_marks_back_faces():
    """Two squares, the nearer one red-marked and half the size: its pixels
    are red; the far square's face is seen from behind and drawn blue."""
    V = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0],          # far, facing away
                  [-.5, -.5, 1], [.5, -.5, 1], [.5, .5, 1], [-.5, .5, 1]], float)
    F = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 6], [4, 6, 7]])
    mark = np.array([False, False, True, True])
    img = render(V, F, eye=(0, 0, 5), target=(0, 0, 0), size=(64, 64), fov=40, up=(0, 1, 0),
                 mark=mark)
    centre, edge = img[32, 32], img[32, 18]
    assert centre[0] > 0.6 and centre[1] < 0.2             # the near square, marked red
    assert edge[2] > edge[0] and edge[2] > 0.5             # the far one, from behind: blue
    assert np.allclose(img[1, 1], 1.0)                     # background
