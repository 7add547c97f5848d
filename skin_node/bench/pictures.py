"""Close-ups of the skin a viewer would judge, drawn with a z-buffer.

    skin_bench pictures --out bench_results/closeups.png

Rows: the arm's elbow at 150 degrees seen from the crease side, its wrist
twisted 180 degrees, the humanoid's deepest squat from the side and from
behind, its walk's armpit, and its arms down while it leans sideways (a
hand driven into the hip). Columns: methods (LBS, DQS, the paper's, ours
by default). Every pixel shows the nearest skin (:mod:`skin_node.kernels.raster`);
faces seen from behind (skin turned inside out) are blue, faces of an
intersecting triangle pair red, and each panel's title gives the pose's
intersecting pairs and sharp folds.
"""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .. import load_character, make_clip  # noqa: E402
from ..kernels.intersect import SelfIntersections  # noqa: E402
from ..kernels.raster import render  # noqa: E402
from ..metrics import SurfaceQuality  # noqa: E402
from .measure import parse_method  # noqa: E402

#: The methods of the columns.
METHODS = ("lbs", "dqs", "paper", "default")


def views(quick: bool = False) -> list:
    """(title, character spec, surface vertices, pose function, camera offset
    from the focus joint, focus joint, up) of every row."""
    arm_n, hum_n = (2000, 6000) if quick else (6000, 24000)
    squat = lambda ch: make_clip("squat", ch.skeleton).frames[  # noqa: E731
        int(np.argmax([ch.skeleton.joint_angles(q).max()
                       for q in make_clip("squat", ch.skeleton).frames]))]
    walk = lambda ch: make_clip("walk", ch.skeleton).frames[  # noqa: E731
        len(make_clip("walk", ch.skeleton).frames) // 4]
    # arms 80 degrees down from the T-pose, spine and chest leaning 15 each:
    # the pose drives the right forearm and hand into the hip and thigh
    lean = lambda ch: ch.pose(spine_rx=np.radians(15), chest_rx=np.radians(15),  # noqa: E731
                              l_shoulder_rx=-1.4, r_shoulder_rx=1.4)
    return [
        ("arm, elbow 150 deg, crease side", "arm", arm_n,
         lambda ch: ch.pose(elbow_rz=np.radians(150)), (0.12, 0.32, 0.16), "elbow", (0, 0, 1)),
        ("arm, wrist twisted 180 deg", "arm", arm_n,
         lambda ch: ch.pose(wrist_rx=np.pi), (0.0, -0.25, 0.18), "wrist", (0, 0, 1)),
        ("humanoid, deepest squat, side", "humanoid", hum_n, squat, (0.1, -1.0, 0.15),
         "l_knee", (0, 0, 1)),
        ("humanoid, deepest squat, behind", "humanoid", hum_n, squat, (-0.9, -0.25, 0.1),
         "pelvis", (0, 0, 1)),
        ("humanoid, walk, armpit", "humanoid", hum_n, walk, (0.35, -0.45, -0.05),
         "r_shoulder", (0, 0, 1)),
        ("humanoid, arms down, leaning 30 deg", "humanoid", hum_n, lean, (1.0, -0.5, 0.1),
         "r_hip", (0, 0, 1)),
    ]


def closeups(out: Path, methods=METHODS, quick: bool = False, size: int = 300) -> Path:
    """Render every row of :func:`views` for every method into one PNG."""
    rows = views(quick)
    fig, axes = plt.subplots(len(rows), len(methods),
                             figsize=(size / 80 * len(methods), size / 80 * len(rows) + 0.3),
                             squeeze=False, dpi=80)
    cache = {}
    for r, (title, spec, n, pose, offset, focus, up) in enumerate(rows):
        if (spec, n) not in cache:
            ch = load_character(spec, surface_vertices=n, progress=False)
            cache[spec, n] = (ch, SelfIntersections(ch.V, ch.F, 0.0), SurfaceQuality(ch.V, ch.F))
        ch, si, sq = cache[spec, n]
        q = pose(ch)
        for c, m in enumerate(methods):
            method = parse_method(m)
            pipe = method.build(ch)
            X = pipe.deform(q)
            G = pipe.last_frame.G
            centre = G[ch.skeleton.index(focus), :3, 3]
            pairs = si.pairs(X)
            mark = np.zeros(len(ch.F), dtype=bool)
            mark[pairs.ravel()] = True
            img = render(X, ch.F, centre + np.asarray(offset), centre, size=(size, size),
                         fov=40.0, up=up, mark=mark)
            ax = axes[r, c]
            ax.imshow(img)
            ax.set_xticks([])
            ax.set_yticks([])
            s = sq(X)
            ax.set_title(f"{method.name}: {len(pairs)} pairs, {s['folds90']} folds",
                         fontsize=8)
            if c == 0:
                ax.set_ylabel(title, fontsize=8)
    fig.suptitle("z-buffer close-ups: red = faces of intersecting triangle pairs, "
                 "blue = faces seen from behind", fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 1 - 0.3 / (size / 80 * len(rows) + 0.3)))
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out
