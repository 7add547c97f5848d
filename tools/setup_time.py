"""Set-up and JIT time of a character, apart from per-frame time.

    python tools/setup_time.py humanoid            # as a restart sees it (warm caches)
    python tools/setup_time.py humanoid --cold     # empty rig and numba caches, in a child process

Prints the time to import, to build (or load) the rig, to the first deformed frame
(numba compiles or loads its kernels then) and of the next frame.
"""
from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def measure(name: str) -> None:
    t0 = time.perf_counter()
    from skin_node import Pipeline, default_clip_name, load_character, make_clip
    t1 = time.perf_counter()
    ch = load_character(name, progress=False)
    t2 = time.perf_counter()
    pipe = Pipeline(ch)
    clip = make_clip(default_clip_name(name), ch.skeleton)
    q = clip.frames[len(clip.frames) // 2]
    pipe.deform(q)
    t3 = time.perf_counter()
    pipe.deform(clip.frames[len(clip.frames) // 2 + 1])
    t4 = time.perf_counter()
    print(f"{name}: import {t1 - t0:.1f} s, set-up {t2 - t1:.1f} s, first frame (JIT or kernel "
          f"cache) {t3 - t2:.2f} s, next frame {(t4 - t3) * 1e3:.1f} ms")


def main() -> None:
    args = [a for a in sys.argv[1:] if a != "--cold"]
    name = args[0] if args else "humanoid"
    if "--cold" in sys.argv:
        with tempfile.TemporaryDirectory() as d:
            env = dict(os.environ, SKIN_NODE_CACHE=str(Path(d) / "rig"),
                       NUMBA_CACHE_DIR=str(Path(d) / "numba"))
            subprocess.run([sys.executable, __file__, name], env=env, check=True)
        return
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
    measure(name)


if __name__ == "__main__":
    main()
