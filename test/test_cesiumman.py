"""CesiumMan.glb with real CMU mocap: the shipped mapping, automatic against
file weights, and the issue's acceptance measures on the walk and punch clips.

Frames are subsampled (every 12th walk frame, the most-bent punch frames) to
keep the file fast; ``skin_bench`` style full runs are for the report.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pygltflib")

from skin_node import Pipeline, load_character  # noqa: E402
from skin_node.io.bvh import load_bvh  # noqa: E402
from skin_node.metrics import region_volume  # noqa: E402
from skin_node.retarget import axis_conversion, load_mapping, retarget_bvh  # noqa: E402
from skin_node.rigging.regions import JointRegions, count_crossings  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
CESIUMMAN = DATA / "rigged" / "CesiumMan.glb"
CLIPS = {"walk": "cmu_02_01_walk.bvh", "punch": "cmu_02_05_punch_strike.bvh"}
LIMBS = ["joint3", "joint5", "joint7", "joint6", "joint8", "joint11", "joint13", "joint12",
         "joint14", "joint15", "joint16"]

#: The turn stage off, for the tests that measure what the later stages do
#: where the retargeted walk leaves a hand in the hip (as they were
#: measured): turned out of it before skinning, the hand leaves them little
#: to do there, and what each one does no longer shows.
HAND_IN_HIP = {"turn_depth": 0.0}


def need(p: Path) -> Path:
    if not p.exists():
        pytest.skip(f"test data {p} is absent")
    return p


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    import os
    old = os.environ.get("SKIN_NODE_CACHE")
    os.environ["SKIN_NODE_CACHE"] = old or str(tmp_path_factory.mktemp("cache"))
    yield
    if old is None:
        os.environ.pop("SKIN_NODE_CACHE", None)


@pytest.fixture(scope="module")
def characters(cache):
    p = str(need(CESIUMMAN))
    return {w: load_character(p, weights=w, progress=False) for w in ("automatic", "file")}


@pytest.fixture(scope="module")
def motions(characters):
    skel = characters["file"].skeleton
    out = {}
    for name, f in CLIPS.items():
        src = load_bvh(need(DATA / "bvh" / f))
        mapping = load_mapping(ROOT / "config" / "cmu_to_cesiumman.yaml", skel, src)
        _, q, fps = retarget_bvh(src, skel, mapping)
        out[name] = (src, mapping, q)
    return out


@pytest.mark.parametrize("clip", list(CLIPS))
def test_mapping_puts_limbs_along_the_mocap_bones(clip, characters, motions):
    """With the rest offsets, every mapped limb bone points where its CMU bone
    points (axis-converted), in the reference T-pose and through the clip."""
    skel = characters["file"].skeleton
    src, mapping, q = motions[clip]
    C = axis_conversion(mapping)
    Gs = src.world_matrices()
    j_of = mapping["joints"]
    errs = []
    for t in list(range(0, len(q), max(1, len(q) // 40))):
        G = skel.world_matrices(q[t])
        for name in LIMBS:
            j = skel.index(name)
            k = next(c for c in skel.children(j) if skel.names[c] in j_of)
            dt = G[k, :3, 3] - G[j, :3, 3]
            ds = C @ (Gs[t, src.index(j_of[skel.names[k]]), :3, 3] - Gs[t, src.index(j_of[name]), :3, 3])
            cos = dt @ ds / np.linalg.norm(dt) / np.linalg.norm(ds)
            errs.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
            if t == 0:                 # the neck has no offset: within 3 degrees
                assert errs[-1] < 3.0, (name, errs[-1])
    assert np.mean(errs) < 2.0 and np.max(errs) < 10.0, (np.mean(errs), np.max(errs))
    if clip == "walk":   # walks forward (+x) about 2.3 m, metres not inches
        assert 1.5 < q[-1, 0] - q[0, 0] < 3.5 and abs(q[-1, 1] - q[0, 1]) < 0.3


def test_player_picks_the_cesiumman_map(characters):
    pytest.importorskip("rclpy")
    from skin_node.player import load_motion
    name, names, frames, fps = load_motion(str(CESIUMMAN), bvh=str(DATA / "bvh" / CLIPS["walk"]))
    assert name == "cmu_02_01_walk" and fps == 120.0
    assert names == characters["file"].channel_names and frames.shape == (344, 60)


def test_automatic_against_file_weights(characters):
    """Bone heat against the artist's weights on CesiumMan: they differ
    (mean over vertices of half the L1 distance, 0..1) but deform the file's
    own walk within millimetres on average."""
    a, f = characters["automatic"], characters["file"]
    J = a.skeleton.n_joints

    def dense(ch):
        W = np.zeros((len(ch.V), J))
        K = ch.rig.Widx.shape[1]
        np.add.at(W, (np.repeat(np.arange(len(ch.V)), K), ch.rig.Widx.ravel()), ch.rig.Wval.ravel())
        return W

    tv = 0.5 * np.abs(dense(a) - dense(f)).sum(1)
    assert 0.05 < tv.mean() < 0.4, tv.mean()
    from skin_node.io.gltf import load_gltf
    walk = load_gltf(CESIUMMAN).clip(fps=10.0).frames
    pa, pf = Pipeline.preset(a, "lbs"), Pipeline.preset(f, "lbs")
    d = np.concatenate([np.linalg.norm(pa.deform(q) - pf.deform(q), axis=1) for q in walk])
    assert d.mean() < 0.01 and d.max() < 0.2, (d.mean(), d.max())


def frames_of(clip: str, q: np.ndarray, ch) -> np.ndarray:
    if clip == "walk":
        return np.arange(1, len(q), 12)
    bend = np.array([ch.skeleton.joint_angles(x)[1:].max() for x in q[1::4]])
    return 1 + 4 * np.sort(np.argsort(bend)[-24:])          # the most-bent punch frames


def measures(ch, qs, outputs) -> dict:
    """The acceptance measures of skinned ``outputs`` of the poses ``qs``: any NaN,
    joint-region vertices through the skin against LBS's (summed over the
    frames), and each frame's most-bent joint's region volume over rest."""
    regions = JointRegions(ch)
    skel = ch.skeleton
    rj = [j for j in range(skel.n_joints) if skel.parents[j] >= 0 and len(regions.tris[j])]
    rest = {j: region_volume(ch.V, ch.F, regions.tris[j], skel.rest_positions[j]) for j in rj}
    lbs = Pipeline.preset(ch, "lbs")
    out = {"nan": False, "lbs": 0, "ours": 0, "ratio": []}
    for q, Vo in zip(qs, outputs):
        Vl = lbs.deform(q)
        fr = lbs.last_frame                                     # the pose's M, G and angles
        Vo = np.asarray(Vo, dtype=np.float64)
        out["nan"] |= not np.all(np.isfinite(Vo))
        out["lbs"] += count_crossings(Vl, ch.V, ch.F, fr.M, regions)
        out["ours"] += count_crossings(Vo, ch.V, ch.F, fr.M, regions)
        j = max(rj, key=lambda j: fr.angles[j])                 # the most-bent joint
        out["ratio"].append(region_volume(Vo, ch.F, regions.tris[j], fr.G[j, :3, 3]) / rest[j])
    return out


def run(ch, clip, q):
    ours = Pipeline(ch)
    qs = [q[t] for t in frames_of(clip, q, ch)]
    return measures(ch, qs, [ours.deform(x).copy() for x in qs])


def test_coarse_contact_against_dqs_and_its_settling(monkeypatch, characters, motions):
    """CesiumMan's arms lie on its hips through the CMU walk (every 12th
    frame, automatic weights), on skin coarser than the limbs are thick.
    Exact intersecting pairs stay under 30% of DQS's (87 of 4,873 measured),
    and the settling pass after the contact's last projection (one
    Laplacian pass with the constraints held) takes out more than half of the
    sharp folds the projection leaves, measured without the relief cap and
    the easing that come after it (30 against 152)."""
    import skin_node.stages.contact as contact
    from skin_node.kernels.intersect import SelfIntersections
    from skin_node.metrics import SurfaceQuality
    ch = characters["automatic"]
    q = motions["walk"][2]
    qs = [q[t] for t in frames_of("walk", q, ch)]
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    out = {}

    def measure(pipe):
        Vs = [pipe.deform(x).copy() for x in qs]
        return sum(len(si.pairs(V)) for V in Vs), sum(sq(V)["folds90"] for V in Vs)

    for name, pipe in (("dqs", Pipeline.preset(ch, "dqs")), ("ours", Pipeline(ch))):
        out[name] = measure(pipe)
    monkeypatch.setattr(contact, "EASE_BEND", 1e9)
    for name, pipe in (("settled", Pipeline(ch, relief_limit=0.0)),
                       ("unsettled", Pipeline(ch, relief_limit=0.0, contact_settle=0))):
        out[name] = measure(pipe)
    assert out["ours"][0] <= 0.3 * out["dqs"][0], out
    assert out["settled"][1] <= 0.5 * out["unsettled"][1], out


def test_relief_cap_takes_the_spikes_out_of_coarse_contact(monkeypatch, characters, motions):
    """On CesiumMan's coarse skin the contact's projections and the
    inflation's layers move lone vertices far beyond their neighbours
    (spikes a viewer sees at the elbows and where the hands meet the hips).
    Through the CMU walk, measured before the contact's easing and the
    mush's tangential relaxation that come after it and with the hand left
    in the hip (the turn stage off), the relief cap leaves at most 40% of
    the sharp folds the default leaves without it on automatic weights
    (every 12th frame; measured 0 against 30) and at most 90% on the
    artist's (over every frame: 1,521 against 1,715; most of those are the
    file weights' own creases, and frame by frame the cap's share swings:
    every 12th frame from each start gives 0.79 to 1.02; with the
    relaxation on in both, 1,510 against 1,663, as it takes folds out with
    the cap or without), and roughness below what it was without it (1.0222
    against 1.0281; the file's 1.0495 against 1.0524). The default leaves
    no more sharp folds than DQS's on the artist's (107 against 241),
    roughness within 1% of DQS's (1.0213 and DQS's 1.0219; the file's
    1.0413 and 1.0468), and the exact intersecting pairs at most 10% of
    DQS's on automatic weights, 20% on the artist's (0 of 4,873; 114 of
    5,295)."""
    import skin_node.stages.contact as contact
    from skin_node.kernels.intersect import SelfIntersections
    from skin_node.metrics import SurfaceQuality
    q = motions["walk"][2]
    out = {}
    for w in ("automatic", "file"):
        ch = characters[w]
        qs = [q[t] for t in frames_of("walk", q, ch)]
        si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)

        def measure(pipe):
            Vs = [pipe.deform(x)[:len(ch.V)].copy() for x in qs]
            return {"pairs": sum(len(si.pairs(V)) for V in Vs),
                    "folds": sum(sq(V)["folds90"] for V in Vs),
                    "rough": float(np.mean([sq(V)["roughness"] for V in Vs]))}

        out[w, "dqs"], out[w, "ours"] = measure(Pipeline.preset(ch, "dqs")), measure(Pipeline(ch))
        with monkeypatch.context() as m:
            m.setattr(contact, "EASE_BEND", 1e9)
            for name, kw in (("capped", dict(mush_relax=0, **HAND_IN_HIP)),
                             ("uncapped", dict(relief_limit=0.0, mush_relax=0, **HAND_IN_HIP))):
                pipe = Pipeline(ch, **kw)
                out[w, name] = measure(pipe)
                if w == "file":
                    # the file weights' folds swing from frame to frame: every frame
                    out[w, name]["every frame"] = sum(
                        sq(pipe.deform(x)[:len(ch.V)])["folds90"] for x in q[1:])
    a, f = "automatic", "file"
    assert out[a, "capped"]["folds"] <= 0.4 * out[a, "uncapped"]["folds"], out
    assert out[f, "capped"]["every frame"] <= 0.9 * out[f, "uncapped"]["every frame"], out
    assert out[f, "ours"]["folds"] <= out[f, "dqs"]["folds"], out
    for w, share in ((a, 0.1), (f, 0.2)):
        assert out[w, "capped"]["rough"] < out[w, "uncapped"]["rough"], out
        assert out[w, "ours"]["rough"] <= 1.01 * out[w, "dqs"]["rough"], out
        assert out[w, "ours"]["pairs"] <= share * out[w, "dqs"]["pairs"], out


def test_the_tangential_relaxation_leaves_crushed_skin_where_it_would_turn_it_over(
        monkeypatch, characters):
    """A pose far past CesiumMan's joints' reach (rotation channels drawn
    within +-92 degrees, as the benchmark's stress poses are; number 9 of
    seed 7) crushes its head's skin flat, where a vertex's frame can point
    anywhere. Sliding that skin along such a frame turned regular 15 mm
    triangles over: 44 intersecting pairs and 18 sharp folds, against 28 and
    7 with no relaxation. Guarded (a vertex keeps its place where its slide
    would turn the worst of its faces further from its normal): 28 and 9."""
    import skin_node.stages.mush as mush
    from skin_node.kernels.intersect import SelfIntersections
    from skin_node.metrics import SurfaceQuality
    ch = characters["automatic"]
    n, skel = len(ch.V), ch.skeleton
    rng = np.random.default_rng(7)
    for _ in range(10):
        q = skel.rest_pose().copy()
        k = len(q) - 3
        q[3:] = rng.uniform(-1.6, 1.6, k) * (rng.random(k) < 0.5)
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    out = {}
    for name, guard, relax in (("off", True, 0), ("unguarded", False, 2), ("guarded", True, 2)):
        monkeypatch.setattr(mush, "RELAX_GUARD", guard)
        X = Pipeline(ch, mush_relax=relax).deform(q)[:n].copy()
        out[name] = (len(si.pairs(X)), sq(X)["folds90"])
    (p0, f0), (p1, f1), (p2, f2) = out["off"], out["unguarded"], out["guarded"]
    assert p1 >= p0 + 8 and f1 >= f0 + 6, out
    assert p2 <= p0 and f2 <= f0 + 3, out


def test_coarse_skin_folded_through_itself_is_smoothed_out(characters, motions):
    """The file's weights fold CesiumMan's shoulders through themselves as
    the punch swings an arm (triangles one to three rings apart cross; DQS
    has the same crumples). Smoothing the crossing triangles' corners, where
    that parts them (``untangle_unfold``), every 16th frame of the punch:
    exact intersecting pairs at most 10% of DQS's on every frame (116 of
    116; 92 without), summed under a fifth of those without (44 against
    428, DQS 11,809), sharp folds fewer than without (413 against 472, DQS
    1,066) and no frame with more than DQS's (2 without). Inflation, after
    it, gives back the volume the smoothing took: the whole mesh keeps at
    least 0.97 of its rest volume (0.978 at least, as without; DQS 0.958),
    within 0.5% of that without on every frame (0.35% at most)."""
    from skin_node.bench.measure import mesh_volume
    from skin_node.kernels.intersect import SelfIntersections
    from skin_node.metrics import SurfaceQuality
    ch = characters["file"]
    n = len(ch.V)
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    pipes = {"dqs": Pipeline.preset(ch, "dqs"), "on": Pipeline(ch),
             "off": Pipeline(ch, untangle_unfold=0)}
    pairs = {k: [] for k in pipes}
    folds = {k: [] for k in pipes}
    volume = {k: [] for k in pipes}
    v0 = mesh_volume(ch.V, ch.F)
    moved = 0
    for q in motions["punch"][2][::16]:
        for k, pipe in pipes.items():
            X = pipe.deform(q)[:n].copy()
            pairs[k].append(len(si.pairs(X)))
            folds[k].append(sq(X)["folds90"])
            volume[k].append(mesh_volume(X, ch.F))
        moved += pipes["on"].last_frame.counts["untangle_unfolded"]
    p, f = ({k: np.array(v) for k, v in d.items()} for d in (pairs, folds))
    assert moved > 0
    assert np.all(p["on"] <= 0.1 * p["dqs"]), (p["on"], p["dqs"])
    assert (p["off"] > 0.1 * p["dqs"]).sum() >= 10, p["off"]
    assert p["on"].sum() <= 0.2 * p["off"].sum(), (p["on"].sum(), p["off"].sum())
    assert f["on"].sum() <= f["off"].sum() and np.all(f["on"] <= f["dqs"]), f
    vol = {k: np.array(v) / v0 for k, v in volume.items()}
    assert vol["on"].min() >= 0.97 and vol["on"].min() >= vol["off"].min(), vol
    assert np.abs(vol["on"] - vol["off"]).max() <= 0.005, np.abs(vol["on"] - vol["off"]).max()


@pytest.mark.parametrize("weights,clip", [("automatic", "punch"), ("file", "walk")])
def test_inflation_is_withheld_where_it_would_fold_or_cross(monkeypatch, characters, motions,
                                                            weights, clip):
    """On CesiumMan's coarse skin even layers of inflation beside a contact
    crease bend edges sharply and run skin through the other side's (across
    the ankles and between the feet on the file's weights). Withheld there
    and laid on the skin left, every 8th frame: sharp folds at most DQS's
    and exact intersecting pairs at most 10% of DQS's, the punch's folds at
    most a fifth of those without withholding (measured 1 against 363, DQS
    205), the walk's pairs at most 60% (510 against 1,387, DQS 7,844; 6.5%),
    roughness no higher
    than without, and the whole mesh's smallest volume at least DQS's
    (0.978 / 0.975 against DQS's 0.976 / 0.960)."""
    import skin_node.stages.shape as shape
    from skin_node.bench.measure import mesh_volume
    from skin_node.kernels.intersect import SelfIntersections
    from skin_node.metrics import SurfaceQuality
    ch = characters[weights]
    qs = motions[clip][2][1::8]
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    v0 = mesh_volume(ch.V, ch.F)

    def measure(pipe):
        Vs = [pipe.deform(x)[:len(ch.V)].copy() for x in qs]
        return {"pairs": sum(len(si.pairs(V)) for V in Vs),
                "folds": sum(sq(V)["folds90"] for V in Vs),
                "rough": float(np.mean([sq(V)["roughness"] for V in Vs])),
                "volume": min(mesh_volume(V, ch.F) for V in Vs) / v0}

    out = {"dqs": measure(Pipeline.preset(ch, "dqs")), "ours": measure(Pipeline(ch, **HAND_IN_HIP))}
    monkeypatch.setattr(shape, "WITHHOLD_ROUNDS", 0)
    monkeypatch.setattr(shape, "FINAL_BEND", 1e9)
    out["without"] = measure(Pipeline(ch, **HAND_IN_HIP))
    o, w, d = out["ours"], out["without"], out["dqs"]
    assert o["folds"] <= d["folds"] and o["pairs"] <= 0.1 * d["pairs"], out
    if clip == "punch":
        assert o["folds"] <= 0.2 * w["folds"], out
    else:
        assert o["pairs"] <= 0.6 * w["pairs"], out
    assert o["rough"] <= w["rough"], out
    assert o["volume"] >= d["volume"], out


@pytest.mark.parametrize("clip", ["walk", "punch"])
def test_whole_mesh_volume_is_laid_again_after_the_relief_cap(monkeypatch, characters, motions,
                                                              clip):
    """On CesiumMan's file weights the spikes the relief cap cuts out of the
    inflation carried much of the whole mesh's volume. Laid again on the
    skin the cut left, every 8th frame: the whole mesh keeps at least 0.97
    of its rest volume at every frame (measured 0.975 / 0.975; 0.960 / 0.967
    without, DQS 0.960 / 0.958), with at most 5% more intersecting pairs and
    sharp folds than without (510 / 1,864 pairs against 490 / 1,866; folds
    190 / 1,383 against 186 / 1,382), still at most 10% of DQS's pairs and
    no more folds than DQS."""
    import skin_node.stages.shape as shape
    from skin_node.bench.measure import mesh_volume
    from skin_node.kernels.intersect import SelfIntersections
    from skin_node.metrics import SurfaceQuality
    ch = characters["file"]
    qs = motions[clip][2][1::8]
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    v0 = mesh_volume(ch.V, ch.F)

    def measure(pipe):
        Vs = [pipe.deform(x)[:len(ch.V)].copy() for x in qs]
        return {"pairs": sum(len(si.pairs(V)) for V in Vs),
                "folds": sum(sq(V)["folds90"] for V in Vs),
                "volume": min(mesh_volume(V, ch.F) for V in Vs) / v0}

    # the relaying alone: the turns out of the hip (the turn stage before
    # skinning, untangle_shift after the untangle's pushes) take out pairs
    # neither leaves and the volume with them, off in both; so is the
    # smoothing of crumples (untangle_unfold), which takes out half the
    # pairs of both and leaves the relaying's 17 more (264 against 247)
    out = {"dqs": measure(Pipeline.preset(ch, "dqs")),
           "ours": measure(Pipeline(ch, untangle_shift=0.0, untangle_unfold=0, **HAND_IN_HIP))}
    monkeypatch.setattr(shape, "RELAY_WHOLE", False)
    out["without"] = measure(Pipeline(ch, untangle_shift=0.0, untangle_unfold=0, **HAND_IN_HIP))
    o, w, d = out["ours"], out["without"], out["dqs"]
    assert o["volume"] >= 0.97 and w["volume"] < 0.97, out
    assert o["pairs"] <= 1.05 * w["pairs"] and o["folds"] <= 1.05 * w["folds"], out
    assert o["pairs"] <= 0.1 * d["pairs"] and o["folds"] <= d["folds"], out


@pytest.mark.parametrize("weights", ["automatic", "file"])
def test_untangle_parts_coarse_triangles_without_crumpling(monkeypatch, characters, motions,
                                                          weights):
    """Where CesiumMan's hands and arms lie on its hips (the CMU walk, every
    12th frame), coarse triangles cross between vertices the contact keeps
    apart. The untangle pushes such pairs apart: the exact intersecting
    pairs fall to at most 60% of what the default leaves without it, and
    at most a fifth of DQS's (measured: 1,058 -> 87 of DQS's 4,873 on
    automatic weights, 1,302 -> 394 of 5,295 on the file's). Its rule is
    that same exact test, so the count alone does not grade it. Judged
    without what cuts folds before and after it (the relief cap, and the
    contact's easing before it), sharp folds rise by at most 15% (29 -> 30;
    the file's 254 -> 170), roughness by at most 1%, and the whole mesh
    keeps its volume within 0.5% of what it had without the untangle
    (inflation gives it back). (With both, 0 -> 0 and 173 -> 124; with the
    easing but no cap, 3 -> 7 and 192 -> 149.)"""
    from skin_node import DEFAULT_STAGES
    from skin_node.bench.measure import mesh_volume
    from skin_node.kernels.intersect import SelfIntersections
    from skin_node.metrics import SurfaceQuality
    ch = characters[weights]
    q = motions["walk"][2]
    qs = [q[t] for t in frames_of("walk", q, ch)]
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    without = [s for s in DEFAULT_STAGES if s != "untangle"]
    import skin_node.stages.contact as contact
    out = {}

    def measure(name, pipe):
        Vs = [pipe.deform(x).copy() for x in qs]
        out[name] = {"pairs": sum(len(si.pairs(V)) for V in Vs),
                     "folds": sum(sq(V)["folds90"] for V in Vs),
                     "rough": float(np.mean([sq(V)["roughness"] for V in Vs])),
                     "volume": min(mesh_volume(V, ch.F) for V in Vs)}

    measure("dqs", Pipeline.preset(ch, "dqs"))
    measure("ours", Pipeline(ch))
    measure("without", Pipeline(ch, without))
    monkeypatch.setattr(contact, "EASE_BEND", 1e9)
    measure("ours uncapped", Pipeline(ch, relief_limit=0.0))
    measure("without uncapped", Pipeline(ch, without, relief_limit=0.0))
    o, w, d = out["ours"], out["without"], out["dqs"]
    assert o["pairs"] <= 0.6 * w["pairs"] and o["pairs"] <= 0.2 * d["pairs"], out
    o, w = out["ours uncapped"], out["without uncapped"]
    assert o["folds"] <= 1.15 * w["folds"], out
    assert o["rough"] <= 1.01 * w["rough"], out
    assert o["volume"] >= 0.995 * w["volume"], out


def _sums(ch, qs, pipe) -> dict:
    from skin_node.kernels.intersect import SelfIntersections
    from skin_node.metrics import SurfaceQuality
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    Vs = [pipe.deform(x)[:len(ch.V)].copy() for x in qs]
    return {"pairs": sum(len(si.pairs(V)) for V in Vs),
            "folds": sum(sq(V)["folds90"] for V in Vs),
            "rough": float(np.mean([sq(V)["roughness"] for V in Vs]))}


def test_untangle_takes_a_pushed_corners_neighbours_along(characters, motions):
    """The untangle pushes a 40 mm triangle's corner out of the other part's
    triangle; pushed alone, past neighbours left where they lay, the
    triangles around it crossed the other part's instead (CesiumMan's hands
    on its hips through the CMU walk, automatic weights). Its unpushed
    neighbours take half its move. Every 4th frame: exact intersecting
    pairs at most 80% of those with corners pushed alone (measured 198
    against 276; DQS 14,473), sharp folds and roughness no higher (0
    against 1; 1.0219 against 1.0222)."""
    ch = characters["automatic"]
    qs = motions["walk"][2][1::4]
    # the pushes alone: the turn out of the hip after them (untangle_shift)
    # takes out what either leaves (12 pairs each)
    o = _sums(ch, qs, Pipeline(ch, **HAND_IN_HIP, untangle_shift=0.0))
    a = _sums(ch, qs, Pipeline(ch, **HAND_IN_HIP, untangle_spread=0.0, untangle_shift=0.0))
    assert o["pairs"] <= 0.8 * a["pairs"], (o, a)
    assert o["folds"] <= a["folds"] and o["rough"] <= a["rough"], (o, a)


def test_untangle_eases_the_pushes_that_crease_the_skin(monkeypatch, characters, motions):
    """Pushes along different triangles' normals crease the coarse hand
    where it lies on the hip. Where a round bent an edge past EASE_BEND
    degrees, the push at its corners is smoothed. The CMU walk's frames
    90-99 and 225-239 (every one; automatic weights), where the hands lie
    on the hips: at most half the sharp folds of the pushes left as they
    are (measured 0 against 6; DQS 0), at most 10% more exact
    intersecting pairs (768 against 745; DQS 5,567), roughness no higher."""
    import skin_node.stages.untangle as untangle
    ch = characters["automatic"]
    q = motions["walk"][2]
    qs = q[np.r_[90:100, 225:240]]
    o = _sums(ch, qs, Pipeline(ch))
    monkeypatch.setattr(untangle, "EASE_BEND", 1e9)
    w = _sums(ch, qs, Pipeline(ch))
    assert o["folds"] <= 0.5 * w["folds"], (o, w)
    assert o["pairs"] <= 1.1 * w["pairs"] and o["rough"] <= w["rough"], (o, w)


def test_untangle_turns_a_limb_left_crossing_out_of_the_other_part(characters, motions):
    """Where the retargeted walk drives CesiumMan's right hand 20-37 mm into
    its hip and thigh (frames 216-240, every 4th, automatic weights), the
    untangle's pushes leave the hand's 40 mm triangles through the
    thigh's. The hand is turned out about the elbow by the least move that
    parts them: at most 10% of the pairs left without the turn (measured
    0 against 144; DQS 1,447), no more sharp folds (0 and 0) nor
    roughness, and no skin moved further than ``untangle_shift`` of the
    hand's radii (53 mm, the limit 3 x 36 mm)."""
    from skin_node.kernels.intersect import SelfIntersections
    from skin_node.metrics import SurfaceQuality
    ch = characters["automatic"]
    qs = motions["walk"][2][216:244:4]
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    on, off = Pipeline(ch, **HAND_IN_HIP), Pipeline(ch, **HAND_IN_HIP, untangle_shift=0.0)
    Von, Voff = ([p.deform(x).copy() for x in qs] for p in (on, off))
    o, w = _sums(ch, qs, on), _sums(ch, qs, off)
    assert o["pairs"] <= 0.1 * w["pairs"], (o, w)
    assert o["folds"] <= w["folds"] and o["rough"] <= w["rough"], (o, w)
    hand = ch.skeleton.index("joint10")
    radius = ch.nearest_segments[1][:, 0]
    span = on.params["untangle_shift"] * np.median(radius[ch.rig.part == hand])
    moved = max(np.linalg.norm(a - b, axis=1).max() for a, b in zip(Von, Voff))
    assert 0.01 < moved <= span, (moved, span)


def test_inflation_turns_a_limb_its_layers_ran_through_another_part(monkeypatch, characters,
                                                                     motions):
    """Inflation's layers swell the hip back into a forearm the untangle had
    just cleared (CesiumMan's punch on the file's weights). The limb its
    layers ran through another part's is turned out as the untangle turns
    it: over frames 1121-1185 (every 4th), at most 70% of the pairs left
    without that second turn (measured 35 against 67; DQS 1,861), no more
    sharp folds (64 and 64) nor roughness, the whole mesh's volume kept."""
    import skin_node.stages.shape as shape
    from skin_node.bench.measure import mesh_volume
    ch = characters["file"]
    qs = motions["punch"][2][1121:1186:4]
    v0 = mesh_volume(ch.V, ch.F)
    o = _sums(ch, qs, Pipeline(ch))
    vo = min(mesh_volume(Pipeline(ch).deform(x), ch.F) for x in qs) / v0
    monkeypatch.setattr(shape, "TURN_REACH", -np.inf)   # no skin tested: no turn
    w = _sums(ch, qs, Pipeline(ch))
    vw = min(mesh_volume(Pipeline(ch).deform(x), ch.F) for x in qs) / v0
    assert o["pairs"] <= 0.7 * w["pairs"], (o, w)
    assert o["folds"] <= w["folds"] and o["rough"] <= w["rough"], (o, w)
    assert vo >= vw - 0.001, (vo, vw)


@pytest.mark.parametrize("weights", ["automatic", "file"])
def test_limb_turns_never_cross_more_on_random_poses(characters, weights):
    """Poses no clip has (half of CesiumMan's joints turned at random, each
    channel up to 92 degrees, seeded): with the turns (``untangle_shift``)
    no pose has more exact intersecting pairs than without them, the skin
    stays finite, and the sharp folds summed are no more (measured over
    these 30: 788 against 812 pairs, 114 and 114 folds on automatic
    weights; 1,896 against 1,903 and 610 and 610 on the file's)."""
    from skin_node.kernels.intersect import SelfIntersections
    from skin_node.metrics import SurfaceQuality
    ch = characters[weights]
    sk = ch.skeleton
    si, sq = SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F)
    on, off = Pipeline(ch), Pipeline(ch, untangle_shift=0.0)
    rng = np.random.default_rng(7)
    folds = np.zeros(2, dtype=int)
    for _ in range(30):
        q = sk.rest_pose().copy()
        n = len(q) - 3
        q[3:] = rng.uniform(-1.6, 1.6, n) * (rng.random(n) < 0.5)
        a, b = on.deform(q).copy(), off.deform(q).copy()
        assert np.isfinite(a).all()
        assert len(si.pairs(a)) <= len(si.pairs(b)), q
        folds += (sq(a)["folds90"], sq(b)["folds90"])
    assert folds[0] <= folds[1], folds


def test_limb_ends_turn_about_a_joint_up_their_chain(characters):
    """Which limb turns, and about which joint (CesiumMan's skeleton): of a
    hand and a thigh the hand, about the elbow when the hand's crossing is
    nearer its wrist than the turn's reach, never above the shoulder nor
    about a joint that carries the other part; two hands both, half each;
    never an upper arm (a limb's top part: turning it at the shoulder swung
    the hand twice as far, a 130 mm flicker on one frame of the walk), nor
    a part out of its parent."""
    from skin_node.stages.untangle import CoarseCrossings, LimbTurn
    ch = characters["automatic"]
    sk = ch.skeleton
    j = {n: sk.index(n) for n in ("joint0", "joint12", "joint6", "joint8", "joint9", "joint10")}
    pelvis, thigh, arm, forearm = j["joint0"], j["joint12"], j["joint6"], j["joint8"]
    left, right = j["joint9"], j["joint10"]
    params = Pipeline(ch).params
    un = LimbTurn(ch, ch.rig.weights(), CoarseCrossings(ch, params["coarse_below"]), params)
    assert un._movers(thigh, right) == ((right, 1.0),)
    assert un._movers(right, thigh) == ((right, 1.0),)
    assert un._movers(left, right) == ((left, 0.5), (right, -0.5))
    assert un._movers(pelvis, arm) == ()            # the upper arm tops its limb
    assert un._movers(forearm, right) == ()         # out of its parent
    assert un._movers(pelvis, forearm) == ((forearm, 1.0),)
    G = sk.world_matrices(sk.rest_pose())
    wrist, elbow = G[right, :3, 3], G[forearm, :3, 3]
    near = wrist + 0.05 * (wrist - elbow) / np.linalg.norm(wrist - elbow)
    reach = 0.5 * np.linalg.norm(near - elbow)
    assert un._pivot(right, np.array([thigh]), near, reach, G) == forearm
    assert un._pivot(right, np.array([thigh]), near, 0.01, G) == right
    # never above the limb's top (the shoulder), however far the reach
    assert un._pivot(right, np.array([thigh]), near, 100.0, G) == arm
    # nor to a joint that carries the other part
    assert un._pivot(right, np.array([forearm]), near, 100.0, G) == right
    assert un._pivot(forearm, np.array([right]), near, 100.0, G) is None


def test_contact_eases_the_moves_that_crease_coarse_skin(monkeypatch, characters, motions):
    """The contact projects each vertex in another part's flesh on its own;
    the corners of a 40 mm triangle of the hand pressed into the hip went
    to different places and creased it past 90 degrees. Where the contact
    bent an edge past EASE_BEND degrees its move is smoothed there and a
    ring round. The CMU walk's frames 90-99 and 225-239 (every one;
    automatic weights), where the hands lie on the hips: no sharp folds
    (measured 0 against 4; DQS 0), at most 10% more exact intersecting
    pairs (768 against 738; DQS 5,567), roughness no higher."""
    import skin_node.stages.contact as contact
    ch = characters["automatic"]
    qs = motions["walk"][2][np.r_[90:100, 225:240]]
    o = _sums(ch, qs, Pipeline(ch, **HAND_IN_HIP))
    monkeypatch.setattr(contact, "EASE_BEND", 1e9)
    w = _sums(ch, qs, Pipeline(ch, **HAND_IN_HIP))
    assert w["folds"] >= 3 and o["folds"] == 0, (o, w)
    assert o["pairs"] <= 1.1 * w["pairs"] and o["rough"] <= w["rough"], (o, w)


def test_inflation_is_reverted_where_it_still_folds_the_skin(monkeypatch, characters,
                                                             motions):
    """After the withholding rounds, inflation is undone at the corners of
    coarse edges it still bends by more than FINAL_BEND degrees. The punch's
    frames where the layers left sharp folds (automatic weights; found on
    every 2nd frame with the revert off): no sharp folds (measured 0 against
    16; DQS 8), no more exact intersecting pairs (0 against 10; DQS 954),
    roughness no higher, and the whole mesh's volume at least 0.97 of rest
    and within 0.5% of that with the layers left (0.982 both). (The stages
    before it have since taken over the folds of the frames this test held
    before: the turn's cap of 4 limb radii took the elbow out of the hip on
    the punch frames it last held, 26 folds there with the revert off, 0
    now; the walk's, 8 on its pelvis and knee, were the layers' past the
    bulge envelope before those stopped at an outer one: PAST_ENVELOPE.)"""
    from skin_node.bench.measure import mesh_volume
    import skin_node.stages.shape as shape
    ch = characters["automatic"]
    v0 = mesh_volume(ch.V, ch.F)
    ts = [496, 522, 526, 530, 546, 548, 660, 1392, 1396, 1400, 1570, 1576, 1580, 1586]
    qs = motions["punch"][2][ts]
    monkeypatch.setattr(shape, "FINAL_BEND", 60.0)
    p = Pipeline(ch)
    o = _sums(ch, qs, p)
    vo = min(mesh_volume(p.deform(x)[:len(ch.V)], ch.F) for x in qs) / v0
    monkeypatch.setattr(shape, "FINAL_BEND", 1e9)
    p = Pipeline(ch)
    w = _sums(ch, qs, p)
    vw = min(mesh_volume(p.deform(x)[:len(ch.V)], ch.F) for x in qs) / v0
    assert w["folds"] >= 8 and o["folds"] <= 0.25 * w["folds"], (o, w)
    assert o["pairs"] <= w["pairs"] and o["rough"] <= w["rough"], (o, w)
    assert vo >= 0.97 and vo >= 0.995 * vw, (vo, vw)


def test_coarse_corners_of_a_fine_part_keep_inflation_from_folding_them(monkeypatch,
                                                                         characters, tmp_path):
    """CesiumMan's mesh as a plain mesh fitted to the humanoid template: its
    chest part is mostly fine skin, so its coarse triangles at the shoulders
    were no coarse part's, and inflation's bent-edge checks passed them by:
    the built-in walk (every 4th frame) kept 152 sharp folds there where DQS
    has none. Checked on every triangle with a coarse corner
    (COARSE_CORNERS): no sharp fold (0), no more intersecting pairs (0
    against 24) and roughness no higher (1.0127 against 1.0132)."""
    import trimesh
    import skin_node.stages.shape as shape
    from skin_node import make_clip
    from skin_node.character import load_character as load
    ch = characters["automatic"]
    trimesh.Trimesh(ch.V, ch.F, process=False).export(tmp_path / "cman.obj")
    (tmp_path / "cman.yaml").write_text("mesh: cman.obj\ntemplate: humanoid\n")
    fitted = load(str(tmp_path / "cman.yaml"), progress=False)
    qs = make_clip("walk", fitted.skeleton).frames[::4]
    o = _sums(fitted, qs, Pipeline(fitted))
    monkeypatch.setattr(shape, "COARSE_CORNERS", False)
    w = _sums(fitted, qs, Pipeline(fitted))
    assert w["folds"] >= 50 and o["folds"] == 0, (o, w)
    assert o["pairs"] <= w["pairs"] and o["rough"] <= w["rough"], (o, w)


def test_layers_past_the_bulge_envelope_stop_at_an_outer_one(monkeypatch, characters,
                                                              motions):
    """Where a coarse joint's region is still short once its layers within
    the bulge limit's envelope are spent, the layers past it stop
    PAST_ENVELOPE rest distances further out: unbounded, a layer of a few
    lone vertices stood out as a flap at the elbow's crease. The CMU walk's
    frames where that flap stood furthest out (automatic weights): the
    largest outward change of the skin from its bone within 10 mm of DQS's
    (measured 15.5-17.7 mm against 10.0-12.1), where unbounded it stood 25
    mm or more beyond it (41.3-43.2); the most bent joint's region still
    within 3% of rest (1.000-1.003 both ways: the flap bought no volume the
    region lacked), and no more intersecting pairs or sharp folds (0 and 0
    both ways)."""
    import skin_node.stages.shape as shape
    from skin_node.bench.measure import SceneMetrics
    ch = characters["automatic"]
    sm = SceneMetrics(ch)
    qs = motions["walk"][2][[49, 51, 53, 179, 181, 221, 223, 313]]

    def run(pipe):
        out = []
        for q in qs:
            X = pipe.deform(q)[:len(ch.V)]
            fr = pipe.last_frame
            j = max(sm.region_joints, key=lambda j: fr.angles[j])
            out.append((sm.deviation_mm(X, fr.seg_A, fr.seg_B).max(),
                        sm.region_ratio(X, fr.G, j)))
        return np.array(out)

    dqs = run(Pipeline.preset(ch, "dqs"))
    ours = run(Pipeline(ch, **HAND_IN_HIP))
    o = _sums(ch, qs, Pipeline(ch, **HAND_IN_HIP))
    monkeypatch.setattr(shape, "PAST_ENVELOPE", 1e6)
    free = run(Pipeline(ch, **HAND_IN_HIP))
    w = _sums(ch, qs, Pipeline(ch, **HAND_IN_HIP))
    assert np.all(ours[:, 0] <= dqs[:, 0] + 10.0), (ours[:, 0], dqs[:, 0])
    assert np.all(free[:, 0] >= dqs[:, 0] + 25.0), (free[:, 0], dqs[:, 0])
    assert np.all(np.abs(ours[:, 1] - 1.0) <= 0.03), ours[:, 1]
    assert o["pairs"] <= w["pairs"] and o["folds"] <= w["folds"], (o, w)


@pytest.fixture(scope="module")
def acceptance(characters, motions):
    return {(w, c): run(characters[w], c, motions[c][2]) for w in characters for c in CLIPS}


@pytest.mark.parametrize("weights,clip", [
    ("automatic", "walk"), ("automatic", "punch"), ("file", "walk"), ("file", "punch")])
def test_no_nan_and_no_more_crossings_than_lbs(acceptance, weights, clip):
    r = acceptance[(weights, clip)]
    assert not r["nan"]
    assert r["ours"] <= r["lbs"], r


@pytest.mark.parametrize("weights,clip", [
    ("automatic", "walk"), ("automatic", "punch"), ("file", "walk"), ("file", "punch")])
def test_joint_region_volume_within_3_percent(acceptance, weights, clip):
    ratio = np.array(acceptance[(weights, clip)]["ratio"])
    assert np.all(np.abs(ratio - 1.0) <= 0.03), (ratio.min(), ratio.max())


@pytest.mark.parametrize("weights", ["automatic", "file"])
def test_acceptance_through_the_node(tmp_path, weights, characters, motions):
    """The same measures on what the node publishes: ``skin_node`` started as its
    installed executable with CesiumMan, fed the walk's and the punch's frames
    above from a bag in lockstep (each once the one before is answered, so none
    is skipped however loaded the machine), its point clouds recorded."""
    pytest.importorskip("rclpy")
    import test_node_integration as node
    from msg_adapters import point_cloud2_to_vertices
    ch = characters[weights]
    t0, dt = 1_700_000_000 * 10**9, 10**8
    stream, poses = [], []
    for clip in CLIPS:
        q = motions[clip][2]
        for t in frames_of(clip, q, ch):
            stamp = t0 + len(stream) * dt
            stream.append((stamp, node.joint_state(stamp, ch.channel_names, q[t])))
            poses.append((clip, q[t]))
    node.write_bag(tmp_path / "in", "mcap", stream)
    with node.running_node(tmp_path, "-p", f"character:={CESIUMMAN}",
                           "-p", f"weights:={weights}") as (proc, env, log):
        out = node.play_and_record(env, tmp_path / "in", tmp_path / "out", "--lockstep", "10")
        assert proc.poll() is None, "node died"
    assert "in lockstep (0 unanswered within 10 s)" in out
    clouds, diag = node.read_outputs(tmp_path / "out")
    assert [node.stamp_ns(c) for c in clouds] == [t for t, _ in stream]
    assert int(diag["frames_skipped_stale"]) == 0 and int(diag["rejected_total"]) == 0
    V = [point_cloud2_to_vertices(c) for c in clouds]
    # the node runs this character's pipeline (its weights, the pose alone decides)
    ours = Pipeline(ch)
    for i in (0, len(V) - 1):
        assert np.abs(V[i] - ours.deform(poses[i][1])).max() < 1e-5
    for clip in CLIPS:
        k = [i for i, (c, _) in enumerate(poses) if c == clip]
        r = measures(ch, [poses[i][1] for i in k], [V[i] for i in k])
        assert not r["nan"], clip
        assert r["ours"] <= r["lbs"], (clip, r)
        ratio = np.array(r["ratio"])
        assert np.all(np.abs(ratio - 1.0) <= 0.03), (clip, ratio.min(), ratio.max())
