"""``skin_bench``: speed, accuracy, stability, memory and ROS latency of skin_node.

Subcommands (``run`` is the default when the first argument is an option)::

    skin_bench run --pipelines lbs,dqs,pbs,paper,default --scenes arm:2000,arm:6000 \\
                   --clips elbow_bend,wrist_twist --iterations 1,2,5,10,30 --out out/
    skin_bench run --pipelines '{"name": "dqs+pbd", "stages": ["dqs", "pbd"]}' ...
    skin_bench run --scenes CesiumMan.glb --clips gltf:animation0   # a file's own clip
    skin_bench run --scenes CesiumMan.glb --clips cmu_02_01_walk.bvh --stride 24   # mocap
    skin_bench run --scenes CesiumMan.glb,CesiumMan.glb@file ...   # both weightings
    skin_bench stability --pipelines lbs,default --long-frames 100000
    skin_bench memory --scene humanoid:24000 --frames 3000
    skin_bench export-memory --frames 1000   # the streaming exporter's peak RSS
    skin_bench ablation --scenes humanoid:24000 --clips walk,squat   # each part's worth
    skin_bench ros-latency --seconds 10
    skin_bench carried --scene humanoid:24000 --clips walk,squat   # correction solved behind
    skin_bench carried --clips squat --solve-poses 3   # the same, on a fixed schedule
    skin_bench pictures --out closeups.png      # z-buffer close-ups, LBS / DQS / paper / ours
    skin_bench report            # everything, into bench_results/, prints a markdown table

Outputs: ``runs.csv`` / ``runs.json`` (one summary row per method, scene and
motion), ``frames.csv`` (every measured frame), PNG charts. Definitions of every
column are in :mod:`skin_node.bench.measure` and :mod:`skin_node.bench.stability`.
"""
from __future__ import annotations

import argparse
import csv
import json
import math
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numba
import numpy as np

from . import charts
from ..motion import GLTF_PREFIX, default_clip, file_animations, file_clip, load_motion
from ..pipeline import DEFAULT_STAGES, STAGE_NAMES
from .carried import carried_table, run_carried
from .export_memory import export_memory_line, run_export_memory
from .measure import (Motion, Progress, clip_motion, expand_methods, expand_scenes,
                      load_scene, make_motion, memory_profile, parse_method, run_method)
from .pictures import closeups
from .ros_latency import latency_line, main as ros_main, measure_latency
from .stability import CASES, stability_map

DEFAULT_PIPELINES = "lbs,dqs,pbs,paper,default"
DEFAULT_CLIPS = {"arm": ["elbow_bend", "wrist_twist"], "humanoid": ["walk", "squat"]}
#: The clips of each character the report's table shows.
TABLE_CLIPS = {"arm": ("elbow_bend",), "humanoid": ("walk", "squat")}


# ------------------------------------------------------------------- helpers
def _list(s: str | None, cast=str) -> list:
    return [cast(x) for x in s.split(",") if x.strip()] if s else []


def _pipelines(values) -> list:
    """``--pipelines`` items: comma-separated preset names, or JSON dicts."""
    out = []
    for v in values or [DEFAULT_PIPELINES]:
        out.extend([v] if v.lstrip().startswith("{") else _list(v))
    return [parse_method(v) for v in out]


def chart_name(scene: str) -> str:
    """A scene as part of a file name: a character file's own name without
    its folders (a path's separators made a chart's name a missing
    folder), ':' and anything else but letters, digits, '.', '-' as '_'."""
    return re.sub(r"[^A-Za-z0-9._-]", "_", os.path.basename(scene.rstrip("/\\")))


def _clean(v):
    if isinstance(v, (np.floating, float)):
        return None if not math.isfinite(float(v)) else round(float(v), 6)
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, dict):
        return {k: _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    return v


def write_csv(rows: list, path: Path) -> Path:
    """Rows of dicts to CSV (union of keys, in first-seen order; floats to 6 digits)."""
    keys = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v)
                        for k, v in ((k, r.get(k, "")) for k in keys)})
    return path


def write_json(obj, path: Path) -> Path:
    path.write_text(json.dumps(_clean(obj), indent=1) + "\n")
    return path


def environment() -> dict:
    """What the figures were measured on."""
    env = {"python": platform.python_version(), "numpy": np.__version__,
           "numba": numba.__version__, "machine": platform.machine(),
           "cpus": os.cpu_count(), "numba_threads": numba.config.NUMBA_NUM_THREADS,
           "date": time.strftime("%Y-%m-%d %H:%M:%S")}
    try:
        env["load_average"] = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        pass
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                env["cpu"] = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return env


# ------------------------------------------------------------------------ run
def scene_clips(character: str) -> list:
    """The clips a scene runs when none are named: a glTF character's own
    animations (``gltf:NAME``), else the character's built-in ones."""
    own = [GLTF_PREFIX + a for a in file_animations(character)]
    return own or DEFAULT_CLIPS.get(character, [default_clip(character)])


def motion(name: str, character_spec: str, ch, steps: int = 37, stride: int = 1,
           max_frames: int | None = None) -> Motion | None:
    """:func:`~skin_node.bench.measure.make_motion`, or a glTF character's own
    animation (``NAME`` or ``gltf:NAME``, sampled at 120 Hz like the built-in
    clips, named ``gltf:NAME`` in the results), or a BVH file (``*.bvh``)
    retargeted through the character's ``config/cmu_to_<character>.yaml``
    (named ``bvh:STEM``)."""
    if name.lower().endswith(".bvh"):
        clip = load_motion(character_spec, bvh=name, skeleton=ch.skeleton)
        return clip_motion("bvh:" + clip.name, clip.frames, clip.fps, stride, max_frames)
    clip = file_clip(character_spec, name)
    if clip is None:
        return make_motion(name, ch, steps=steps, stride=stride, max_frames=max_frames)
    return clip_motion(GLTF_PREFIX + clip.name, clip.frames, clip.fps, stride, max_frames)


def run_bench(pipelines, scenes, clips=None, iterations=None, stiffness=None, tets=None,
              stride: int = 6, max_frames: int | None = None, sweep_steps: int = 37,
              reference: bool = True, ref_frames: int = 6, crossings_every: int = 1,
              out: Path | None = None, charts_: bool = True, progress: bool = True,
              frames_csv: bool = True) -> dict:
    """Every (method, scene, motion); returns ``{"runs": [...], "frames": {...}}``
    and writes CSV/JSON/PNG into ``out`` when given."""
    methods = expand_methods(pipelines, iterations, stiffness)
    scenes = expand_scenes(scenes, tets)
    plan = []
    for sc in scenes:
        ch, _ = load_scene(sc)
        for c in (clips or scene_clips(sc.character)):
            mo = motion(c, sc.character, ch, steps=sweep_steps, stride=stride,
                        max_frames=max_frames)
            if mo is None:
                print(f"skin_bench: {c} does not apply to {sc.label}; skipped", file=sys.stderr)
                continue
            plan.extend((m, sc, mo) for m in methods)
    bar = Progress(sum(len(mo.frames) for _, _, mo in plan), "run", enabled=progress)
    runs, frames = [], {}
    for m, sc, mo in plan:
        bar.label = f"{m.name} {sc.label} {mo.name}"
        r = run_method(m, sc, mo, reference=reference, ref_frames=ref_frames,
                       crossings_every=crossings_every, progress=bar)
        runs.append(r.summary)
        frames.setdefault(sc.label, {}).setdefault(mo.name, {})[m.name] = r.rows
    bar.close()
    frame_pairs_against_dqs(runs, frames)
    result = {"environment": environment(), "runs": runs, "frames": frames}
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        write_csv(runs, out / "runs.csv")
        write_json({"environment": result["environment"], "runs": runs}, out / "runs.json")
        if frames_csv:
            flat = [{"scene": s, "motion": mo, "method": m, **row}
                    for s, d in frames.items() for mo, dm in d.items()
                    for m, rows in dm.items() for row in rows]
            write_csv(flat, out / "frames.csv")
        if charts_:
            draw_run_charts(result, out)
    return result


def frame_pairs_against_dqs(runs: list, frames: dict) -> None:
    """Frame by frame against DQS in the same run: to every summary of a method
    other than DQS on a scene and clip DQS ran too, ``pairs_frames_within``
    (the share of the frames counted where its intersecting pairs are at most
    a tenth of DQS's there), ``pairs_frames_over_none`` (frames where DQS has
    none and it has some) and ``pairs_sum_ratio`` (its pairs over DQS's,
    summed over those frames). The worst frame alone says how bad it gets;
    these say how often."""
    for r in runs:
        rows = frames.get(r["scene"], {}).get(r["motion"], {})
        ours, dqs = rows.get(r["method"]), rows.get("dqs")
        if r["method"] == "dqs" or not ours or not dqs:
            continue
        by = {row["frame"]: row.get("pairs", np.nan) for row in dqs}
        both = [(row["pairs"], by[row["frame"]]) for row in ours
                if row["frame"] in by and np.isfinite(row.get("pairs", np.nan))
                and np.isfinite(by[row["frame"]])]
        if not both:
            continue
        a, d = np.array(both, dtype=float).T
        r["pairs_frames_within"] = float(np.mean(a <= 0.1 * d))
        r["pairs_frames_over_none"] = int(np.sum((d == 0) & (a > 0)))
        r["pairs_sum_ratio"] = float(a.sum() / d.sum()) if d.sum() else \
            (0.0 if a.sum() == 0 else float("inf"))


def draw_run_charts(result: dict, out: Path) -> list:
    """Speed/accuracy per scene (clip runs), pose sweeps per scene (sweep runs)."""
    paths = []
    by_scene = {}
    for s in result["runs"]:
        if s["motion"] not in ("elbow_sweep", "twist_sweep"):
            by_scene.setdefault(s["scene"], []).append(s)
    for sc, runs in by_scene.items():
        clips = sorted({r["motion"] for r in runs})
        paths.append(charts.speed_accuracy(
            runs, out / f"speed_accuracy_{chart_name(sc)}.png",
            f"{sc} ({', '.join(clips)}): speed against accuracy; lower is better, "
            "lines = Pareto fronts"))
    for sc, d in result["frames"].items():
        sweeps = {m: d[m] for m in ("elbow_sweep", "twist_sweep") if m in d}
        if sweeps:
            paths.append(charts.pose_sweeps(sweeps, out / f"pose_sweeps_{chart_name(sc)}.png",
                                            f"{sc}: volume and deviation over pose sweeps"))
    return paths


# ------------------------------------------------------------------- markdown
def _num(v, d: int = 2) -> str:
    """``v`` with ``d`` decimals for a table, "-" for a missing or non-finite value."""
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else f"{v:.{d}f}"


def markdown_table(runs: list, clips: dict | None = None) -> str:
    """Method x scene x clip, pose sweeps left out; with ``clips`` (character ->
    clip names, e.g. :data:`TABLE_CLIPS`) only those clips of those characters."""
    clips = clips or {}
    rows = [r for r in runs if r["motion"] not in ("elbow_sweep", "twist_sweep")
            and r["motion"] in clips.get(r["scene"].split(":")[0], (r["motion"],))]
    f = _num
    lines = ["| method | scene | clip | ms p50 / p90 | intersecting pairs / folds90 / "
             "roughness at deepest bend | the same, worst frame | volume / joint region at "
             "deepest bend | bulge (mm) | jitter (mm, median / max) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for s in rows:
        lines.append(
            f"| {s['method']} | {s['scene']} | {s['motion']} ({f(s['deepest_angle_deg'], 0)} deg) | "
            f"{f(s['ms_total_p50'], 1)} / {f(s['ms_total_p90'], 1)} | "
            f"{f(s.get('pairs_deepest'), 0)} / {f(s.get('folds90_deepest'), 0)} / "
            f"{f(s.get('surface_roughness_deepest'), 2)} | "
            f"{f(s.get('pairs_max'), 0)} / {f(s.get('folds90_max'), 0)} / "
            f"{f(s.get('surface_roughness_max'), 2)} | "
            f"{f(s['volume_ratio_deepest'], 3)} / {f(s['region_volume_ratio_deepest'], 3)} | "
            f"{f(s['bulge_mm'], 1)} | "
            f"{f(s.get('jitter_mm_p50'), 1)} / {f(s.get('jitter_mm_max'), 1)} |")
    return "\n".join(lines)


def against_dqs(runs: list, method: str = "default") -> list:
    """``method`` against plain DQS on every scene and clip both ran, in the
    same run: one dict of ratios (and DQS's own figures) each."""
    dqs = {(r["scene"], r["motion"]): r for r in runs if r["method"] == "dqs"}
    out = []
    for r in runs:
        d = dqs.get((r["scene"], r["motion"]))
        if r["method"] != method or d is None or r["motion"] in ("elbow_sweep", "twist_sweep"):
            continue
        ratio = lambda a, b: a / b if b else (0.0 if a == 0 else float("inf"))  # noqa: E731
        out.append({
            "scene": r["scene"], "motion": r["motion"],
            "dqs_ms_p50": d["ms_total_p50"],
            "time_p50": r["ms_total_p50"] / d["ms_total_p50"],
            "time_p90": r["ms_total_p90"] / d["ms_total_p50"],
            "pairs": (r.get("pairs_max"), d.get("pairs_max")),
            "pairs_ratio": ratio(r.get("pairs_max", np.nan), d.get("pairs_max", np.nan)),
            "pairs_frames_within": r.get("pairs_frames_within", np.nan),
            "pairs_sum_ratio": r.get("pairs_sum_ratio", np.nan),
            "folds90": (r.get("folds90_max"), d.get("folds90_max")),
            "roughness_ratio": r.get("surface_roughness_max", np.nan)
            / d.get("surface_roughness_max", np.nan),
            # a ratio to no bulge (a twist: DQS leaves the radius alone) says nothing
            "bulge_ratio": r["bulge_mm"] / d["bulge_mm"] if d["bulge_mm"] > 0.5 else np.nan,
            "region": r["region_volume_ratio_deepest"],
            "region_error_max": r["region_volume_error_max"],
            "volume_min": r["volume_ratio_min"]})
    return out


def dqs_table(runs: list, method: str = "default") -> str:
    """:func:`against_dqs` as markdown: ratios first, DQS's own time beside them."""
    f = _num
    lines = [f"| {method} against DQS: scene | clip | time p50 / p90 (x DQS p50; DQS ms) | "
             "intersecting pairs (worst frame; x DQS) | frames within 10% of DQS's pairs "
             "(all frames' pairs x DQS) | folds90 (worst frame): ours / DQS | "
             "roughness (x DQS) | bulge (x DQS) | joint region at deepest bend / worst error "
             "| volume (min) |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for a in against_dqs(runs, method):
        lines.append(
            f"| {a['scene']} | {a['motion']} | {f(a['time_p50'], 1)} / {f(a['time_p90'], 1)} "
            f"({f(a['dqs_ms_p50'], 2)}) | {f(a['pairs'][0], 0)} / {f(a['pairs'][1], 0)} "
            f"({f(a['pairs_ratio'], 2)}) | {f(100 * a['pairs_frames_within'], 0)}% "
            f"({f(a['pairs_sum_ratio'], 3)}) | {f(a['folds90'][0], 0)} / {f(a['folds90'][1], 0)} | "
            f"{f(a['roughness_ratio'], 3)} | {f(a['bulge_ratio'], 2)} | "
            f"{f(a['region'], 3)} / {f(100 * a['region_error_max'], 1)}% | "
            f"{f(a['volume_min'], 3)} |")
    return "\n".join(lines)


def stage_table(runs: list, method: str = "default") -> str:
    """Median ms per stage of ``method`` on every scene and clip it ran."""
    rows = [r for r in runs if r["method"] == method
            and r["motion"] not in ("elbow_sweep", "twist_sweep")]
    order = rows[0]["stages"].split("+") if rows else []
    stages = ["fk"] + [k for k in order if k in STAGE_NAMES]
    f = _num
    lines = [f"| {method}: scene | clip | " + " | ".join(stages)
             + " | total p50 / p90 | us a vertex (p50) |",
             "|---|---|" + "---|" * len(stages) + "---|---|"]
    for r in rows:
        # the cost of a frame per surface vertex: scenes of different
        # resolutions compared (a finer mesh should cost no more a vertex)
        per = 1e3 * r["ms_total_p50"] / r["vertices"] if r.get("vertices") else float("nan")
        lines.append(f"| {r['scene']} | {r['motion']} | "
                     + " | ".join(f(r.get(f"ms_{k}_p50", float("nan"))) for k in stages)
                     + f" | {f(r['ms_total_p50'])} / {f(r['ms_total_p90'])} | {f(per, 3)} |")
    return "\n".join(lines)


# ------------------------------------------------------------------ ablation
#: The default pipeline with one part taken out, cut down or added: (name, the
#: pipeline's JSON spec over the default preset, what).
def _without(stage: str) -> list:
    return [s for s in DEFAULT_STAGES if s != stage]


ABLATIONS = (
    ("no-turn", {"params": {"turn_depth": 0.0}},
     "no limb turned out of another part before skinning (no change where none lies deep)"),
    ("no-contact", {"stages": _without("contact")}, "no contact stage"),
    ("contact-unsmoothed", {"params": {"contact_rounds": 0}},
     "contact projected once, not smoothed"),
    ("no-untangle", {"stages": _without("untangle")},
     "coarse skin's crossing triangles not pushed apart (no change without coarse parts)"),
    ("no-mush", {"stages": _without("mush")}, "no mush of the crease"),
    ("no-bulge", {"stages": _without("bulge")}, "no bulge limit"),
    ("no-inflate", {"stages": _without("inflate")}, "no inflation"),
    ("with-solve", {"stages": [t for s in DEFAULT_STAGES
                               for t in ((s, "pbd") if s == "dqs" else (s,))]},
     "with the extended PBD solve over the tet mesh after stage 1"),
    ("paper-weights", {"params": {"weight_scheme": "inverse_distance"}},
     "the paper's inverse-distance weights"),
)


def run_ablation(scenes=("humanoid:24000",), clips=("walk", "squat"), stride: int = 2,
                 out: Path | None = None, progress: bool = True) -> dict:
    """The default pipeline against each of :data:`ABLATIONS` (and DQS alone):
    what each part costs per frame and what leaving it out costs in accuracy."""
    pipes = ["dqs", "default"] + [json.dumps({"name": n, "preset": "default", **p})
                                  for n, p, _ in ABLATIONS]
    return run_bench(pipes, list(scenes), list(clips), stride=stride, reference=False,
                     ref_frames=0, out=out, charts_=False, progress=progress)


def ablation_table(runs: list) -> str:
    """Each variant's time against the default's on the same scene and clip, and
    its accuracy."""
    what = {"dqs": "DQS alone (stage 1)", "default": "the default pipeline",
            **{n: w for n, _, w in ABLATIONS}}
    base = {(r["scene"], r["motion"]): r for r in runs if r["method"] == "default"}
    f = lambda v, d=1: _num(v, d)  # noqa: E731
    lines = ["| variant | scene | clip | ms p50 (against default) | intersecting pairs / "
             "folds90 / roughness (worst frame) | joint region at deepest bend / worst "
             "error | volume (min) | bulge (mm) | jitter (mm, median / max) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in runs:
        b = base.get((r["scene"], r["motion"]))
        d = r["ms_total_p50"] - b["ms_total_p50"] if b else float("nan")
        lines.append(
            f"| {what.get(r['method'], r['method'])} | {r['scene']} | {r['motion']} | "
            f"{f(r['ms_total_p50'])} ({'+' if d >= 0 else ''}{f(d)}) | "
            f"{f(r.get('pairs_max'), 0)} / {f(r.get('folds90_max'), 0)} / "
            f"{f(r.get('surface_roughness_max'), 2)} | "
            f"{f(r['region_volume_ratio_deepest'], 3)} / "
            f"{f(100 * r['region_volume_error_max'])}% | {f(r['volume_ratio_min'], 3)} | "
            f"{f(r['bulge_mm'])} | {f(r.get('jitter_mm_p50'))} / {f(r.get('jitter_mm_max'))} |")
    return "\n".join(lines)


# ----------------------------------------------------------------- stability
def run_stability(pipelines, scene="arm:2000", long_frames=100_000, jitter_frames=1000,
                  cases=None, out: Path | None = None, progress=True) -> list:
    res = stability_map(pipelines, scene, cases or CASES, long_frames=long_frames,
                        jitter_frames=jitter_frames, progress=progress)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        write_json({"environment": environment(), "scene": str(scene), "results": res},
                   out / "stability.json")
        write_csv([{**r, "failed": " ".join(r["failed"])} for r in res], out / "stability.csv")
        charts.stability_chart(res, out / "stability.png", f"stability map on {scene}")
    return res


# -------------------------------------------------------------------- memory
def run_memory(scene="humanoid:24000", frames=3000, every=250, out: Path | None = None,
               fresh: bool = True, progress=True) -> dict:
    """:func:`memory_profile` in a fresh Python process (``fresh``) or in this one.

    Fresh, it runs twice on an empty numba cache of its own: first a start that
    compiles every kernel (``first_start``: the JIT's compiler memory stays with
    the process), then the measured run, which loads them from that cache as
    every later start does. The figures then do not depend on what the user's
    cache happened to hold."""
    if fresh:
        def one(n, env):
            cmd = [sys.executable, "-m", "skin_node.bench.cli", "memory", "--in-process",
                   "--scene", str(scene), "--frames", str(n), "--every", str(every),
                   "--print-json"] + ([] if progress else ["--no-progress"])
            p = subprocess.run(cmd, stdout=subprocess.PIPE, text=True, check=True, env=env)
            return json.loads(p.stdout.strip().splitlines()[-1])

        with tempfile.TemporaryDirectory(prefix="skin_bench_numba_") as cache:
            env = dict(os.environ, NUMBA_CACHE_DIR=cache)
            first = one(min(every, frames), env)
            mem = one(frames, env)
        mem["first_start"] = {k: first[k] for k in ("after_warmup_mb", "peak_mb", "warmup_s")}
    else:
        mem = memory_profile(scene, frames, every, progress=progress)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        write_json(mem, out / "memory.json")
        charts.memory_chart(mem, out / "memory.png")
    return mem


def memory_line(mem: dict) -> str:
    return (f"memory ({mem['method']}, {mem['scene']}, {mem['frames']} frames): start "
            f"{mem['start_mb']:.0f} MB, after set-up {mem['after_setup_mb']:.0f}, after warm-up "
            f"{mem['after_warmup_mb']:.0f}, peak {mem['peak_mb']:.0f}, end {mem['end_mb']:.0f} MB; "
            f"growth after warm-up {100 * mem['growth']:+.1f}% -> "
            f"{'FLAT (< 10%)' if mem['flat'] else 'NOT FLAT (>= 10%)'}"
            + ("; a first start, compiling the kernels ({:.0f} s): {:.0f} MB after warm-up, "
               "peak {:.0f} MB".format(mem["first_start"]["warmup_s"],
                                       mem["first_start"]["after_warmup_mb"],
                                       mem["first_start"]["peak_mb"])
               if "first_start" in mem else ""))


# -------------------------------------------------------------------- report
def report(out: Path, quick: bool = False, ros: bool = True, progress: bool = True) -> str:
    """Regenerate every result in ``out``; returns the markdown summary."""
    t0 = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    pipes = _pipelines([DEFAULT_PIPELINES])
    scenes = ["arm:2000"] if quick else ["arm:2000", "arm:6000", "humanoid:24000"]
    # every 4th frame: the clips' deepest frames and their neighbours all count
    stride = 24 if quick else 4
    main = run_bench(pipes, scenes, stride=stride, ref_frames=3 if quick else 5,
                     out=out, progress=progress, charts_=False, frames_csv=False)
    sweep_scene = "arm:2000" if quick else "arm:6000"
    sims = [p for p in pipes if p.simulates]
    iters = run_bench(sims, [sweep_scene], clips=["elbow_bend"], iterations=[1, 2, 5, 10, 30],
                      stride=stride * 2, ref_frames=3, progress=progress, charts_=False)
    poses = run_bench(pipes, [sweep_scene], clips=["elbow_sweep", "twist_sweep"],
                      sweep_steps=13 if quick else 25, reference=False, progress=progress,
                      charts_=False)
    # a finer humanoid (the class of a scanned creature: 43k vertices, 88k
    # tets), DQS and the default only: what a vertex costs and what the
    # skin keeps at a resolution the counts were not given for
    fine = [] if quick else run_bench(_pipelines(["dqs,default"]), ["humanoid:43000:88000"],
                                      stride=stride, reference=False, progress=progress,
                                      charts_=False)["runs"]
    allruns = main["runs"] + iters["runs"] + poses["runs"] + fine
    write_csv(allruns, out / "runs.csv")
    write_json({"environment": main["environment"], "runs": allruns}, out / "runs.json")
    flat = [{"scene": s, "motion": mo, "method": m, **row}
            for s, d in poses["frames"].items() for mo, dm in d.items()
            for m, rows in dm.items() for row in rows]
    write_csv(flat, out / "pose_sweeps.csv")
    for sc in scenes:
        charts.speed_accuracy([r for r in main["runs"] if r["scene"] == sc],
                              out / f"speed_accuracy_{chart_name(sc)}.png",
                              f"{sc}, all clips: speed against accuracy (lower is better)")
    charts.speed_accuracy(
        [r for r in iters["runs"]] + [r for r in main["runs"] if r["scene"] == sweep_scene
                                      and r["motion"] == "elbow_bend"
                                      and r["method"] in ("lbs", "dqs")],
        out / "speed_accuracy_iterations.png",
        f"{sweep_scene} elbow_bend, iterations 1/2/5/10/30: speed against accuracy; "
        "lines = each method's Pareto front")
    draw_run_charts({"runs": [], "frames": poses["frames"]}, out)
    stab = run_stability(pipes, "arm:2000", long_frames=200 if quick else 1000,
                         jitter_frames=100 if quick else 300, out=out, progress=progress)
    mem = run_memory("arm:2000" if quick else "humanoid:24000", 300 if quick else 1000,
                     100 if quick else 200, out=out, progress=progress)
    lats = []
    if ros:
        try:
            # each pose solved before it is published (the node's default), on
            # one worker and two, on the walk and the squat (its deep bends are
            # the slow frames); and the correction carried (config/humanoid.yaml),
            # every 8th published skin graded
            clips = [""] if quick else ["", "squat"]
            runs = [([f"workers:={w}"], c, 0) for w in (1, 2) for c in clips] + \
                [(["correction:=carried"], c, 8) for c in clips]
            for params, clip, every in runs:
                lats.append(measure_latency(seconds=5 if quick else 20,
                                            surface_vertices=2000 if quick else 24000,
                                            character="arm" if quick else "humanoid",
                                            params=params, clip=clip, measure_every=every))
            write_json(lats, out / "ros_latency.json")
        except Exception as e:  # noqa: BLE001 - ROS may be missing; the rest still stands
            print(f"skin_bench: ros-latency skipped: {type(e).__name__}: {e}", file=sys.stderr)
    carried = run_carried("arm:2000" if quick else "humanoid:24000",
                          ["elbow_bend"] if quick else ["walk", "squat"], progress=progress)
    write_json(carried, out / "carried.json")
    closeups(out / "closeups.png", quick=quick)
    write_json(against_dqs(main["runs"]), out / "against_dqs.json")
    md = ["## Benchmark summary", "",
          f"Measured by `skin_bench report` in {time.perf_counter() - t0:.0f} s on "
          f"{main['environment'].get('cpu', platform.machine())} "
          f"({main['environment']['cpus']} cpus, load average "
          f"{main['environment'].get('load_average')}). ms = deform time per frame after a "
          "JIT warm-up, one thread; set-up and warm-up times are in runs.csv. Every "
          f"{stride}th frame of each clip.", "",
          dqs_table(main["runs"]), "",
          markdown_table(main["runs"], TABLE_CLIPS), "",
          "Median milliseconds per stage (fk = forward kinematics):", "",
          stage_table(main["runs"] + fine), "",
          *(["The humanoid at 43k vertices (88k tets) against DQS:", "", dqs_table(fine), ""]
            if fine else []),
          "Stability (arm:2000): " + "; ".join(
              f"{m}: " + ", ".join(f"{r['case']} {'ok' if r['stable'] else '+'.join(r['failed'])}"
                                   for r in stab if r["method"] == m)
              for m in dict.fromkeys(r["method"] for r in stab)), "",
          memory_line(mem), "",
          "The correction carried (`AsyncPipeline`, the node's `correction:=carried`): "
          "each pose answered at once with DQS plus the newest correction solved behind "
          "it, streamed in real time at the clip's rate; measures every 4th answer:", "",
          carried_table(carried)]
    for lat in lats:
        md += ["", latency_line(lat)]
    md += ["", "![z-buffer close-ups](closeups.png)"]
    text = "\n".join(md) + "\n"
    (out / "summary.md").write_text(text)
    return text


# ----------------------------------------------------------------------- CLI
def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="skin_bench", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd")

    def common(p):
        p.add_argument("--out", type=Path, default=Path("bench_out"), help="output folder")
        p.add_argument("--no-progress", action="store_true", help="no progress bar")

    r = sub.add_parser("run", help="speed and accuracy of pipelines over scenes and clips")
    r.add_argument("--pipelines", nargs="+", default=[DEFAULT_PIPELINES],
                   help="preset names (comma-separated) and/or JSON dicts "
                        '{"name", "preset", "stages", "params"}')
    r.add_argument("--scenes", default="arm:2000",
                   help="comma-separated character:surface_vertices[:tets] (or a character "
                        "file), each with @file for a glTF's own weights (automatic unless said)")
    r.add_argument("--clips", default="", help="clips and pose sweeps (elbow_bend, wrist_twist, "
                   "walk, squat, elbow_sweep, twist_sweep, thigh_sweep, random_poses: 30 seeded "
                   "poses within the joint limits, random_poses:SEED from another seed) or a glTF "
                   "character's animations (NAME or gltf:NAME), or BVH files retargeted to the "
                   "character; default per character, a glTF's own animations")
    r.add_argument("--iterations", default="", help="sweep, e.g. 1,2,5,10,30")
    r.add_argument("--stiffness", default="", help="sweep, e.g. 0.2,0.5,0.8")
    r.add_argument("--tets", default="", help="sweep of tet counts, e.g. 6000,12000,24000")
    r.add_argument("--stride", type=int, default=6, help="use every n-th clip frame")
    r.add_argument("--max-frames", type=int, default=0, help="at most this many frames per clip")
    r.add_argument("--sweep-steps", type=int, default=37, help="poses of a pose sweep")
    r.add_argument("--ref-frames", type=int, default=6,
                   help="frames compared with the converged reference (0 = none)")
    r.add_argument("--crossings-every", type=int, default=1)
    r.add_argument("--no-charts", action="store_true")
    common(r)

    s = sub.add_parser("stability", help="stability map of pipelines against failure cases")
    s.add_argument("--pipelines", nargs="+", default=[DEFAULT_PIPELINES])
    s.add_argument("--scene", default="arm:2000")
    s.add_argument("--cases", default="", help="subset of bend180,twist360,jumps,jitter,long")
    s.add_argument("--long-frames", type=int, default=100_000)
    s.add_argument("--jitter-frames", type=int, default=1000)
    common(s)

    m = sub.add_parser("memory", help="RSS of a process running the default pipeline")
    m.add_argument("--scene", default="humanoid:24000")
    m.add_argument("--frames", type=int, default=3000)
    m.add_argument("--every", type=int, default=250)
    m.add_argument("--in-process", action="store_true", help="measure this process")
    m.add_argument("--print-json", action="store_true", help=argparse.SUPPRESS)
    common(m)

    e = sub.add_parser("export-memory", help="peak RSS of the streaming exporter against "
                                             "the pipeline alone")
    e.add_argument("--character", default="humanoid")
    e.add_argument("--frames", type=int, default=1000)
    e.add_argument("--bvh", default=None,
                   help="BVH take to retarget (default: CMU 01_01 from the shared data)")
    e.add_argument("--clip", default="", help="a clip instead of a BVH take")
    e.add_argument("--outputs", default="glb,usdc", help="suffixes to write at once")
    e.add_argument("--keep", action="store_true", help="keep the exported files in --out")
    common(e)

    b = sub.add_parser("ablation", help="the default pipeline with each part left out: "
                                        "time against accuracy")
    b.add_argument("--scenes", default="humanoid:24000")
    b.add_argument("--clips", default="walk,squat")
    b.add_argument("--stride", type=int, default=2, help="use every n-th clip frame")
    common(b)

    sub.add_parser("ros-latency", help="input-to-output latency of the node", add_help=False)

    k = sub.add_parser("carried", help="the correction solved behind the answers, streamed "
                                       "in real time: time against DQS, age, skin measures")
    k.add_argument("--scene", default="humanoid:24000")
    k.add_argument("--clips", default="walk,squat",
                   help="built-in clips, or BVH files retargeted to the character")
    k.add_argument("--every", type=int, default=4, help="measure every n-th answer")
    k.add_argument("--solve-poses", type=int, default=None, metavar="L",
                   help="not in real time: every solve takes exactly L poses (repeatable, "
                        "independent of the machine's speed)")
    common(k)

    c = sub.add_parser("pictures", help="z-buffer close-ups of methods side by side")
    c.add_argument("--out", type=Path, default=Path("bench_results/closeups.png"))
    c.add_argument("--pipelines", nargs="+", default=["lbs,dqs,paper,default"],
                   help="columns: preset names and/or JSON dicts, as for run")
    c.add_argument("--quick", action="store_true", help="small meshes")
    c.add_argument("--no-progress", action="store_true")

    p = sub.add_parser("report", help="regenerate bench_results/ and print a markdown table")
    p.add_argument("--out", type=Path, default=Path("bench_results"))
    p.add_argument("--quick", action="store_true", help="small sizes (a smoke run)")
    p.add_argument("--no-ros", action="store_true", help="skip the ROS latency measurement")
    p.add_argument("--no-progress", action="store_true")
    return ap


def main(argv: list | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] == "ros-latency":
        return ros_main(argv[1:])
    if not argv or argv[0].startswith("-") and argv[0] not in ("-h", "--help"):
        argv = ["run"] + argv
    a = _parser().parse_args(argv)
    prog = not a.no_progress
    try:
        if a.cmd == "run":
            res = run_bench(_pipelines(a.pipelines), _list(a.scenes), _list(a.clips) or None,
                            _list(a.iterations, int), _list(a.stiffness, float),
                            _list(a.tets, int), a.stride, a.max_frames or None, a.sweep_steps,
                            a.ref_frames > 0, a.ref_frames, a.crossings_every, a.out,
                            not a.no_charts, prog)
            print(markdown_table(res["runs"]))
            if any(r["method"] == "default" for r in res["runs"]):
                print("\n" + stage_table(res["runs"]))
                if any(r["method"] == "dqs" for r in res["runs"]):
                    print("\n" + dqs_table(res["runs"]))
            print(f"\nwritten to {a.out}/")
        elif a.cmd == "ablation":
            res = run_ablation(_list(a.scenes), _list(a.clips), a.stride, a.out, prog)
            print(ablation_table(res["runs"]))
            print(f"\nwritten to {a.out}/")
        elif a.cmd == "stability":
            res = run_stability(_pipelines(a.pipelines), a.scene, a.long_frames, a.jitter_frames,
                                _list(a.cases) or None, a.out, prog)
            for r in res:
                print(f"{r['method']:>10s} {r['case']:>9s} ({r['frames']} frames): "
                      f"{'stable' if r['stable'] else 'FAILED ' + ', '.join(r['failed'])}")
        elif a.cmd == "memory":
            if a.in_process:
                mem = memory_profile(a.scene, a.frames, a.every, progress=prog)
                if a.print_json:
                    print(json.dumps(_clean(mem)))
                    return 0
                write_json(mem, (a.out.mkdir(parents=True, exist_ok=True), a.out)[1] / "memory.json")
            else:
                mem = run_memory(a.scene, a.frames, a.every, a.out, progress=prog)
            print(memory_line(mem))
            return 0 if mem["flat"] else 1
        elif a.cmd == "export-memory":
            res = run_export_memory(a.character, a.frames, a.bvh, a.clip, _list(a.outputs),
                                    a.out, a.keep)
            print(export_memory_line(res))
            for line in res["lines"]:
                print("  " + line)
        elif a.cmd == "carried":
            rows = run_carried(a.scene, _list(a.clips), a.every, progress=prog,
                               solve_poses=a.solve_poses)
            a.out.mkdir(parents=True, exist_ok=True)
            write_json(rows, a.out / "carried.json")
            print(carried_table(rows))
            print(f"\nwritten to {a.out}/")
        elif a.cmd == "pictures":
            print(closeups(a.out, methods=_pipelines(a.pipelines), quick=a.quick))
        elif a.cmd == "report":
            print(report(a.out, quick=a.quick, ros=not a.no_ros, progress=prog))
    except ValueError as e:
        print(f"skin_bench: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
