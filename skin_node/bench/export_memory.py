"""``skin_bench export-memory``: peak memory of the exporter against the pipeline alone.

Two fresh processes deform the same poses of the same character: one runs
``python -m skin_node.io.export`` into the asked outputs (``.glb``, ``.usdc``,
...), the other only deforms them (what the node does per frame, without
ROS). The peak resident size of each comes from the kernel (``ru_maxrss`` of
the finished child), so no sample can miss it. With frames written as they
are made, the exporter's peak is the pipeline's plus a constant: the
difference is what writing costs, and it must not grow with the frames.

The motion is a BVH take retargeted onto the character (default: CMU 01_01,
2,752 frames at 120 Hz, from the shared test data) or a built-in clip.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

DATA = Path(__file__).resolve().parents[3] / "shared" / "data"
DEFAULT_BVH = DATA / "bvh" / "cmu_01_01_forward_jumps.bvh"

#: The pipeline alone: the exporter's own code path without writing (argv: character,
#: clip, bvh, frames).
_DEFORM_ONLY = """
import sys
from skin_node.character import load_character
from skin_node.io.export import deform_frames
from skin_node.motion import load_motion
character, clip, bvh, n = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
ch = load_character(character, progress=False)
q = load_motion(character, clip, bvh, skeleton=ch.skeleton).frames[:n]
k = sum(1 for _ in deform_frames(ch, q))
print(k)
"""


def _measure(cmd: list[str], env: dict) -> dict:
    """Run ``cmd`` in a helper process that reports the child's peak RSS exactly
    (its only child's ``ru_maxrss``, KiB, as MiB like the other memory figures)."""
    helper = ("import json, resource, subprocess, sys, time\n"
              "t = time.monotonic()\n"
              "p = subprocess.run(sys.argv[1:], capture_output=True, text=True)\n"
              "r = resource.getrusage(resource.RUSAGE_CHILDREN)\n"
              "print(json.dumps({'rc': p.returncode, 'peak_mb': r.ru_maxrss / 1024.0,\n"
              "                  'seconds': time.monotonic() - t, 'out': p.stdout,\n"
              "                  'err': p.stderr[-3000:]}))\n")
    res = subprocess.run([sys.executable, "-c", helper, *cmd], capture_output=True, text=True,
                         env=env, check=True)
    got = json.loads(res.stdout.strip().splitlines()[-1])
    if got["rc"] != 0:
        raise RuntimeError(f"{' '.join(cmd[:4])} ... failed ({got['rc']}):\n{got['err']}")
    return got


def run_export_memory(character: str = "humanoid", frames: int = 1000, bvh: str | None = None,
                      clip: str = "", outputs=("glb", "usdc"), out: Path | None = None,
                      keep: bool = False) -> dict:
    """Peak RSS of exporting ``frames`` frames of ``character`` to each of ``outputs``
    (suffixes) at once, against deforming them alone.

    Returns
    -------
    dict
        ``export_peak_mb``, ``deform_only_peak_mb``, ``writing_mb`` (the
        difference), and per output its size, size per frame and (glTF) error.
    """
    if bvh is None and not clip:
        if not DEFAULT_BVH.exists():
            raise ValueError(f"{DEFAULT_BVH} is absent: give --bvh FILE or --clip NAME")
        bvh = str(DEFAULT_BVH)
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    with tempfile.TemporaryDirectory(prefix="skin_bench_export_") as tmp:
        files = [Path(out or tmp) / f"export_memory.{s}" for s in outputs]
        cmd = [sys.executable, "-m", "skin_node.io.export", "--character", character,
               "--frames", str(frames)] + (["--bvh", bvh] if bvh else ["--clip", clip])
        for f in files:
            f.parent.mkdir(parents=True, exist_ok=True)
            cmd += ["-o", str(f)]
        # The rig and the numba kernels from the cache for both runs alike.
        _measure([sys.executable, "-c", _DEFORM_ONLY, character, clip, bvh or "", "2"], env)
        alone = _measure([sys.executable, "-c", _DEFORM_ONLY, character, clip, bvh or "",
                          str(frames)], env)
        export = _measure(cmd, env)
        written = [line for line in export["out"].splitlines() if line.startswith("export: ")]
        res = {"character": character, "motion": Path(bvh).stem if bvh else clip,
               "frames": int(alone["out"].split()[-1]),
               "export_peak_mb": export["peak_mb"], "export_s": export["seconds"],
               "deform_only_peak_mb": alone["peak_mb"], "deform_only_s": alone["seconds"],
               "writing_mb": export["peak_mb"] - alone["peak_mb"],
               "outputs": {f.suffix: {"bytes": f.stat().st_size,
                                      "bytes_per_frame": f.stat().st_size / frames}
                           for f in files},
               "lines": written}
        if not keep and out is not None:
            for f in files:
                f.unlink(missing_ok=True)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / "export_memory.json").write_text(json.dumps(res, indent=1) + "\n")
    return res


def export_memory_line(res: dict) -> str:
    outs = ", ".join(f"{k} {v['bytes'] / 1e6:.1f} MB ({v['bytes_per_frame'] / 1e3:.0f} kB a "
                     f"frame)" for k, v in res["outputs"].items())
    return (f"export memory ({res['character']}, {res['frames']} frames of {res['motion']}): "
            f"peak {res['export_peak_mb']:.0f} MB writing {outs}, against "
            f"{res['deform_only_peak_mb']:.0f} MB deforming alone "
            f"({res['writing_mb']:+.0f} MB); {res['export_s']:.0f} s")
