"""Stability map: every method against the poses and rates that break skinning.

Cases (columns), on the small arm (``arm:2000``) by default
------------------------------------------------------------
``bend180``
    Elbow from 0 to 180 degrees (past its 154-degree limit) and held there.
``twist360``
    Wrist twist from 0 to 360 degrees (through the 180-degree candy wrapper).
``jumps``
    Random poses inside ``skeleton.limits`` where, from one frame to the
    next, one rotation channel also jumps by 90 degrees.
``jitter``
    1 kHz input: a bent pose plus tiny random noise on every channel
    (1e-3 rad, 0.1 mm on the root) every frame, for ``jitter_frames`` frames.
``long``
    ``long_frames`` frames (100,000 by default) of the arm's clips in a loop.

Failures (what a cell lists)
----------------------------
``nan``        any non-finite output vertex;
``explosion``  any vertex more than 0.5 m from its stage-1 (skinning) position;
``inverted``   tets that embed skin vertices and whose signed volume has
               flipped sign since rest (``pipe.last_frame.tet`` against
               ``rig.vol0``; only for pipelines that simulate the tets, the
               others do not use them). Flipped tets that carry no skin (lattice
               cells crushed inside a fold) are counted in ``inverted_all``
               but are not a failure: the skin never sees them;
``crossings``  skin passed through skin by the paper's vertex test
               (:func:`count_crossings` > 0);
``pairs``      skin passed through skin, counted exactly: any intersecting pair
               of triangles that share no corner
               (:class:`~skin_node.kernels.intersect.SelfIntersections`);
``folds``      more than :data:`FOLDS` sharp folds (edges whose dihedral angle
               grew by more than 90 degrees, :class:`~skin_node.metrics.SurfaceQuality`);
``drift``      after the run, the rest pose is deformed once and differs from
               the rest mesh by more than 1 mm somewhere.
Inverted tets, crossings, pairs and folds are checked every ``check_every``
frames and on the last frame of a case; NaN and explosion on every frame.
"""
from __future__ import annotations

import numpy as np

from .measure import (Method, Progress, Scene, inverted_tets, load_scene, make_motion,
                      parse_method, parse_scene, scene_metrics)
from ..rigging.regions import count_crossings

CASES = ("bend180", "twist360", "jumps", "jitter", "long")
EXPLOSION_M = 0.5
DRIFT_MM = 1.0
#: Sharp folds a case may leave before it counts as failed.
FOLDS = 10


def case_frames(case: str, character, frames: int | None = None,
                seed: int = 0) -> np.ndarray | None:
    """(T, C) poses of a failure case, or None when the character lacks its channels."""
    skel = character.skeleton
    rng = np.random.default_rng(seed)
    if case == "bend180":
        m = make_motion("elbow_sweep", character, steps=frames or 61)
        return None if m is None else np.concatenate([m.frames, np.repeat(m.frames[-1:], 10, 0)])
    if case == "twist360":
        m = make_motion("twist_sweep", character, steps=frames or 91)
        return None if m is None else m.frames
    lim = skel.limits.reshape(-1, 2)                     # (3J, 2) per rotation channel
    if case == "jumps":
        T = frames or 60
        span = lim[:, 1] - lim[:, 0]
        can = np.flatnonzero(span >= np.pi / 2)
        Q = np.zeros((T, skel.n_channels))
        for t in range(T):
            q = rng.uniform(lim[:, 0], lim[:, 1])
            if t and len(can):
                c = rng.choice(can)
                prev = Q[t - 1, 3 + c]
                up = prev + np.pi / 2
                q[c] = up if up <= lim[c, 1] else prev - np.pi / 2
            Q[t, 3:] = q
        return Q
    if case == "jitter":
        T = frames or 1000
        base = np.zeros(skel.n_channels)
        base[3:] = lim.mean(axis=1) + 0.25 * (lim[:, 1] - lim[:, 0])
        noise = rng.normal(0.0, 1e-3, (T, skel.n_channels))
        noise[:, :3] *= 0.1
        return base + noise
    if case == "long":
        T = frames or 100_000
        parts = [m.frames for m in (make_motion(c, character) for c in
                                    ("elbow_bend", "wrist_twist", "walk", "squat")) if m]
        loop = np.concatenate(parts)
        return loop[np.arange(T) % len(loop)]
    raise ValueError(f"unknown case '{case}'; cases are {list(CASES)}")


def run_case(method: Method, scene: Scene, case: str, frames: int | None = None,
             check_every: int = 25, progress: Progress | None = None) -> dict | None:
    """Run one failure case; a dict with ``stable`` and what failed (None if n/a)."""
    ch, _ = load_scene(scene)
    Q = case_frames(case, ch, frames)
    if Q is None:
        return None
    metrics = scene_metrics(scene)
    pipe = method.build(ch)
    nan = False
    worst_m = inverted = inverted_all = crossings = pairs = folds = 0.0
    T = len(Q)
    for t, q in enumerate(Q):
        V = pipe.deform(q)[:len(ch.V)]        # the body: passengers have no failure modes
        fr = pipe.last_frame
        if not np.all(np.isfinite(V)):
            nan = True
            if progress is not None:
                progress.update(T - t)
            break
        worst_m = max(worst_m, float(np.sqrt(((V - fr.surface_base) ** 2).sum(1).max())))
        if t % check_every == 0 or t == T - 1:
            if method.simulates:
                inverted = max(inverted, inverted_tets(fr.tet, ch, skin_only=True))
                inverted_all = max(inverted_all, inverted_tets(fr.tet, ch))
            crossings = max(crossings, count_crossings(V, ch.V, ch.F, fr.M, metrics.regions,
                                                          search=metrics.search))
            pairs = max(pairs, len(metrics.intersections.pairs(V)))
            folds = max(folds, metrics.surface(V)["folds90"])
        if progress is not None:
            progress.update(1)
    R = pipe.deform(ch.skeleton.rest_pose())[:len(ch.V)]
    drift = float(np.sqrt(((R - ch.V) ** 2).sum(1).max()) * 1e3) if np.all(np.isfinite(R)) \
        else float("inf")
    failed = []
    if nan:
        failed.append("nan")
    if worst_m > EXPLOSION_M:
        failed.append("explosion")
    if inverted > 0:
        failed.append("inverted")
    if crossings > 0:
        failed.append("crossings")
    if pairs > 0:
        failed.append("pairs")
    if folds > FOLDS:
        failed.append("folds")
    if drift > DRIFT_MM:
        failed.append("drift")
    return {"method": method.name, "scene": scene.label, "case": case, "frames": T,
            "stable": not failed, "failed": failed, "nan": nan, "max_offset_m": worst_m,
            "inverted_max": int(inverted),
            "inverted_all": int(inverted_all), "crossings_max": int(crossings),
            "pairs_max": int(pairs), "folds90_max": int(folds), "drift_mm": drift}


def stability_map(methods, scene="arm:2000", cases=CASES, long_frames: int = 100_000,
                  jitter_frames: int = 1000, check_every: int = 25,
                  progress: bool = True) -> list:
    """Every method against every case; a list of :func:`run_case` dicts."""
    scene = parse_scene(scene) if isinstance(scene, str) else scene
    methods = [parse_method(m) for m in methods]
    ch, _ = load_scene(scene)
    sizes = {c: (long_frames if c == "long" else jitter_frames if c == "jitter" else None)
             for c in cases}
    total = sum(len(Q) for Q in (case_frames(c, ch, sizes[c]) for c in cases) if Q is not None)
    bar = Progress(total * len(methods), "stability", enabled=progress)
    out = []
    for m in methods:
        for c in cases:
            bar.label = f"stability {m.name} {c}"
            r = run_case(m, scene, c, sizes[c], check_every, bar)
            if r is not None:
                out.append(r)
    bar.close()
    return out
