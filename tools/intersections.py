"""Where a pipeline's surface passes through itself: inside the joint regions
(which the crossing test and the collision stage look at) or beyond them.

    python tools/intersections.py --character arm --pose elbow_rz=2.6
    python tools/intersections.py --character humanoid --clip squat --every 24 --preset dqs

Prints, per method, the intersecting triangle pairs of the worst frame
(skin_node.kernels.intersect.SelfIntersections: skin through skin / crumpled)
and how many of the skin-through-skin pairs have no corner in any joint region.
"""
from __future__ import annotations

import argparse

import numpy as np

from skin_node import Pipeline, load_character, make_clip
from skin_node.kernels.intersect import SelfIntersections


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--character", default="arm")
    ap.add_argument("--surface-vertices", type=int, default=None)
    ap.add_argument("--pose", default="", help="channel=value,... (radians)")
    ap.add_argument("--clip", default="", help="a built-in clip instead of one pose")
    ap.add_argument("--every", type=int, default=8, help="with --clip: every n-th frame")
    ap.add_argument("--preset", default="lbs,dqs,paper,default")
    a = ap.parse_args()
    kw = {} if a.surface_vertices is None else {"surface_vertices": a.surface_vertices}
    ch = load_character(a.character, progress=False, **kw)
    regions = ch.regions()
    count = SelfIntersections(ch.V, ch.F, 3.0 * regions.edge)
    in_region = (ch.rig.region[ch.F] >= 0).any(axis=1)          # per triangle
    if a.clip:
        frames = make_clip(a.clip, ch.skeleton).frames[::a.every]
    else:
        pose = {k: float(v) for k, v in (p.split("=") for p in a.pose.split(",") if p)}
        frames = [ch.pose(**pose)]
    for preset in a.preset.split(","):
        pipe = Pipeline.preset(ch, preset)
        worst = None
        for q in frames:
            X = pipe.deform(q)
            pairs = count.pairs(X)
            through = pairs[count.through(pairs)]
            beyond = int(np.count_nonzero(~in_region[through].any(axis=1)))
            row = (len(through), len(pairs) - len(through), beyond)
            worst = row if worst is None or row[0] > worst[0] else worst
        print(f"{preset:8s} skin through skin {worst[0]:5d} pairs ({worst[2]} with no corner in a "
              f"joint region), crumpled {worst[1]:5d}  [worst of {len(frames)} frames]")


if __name__ == "__main__":
    main()
