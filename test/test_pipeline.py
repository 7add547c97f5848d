"""Acceptance tests of the deformer on the built-in characters.

Each asserts a measured number against a bound, for our default pipeline and
for the plain method it must beat, so a stage that silently does nothing fails.
"""
from __future__ import annotations

import numpy as np
import pytest

from skin_node import DEFAULT_STAGES, Pipeline, load_character
from skin_node.metrics import mesh_volume, roughness
from skin_node.rigging.regions import JointRegions, count_crossings

#: The tet solve with the paper's collision stage (extended) and the joint
#: volume stage after it: the stages these tests check, as a pipeline, on the
#: paper's weights (under which they were made).
SOLVED = ("dqs", "pbd", "smooth", "collision", "volume")
OLD = {"weight_scheme": "inverse_distance"}


@pytest.fixture(scope="module")
def arm():
    return load_character("arm", progress=False)


@pytest.fixture(scope="module")
def small_arm():
    return load_character("arm", surface_vertices=2000, tet_count=3000, progress=False)


@pytest.fixture(scope="module")
def humanoid():
    return load_character("humanoid", surface_vertices=8000, tet_count=20000, progress=False)


def volume_ratio(ch, stages, q, **params) -> float:
    pipe = Pipeline(ch, stages, **params)
    V = pipe.deform(q)
    return mesh_volume(V, ch.F) / mesh_volume(ch.V, ch.F)


def thinnest_section(ch, V, x0=0.30, x1=0.58) -> float:
    """Smallest ratio, over 1 cm slabs of the rest arm between x0 and x1, of the
    mean distance from the arm's axis now to that at rest."""
    m = (ch.V[:, 0] > x0) & (ch.V[:, 0] < x1)
    r = np.hypot(V[m, 1], V[m, 2])
    r0 = np.hypot(ch.V[m, 1], ch.V[m, 2])
    slab = np.floor(ch.V[m, 0] * 100).astype(int)
    return min(r[slab == s].mean() / r0[slab == s].mean() for s in np.unique(slab))


def test_elbow_150_keeps_volume(arm):
    q = arm.pose(elbow_rz=np.radians(150))
    ours = volume_ratio(arm, DEFAULT_STAGES, q)
    lbs = volume_ratio(arm, ["lbs"], q)
    assert ours >= 0.97, ours
    assert ours <= 1.03, ours
    assert lbs <= 0.92, lbs


def test_wrist_twist_180_keeps_section(arm):
    q = arm.pose(wrist_rx=np.radians(180))
    ours = thinnest_section(arm, Pipeline(arm).deform(q))
    lbs = thinnest_section(arm, Pipeline(arm, ["lbs"]).deform(q))
    assert ours >= 0.80, ours
    assert lbs < 0.2, lbs          # the candy wrapper


def test_walk_keeps_every_bent_joint_region_volume(humanoid):
    """The built-in walk, every 8th frame: each bent joint's region (the cone
    from its posed centre over its skin, :func:`region_volume`) within 3% of
    rest, where the stages before the volume stage lose over 10% at the
    lowered shoulders; and no more crossings than without the volume stage."""
    from skin_node import make_clip
    from skin_node.metrics import region_volume
    ch = humanoid
    skel, regions = ch.skeleton, JointRegions(ch, ch.rig.weights(OLD["weight_scheme"]))
    joints = [j for j in range(1, skel.n_joints) if len(regions.tris[j])]
    rest = {j: region_volume(ch.V, ch.F, regions.tris[j], skel.rest_positions[j]) for j in joints}
    frames = make_clip("walk", skel).frames[::8]
    ours, before = Pipeline(ch, SOLVED, **OLD), Pipeline(ch, SOLVED, **OLD, volume_preserve=False)
    worst, worst_before, cross, cross_before = 1.0, 1.0, 0, 0
    for q in frames:
        for pipe in (ours, before):
            V = pipe.deform(q)
            fr = pipe.last_frame
            r = min(region_volume(V, ch.F, regions.tris[j], fr.G[j, :3, 3]) / rest[j]
                    for j in joints if fr.bent[j])
            n = count_crossings(V, ch.V, ch.F, fr.M, regions)
            if pipe is ours:
                worst, cross = min(worst, r), cross + n
            else:
                worst_before, cross_before = min(worst_before, r), cross_before + n
    assert worst >= 0.97, worst
    assert worst_before < 0.9, worst_before
    assert cross <= cross_before, (cross, cross_before)


def test_parent_region_check_clears_the_chest_under_lowered_arms():
    """Built-in humanoid at its default 24k vertices, walk every 12th frame: the
    lowered arms' solve moves chest skin through the skin; checking the folding
    joints' parent region (``collision_parent``) leaves none, in any region."""
    from skin_node import make_clip
    ch = load_character("humanoid", progress=False)
    regions = JointRegions(ch, ch.rig.weights(OLD["weight_scheme"]))
    frames = make_clip("walk", ch.skeleton).frames[::12]
    chest = ch.skeleton.names.index("chest")

    def crossings(**params):
        pipe, total, in_chest = Pipeline(ch, SOLVED, **OLD, **params), 0, 0
        for q in frames:
            V = pipe.deform(q)
            M = pipe.last_frame.M
            total += count_crossings(V, ch.V, ch.F, M, regions)
            in_chest += count_crossings(V, ch.V, ch.F, M, regions, joints=[chest])
        return total, in_chest

    assert crossings(collision_parent=False)[1] > 5
    assert crossings() == (0, 0)


def test_recheck_after_push_out_reaches_as_far_as_the_test():
    """Built-in humanoid at 24k, the squat's deepest frames (knees at 149
    degrees): pushing calf skin out drags its triangles over thigh skin that
    the push-out's recheck must cover. It used to recheck two median edges
    around each pushed vertex, less than the test's own reach, and one thigh
    vertex stayed through the skin in each of these frames."""
    from skin_node import make_clip
    ch = load_character("humanoid", progress=False)
    regions = JointRegions(ch, ch.rig.weights(OLD["weight_scheme"]))
    frames = make_clip("squat", ch.skeleton).frames
    pipe = Pipeline(ch, SOLVED, **OLD)
    left = []
    for k in (225, 226, 253, 254):
        V = pipe.deform(frames[k])
        left.append(count_crossings(V, ch.V, ch.F, pipe.last_frame.M, regions))
    assert left == [0, 0, 0, 0]


@pytest.mark.parametrize("case", ["arm", "humanoid"])
def test_no_skin_crossings_after_collision(case, arm, humanoid):
    ch = arm if case == "arm" else humanoid
    q = ch.pose(elbow_rz=np.radians(150)) if case == "arm" else ch.pose(l_knee_ry=np.radians(150))
    regions = JointRegions(ch, ch.rig.weights(OLD["weight_scheme"]))
    lbs = Pipeline(ch, ["lbs"])
    V = lbs.deform(q)
    before = count_crossings(V, ch.V, ch.F, lbs.last_frame.M, regions)
    ours = Pipeline(ch, SOLVED, **OLD)
    V = ours.deform(q)
    after = count_crossings(V, ch.V, ch.F, ours.last_frame.M, regions)
    assert before > 20, before
    assert after == 0, after
    # the collision stage itself (paper's projection) is what removes them
    no_col = Pipeline(ch, SOLVED, **OLD, self_collision=False)
    V = no_col.deform(q)
    assert count_crossings(V, ch.V, ch.F, no_col.last_frame.M, regions) > 0


@pytest.mark.parametrize("case", ["arm", "humanoid"])
def test_checked_swell_gives_a_folded_region_its_volume_without_crossings(case, arm, humanoid):
    """Past its guards the volume stage also swells skin near the other side's
    flesh, and keeps only the moves that cross no skin: at a 150 degree fold
    the region gets most of what the guards alone leave missing, with no new
    crossing anywhere."""
    from skin_node.metrics import region_volume
    ch = arm if case == "arm" else humanoid
    name = "elbow" if case == "arm" else "l_knee"
    q = ch.pose(**{f"{name}_rz" if case == "arm" else f"{name}_ry": np.radians(150)})
    j = ch.skeleton.index(name)
    regions = JointRegions(ch, ch.rig.weights(OLD["weight_scheme"]))
    rest = region_volume(ch.V, ch.F, regions.tris[j], ch.skeleton.rest_positions[j])

    def measure(**params):
        pipe = Pipeline(ch, SOLVED, **OLD, **params)
        V = pipe.deform(q)
        fr = pipe.last_frame
        return (region_volume(V, ch.F, regions.tris[j], fr.G[j, :3, 3]) / rest,
                count_crossings(V, ch.V, ch.F, fr.M, regions))

    guarded, guarded_crossings = measure(volume_checked_below=1.0)
    checked, crossings = measure()
    assert guarded < 0.9, guarded
    assert checked > guarded + 0.05, (checked, guarded)
    assert checked < 1.03, checked
    assert crossings <= guarded_crossings, (crossings, guarded_crossings)


def test_smooth_lowers_roughness_inside_region_only(arm):
    """The paper's smoothing (positions, joint region only)."""
    q = arm.pose(elbow_rz=np.radians(120))
    rough = Pipeline(arm, ["lbs", "pbd"])
    smooth = Pipeline(arm, ["lbs", "pbd", "smooth"], smooth_mode="position", smoothing=0.5,
                      smoothing_iterations=2)
    A, B = rough.deform(q), smooth.deform(q)
    region = np.flatnonzero(arm.rig.region == arm.skeleton.index("elbow"))
    r = arm.rig
    assert roughness(B, region, r.adj_ptr, r.adj) < 0.9 * roughness(A, region, r.adj_ptr, r.adj)
    outside = np.setdiff1d(np.arange(len(arm.V)), region)
    assert np.abs(B[outside] - A[outside]).max() == 0.0
    assert np.abs(B[region] - A[region]).max() > 1e-5


def test_displacement_smoothing_keeps_detail(arm):
    """Ours: smoothing the solve's correction lowers the correction's roughness,
    moves only vertices the solve moved, and keeps the volume (it does not
    shrink the skin the way position smoothing does)."""
    q = arm.pose(elbow_rz=np.radians(120))
    rough = Pipeline(arm, ["lbs", "pbd"])
    smooth = Pipeline(arm, ["lbs", "pbd", "smooth"], smooth_mode="displacement")
    A, B = rough.deform(q), smooth.deform(q)
    base = rough.last_frame.surface_base
    r = arm.rig
    moved = np.flatnonzero(np.linalg.norm(A - base, axis=1) > 0)
    assert roughness(B - base, moved, r.adj_ptr, r.adj) < \
        0.7 * roughness(A - base, moved, r.adj_ptr, r.adj)
    still = np.setdiff1d(np.arange(len(arm.V)), smooth.stages[-1].verts(
        smooth.last_frame.bent, "displacement"))
    assert np.abs(B[still] - A[still]).max() == 0.0
    v0 = mesh_volume(arm.V, arm.F)
    assert abs(mesh_volume(B, arm.F) - mesh_volume(A, arm.F)) / v0 < 0.005


def test_rest_pose_is_rest_mesh(arm):
    for stages in (["lbs"], ["dqs"], DEFAULT_STAGES, SOLVED):
        V = Pipeline(arm, stages).deform(arm.skeleton.rest_pose())
        assert np.abs(V - arm.V).max() < 1e-9


@pytest.mark.parametrize("skinning", ["lbs", "dqs"])
def test_tet_mesh_is_skinned_where_the_solve_reads_it_and_whole_when_read_back(arm, skinning):
    """Stage 1 skins only the tet vertices of the tets the solve touches; the
    frame read back through ``last_frame`` has the whole tet mesh, equal to a
    run that skinned every vertex up front, and the same surface."""
    q = arm.pose(elbow_rz=2.2)
    stages = [skinning, *SOLVED[1:]]
    lazy, whole = Pipeline(arm, stages, **OLD), Pipeline(arm, stages, **OLD)
    whole.stages[1].tet_vertices = lambda fr: None         # every vertex, up front
    V, V_whole = lazy.deform(q), whole.deform(q)
    rows = lazy._last_frame.tet_rows
    n = len(arm.rig.TV)
    assert 0 < len(rows) < 0.8 * n, (len(rows), n)          # the elbow's zone, not the arm
    assert whole._last_frame.tet_rows is None
    assert np.array_equal(V, V_whole)
    fr, fr_whole = lazy.last_frame, whole.last_frame
    assert fr.unskinned is None
    assert np.array_equal(fr.tet, fr_whole.tet)
    assert np.array_equal(fr.tet_base, fr_whole.tet_base)
    # a pipeline with no tet stage skins none of the tet mesh until it is read
    plain = Pipeline(arm, [skinning], **OLD)
    plain.deform(q)
    assert len(plain._last_frame.tet_rows) == 0
    assert np.array_equal(plain.last_frame.tet, fr_whole.tet_base)


def test_frames_leave_no_reference_cycles(small_arm):
    """A deformed frame is freed when the next one replaces it, not when the
    cycle collector gets round to it: garbage in cycles grows the node's
    resident memory between collections (and a collection is a pause)."""
    import gc
    pipe = Pipeline(small_arm)
    poses = [small_arm.pose(elbow_rz=a) for a in np.linspace(0.5, 2.5, 12)]
    for q in poses:                  # first calls compile, and compiling leaves cycles
        pipe.deform(q)
    gc.collect()
    was = gc.isenabled()
    gc.disable()
    gc.set_debug(gc.DEBUG_SAVEALL)
    try:
        for q in poses:
            pipe.deform(q)
            assert pipe.last_frame.tet.shape == small_arm.rig.TV.shape
        found = gc.collect()
        kinds = sorted({type(o).__name__ for o in gc.garbage})
    finally:
        gc.set_debug(0)
        gc.garbage.clear()
        if was:
            gc.enable()
    assert found == 0, kinds


def test_timings_and_presets(small_arm):
    q = small_arm.pose(elbow_rz=2.0)
    for name in ("lbs", "dqs", "pbs", "paper", "default"):
        pipe = Pipeline.preset(small_arm, name)
        V = pipe.deform(q)
        assert np.all(np.isfinite(V))
        assert set(pipe.timings) >= {"fk", "total", *pipe.stage_names}
        assert pipe.timings["total"] >= max(pipe.timings[s] for s in pipe.stage_names)


def test_a_part_is_coarse_when_its_median_vertex_resolves_its_limb_less_than_coarse_below():
    from types import SimpleNamespace
    from skin_node.stages.untangle import coarse_triangles
    # three parts of two triangles each, their vertices' resolutions (median
    # 0.2, 0.6 and 1.0; part 1's mean is under 0.5, its median is not)
    part = np.repeat([0, 1, 2], 4)
    resolved = np.array([0.2, 0.2, 0.9, 0.0, 0.6, 0.6, 0.0, 1.0, 1.0, 1.0, 0.0, 1.0])
    F = np.array([[4 * p, 4 * p + 1, 4 * p + 2] for p in range(3)]
                 + [[4 * p + 1, 4 * p + 3, 4 * p + 2] for p in range(3)])
    ch = SimpleNamespace(F=F, resolved=resolved, rig=SimpleNamespace(part=part),
                         skeleton=SimpleNamespace(n_joints=3))
    coarse = lambda below: sorted(coarse_triangles(ch, below)[2].tolist())  # noqa: E731
    assert coarse(0.5) == [0, 3]                 # part 0's two triangles
    assert coarse(1.0) == [0, 1, 3, 4]           # parts 0 and 1
    assert coarse(0.0) == []


def test_coarse_below_rebuilds_the_stages_that_read_it(humanoid):
    # the 8k humanoid's forearms, hands and left foot are coarse; at 1 its
    # shoulders, knees and right foot are too
    pipe = Pipeline(humanoid)
    untangle = lambda: pipe.stages[pipe.stage_names.index("untangle")]  # noqa: E731
    half = len(untangle().coarse)
    assert 0 < half < len(humanoid.F) // 4
    pipe.set_params(coarse_below=1.0)
    assert len(untangle().coarse) > 1.5 * half
    pipe.set_params(coarse_below=0.0)
    assert len(untangle().coarse) == 0 and not untangle()._cross
    assert np.isfinite(pipe.deform(humanoid.pose(l_elbow_rz=2.0))).all()


def test_pose_errors(small_arm):
    pipe = Pipeline(small_arm)
    with pytest.raises(ValueError, match="shape"):
        pipe.deform(np.zeros(3))
    q = small_arm.skeleton.rest_pose()
    q[4] = np.nan
    with pytest.raises(ValueError, match="NaN"):
        pipe.deform(q)


def test_stage_order_errors(small_arm):
    """Stages on the pose come before the one skinning stage, which comes
    before the rest; a list that breaks that is refused, saying what it got."""
    for bad in (["turn"], ["dqs", "turn"], ["turn", "bulge", "dqs"], ["turn", "dqs", "lbs"],
                ["bulge", "dqs"]):
        with pytest.raises(ValueError, match="first stage must be 'lbs' or 'dqs'|only the first stage may skin"):
            Pipeline(small_arm, bad)
    assert Pipeline(small_arm, ["turn", "lbs", "bulge"]).stage_names == ["turn", "lbs", "bulge"]


def random_motion(skel, n: int, rng: np.random.Generator) -> np.ndarray:
    """Smooth random motion within the joint limits, with bursts of 90-degree
    jumps between consecutive frames."""
    lo, hi = skel.limits[..., 0].ravel(), skel.limits[..., 1].ravel()
    q = np.zeros(skel.n_channels)
    out = np.empty((n, skel.n_channels))
    a = np.zeros_like(lo)
    for t in range(n):
        a = np.clip(a + rng.normal(0.0, 0.03, a.shape), lo, hi)
        if (t // 250) % 8 == 7:                    # a burst: jump 90 degrees every frame
            a = np.clip(a + rng.choice([-1, 1], a.shape) * np.pi / 2, lo, hi)
        q[3:] = a
        out[t] = q
    return out


def test_stability_10000_random_frames(small_arm):
    ch = small_arm
    rng = np.random.default_rng(7)
    frames = random_motion(ch.skeleton, 10_000, rng)
    ours, lbs = Pipeline(ch), Pipeline(ch, ["lbs"])
    worst = 0.0
    for q in frames:
        V = ours.deform(q)
        assert np.all(np.isfinite(V))
        worst = max(worst, float(np.linalg.norm(V - lbs.deform(q), axis=1).max()))
    assert worst < 0.5, worst
    V = ours.deform(ch.skeleton.rest_pose())
    assert np.linalg.norm(V - ch.V, axis=1).max() < 1e-3


@pytest.mark.parametrize("stages", ["default", "solved"])
def test_two_threads_give_the_skin_of_one(humanoid, stages):
    """Without solve_slabs, threads only split work whose result does not
    depend on the split (skinning, the collision test, smoothing, the
    embedding): the walk comes out bitwise the same on two threads as on one."""
    import numba
    from skin_node import make_clip
    if numba.config.NUMBA_NUM_THREADS < 2:
        pytest.skip("numba has one thread here")
    st = DEFAULT_STAGES if stages == "default" else SOLVED
    one, two = Pipeline(humanoid, st, threads=1), Pipeline(humanoid, st, threads=2)
    frames = make_clip("walk", humanoid.skeleton).frames[::24]
    try:
        for q in frames:
            assert np.array_equal(one.deform(q), two.deform(q))
        if stages == "solved":
            assert two.counts["pushed"] + two.counts["projected"] > 0      # collision ran
        else:
            assert two.counts["contact_vertices"] + two.counts["bulge_vertices"] > 0
    finally:
        numba.set_num_threads(1)


def test_two_thread_solve_splits_into_slabs_that_share_no_vertex(arm):
    """threads: 2 with solve_slabs sweeps two vertex-disjoint slabs at once, then the constraints
    between them: the parts must not share a vertex (a race otherwise), the
    separator must be small, and running the parts in parallel must give what
    running them one after the other gives."""
    import numba
    from skin_node.kernels import solver
    from skin_node.kernels.solver import BIND, ENERGY, STRETCH, VOLUME
    pipe = Pipeline(arm, ["dqs", "pbd"], threads=2, solve_slabs=True)
    pipe.deform(arm.pose(elbow_rz=np.radians(120)))
    pbd, r = pipe.stages[1], arm.rig
    sets, w = pbd._sets.get(pbd._key, None)[:2]
    for kind, members in ((STRETCH, r.E), (VOLUME, r.T), (BIND, np.arange(len(r.TV))[:, None])):
        idx, bounds = sets[kind]
        assert len(bounds) == 4 and bounds[-1] == len(idx)
        parts = [set(members[idx[bounds[h]:bounds[h + 1]]].ravel()) for h in range(2)]
        assert parts[0] and parts[1] and not parts[0] & parts[1]
        assert bounds[3] - bounds[2] < 0.2 * len(idx), (kind, bounds)
    fr = pipe.last_frame
    idx, bounds = sets[ENERGY]
    out = []
    for threads in (1, 2):
        numba.set_num_threads(threads)
        X = fr.tet_base.copy()
        solver.sweep(ENERGY, X, w, pbd.mass, r.E, r.T, np.full(4, 0.5), r.bseg, fr.seg_A,
                     fr.seg_B, r.brest, r.erest, np.zeros(len(r.T)), idx, bounds, 0.5, 0.0,
                     threads)
        out.append(X)
    numba.set_num_threads(1)
    assert np.abs(out[0] - out[1]).max() < 1e-12
    assert np.abs(out[0] - fr.tet_base).max() > 1e-4


@pytest.mark.parametrize("stages", ["default", "solved"])
def test_skin_depends_on_the_pose_alone(arm, stages):
    """Started from stage 1 every frame, a pipeline gives one pose the same
    skin whatever came before it (a DCC scrubbing back and forth, a bag
    replayed from the middle). The solve warm-started, the history shows."""
    st = DEFAULT_STAGES if stages == "default" else SOLVED
    target = arm.pose(elbow_rz=np.radians(130), wrist_rx=np.radians(40))
    before = [arm.pose(elbow_rz=np.radians(a)) for a in (30, 90, 150, 170)]

    def after(history, **params):
        pipe = Pipeline(arm, st, **params)
        for q in history:
            pipe.deform(q)
        return pipe.deform(target)

    fresh = after([])
    assert np.abs(after(before) - fresh).max() < 1e-9
    assert np.abs(after(before[::-1]) - fresh).max() < 1e-9
    if stages == "solved":
        warm = np.abs(after(before, warm_start=True) - after([], warm_start=True)).max()
        assert warm > 1e-4, warm
