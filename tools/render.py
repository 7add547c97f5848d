"""Render skin_node's output next to plain LBS and DQS into a PNG for the README.

    python tools/render.py docs/skin_node.png

Top row: the built-in arm with the elbow at 150 degrees and the wrist twisted
180 degrees; bottom row: the built-in humanoid in a deep squat (knees 150
degrees). Columns: LBS, DQS, skin_node's default pipeline. Skin that passed
through skin is drawn red.
"""
from __future__ import annotations

import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from skin_node import Pipeline, load_character, make_clip  # noqa: E402
from skin_node.metrics import mesh_volume  # noqa: E402
from skin_node.stages.collision import JointRegions  # noqa: E402


def shade(ax, V, F, hot, view, title):
    P = V[F]
    n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    light = np.array([0.4, -0.5, 0.8])
    light /= np.linalg.norm(light)
    lam = 0.35 + 0.65 * np.clip(n @ light, 0, 1)
    base = np.where(hot[F].any(axis=1)[:, None], [0.85, 0.2, 0.2], [0.85, 0.72, 0.62])
    ax.add_collection3d(Poly3DCollection(P, facecolors=base * lam[:, None], linewidths=0))
    lo, hi = V.min(0), V.max(0)
    c, r = (lo + hi) / 2, (hi - lo).max() / 2
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.view_init(*view)
    ax.set_axis_off()
    ax.set_title(title, fontsize=9)


def crossed(ch, V, M, regions):
    hot = np.zeros(len(V), dtype=bool)
    for j in range(1, ch.skeleton.n_joints):
        if len(regions.verts[j]):
            hit = regions.crossed(V, ch.V, ch.F, M, j)
            hot[regions.verts[j][hit != -1]] = True
    return hot


def main(out: str = "docs/skin_node.png") -> None:
    arm = load_character("arm")
    human = load_character("humanoid")
    squat = make_clip("squat", human.skeleton)
    scenes = [
        (arm, arm.pose(elbow_rz=np.radians(150)), (20, -80), "elbow 150°"),
        (arm, arm.pose(wrist_rx=np.radians(180)), (20, -60), "wrist twist 180°"),
        (human, squat.frames[len(squat.frames) // 2], (10, -70), "squat, knees 150°"),
    ]
    fig = plt.figure(figsize=(12, 10), dpi=90)
    methods = [("LBS", ["lbs"]), ("DQS", ["dqs"]), ("skin_node", None)]
    for row, (ch, q, view, label) in enumerate(scenes):
        regions = JointRegions(ch)
        v0 = mesh_volume(ch.V, ch.F)
        for col, (name, stages) in enumerate(methods):
            pipe = Pipeline(ch) if stages is None else Pipeline(ch, stages)
            V = pipe.deform(q)
            hot = crossed(ch, V, pipe.last_frame.M, regions)
            ax = fig.add_subplot(3, 3, 3 * row + col + 1, projection="3d")
            shade(ax, V, ch.F, hot, view,
                  f"{name}, {label}\nvolume {mesh_volume(V, ch.F) / v0:.3f}, "
                  f"{int(hot.sum())} vertices through skin")
    fig.tight_layout()
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(*sys.argv[1:])
