"""Render the README's figure: z-buffer close-ups of LBS, DQS, the paper's
method and skin_node's default side by side.

    python tools/render.py docs/skin_node.png

Rows and colours as :mod:`skin_node.bench.pictures` (``skin_bench pictures``)
draws them: red faces belong to intersecting triangle pairs, blue faces are
seen from behind.
"""
from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from skin_node.bench.pictures import closeups  # noqa: E402


def main(out: str = "docs/skin_node.png") -> None:
    print(f"wrote {closeups(Path(out), size=200)}")


if __name__ == "__main__":
    main(*sys.argv[1:])
