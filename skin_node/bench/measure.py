"""Speed and accuracy of a pipeline on a scene over a motion, frame by frame.

Definitions (what every column of the output means)
---------------------------------------------------
Scene
    ``character:surface_vertices[:tets]``, e.g. ``arm:6000`` or ``arm:6000:24000``.
    Of a glTF character of several meshes every measure is of its simulated
    body (``Character.V``); its passengers are posed and timed
    (``ms_passengers``), not measured.
Timing
    ``pipe.timings`` of every frame (ms per stage and ``total``), reported as
    median (p50) and 90th percentile (p90). Before the timed frames the pipeline
    warms up as the node does (:meth:`skin_node.Pipeline.warm_up`: poses at and
    within the joints' limits, then the motion's first, deepest and last frame
    and rest) so numba compilation or cache loading never lands in a timed
    frame; that warm-up time and the set-up time (character + rig load,
    pipeline construction) are reported apart, in seconds.
``volume_ratio``
    Enclosed volume of the deformed surface over the rest volume.
``region_volume_ratio``
    For the most bent joint of the frame: the volume of the cone from the
    joint's *posed* centre over the triangles of its joint region
    (:func:`skin_node.metrics.region_volume`; the centre moves with the joint,
    so a rigid motion keeps the ratio at 1), over the same at rest.
``dev_min_mm`` / ``dev_max_mm``
    Deviation from the rigidly posed parts, by the radial proxy: every vertex
    is bound at rest to the bone segment nearest to it and its rest distance
    ``r0`` to that segment is kept; in a pose the deviation is the distance of
    the deformed vertex to the same segment, posed rigidly, minus ``r0`` (mm).
    Most negative = collapse (candy wrapper, elbow pinch), most positive =
    bulge. Skin pressed flat where two limbs touch also reads as negative.
    The segments are the frame's: where the ``turn`` stage turned a limb out
    of another part, its turned bones (how far it moved skin off the pose's
    bones is the summary's ``turn_mm_max``).
``crossings``
    Joint-region vertices that have passed through the skin
    (:func:`skin_node.rigging.regions.count_crossings`).
``intersections`` / ``crumples`` / ``pairs``
    Pairs of triangles of the whole surface that pass through each other,
    found exactly (:class:`skin_node.kernels.intersect.SelfIntersections`),
    independent of the crossing test above: pairs that were three median
    edges or more apart at rest (skin through skin) / nearer ones (the surface
    crumpled over itself) / all of them (every pair that shares no corner).
    Counted on the same frames as ``crossings``.
``folds90`` / ``folds45``
    Sharp folds: interior edges whose dihedral angle grew by more than 90 / 45
    degrees from rest (:class:`skin_node.metrics.SurfaceQuality`).
``roughness`` / ``roughness_p99``
    The whole surface's mean umbrella-Laplacian length over the same at rest,
    and the ratio of the 99th percentiles (1 = as smooth as at rest).
``weight_jump_max`` / ``weight_jumps`` (summary only)
    The rig's weight continuity under the method's weights: the largest
    per-edge weight jump (:func:`skin_node.metrics.weight_jumps`, 0 to 2) and
    how many edges jump by more than 0.5.
``roughness_mm``
    Mean umbrella-Laplacian length over all joint-region vertices
    (:func:`skin_node.metrics.roughness`), mm; its rest value is in the summary.
``inverted_tets`` / ``inverted_skin_tets``
    Tets whose signed volume flipped sign since rest, all of them / only those
    that embed surface vertices (0 for skinning-only pipelines).
``ref_mean_mm`` / ``ref_max_mm``
    Mean / largest vertex distance to a converged reference: the same scene
    with twice the tets, the same pipeline with ``iterations = 60`` and
    ``active_threshold = 0``, on a subsample of the frames. Pipelines that only
    skin (``lbs``, ``dqs``) do not depend on either setting: their distance is
    0 by construction and is not computed.
``jitter_mm_p50`` / ``jitter_mm_max`` (summary only)
    Smoothness in time. Over every frame of the stretch of the clip the run
    covers (all of it unless ``max_frames`` cuts it), consecutive (120 Hz),
    from a fresh start: per pair of frames the largest
    vertex change of the correction the pipeline adds to its stage 1 (LBS or
    DQS alone), ``max_i |(V_t - S_t) - (V_t-1 - S_t-1)|``; median and largest
    over the frame pairs, mm. A smooth motion changes the correction by a
    fraction of a millimetre between frames; skin that flickers shows here.
    Pose sweeps and skinning-only pipelines have none (their value is 0 or empty).
"""
from __future__ import annotations

import json
import sys
import time
from dataclasses import dataclass, field, replace

import numpy as np
import psutil

from .. import default_clip_name, load_character, make_clip
from ..kernels.intersect import SelfIntersections
from ..metrics import SurfaceQuality, mesh_volume, region_volume, weight_jumps
from ..pipeline import PRESETS, STAGE_NAMES, Pipeline, skinning_stage
from ..rigging.regions import RegionSearch, count_crossings
from ..rigging.weights import point_segment_distance, segment_distance

#: Skinning-only stages: iterations, tets and active_threshold do not change their result.
SKIN_ONLY = {"lbs", "dqs"}

# --------------------------------------------------------------------- progress
class Progress:
    """A plain progress bar on stderr (``\\r`` updates on a terminal, a line
    every quarter otherwise); silent when ``enabled`` is False."""

    def __init__(self, total: int, label: str = "", enabled: bool = True,
                 stream=None) -> None:
        self.total, self.label, self.enabled = max(int(total), 1), label, enabled
        self.stream = stream or sys.stderr
        self.n = 0
        self.t0 = self._last = time.perf_counter()
        self._tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._quarter = -1

    def update(self, n: int = 1, label: str | None = None) -> None:
        self.n += n
        if label is not None:
            self.label = label
        if not self.enabled:
            return
        now = time.perf_counter()
        frac = min(self.n / self.total, 1.0)
        if self._tty:
            if now - self._last < 0.2 and self.n < self.total:
                return
            bar = "#" * int(30 * frac) + "." * (30 - int(30 * frac))
            eta = (now - self.t0) * (1 - frac) / max(frac, 1e-9)
            self.stream.write(f"\r[{bar}] {100 * frac:5.1f}% eta {eta:5.0f}s {self.label[:40]:40s}")
            self.stream.flush()
        elif int(4 * frac) > self._quarter:
            self._quarter = int(4 * frac)
            self.stream.write(f"[{100 * frac:3.0f}%] {now - self.t0:6.1f}s {self.label}\n")
            self.stream.flush()
        self._last = now

    def close(self) -> None:
        if self.enabled and self._tty:
            self.stream.write("\n")
            self.stream.flush()


# ----------------------------------------------------------------------- scenes
@dataclass(frozen=True)
class Scene:
    """A character at a density: ``arm:6000`` or ``arm:6000:24000`` (tets);
    a glTF character on its own skin weights: ``CesiumMan.glb@file``."""

    character: str
    surface_vertices: int
    tets: int | None = None
    weights: str = "automatic"

    @property
    def label(self) -> str:
        return (f"{self.character}:{self.surface_vertices}" + (f":{self.tets}" if self.tets else "")
                + (f"@{self.weights}" if self.weights != "automatic" else ""))

    def with_tets(self, tets: int | None) -> "Scene":
        return replace(self, tets=tets)


def parse_scene(spec: str) -> Scene:
    """``"arm:6000"`` / ``"arm:6000:24000"`` / ``"humanoid"`` -> :class:`Scene`;
    a suffix ``@file`` or ``@automatic`` picks the weights (``automatic``
    unless said: a glTF file's own are ``@file``)."""
    spec, _, weights = str(spec).partition("@")
    weights = weights or "automatic"
    if weights not in ("automatic", "file"):
        raise ValueError(f"scene '{spec}@{weights}': weights are 'automatic' or 'file'")
    parts = spec.split(":")
    if not parts[0] or len(parts) > 3:
        raise ValueError(f"scene '{spec}': expected character[:surface_vertices[:tets]]")
    try:
        n = int(parts[1]) if len(parts) > 1 and parts[1] else 0
        t = int(parts[2]) if len(parts) > 2 and parts[2] else None
    except ValueError:
        raise ValueError(f"scene '{spec}': vertex and tet counts must be integers") from None
    return Scene(parts[0], n, t, weights)


_SCENES: dict = {}


def load_scene(scene: Scene, cache: bool = True):
    """The scene's :class:`~skin_node.Character` and its set-up time in seconds
    (memoised in this process; the set-up time is that of the first load)."""
    if scene not in _SCENES:
        t0 = time.perf_counter()
        ch = load_character(scene.character, surface_vertices=scene.surface_vertices or None,
                            tet_count=scene.tets, cache=cache, progress=False,
                            weights=scene.weights)
        if ch.rig is None:
            raise ValueError(f"scene '{scene.label}': {ch.notes[-1]}; there is no simulated "
                             "body to measure")
        _SCENES[scene] = (ch, time.perf_counter() - t0)
    return _SCENES[scene]


def reference_scene(scene: Scene) -> Scene:
    """The same surface with twice the tets of ``scene``."""
    ch, _ = load_scene(scene)
    return scene.with_tets(2 * int(ch.options.tet_count))


# ---------------------------------------------------------------------- methods
@dataclass(frozen=True)
class Method:
    """A named pipeline: stage list and parameters."""

    name: str
    stages: tuple
    params: tuple = ()            # sorted (key, value) pairs, values JSON-able

    @property
    def param_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.params}

    @property
    def simulates(self) -> bool:
        """True when the result depends on iterations / tets (anything past skinning)."""
        return not set(self.stages) <= SKIN_ONLY

    def with_params(self, label: bool = True, **params) -> "Method":
        """A copy with ``params`` added; its name gets ``[k=v,...]`` when ``label``."""
        p = {**self.param_dict, **params}
        name = self.name
        if label and params:
            name += "[" + ",".join(f"{k}={v}" for k, v in params.items()) + "]"
        return Method(name, self.stages, _freeze(p))

    def build(self, character) -> Pipeline:
        return Pipeline(character, list(self.stages), **self.param_dict)

    def to_json(self) -> dict:
        return {"name": self.name, "stages": list(self.stages), "params": self.param_dict}


def _freeze(p: dict) -> tuple:
    return tuple(sorted((k, tuple(v) if isinstance(v, list) else v) for k, v in p.items()))


def parse_method(spec) -> Method:
    """A preset name (``lbs``, ``dqs``, ``pbs``, ``paper``, ``default``) or a JSON
    dict ``{"name": ..., "preset": ..., "stages": [...], "params": {...}}``
    (``preset`` supplies stages and parameters that the others override)."""
    if isinstance(spec, Method):
        return spec
    if isinstance(spec, str) and not spec.lstrip().startswith("{"):
        if spec not in PRESETS:
            raise ValueError(f"unknown pipeline '{spec}'; presets are {list(PRESETS)} "
                             "or give a JSON dict of stages and params")
        stages, params = PRESETS[spec]
        return Method(spec, tuple(stages), _freeze(params))
    d = json.loads(spec) if isinstance(spec, str) else dict(spec)
    base = parse_method(d["preset"]) if "preset" in d else Method("custom", ())
    stages = tuple(d.get("stages", base.stages))
    if not stages:
        raise ValueError(f"pipeline {d}: needs 'stages' or 'preset'")
    params = {**base.param_dict, **d.get("params", {})}
    name = d.get("name") or (base.name if "preset" in d and "stages" not in d else "+".join(stages))
    bad = [st for st in stages if st not in STAGE_NAMES]
    if bad:
        raise ValueError(f"pipeline {d}: unknown stage(s) {bad}; stages are {list(STAGE_NAMES)}")
    return Method(str(name), stages, _freeze(params))


# ---------------------------------------------------------------------- motions
@dataclass
class Motion:
    """Poses to deform in order; ``x`` is the swept angle in degrees for pose sweeps."""

    name: str
    frames: np.ndarray
    x: np.ndarray | None = None
    fps: float = 120.0
    #: every frame of the stretch ``frames`` samples, consecutive (no stride),
    #: for the jitter measure
    dense: np.ndarray | None = None


def clip_motion(name: str, clip_frames: np.ndarray, fps: float, stride: int = 1,
                max_frames: int | None = None) -> Motion:
    """A clip's every ``stride``-th frame, at most ``max_frames``; its ``dense``
    frames are all the clip's frames from the first to the last one kept, so
    the jitter measure sees the clip's deepest bends at 120 Hz, not just its
    start."""
    stride = max(1, stride)
    frames = clip_frames[::stride][:max_frames or None]
    dense = clip_frames[:(len(frames) - 1) * stride + 1]
    return Motion(name, frames, None, fps / stride, dense)


#: Pose sweeps: (channel, last angle in degrees). On the arm its elbow
#: and its wrist's twist; on the humanoid a thigh turned in towards the
#: other (``thigh_sweep``), across the angles where the turn stage moves
#: from one limb to another (its ``turn_rate``; the sweep's jitter is a
#: step's change).
SWEEPS = {"elbow_sweep": ("elbow_rz", 180.0), "twist_sweep": ("wrist_rx", 360.0),
          "thigh_sweep": ("r_hip_rx", 25.0)}
#: ``random_poses``: how many, and the seed.
RANDOM_POSES = (30, 7)


def random_poses(skel, count: int = RANDOM_POSES[0], seed: int = RANDOM_POSES[1]):
    """Poses no clip has, within the skeleton's joint limits: each rotation
    channel drawn uniformly within its limits and kept with probability one
    half (the others at rest), the root at rest; (count, C), seeded. None
    for a skeleton without limits (every channel free over a full turn, as
    a glTF file's): drawn over a full turn, its poses would say nothing of
    a body's."""
    if not skel.limited().any():
        return None
    lim = skel.limits.reshape(-1, 2)
    rng = np.random.default_rng(seed)
    out = np.empty((count, skel.n_channels))
    for t in range(count):
        q = skel.rest_pose().copy()
        k = len(q) - 3
        q[3:] = rng.uniform(lim[:, 0], lim[:, 1]) * (rng.random(k) < 0.5)
        out[t] = q
    return out


def make_motion(name: str, character, steps: int = 37, stride: int = 1,
                max_frames: int | None = None) -> Motion | None:
    """A clip by name (:data:`skin_node.CLIP_NAMES`), a pose sweep
    (``elbow_sweep``: elbow 0..180 degrees, ``twist_sweep``: wrist twist
    0..360 degrees, ``steps`` poses) or ``random_poses``
    (:func:`random_poses`: each its own, so no jitter is measured on them;
    every one is kept; ``random_poses:SEED`` draws them from another seed);
    None if the character lacks its channels or limits.
    Clips keep every ``stride``-th frame, at most ``max_frames``."""
    skel = character.skeleton
    if name == "random_poses" or name.startswith("random_poses:"):
        seed = name.partition(":")[2] or str(RANDOM_POSES[1])
        if not seed.isdigit():
            raise ValueError(f"{name}: the seed after 'random_poses:' must be a whole "
                             "number (e.g. random_poses:13)")
        frames = random_poses(skel, seed=int(seed))
        return None if frames is None else Motion(name, frames[:max_frames or None])
    if name in SWEEPS:
        chan, top = SWEEPS[name]
        if chan not in skel.channel_names:
            return None
        x = np.linspace(0.0, top, steps)
        frames = np.stack([skel.pose(**{chan: np.radians(a)}) for a in x])
        return Motion(name, frames, x, dense=frames)
    try:
        clip = make_clip(name, skel)
    except ValueError:
        return None
    return clip_motion(name, clip.frames, clip.fps, stride, max_frames)


def jitter(pipe: Pipeline, stage1: Pipeline, frames: np.ndarray) -> np.ndarray:
    """Per consecutive pair of ``frames``: the largest vertex change (mm) of the
    correction ``pipe`` adds to ``stage1``'s result (see the module docstring)."""
    prev, out = None, []
    for q in frames:
        c = pipe.deform(q) - stage1.deform(q)
        if prev is not None:
            out.append(float(np.linalg.norm(c - prev, axis=1).max()) * 1e3)
        prev = c
    return np.array(out)


# ---------------------------------------------------------------------- metrics
def tet_volumes(X: np.ndarray, T: np.ndarray) -> np.ndarray:
    """Signed volumes of tets ``T`` over vertices ``X``, in the convention of
    ``rig.vol0``: ``(1/6) [(p1 - p2) x (p1 - p3)] . (p1 - p4)``."""
    p1, p2, p3, p4 = (X[T[:, a]] for a in range(4))
    return np.einsum("ij,ij->i", np.cross(p1 - p2, p1 - p3), p1 - p4) / 6.0


def inverted_tets(X: np.ndarray, character, skin_only: bool = False) -> int:
    """Tets whose signed volume has a different sign now than at rest; with
    ``skin_only`` only the tets that embed surface vertices (an inverted one
    turns the skin it carries inside out)."""
    r = character.rig
    flipped = np.sign(tet_volumes(X, r.T)) != np.sign(r.vol0)
    if skin_only:
        flipped = flipped[np.unique(r.Etet)]
    return int(np.count_nonzero(flipped))


class SceneMetrics:
    """Accuracy measures of deformed surfaces of one character (precomputed rest data).

    Parameters
    ----------
    character : Character
    """

    def __init__(self, character) -> None:
        ch = self.character = character
        skel, r = ch.skeleton, ch.rig
        self.F = ch.F
        self.V0 = mesh_volume(ch.V, ch.F)
        self.regions = ch.regions()
        self.search = RegionSearch(self.regions)
        self.intersections = SelfIntersections(ch.V, ch.F, 3.0 * self.regions.edge)
        self.surface = SurfaceQuality(ch.V, ch.F)
        # joint-region volumes at rest, about each joint's rest position
        self.region_joints = np.array([j for j in range(skel.n_joints)
                                       if skel.parents[j] >= 0 and len(self.regions.tris[j])])
        self.region_rest = {int(j): region_volume(ch.V, ch.F, self.regions.tris[j],
                                                  skel.rest_positions[j])
                            for j in self.region_joints}
        # radial-deviation proxy: nearest rest bone segment and rest distance
        seg_joint, A, B = skel.bone_segments()
        D = point_segment_distance(ch.V, A, B)
        self.seg = np.argmin(D, axis=1)
        self.r0 = D[np.arange(len(ch.V)), self.seg]
        # joint-region roughness, as metrics.roughness, with the index arrays built once
        verts = np.flatnonzero(r.region >= 0)
        ptr, nbr = r.adj_ptr, r.adj
        counts = ptr[verts + 1] - ptr[verts]
        self._rverts = verts
        self._rrows = np.repeat(np.arange(len(verts)), counts)
        self._rcols = (np.concatenate([nbr[ptr[i]:ptr[i + 1]] for i in verts])
                       if len(verts) else np.zeros(0, np.int64))
        self._rcount = np.maximum(counts, 1)[:, None]
        self.roughness_rest_mm = self.roughness(ch.V) * 1e3

    def roughness(self, V: np.ndarray) -> float:
        """:func:`skin_node.metrics.roughness` over all joint-region vertices, m."""
        if not len(self._rverts):
            return 0.0
        mean = np.zeros((len(self._rverts), 3))
        np.add.at(mean, self._rrows, V[self._rcols])
        mean /= self._rcount
        return float(np.linalg.norm(mean - V[self._rverts], axis=1).mean())

    def deviation_mm(self, V: np.ndarray, seg_A: np.ndarray, seg_B: np.ndarray) -> np.ndarray:
        """Per-vertex signed radial deviation (mm) from the rigidly posed bones
        ``seg_A, seg_B`` (posed :meth:`Skeleton.bone_segments`, e.g. ``frame.seg_A``)."""
        return (segment_distance(V, seg_A[self.seg], seg_B[self.seg]) - self.r0) * 1e3

    def region_ratio(self, V: np.ndarray, G: np.ndarray, j: int) -> float:
        """Joint ``j``'s region volume now (about its posed centre) over at rest."""
        return region_volume(V, self.F, self.regions.tris[j], G[j, :3, 3]) / self.region_rest[int(j)]

    def measure(self, V: np.ndarray, frame, crossings: bool = True) -> dict:
        """All per-frame accuracy measures of surface ``V`` deformed in ``frame``
        (``pipe.last_frame``)."""
        dev = self.deviation_mm(V, frame.seg_A, frame.seg_B)
        out = {"volume_ratio": mesh_volume(V, self.F) / self.V0,
               "dev_min_mm": float(dev.min()), "dev_max_mm": float(dev.max()),
               "roughness_mm": self.roughness(V) * 1e3}
        if len(self.region_joints):
            j = int(self.region_joints[np.argmax(frame.angles[self.region_joints])])
            out["region_joint"] = self.character.skeleton.names[j]
            out["region_volume_ratio"] = self.region_ratio(V, frame.G, j)
        out["crossings"] = (count_crossings(V, self.character.V, self.F, frame.M, self.regions,
                                            search=self.search) if crossings else np.nan)
        out["intersections"], out["crumples"] = (self.intersections(V) if crossings
                                                 else (np.nan, np.nan))
        out["pairs"] = out["intersections"] + out["crumples"]
        out.update(self.surface(V))
        return out

    def weight_continuity(self, weights) -> dict:
        """``weight_jump_max`` and ``weight_jumps`` (edges over 0.5) of ``weights``."""
        j = weight_jumps(self.F, weights.Widx, weights.Wval, self.character.skeleton.n_joints)
        return {"weight_jump_max": float(j.max()), "weight_jumps": int((j > 0.5).sum())}


_METRICS: dict = {}


def scene_metrics(scene: Scene) -> SceneMetrics:
    if scene not in _METRICS:
        _METRICS[scene] = SceneMetrics(load_scene(scene)[0])
    return _METRICS[scene]


# -------------------------------------------------------------------------- runs
def percentiles(values, qs=(50, 90)) -> list:
    v = np.asarray(values, dtype=float)
    return [float(np.percentile(v, q)) if v.size else float("nan") for q in qs]


@dataclass
class RunResult:
    """Per-frame rows and a summary of one (method, scene, motion) run."""

    method: Method
    scene: Scene
    motion: str
    rows: list = field(default_factory=list)
    summary: dict = field(default_factory=dict)


def _warm_up(pipe: Pipeline, frames: np.ndarray) -> float:
    """:meth:`Pipeline.warm_up` with the first, deepest and last pose of
    ``frames`` too; the seconds it took."""
    skel = pipe.character.skeleton
    depth = [skel.joint_angles(q).max() for q in frames]
    return pipe.warm_up((frames[0], frames[int(np.argmax(depth))], frames[-1]))


def run_method(method: Method, scene: Scene, motion: Motion, reference: bool = True,
               ref_frames: int = 8, crossings_every: int = 1,
               progress: Progress | None = None) -> RunResult:
    """Deform ``motion`` with ``method`` on ``scene``; time and measure every frame.

    Parameters
    ----------
    reference : bool
        Also measure the distance to the converged reference (on ``ref_frames``
        evenly spaced frames, plus the deepest one).
    crossings_every : int
        Count crossings on every n-th frame only (0 = never); the rest get NaN.

    Returns
    -------
    RunResult
    """
    ch, load_s = load_scene(scene)
    metrics = scene_metrics(scene)
    t0 = time.perf_counter()
    pipe = method.build(ch)
    build_s = time.perf_counter() - t0
    warm_s = _warm_up(pipe, motion.frames)
    skel = ch.skeleton
    T = len(motion.frames)
    depth = np.array([skel.joint_angles(q).max() for q in motion.frames])
    ref_at = set()
    ref_pipe, ref_warm = None, 0.0
    if reference and method.simulates and ref_frames > 0:
        ref_at = set(np.linspace(0, T - 1, ref_frames).round().astype(int).tolist())
        ref_at.add(int(np.argmax(depth)))
        rscene = reference_scene(scene)
        rch, _ = load_scene(rscene)
        ref_pipe = method.with_params(label=False, iterations=60, active_threshold=0.0).build(rch)
        ref_warm = _warm_up(ref_pipe, motion.frames[:1])
    rows, times = [], {}
    body = len(ch.V)            # the metrics are of the simulated body, not the passengers
    for t, q in enumerate(motion.frames):
        V = pipe.deform(q)[:body]
        for k, v in pipe.timings.items():
            times.setdefault(k, []).append(v)
        fr = pipe.last_frame
        row = {"frame": t, "x": float(motion.x[t]) if motion.x is not None else float(t),
               "angle_max_deg": float(np.degrees(depth[t])),
               **{f"ms_{k}": v for k, v in pipe.timings.items()},
               **metrics.measure(V, fr, crossings=bool(crossings_every) and
                                 t % max(crossings_every, 1) == 0),
               **{f"count_{k}": v for k, v in pipe.counts.items()
                  if isinstance(v, (int, float, np.integer, np.floating))}}
        row["inverted_tets"] = inverted_tets(fr.tet, ch) if method.simulates else 0
        row["inverted_skin_tets"] = (inverted_tets(fr.tet, ch, skin_only=True)
                                     if method.simulates else 0)
        if not method.simulates:
            row["ref_mean_mm"] = row["ref_max_mm"] = 0.0
        elif t in ref_at:
            R = ref_pipe.deform(q)[:body]
            d = np.linalg.norm(V - R, axis=1) * 1e3
            row["ref_mean_mm"], row["ref_max_mm"] = float(d.mean()), float(d.max())
        else:
            row["ref_mean_mm"] = row["ref_max_mm"] = float("nan")
        rows.append(row)
        if progress is not None:
            progress.update(1)
    res = RunResult(method, scene, motion.name, rows)
    res.summary = summarize(res, load_s=load_s, build_s=build_s, warm_s=warm_s,
                            ref_warm_s=ref_warm, times=times, roughness_rest_mm=
                            metrics.roughness_rest_mm, tets=len(ch.rig.T),
                            vertices=len(ch.V),
                            **metrics.weight_continuity(pipe.stages[0].weights))
    if motion.dense is not None and len(motion.dense) > 1:
        if method.simulates:
            for s in pipe.stages:           # from a fresh start, like the clip's
                s.reset()
            j = jitter(pipe, Pipeline(ch, [skinning_stage(method.stages)]), motion.dense)
        else:
            j = np.zeros(1)
        res.summary["jitter_mm_p50"] = float(np.median(j))
        res.summary["jitter_mm_max"] = float(j.max())
    return res


def summarize(res: RunResult, times: dict, **extra) -> dict:
    """One summary row of a run: timing percentiles and accuracy extremes."""
    rows = res.rows
    col = lambda k: np.array([r.get(k, np.nan) for r in rows], dtype=float)  # noqa: E731

    def most(k: str) -> float:
        """The largest of a column measured on some frames only (NaN if on none)."""
        v = col(k)
        return float(np.nanmax(v)) if np.isfinite(v).any() else float("nan")

    s = {"method": res.method.name, "scene": res.scene.label, "motion": res.motion,
         "frames": len(rows), "stages": "+".join(res.method.stages),
         "params": json.dumps(res.method.param_dict, sort_keys=True),
         "setup_s": extra.pop("load_s") + extra.pop("build_s"),
         "warmup_s": extra.pop("warm_s"), "ref_warmup_s": extra.pop("ref_warm_s")}
    s.update(extra)
    for k, v in times.items():
        p50, p90 = percentiles(v)
        s[f"ms_{k}_p50"], s[f"ms_{k}_p90"] = p50, p90
    deep = int(np.nanargmax(col("angle_max_deg"))) if rows else 0
    vr, rr = col("volume_ratio"), col("region_volume_ratio")
    s.update({
        "deepest_angle_deg": float(col("angle_max_deg")[deep]),
        "volume_ratio_deepest": float(vr[deep]),
        "volume_ratio_min": float(np.nanmin(vr)), "volume_ratio_max": float(np.nanmax(vr)),
        "volume_error_max": float(np.nanmax(np.abs(vr - 1.0))),
        "region_volume_ratio_deepest": float(rr[deep]),
        "region_volume_error_max": float(np.nanmax(np.abs(rr - 1.0))),
        "collapse_mm": float(np.nanmin(col("dev_min_mm"))),
        "bulge_mm": float(np.nanmax(col("dev_max_mm"))),
        "crossings_max": most("crossings"),
        "intersections_max": most("intersections"),
        "crumples_max": most("crumples"),
        "pairs_max": most("pairs"),
        "pairs_deepest": float(col("pairs")[deep]),
        "folds90_max": float(np.nanmax(col("folds90"))),
        "folds90_deepest": float(col("folds90")[deep]),
        "folds45_max": float(np.nanmax(col("folds45"))),
        "surface_roughness_max": float(np.nanmax(col("roughness"))),
        "surface_roughness_deepest": float(col("roughness")[deep]),
        "surface_roughness_p99_max": float(np.nanmax(col("roughness_p99"))),
        "roughness_mm_max": float(np.nanmax(col("roughness_mm"))),
        "inverted_tets_max": float(np.nanmax(col("inverted_tets"))),
        "inverted_skin_tets_max": float(np.nanmax(col("inverted_skin_tets"))),
        "ref_mean_mm": float(np.nanmean(col("ref_mean_mm"))) if np.isfinite(col("ref_mean_mm")).any()
        else float("nan"),
        "ref_max_mm": most("ref_max_mm"),
        # how far the turn stage moved skin off the bones the pose put it on
        # (the bulge is measured from the turned bones), and on how many frames
        "turn_mm_max": float(np.nanmax(np.nan_to_num(col("count_turn_mm")))) if rows else 0.0,
        "turned_frames": int(np.count_nonzero(col("count_turned") > 0)),
    })
    return s


def expand_methods(methods, iterations=None, stiffness=None) -> list:
    """Every method, times every sweep value that applies to it (iterations and
    stiffness only to methods that simulate)."""
    out = []
    for m in methods:
        m = parse_method(m)
        if not m.simulates or not (iterations or stiffness):
            out.append(m)
            continue
        for it in (iterations or [None]):
            for k in (stiffness or [None]):
                p = {}
                if it is not None:
                    p["iterations"] = int(it)
                if k is not None:
                    p["stiffness"] = float(k)
                out.append(m.with_params(**p))
    return out


def expand_scenes(scenes, tets=None) -> list:
    """Every scene, times every tet count of ``tets`` when given."""
    out = []
    for s in scenes:
        s = parse_scene(s) if isinstance(s, str) else s
        out.extend([s.with_tets(int(t)) for t in tets] if tets else [s])
    return out


# ----------------------------------------------------------------------- memory
def memory_profile(scene="humanoid:24000", frames: int = 3000, every: int = 250,
                   method="default", clip: str | None = None, progress: bool = True) -> dict:
    """Resident set size of *this* process while ``method`` deforms ``clip`` in a
    loop on ``scene`` for ``frames`` frames, sampled every ``every`` frames.

    Returns start (after imports), after set-up, after warm-up, peak, end (MB),
    the samples, and ``flat``: ``(end - after_warmup) / after_warmup < 10%``.
    Run it in a fresh process (``skin_bench memory`` does) for clean figures."""
    proc = psutil.Process()
    rss = lambda: proc.memory_info().rss / 2**20  # noqa: E731
    start = rss()
    scene = parse_scene(scene) if isinstance(scene, str) else scene
    ch, load_s = load_scene(scene)
    pipe = parse_method(method).build(ch)
    setup = rss()
    clip = clip or default_clip_name(ch.name)
    Q = make_motion(clip, ch).frames
    warm_s = _warm_up(pipe, Q)
    warm = rss()
    samples = [(0, warm)]
    bar = Progress(frames, f"memory {scene.label}", enabled=progress)
    t0 = time.perf_counter()
    for t in range(frames):
        pipe.deform(Q[t % len(Q)])
        if (t + 1) % every == 0 or t == frames - 1:
            samples.append((t + 1, rss()))
        bar.update(1)
    bar.close()
    end = samples[-1][1]
    growth = (end - warm) / warm
    return {"scene": scene.label, "method": parse_method(method).name, "clip": clip,
            "frames": frames, "every": every, "start_mb": start, "after_setup_mb": setup,
            "after_warmup_mb": warm, "peak_mb": max(v for _, v in samples), "end_mb": end,
            "growth": growth, "flat": bool(growth < 0.10), "setup_s": load_s,
            "warmup_s": warm_s, "run_s": time.perf_counter() - t0,
            "samples": [[int(f), float(v)] for f, v in samples]}
