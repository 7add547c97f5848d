"""``skin_bench carried``: the carried correction against DQS and the solved skin.

Plays each clip in real time at its rate (120 Hz for the built-in clips)
into an :class:`~skin_node.async_pipeline.AsyncPipeline` on this process, as
a live stream would reach it, with plain DQS timed right after each answer
(interleaved, so both see the same machine). Per clip:

- the answer's time per pose against DQS's median (median and 90th
  percentile: a 120 Hz consumer sees the tail), and DQS's own time;
- how many poses old the correction was (median, 90th percentile, most),
  the poses the solver never took, and the answers that carried less than
  the whole correction (``faded``: a pose far from the solved one, or a
  jump);
- on every ``every``-th answer, after the stream: exact intersecting pairs,
  sharp folds (``folds90``) and roughness of the answer, of the pipeline's
  skin solved for that very pose (the inline reference) and of DQS's, and the
  answer's farthest vertex from the solved skin (median and largest frame).

The figures depend on the machine's speed (a slower solve is older when it
lands): the report runs this beside the other figures of the same run.
With ``solve_poses`` (``--solve-poses L``) the skin's figures do not (the
times still do): the clip is played as fast as it goes and every solve
takes exactly ``L`` poses (the solver takes the pose just answered and its
correction lands before the answer ``L`` poses later; the poses given while
it works are skipped), so two builds or settings compare on the same
schedule, bitwise repeatable.
"""
from __future__ import annotations

import threading
import time

import numpy as np

from ..async_pipeline import AsyncPipeline
from ..motion import load_motion
from ..pipeline import Pipeline
from .measure import Progress, load_scene, make_motion, parse_scene, scene_metrics


def skin_measures(metrics, V: np.ndarray) -> tuple:
    """(exact intersecting pairs, folds90, roughness) of surface ``V``."""
    s = metrics.surface(V)
    through, crumpled = metrics.intersections(V)
    return int(through + crumpled), int(s["folds90"]), float(s["roughness"])


def compare_skins(scene: str, poses: list, skins: list, progress: bool = False) -> dict:
    """Sums over ``skins`` (answers to ``poses``) of :func:`skin_measures`,
    beside the default pipeline's skin solved for each pose and DQS's, and
    how far each answer lies from the solved skin (per frame its farthest
    vertex: ``dev_median_mm``, ``dev_max_mm``)."""
    sc = parse_scene(scene)
    ch, _ = load_scene(sc)
    metrics = scene_metrics(sc)
    ref, dqs = Pipeline(ch), Pipeline.preset(ch, "dqs")
    n = len(ch.V)
    sums = {k: np.zeros(3) for k in ("answer", "solved", "dqs")}
    dev = []
    bar = Progress(len(poses), f"{scene} measures", progress)
    for q, V in zip(poses, skins):
        R = ref.deform(q)[:n]
        dev.append(float(np.linalg.norm(V[:n] - R, axis=1).max()) * 1e3)
        for key, X in (("answer", V[:n]), ("solved", R), ("dqs", dqs.deform(q)[:n])):
            sums[key] += skin_measures(metrics, X)
        bar.update()
    bar.close()
    out = {"frames_measured": len(poses),
           "dev_median_mm": float(np.median(dev)) if dev else float("nan"),
           "dev_max_mm": float(np.max(dev)) if dev else float("nan")}
    for key, s in sums.items():
        out[f"{key}_pairs"], out[f"{key}_folds90"] = int(s[0]), int(s[1])
        out[f"{key}_roughness"] = float(s[2] / max(len(poses), 1))
    return out


class _Paced(Pipeline):
    """A solver that, once ``paced``, says when it took a pose (``taken``)
    and returns its solve only when released (``release``)."""
    paced = False

    def __init__(self, *args, **kw) -> None:
        super().__init__(*args, **kw)
        self.taken, self.release = threading.Semaphore(0), threading.Semaphore(0)

    def deform(self, q):
        paced = self.paced
        if paced:
            self.taken.release()
        try:
            return super().deform(q)
        finally:                # a failed solve lands when released too
            if paced:
                self.release.acquire()


def run_carried(scene: str = "humanoid:24000", clips=("walk", "squat"), every: int = 4,
                warm_frames: int = 8, progress: bool = True,
                solve_poses: int | None = None) -> list:
    """One row per clip (a built-in clip, or a BVH file retargeted to the
    character); see the module docstring."""
    if solve_poses is not None and int(solve_poses) < 1:
        raise ValueError(f"solve_poses must be at least 1, got {solve_poses}")
    sc = parse_scene(scene)
    ch, _ = load_scene(sc)
    rows = []
    for clip in clips:
        if clip.lower().endswith(".bvh"):
            c = load_motion(sc.character, bvh=clip, skeleton=ch.skeleton)
            frames, rate, clip = np.asarray(c.frames), float(c.fps), "bvh:" + c.name
        else:
            mo = make_motion(clip, ch)
            if mo is None or mo.x is not None:
                raise ValueError(f"'{clip}' is not a clip of {scene}")
            frames, rate = np.asarray(mo.frames), float(mo.fps)
        dqs = Pipeline.preset(ch, "dqs")
        solver = _Paced(ch) if solve_poses else None
        with AsyncPipeline(ch, solver_pipeline=solver) as ap:
            t_warm = ap.warm_up()
            dqs.deform(frames[0])
            answer_ms, dqs_ms, lags, kept, faded = [], [], [], [], 0
            how = f"each solve {solve_poses} poses" if solve_poses else f"at {rate:.0f} Hz"
            bar = Progress(len(frames), f"{scene} {clip} {how}", progress)
            due = 0
            if solver is not None:
                solver.paced = True
            t0 = time.perf_counter()
            for k, q in enumerate(frames):
                take = True
                if solver is not None:
                    take = k == due
                    if take and k:      # the solve under way lands; the solver takes q
                        landed = ap.solved + ap.failed + 1
                        solver.release.release()
                        while ap.solved + ap.failed < landed:
                            time.sleep(1e-4)
                    if take:
                        due = k + int(solve_poses)
                else:
                    # sleep, not spin: a spinning thread would hold the GIL the solver needs
                    wait = t0 + k / rate - time.perf_counter()
                    if wait > 0:
                        time.sleep(wait)
                a = time.perf_counter()
                V = ap.deform(q, hand_over=take)  # the poses between are held: skipped
                b = time.perf_counter()
                dqs.deform(q)
                e = time.perf_counter()
                if solver is not None and take:
                    solver.taken.acquire()      # before the next pose can replace it
                answer_ms.append((b - a) * 1e3)
                dqs_ms.append((e - b) * 1e3)
                lags.append(ap.lag)
                if k >= warm_frames and ap.counts["correction_share"] < 1.0:
                    faded += 1
                if k >= warm_frames and k % every == 0:
                    kept.append((q, V))
                bar.update()
            bar.close()
            if solver is not None:
                solver.paced = False
                solver.release.release()        # the last solve under way
                ap.wait()
            skipped, failed = ap.skipped, ap.failed
        d50 = float(np.median(dqs_ms))
        L = np.asarray(lags[warm_frames:])
        row = {"scene": scene, "motion": clip, "rate_hz": rate, "frames": len(frames),
               "solve_poses": int(solve_poses) if solve_poses else None,
               "dqs_ms_p50": d50, "answer_ms_p50": float(np.median(answer_ms)),
               "answer_ms_p90": float(np.percentile(answer_ms, 90)),
               "answer_x_dqs_p50": float(np.median(answer_ms)) / d50,
               "answer_x_dqs_p90": float(np.percentile(answer_ms, 90)) / d50,
               "lag_p50": float(np.median(L)), "lag_p90": float(np.percentile(L, 90)),
               "lag_max": int(L.max()), "solves_skipped": skipped, "solves_failed": failed,
               "faded": faded,
               "warm_up_s": t_warm}
        row.update(compare_skins(scene, [q for q, _ in kept], [V for _, V in kept], progress))
        rows.append(row)
    return rows


def carried_table(rows: list) -> str:
    """Markdown: the answer against DQS, the correction's age, the skins' measures."""
    out = ["| scene | motion | answer x DQS p50 / p90 (DQS ms) | correction age p50 / p90 / max "
           "(poses); answers faded | pairs answer / solved / DQS | folds90 answer / solved / DQS"
           " | roughness answer / solved | from solved p50 / max (mm) |",
           "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(
            f"| {r['scene']} | {r['motion']} "
            f"{_schedule(r)} | "
            f"{r['answer_x_dqs_p50']:.2f} / {r['answer_x_dqs_p90']:.2f} ({r['dqs_ms_p50']:.2f}) | "
            f"{r['lag_p50']:.0f} / {r['lag_p90']:.0f} / {r['lag_max']}; {r.get('faded', '-')} | "
            f"{r['answer_pairs']} / {r['solved_pairs']} / {r['dqs_pairs']} | "
            f"{r['answer_folds90']} / {r['solved_folds90']} / {r['dqs_folds90']} | "
            f"{r['answer_roughness'] / max(r['solved_roughness'], 1e-12):.3f} x | "
            f"{r['dev_median_mm']:.1f} / {r['dev_max_mm']:.1f} |")
    return "\n".join(out)


def _schedule(row: dict) -> str:
    n = row.get("solve_poses")
    return f"(each solve {n} poses)" if n else f"at {row['rate_hz']:.0f} Hz"
