"""Automatic skeleton embedding: templates placed inside bare closed meshes, then
rigged and deformed with no hand work; the fit finds the mesh's orientation and
checks itself, and a fit that fails its checks is refused."""
import itertools
from pathlib import Path

import numpy as np
import pytest

from skin_node.builtin.characters import make_humanoid
from skin_node.builtin.quadruped import quadruped_walk
from skin_node.character import load_embedded
from skin_node.io.character_file import CharacterFileError, load_character_file, read_closed_mesh
from skin_node.rigging.embed import (EmbeddingError, embed_skeleton, fit_template, load_template,
                                     surface_distance, winding_numbers)

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
SPOT = DATA / "meshes" / "spot_triangulated.obj"
CESIUM = DATA / "rigged" / "CesiumMan.glb"


def _need(path: Path) -> Path:
    if not path.exists():
        pytest.skip(f"test data {path} is not available")
    return path


def _all_points(skel):
    tips = skel.tips[np.isfinite(skel.tips).all(1)]
    return np.vstack([skel.rest_positions, tips])


def assert_inside(skel, V, F):
    P = _all_points(skel)
    w = winding_numbers(P, V, F)
    assert np.all(w > 0.99), dict(zip(skel.names, np.round(w, 3)))
    assert surface_distance(P, V, F).min() > 1e-3


@pytest.fixture(scope="module")
def humanoid_mesh():
    return make_humanoid(4000)


@pytest.fixture(scope="module")
def spot():
    V, F = read_closed_mesh(_need(SPOT))
    return V, F, embed_skeleton(V, F, "quadruped")


def test_templates_load():
    h = load_template("humanoid")
    assert h.names == make_humanoid(2000)[2].names        # its clips apply
    q = load_template("quadruped")
    for t in (h, q):
        assert np.all((t.positions >= 0) & (t.positions <= 1))
    with pytest.raises(ValueError, match="no_such_template"):
        load_template("no_such_template")


def test_bad_template_file_names_the_file(tmp_path):
    p = tmp_path / "broken.yaml"
    p.write_text("joints:\n  - {name: a, position: [0.5, 0.5, 0.5]}\n")   # a leaf without tip
    with pytest.raises(ValueError, match="broken.yaml.*tip"):
        load_template(p)


def test_humanoid_embeds_near_the_builtin_joints(humanoid_mesh):
    V, F, ref = humanoid_mesh
    skel = embed_skeleton(V, F, "humanoid")
    np.testing.assert_allclose(skel.rest_rotations[0], np.eye(3), atol=1e-9)   # z up, x forward
    assert_inside(skel, V, F)
    err = np.linalg.norm(skel.rest_positions - ref.rest_positions, axis=1)
    assert err.max() < 0.08, dict(zip(skel.names, np.round(err, 3)))
    assert np.median(err) < 0.03


def test_humanoid_orientation_is_detected(humanoid_mesh):
    """The same body lying y-up and facing -z embeds to the same joints, rotated."""
    V, F, ref = humanoid_mesh
    R = np.column_stack([[0, 0, -1], [-1, 0, 0], [0, 1, 0]]).astype(float)  # x->-z, y->-x, z->y
    skel = embed_skeleton(V @ R.T, F, "humanoid")
    np.testing.assert_allclose(skel.rest_rotations[0], R, atol=1e-9)
    err = np.linalg.norm(skel.rest_positions - ref.rest_positions @ R.T, axis=1)
    assert err.max() < 0.08, dict(zip(skel.names, np.round(err, 3)))


def test_cesium_man_bind_pose(tmp_path):
    V, F = read_closed_mesh(_need(CESIUM))
    skel = embed_skeleton(V, F, "humanoid")
    assert_inside(skel, V, F)
    up, left = skel.rest_rotations[0][:, 2], skel.rest_rotations[0][:, 1]
    np.testing.assert_allclose(up, [0, 1, 0], atol=1e-9)           # glTF is y up
    P = {n: p for n, p in zip(skel.names, skel.rest_positions)}
    for s in ("l", "r"):
        assert P[f"{s}_hip"] @ up > P[f"{s}_knee"] @ up > P[f"{s}_ankle"] @ up
    assert P["head"] @ up > P["neck"] @ up > P["chest"] @ up > P["pelvis"] @ up
    assert (P["l_wrist"] - P["r_wrist"]) @ left > 0.5               # hands apart, left on the left


def test_spot_joints_inside_symmetric_and_legs_in_legs(spot):
    V, F, skel = spot
    assert_inside(skel, V, F)
    A = skel.rest_rotations[0]
    np.testing.assert_allclose(A[:, 2], [0, 1, 0], atol=1e-9)      # Spot is y up ...
    np.testing.assert_allclose(A[:, 0], [0, 0, -1], atol=1e-9)     # ... and faces -z
    Q = V @ A                                                      # forward, left, up
    P = skel.rest_positions @ A
    idx = {n: i for i, n in enumerate(skel.names)}
    # Left/right pairs mirror each other about the mesh's symmetry plane.
    c = 0.5 * (Q[:, 1].min() + Q[:, 1].max())
    for n, i in idx.items():
        if n.startswith("l_"):
            k = idx["r_" + n[2:]]
            mirrored = P[k] * [1, -1, 1] + [0, 2 * c, 0]
            assert np.linalg.norm(P[i] - mirrored) < 0.01 * np.ptp(Q, 0).max(), n
    # Belly height: the lowest skin on the midline half way between the legs.
    hooves = ["l_wrist", "r_wrist", "l_ankle", "r_ankle"]
    T = skel.tips @ A
    front, hind = T[idx["l_wrist"], 0], T[idx["l_ankle"], 0]
    mid = (np.abs(Q[:, 1] - c) < 0.05) & (np.abs(Q[:, 0] - 0.5 * (front + hind))
                                          < 0.25 * abs(front - hind))
    belly = Q[mid, 2].min()
    for n in hooves:
        t = T[idx[n]]
        assert t[2] < belly, (n, t, belly)
        nearest = Q[np.argmin(((Q - t) ** 2).sum(1))]
        assert nearest[2] < belly, (n, nearest, belly)
        # each leg joint is on its own side and end of the body
        side = np.sign(t[1] - c)
        assert side == (1 if n.startswith("l_") else -1)
    assert front > hind


def test_spot_walks_without_crossings():
    from skin_node.pipeline import Pipeline
    from skin_node.rigging.regions import JointRegions, count_crossings
    ch = load_embedded(_need(SPOT), "quadruped", tet_count=6000, progress=False)
    frames = quadruped_walk(ch.skeleton)
    assert frames.shape == (240, ch.n_channels)
    regions = JointRegions(ch)
    pipe = Pipeline(ch)
    checked = []
    for t in range(120):
        X = pipe.deform(frames[t])
        assert np.all(np.isfinite(X)), t
        if t % 10 == 0:
            checked.append(count_crossings(X, ch.V, ch.F, pipe.last_frame.M, regions))
    assert checked == [0] * len(checked), checked
    # the walk really moves the legs
    G = ch.skeleton.world_matrices(frames[30])
    moved = np.linalg.norm(G[ch.skeleton.index("l_ankle"), :3, 3]
                           - G[0, :3, 3] - (ch.skeleton.rest_positions[ch.skeleton.index("l_ankle")]
                                            - ch.skeleton.rest_positions[0]))
    assert moved > 0.02


def test_character_file_with_template(tmp_path):
    from skin_node.character import load_character
    spot = _need(SPOT)
    p = tmp_path / "cow.yaml"
    p.write_text(f"mesh: {spot}\ntemplate: quadruped\nup: y\nforward: -z\n")
    ch = load_character(str(p), tet_count=6000, progress=False)
    assert "l_ankle" in ch.skeleton.names
    assert_inside(ch.skeleton, ch.V, ch.F)
    bad = tmp_path / "bad.yaml"
    bad.write_text(f"mesh: {spot}\ntemplate: no_such_template\n")
    with pytest.raises(ValueError, match="bad.yaml.*no_such_template"):
        load_character(str(bad), tet_count=6000, progress=False)


def test_an_embedded_character_plays_its_templates_clip_by_default(tmp_path):
    """With no clip named, a quadruped walks as a quadruped (the player, the
    exporter and the benchmark alike), not with the humanoid's walk its
    channels happen to fit (DQS crossed itself at 232 pairs on Spot there)."""
    from skin_node.bench.cli import scene_clips
    from skin_node.motion import default_clip, load_motion
    cow, man, own = tmp_path / "cow.yaml", tmp_path / "man.yaml", tmp_path / "own.yaml"
    cow.write_text(f"mesh: {SPOT}\ntemplate: quadruped\nup: y\nforward: -z\n")
    man.write_text("mesh: man.obj\ntemplate: humanoid\n")
    own.write_text("mesh: arm.obj\njoints: []\n")
    assert load_template("quadruped").clip == "quadruped_walk"
    assert [default_clip(str(p)) for p in (cow, man, own)] == ["quadruped_walk", "walk", "walk"]
    assert scene_clips(str(cow)) == ["quadruped_walk"]
    _need(SPOT)
    clip = load_motion(str(cow))
    assert clip.name == "quadruped_walk"
    skel = load_character_file(cow, verbose=False)[2]
    np.testing.assert_array_equal(clip.frames, quadruped_walk(skel))


def test_a_mesh_modelled_in_an_a_pose_plays_the_clips_as_the_template_does(humanoid_mesh,
                                                                          tmp_path):
    """The built-in clips assume the template's rest pose, arms out level. A
    mesh modelled with its arms lowered 35 degrees (our humanoid, posed by
    DQS) played the walk's arms 35 degrees lower than the template, into the
    torso: DQS crossed itself at 456 intersecting pairs and the default
    without its turn stage at 276, against 0 for both on the same body
    modelled in the T-pose; the default turned the arms out of the torso on
    every frame, by up to 109 mm. Its fit records the template's arm
    directions and the clips are turned to them: every arm bone points where
    the T-pose body's does at every frame (0.0 degrees apart, 35 raw), and
    the walk keeps the skin apart (0 pairs under DQS and the default, every
    8th frame) with no arm turned.
    A T-pose mesh's fit records none, and its clips are the template's, bit
    for bit."""
    import trimesh
    from skin_node import Pipeline, make_clip
    from skin_node.builtin.clips import CLIPS
    from skin_node.character import load_character
    from skin_node.kernels.intersect import SelfIntersections
    from skin_node.metrics import SurfaceQuality
    h = load_character("humanoid", surface_vertices=4000, progress=False)
    a = np.radians(35.0)
    X = Pipeline.preset(h, "dqs").deform(h.pose(l_shoulder_rx=-a, r_shoulder_rx=a))[:len(h.V)]
    for name, V in (("t", h.V), ("a", X)):
        trimesh.Trimesh(V, h.F, process=False).export(tmp_path / f"{name}.obj")
        (tmp_path / f"{name}.yaml").write_text(f"mesh: {name}.obj\ntemplate: humanoid\n")
    t = load_character(str(tmp_path / "t.yaml"), progress=False)
    ap = load_character(str(tmp_path / "a.yaml"), progress=False)
    assert t.skeleton.reference is None
    np.testing.assert_array_equal(make_clip("walk", t.skeleton).frames, CLIPS["walk"](t.skeleton))
    ref = ap.skeleton.reference
    assert [ap.skeleton.names[j] for j in np.flatnonzero(np.isfinite(ref).all(1))] == \
        ["l_shoulder", "l_elbow", "r_shoulder", "r_elbow"]
    ft, fa = make_clip("walk", t.skeleton).frames, make_clip("walk", ap.skeleton).frames
    raw = CLIPS["walk"](ap.skeleton)

    def apart(frames):
        err = []
        for k in range(0, len(ft), 10):
            Gt, Ga = t.skeleton.world_matrices(ft[k]), ap.skeleton.world_matrices(frames[k])
            for n in ("l_shoulder", "l_elbow", "r_shoulder", "r_elbow"):
                j = t.skeleton.index(n)
                c = t.skeleton.children(j)[0]
                u, v = Gt[c, :3, 3] - Gt[j, :3, 3], Ga[c, :3, 3] - Ga[j, :3, 3]
                err.append(np.degrees(np.arccos(np.clip(
                    u @ v / np.linalg.norm(u) / np.linalg.norm(v), -1.0, 1.0))))
        return max(err)

    assert apart(fa) < 1.0 and apart(raw) > 30.0, (apart(fa), apart(raw))
    # the feet stay on the ground as the walk keeps them
    ank = [ap.skeleton.index("l_ankle"), ap.skeleton.index("r_ankle")]
    low = [ap.skeleton.world_matrices(q)[ank, 2, 3].min() for q in fa[::20]]
    np.testing.assert_allclose(low, ap.skeleton.rest_positions[ank, 2].min(), atol=1e-9)
    si, sq = SelfIntersections(ap.V, ap.F, 0.0), SurfaceQuality(ap.V, ap.F)

    def worst(pipe, frames):
        Vs, turned = [], 0
        for q in frames[::8]:
            Vs.append(pipe.deform(q)[:len(ap.V)].copy())
            turned += pipe.counts.get("turned", 0) > 0
        return max(len(si.pairs(V)) for V in Vs), max(sq(V)["folds90"] for V in Vs), turned

    for pipe in (Pipeline.preset(ap, "dqs"), Pipeline(ap, turn_depth=0.0)):
        (pc, fc, _), (pr, fr, _) = worst(pipe, fa), worst(pipe, raw)
        assert pr >= 100 and pc == 0 and fc <= fr, (pc, fc, pr, fr)
    (pc, fc, tc), (pr, fr, tr) = worst(Pipeline(ap), fa), worst(Pipeline(ap), raw)
    assert pc == 0 and fc <= fr and tc == 0 and tr >= 0.9 * len(raw[::8]), (pc, fc, tc, tr)


def test_a_fitted_mesh_takes_cmu_mocap_through_its_templates_mapping(tmp_path):
    """A mesh fitted to the humanoid template, with no mapping of its own,
    takes a CMU BVH through the template's (cmu_to_humanoid.yaml), turned to
    the fit's axes and rest pose. Our humanoid modelled in the T-pose, with
    its arms 35 degrees down, and that A-pose mesh turned to be y up (as
    most DCC tools save): through the CMU walk their bones point the same
    way (the arms within 0.1 degree, the legs, fitted apart, within 2;
    measured 0.0 and 1.3) and the root travels as far (3.07 m, 3.07, 3.10:
    hip heights from each fit); without the turn the A-pose's upper arm hung
    35 degrees lower and the y-up walk went 9% further."""
    import trimesh
    from skin_node import Pipeline
    from skin_node.character import load_character
    from skin_node.motion import character_skeleton, load_motion
    walk = DATA / "bvh" / "cmu_02_01_walk.bvh"
    _need(walk)
    h = load_character("humanoid", surface_vertices=4000, progress=False)
    a = np.radians(35.0)
    X = Pipeline.preset(h, "dqs").deform(h.pose(l_shoulder_rx=-a, r_shoulder_rx=a))[:len(h.V)]
    R = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])     # z up -> -y up
    out = {}
    for name, V in (("t", h.V), ("a", X), ("ay", X @ R.T)):
        trimesh.Trimesh(V, h.F, process=False).export(tmp_path / f"{name}.obj")
        (tmp_path / f"{name}.yaml").write_text(f"mesh: {name}.obj\ntemplate: humanoid\n")
        out[name] = (character_skeleton(str(tmp_path / f"{name}.yaml")),
                     load_motion(str(tmp_path / f"{name}.yaml"), bvh=str(walk)).frames)
    bones = ["l_shoulder", "l_elbow", "r_shoulder", "r_elbow", "l_hip", "l_knee", "spine"]

    def dirs(name, t, back=np.eye(3)):
        sk, q = out[name]
        G = sk.world_matrices(q[t])
        d = np.array([G[sk.children(sk.index(b))[0], :3, 3] - G[sk.index(b), :3, 3]
                      for b in bones]) @ back
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    def apart(u, v):
        return np.degrees(np.arccos(np.clip((u * v).sum(1), -1.0, 1.0)))

    T = len(out["t"][1])
    e = np.max([np.r_[apart(dirs("t", t), dirs("a", t)), apart(dirs("a", t), dirs("ay", t, R))]
                for t in range(0, T, 20)], axis=0)
    arms = np.r_[0:4, 7:11]
    assert e[arms].max() < 0.1 and e.max() < 2.0, np.round(e, 2)
    go = [np.linalg.norm(out[n][1][-1, :3] - out[n][1][0, :3]) for n in ("t", "a", "ay")]
    assert max(go) < 1.03 * min(go) and min(go) > 2.0, go


def test_the_walk_goes_forward_on_the_ground_whatever_way_a_mesh_faces(tmp_path):
    """The built-in walk moves the root along the skeleton's forward and keeps
    the lower ankle at its rest height along its up (the root's rest rotation:
    x and z for the built-ins, bit for bit as before). Our humanoid saved y up
    and facing -z, as glTF files are: it walks 4.8 m along -z, not sideways
    along x, and its feet stay on the ground along its up (grounded along z,
    the same mesh facing +x and y up lifted them up to 60 mm)."""
    import trimesh
    from skin_node import make_clip
    from skin_node.builtin.characters import make_humanoid
    from skin_node.motion import character_skeleton
    V, F, _ = make_humanoid(4000)
    R = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, 1.0], [-1.0, 0.0, 0.0]])  # x -> -z, z -> y
    assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) > 0
    trimesh.Trimesh(V @ R.T, F, process=False).export(tmp_path / "m.obj")
    (tmp_path / "m.yaml").write_text("mesh: m.obj\ntemplate: humanoid\n")
    sk = character_skeleton(str(tmp_path / "m.yaml"))
    np.testing.assert_allclose(sk.rest_rotations[0], R, atol=1e-9)
    f = make_clip("walk", sk).frames
    d = f[-1, :3] - f[0, :3]                # along up only what the grounding moves
    np.testing.assert_allclose(d[[0, 2]], [0.0, -1.2 * (len(f) - 1) / 120], atol=1e-9)
    assert abs(d[1]) < 1e-3, d
    ank = [sk.index("l_ankle"), sk.index("r_ankle")]
    low = [(sk.world_matrices(q)[ank, :3, 3] @ R[:, 2]).min() for q in f[::10]]
    np.testing.assert_allclose(low, (sk.rest_positions[ank] @ R[:, 2]).min(), atol=1e-9)


# ------------------------------------------------------- orientation and checks
def turns() -> list:
    """The 24 rotations that take coordinate axes to coordinate axes."""
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1, -1), repeat=3):
            R = np.zeros((3, 3))
            R[range(3), perm] = signs
            if np.linalg.det(R) > 0:
                out.append(R)
    assert len(out) == 24
    return out


CHECKS = ["inside", "order along up", "left/right apart", "mirror", "bones inside"]


def assert_fits_in_every_orientation(V, F, template, joint_tol):
    """Each turned copy is fitted in its first-guess frame (no retry needed), passes
    every check, and its joints are the upright fit's, turned, within joint_tol."""
    base = fit_template(V, F, template)
    assert base.passed and base.tried == 1, base.summary()
    assert [c.name for c in base.checks] == CHECKS
    bad = []
    for R in turns():
        e = fit_template(V @ R.T, F, template)
        err = np.linalg.norm(e.skeleton.rest_positions - base.skeleton.rest_positions @ R.T,
                             axis=1).max()
        if not (e.passed and e.tried == 1 and np.allclose(e.frame, R @ base.frame, atol=1e-9)
                and err < joint_tol):
            bad.append((R.astype(int).tolist(), round(float(err), 3), e.summary()))
    assert not bad, bad


def test_the_builtin_humanoid_fits_in_all_24_orientations(humanoid_mesh):
    V, F, _ = humanoid_mesh
    assert_fits_in_every_orientation(V, F, "humanoid", joint_tol=0.03)   # 1.0 cm measured


def test_spot_fits_the_quadruped_in_all_24_orientations():
    V, F = read_closed_mesh(_need(SPOT))
    # Spot is 1.7 m long; the voxel grid lies differently in each turn (8.8 cm measured).
    assert_fits_in_every_orientation(V, F, "quadruped", joint_tol=0.15)


def test_the_checks_figures_on_a_good_fit(humanoid_mesh):
    V, F, _ = humanoid_mesh
    e = fit_template(V, F, "humanoid")
    c = {x.name: x for x in e.checks}
    assert c["inside"].figure.startswith("22 of 22 joints and tips inside")
    assert "l_knee above l_ankle" in c["order along up"].figure   # the shortest step
    assert "times the limbs' radius" in c["left/right apart"].figure
    line = e.summary()
    assert line.startswith("template 'humanoid' embedded, up +z (detected), forward +x "
                           "(detected); inside: ")
    assert all(f"{n}: " in line for n in CHECKS) and "\n" not in line


def test_a_humanoid_in_a_cow_is_refused_with_the_failed_check_and_hints(tmp_path):
    """Spot (a cow) under the humanoid template: the legs land in one of the cow's
    legs in every orientation; the fit is refused in one line naming the check,
    its figure, the hints and the template that would fit."""
    spot = _need(SPOT)
    V, F = read_closed_mesh(spot)
    with pytest.raises(EmbeddingError) as e:
        embed_skeleton(V, F, "humanoid")
    msg = str(e.value)
    assert "\n" not in msg
    assert "(and in 7 other orientation(s)): check 'left/right apart' failed: " \
           "l_knee and r_knee" in msg, msg
    assert "say up: and forward: (e.g. up: y, forward: -z)" in msg
    assert msg.endswith("or the mesh is no humanoid: template: quadruped"), msg
    fit = e.value.embedding
    assert not fit.passed and fit.tried == 8
    # Told the right way up and round, it still cannot be a humanoid: the hint is
    # explicit joints, and no other template is guessed (the user chose this one).
    p = tmp_path / "cow_as_human.yaml"
    p.write_text(f"mesh: {spot}\ntemplate: humanoid\nup: y\nforward: -z\n")
    with pytest.raises(CharacterFileError) as e:
        load_character_file(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}: template 'humanoid' does not fit this mesh, up +y (given), "
                          "forward -z (given): check 'left/right apart' failed: "), msg
    assert "check up: and forward:, or list the joints (joints:)" in msg


def test_a_quadruped_in_the_humanoid_is_refused(humanoid_mesh):
    V, F, _ = humanoid_mesh
    fit = fit_template(V, F, "quadruped")
    assert not fit.passed and fit.tried == 8
    failed = [c.name for c in fit.checks if not c.passed]
    assert failed and set(failed) <= set(CHECKS)
    assert f"check '{failed[0]}' failed" in fit.failure()


def test_the_start_up_output_reports_every_check(humanoid_mesh, tmp_path, capsys):
    import trimesh
    V, F, _ = humanoid_mesh
    R = turns()[7]
    trimesh.Trimesh(V @ R.T, F, process=False).export(tmp_path / "body.obj")
    p = tmp_path / "body.yaml"
    p.write_text("mesh: body.obj\ntemplate: humanoid\n")
    skel = load_character_file(p)[2]
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"[skin_node] {p}: template 'humanoid' embedded")
    assert all(f"{n}: " in err[0] for n in CHECKS)
    np.testing.assert_allclose(skel.rest_rotations[0], R, atol=1e-6)
    load_character_file(p, verbose=False)
    assert capsys.readouterr().err == ""
