"""Per-frame time of this checkout against an earlier commit, in alternating runs.

    python tools/ab_time.py 6054e01                 # the built-in humanoid's walk, 4 pairs
    python tools/ab_time.py HEAD~3 --runs 6 --clip squat
    python tools/ab_time.py HEAD --params '{"threads": 2}'   # a setting, same code

This machine's run-to-run noise moves a clip's median by 10 to 20% within the
hour, so two figures taken apart compare the hour, not the code. Here each run
is a fresh process timing every other frame of the clip after a warm-up, the
two sides take turns, and the result is the median per stage on each side and
the saving in each pair. The other side is the commit's ``skin_node`` (git
archive), imported in place of this one; both keep their numba caches apart.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]

CHILD = """
import json, sys
import numpy as np
from skin_node import Pipeline, load_character, make_clip
ch = load_character("humanoid", surface_vertices=24000, progress=False)
clip = make_clip(sys.argv[1], ch.skeleton)
pipe = Pipeline(ch, **json.loads(sys.argv[2]))
for q in clip.frames[:10]:
    pipe.deform(q)
times = {}
for q in clip.frames[::2]:
    pipe.deform(q)
    for k, v in pipe.timings.items():
        times.setdefault(k, []).append(v)
import skin_node
times["source"] = skin_node.__file__
print(json.dumps({k: v if k == "source" else float(np.median(v)) for k, v in times.items()}))
"""


def run(src: Path, cache: Path, clip: str, params: str = "{}") -> dict:
    """Median ms per stage of ``clip``, timed in a child importing ``src``,
    its pipeline made with ``params`` (JSON)."""
    cache.mkdir(exist_ok=True)
    env = dict(os.environ, PYTHONPATH=str(src), NUMBA_CACHE_DIR=str(cache))
    # run from the cache folder: ``python -c`` puts the working folder first on
    # the path, and from a checkout that would import the checkout's package
    p = subprocess.run([sys.executable, "-c", CHILD, clip, params], env=env, capture_output=True,
                       text=True, cwd=cache)
    if p.returncode:
        raise RuntimeError(f"the timing run of {src} failed:\n{p.stderr[-2000:]}")
    return json.loads(p.stdout.strip().splitlines()[-1])


def main(argv: list | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("ref", help="the commit to compare with (anything git names)")
    ap.add_argument("--runs", type=int, default=4, help="pairs of runs")
    ap.add_argument("--clip", default="walk")
    ap.add_argument("--params", default="{}", metavar="JSON",
                    help="pipeline parameters of this checkout's side, e.g. '{\"threads\": 2}'")
    ap.add_argument("--ref-params", default="{}", metavar="JSON",
                    help="pipeline parameters of the commit's side")
    a = ap.parse_args(argv)
    for name, text in (("--params", a.params), ("--ref-params", a.ref_params)):
        try:
            if not isinstance(json.loads(text), dict):
                raise ValueError("not an object")
        except ValueError as e:
            ap.error(f"{name} must be a JSON object of parameters, got {text!r} ({e})")
    with tempfile.TemporaryDirectory(prefix="ab_time_") as tmp:
        tmp = Path(tmp)
        old = tmp / "ref"
        old.mkdir()
        try:
            tar = subprocess.run(["git", "-C", str(REPO), "archive", a.ref, "skin_node"],
                                 check=True, capture_output=True).stdout
        except subprocess.CalledProcessError as e:
            print(f"ab_time: error: git archive {a.ref}: {e.stderr.decode().strip()}",
                  file=sys.stderr)
            return 2
        subprocess.run(["tar", "-x", "-C", str(old)], input=tar, check=True)
        sides = {a.ref: (old, tmp / "cache_ref", a.ref_params),
                 "this checkout": (REPO, tmp / "cache_new", a.params)}
        res = {k: [] for k in sides}
        print(f"timing {a.clip} {a.runs} times on each side (the first run of a side "
              f"compiles its kernels)", file=sys.stderr, flush=True)
        for i in range(a.runs):
            # the order alternates too, so neither side always runs on a warmer machine
            for k in (list(sides) if i % 2 == 0 else list(sides)[::-1]):
                try:
                    src, cache, params = sides[k]
                    r = run(src, cache, a.clip, params)
                except RuntimeError as e:
                    print(f"ab_time: error: {e}", file=sys.stderr)
                    return 2
                if not r.pop("source").startswith(str(sides[k][0])):
                    print(f"ab_time: error: the {k} run imported another skin_node",
                          file=sys.stderr)
                    return 2
                res[k].append(r)
                print(f"[{i + 1}/{a.runs}] {k}: total {res[k][-1]['total']:.2f} ms",
                      file=sys.stderr, flush=True)
    stages = list(res["this checkout"][0])
    print(f"humanoid:24000 {a.clip}, median ms per stage over {a.runs} runs each"
          + "".join(f"; {k} with {p}" for k, (_, _, p) in sides.items() if p != "{}"))
    for k, rs in res.items():
        print(f"  {k:>14}: " + "  ".join(f"{s} {np.median([r[s] for r in rs]):.2f}"
                                         for s in stages if s in rs[0]))
    saving = [o["total"] - n["total"] for o, n in zip(res[a.ref], res["this checkout"])]
    print("  total saving in each pair (ms): " + ", ".join(f"{s:.2f}" for s in saving))
    return 0


if __name__ == "__main__":
    sys.exit(main())
