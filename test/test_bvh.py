"""BVH parsing: real CMU files, channel orders, line endings, malformed input."""
from __future__ import annotations

import itertools
import sys
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from skin_node.io.bvh import CMU_SCALE, load_bvh, parse_bvh  # noqa: E402

BVH_DIR = REPO.parent / "shared" / "data" / "bvh"
CMU_FILES = {
    "cmu_02_01_walk.bvh": 344,
    "cmu_02_03_run_jog.bvh": 174,
    "cmu_09_01_run.bvh": 149,
    "cmu_02_05_punch_strike.bvh": 1855,
    "cmu_01_01_forward_jumps.bvh": 2752,
}


def cmu_path(name: str) -> Path:
    p = BVH_DIR / name
    if not p.is_file():
        pytest.skip(f"shared CMU data not found at {p}")
    return p


# Independent elementary rotations (right-handed, radians).
def rx(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def ry(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rz(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


ROT = {"X": rx, "Y": ry, "Z": rz}


# ------------------------------------------------------------------ CMU data
@pytest.mark.parametrize("name,n_frames", sorted(CMU_FILES.items()))
def test_cmu_files_parse(name, n_frames):
    b = load_bvh(cmu_path(name))
    assert b.n_frames == n_frames
    assert b.n_joints == 31 and b.n_channels == 96
    assert b.names[0] == "Hips" and b.parents[0] == -1
    assert b.channels[0] == ("Xposition", "Yposition", "Zposition",
                             "Zrotation", "Yrotation", "Xrotation")
    assert all(c == ("Zrotation", "Yrotation", "Xrotation") for c in b.channels[1:])
    assert b.frame_time == pytest.approx(1 / 120, rel=1e-4)
    assert len(b.end_parents) > 0
    G = b.world_matrices()
    assert G.shape == (n_frames, 31, 4, 4) and np.all(np.isfinite(G))
    R = G[..., :3, :3]
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape),
                               atol=1e-9)
    # A standing adult: hips about 0.9-1.1 m above the feet in metres.
    hips_y = b.root_positions()[:, 1]
    assert 0.5 < np.median(hips_y) < 1.2


def test_cmu_crlf_header_lf_data():
    p = cmu_path("cmu_02_01_walk.bvh")
    raw = p.read_bytes()
    assert b"\r\n" in raw and b"\n" in raw.replace(b"\r\n", b"")  # really mixed
    b = load_bvh(p)
    assert b.n_frames == 344
    # Same content with pure LF gives the same numbers.
    lf = parse_bvh(raw.decode().replace("\r\n", "\n"), "lf")
    np.testing.assert_array_equal(b.frames, lf.frames)
    np.testing.assert_array_equal(b.offsets, lf.offsets)


def test_cmu_first_frame_is_t_pose():
    b = load_bvh(cmu_path("cmu_02_01_walk.bvh"))
    P = b.world_matrices()[0, :, :3, 3]
    ix = b.index
    for hip, foot in (("LeftUpLeg", "LeftFoot"), ("RightUpLeg", "RightFoot")):
        d = P[ix(foot)] - P[ix(hip)]
        assert d[1] / np.linalg.norm(d) < -0.99  # legs straight down (-y)
    for arm, hand, side in (("LeftArm", "LeftHand", 1), ("RightArm", "RightHand", -1)):
        d = P[ix(hand)] - P[ix(arm)]
        assert side * d[0] / np.linalg.norm(d) > 0.98  # arms out along +-x
    assert P[ix("LeftUpLeg"), 0] > P[ix("RightUpLeg"), 0]  # left = +x: facing +z


def test_scale_argument():
    p = cmu_path("cmu_09_01_run.bvh")
    m, u = load_bvh(p), load_bvh(p, scale=1.0)
    np.testing.assert_allclose(m.offsets, u.offsets * CMU_SCALE)
    np.testing.assert_allclose(m.root_positions(), u.root_positions() * CMU_SCALE)
    np.testing.assert_allclose(u.root_positions(), u.frames[:, :3])
    np.testing.assert_array_equal(m.local_rotations(), u.local_rotations())


# ---------------------------------------------------------------- synthetic
def two_joint_bvh(root_channels: str, child_channels: str, rows: list, nl: str = "\n") -> str:
    n_root = len(root_channels.split())
    n_child = len(child_channels.split())
    lines = [
        "HIERARCHY", "ROOT base", "{", "\tOFFSET 0 0 0",
        f"\tCHANNELS {n_root} {root_channels}",
        "\tJOINT arm", "\t{", "\t\tOFFSET 1 2 3",
        f"\t\tCHANNELS {n_child} {child_channels}",
        "\t\tEnd Site", "\t\t{", "\t\t\tOFFSET 0 4 0", "\t\t}", "\t}", "}",
        "MOTION", f"Frames: {len(rows)}", "Frame Time: 0.04",
    ] + [" ".join(str(v) for v in r) for r in rows]
    return nl.join(lines) + nl


@pytest.mark.parametrize("order", ["".join(p) for p in itertools.permutations("XYZ")]
                         + ["X", "ZY", "YX"])
def test_channel_order_composition(order):
    rng = np.random.default_rng(len(order) * 7 + ord(order[0]))
    chans = " ".join(f"{a}rotation" for a in order)
    T = 5
    ang = rng.uniform(-170, 170, size=(T, 2, len(order)))
    pos = rng.uniform(-1, 1, size=(T, 3))
    rows = [list(pos[t]) + list(ang[t, 0]) + list(ang[t, 1]) for t in range(T)]
    text = two_joint_bvh(f"Xposition Yposition Zposition {chans}", chans, rows)
    b = parse_bvh(text, "synthetic", scale=1.0)
    R = b.local_rotations()
    G = b.world_matrices()
    for t in range(T):
        for j in range(2):
            M = np.eye(3)
            for k, a in enumerate(order):  # left-to-right: R = R_first @ R_second ...
                M = M @ ROT[a](np.deg2rad(ang[t, j, k]))
            np.testing.assert_allclose(R[t, j], M, atol=1e-12)
        Rroot = R[t, 0]
        np.testing.assert_allclose(G[t, 0, :3, 3], pos[t], atol=1e-12)
        np.testing.assert_allclose(G[t, 1, :3, 3], pos[t] + Rroot @ [1, 2, 3], atol=1e-12)
        np.testing.assert_allclose(G[t, 1, :3, :3], Rroot @ R[t, 1], atol=1e-12)
    tip = b.end_site_positions(G)
    np.testing.assert_allclose(tip[:, 0], G[:, 1, :3, 3] + G[:, 1, :3, :3] @ [0, 4, 0], atol=1e-12)


def test_position_channels_subset_and_order():
    # Root with only Y and X position (in that order), child with a position channel.
    text = two_joint_bvh("Yposition Xposition Zrotation", "Zposition Yrotation",
                         [[5, 7, 90, 10, 0]], nl="\n")
    b = parse_bvh(text, "synthetic", scale=2.0)
    t = b.local_translations()[0]
    np.testing.assert_allclose(t[0], [14, 10, 0])      # x from Xposition, y from Yposition
    np.testing.assert_allclose(t[1], [2, 4, 20])       # z replaced by the channel, scaled
    assert b.channel_names == ["base_Yposition", "base_Xposition", "base_Zrotation",
                               "arm_Zposition", "arm_Yrotation"]


@pytest.mark.parametrize("nl", ["\n", "\r\n", "\r"])
def test_line_endings_tabs_blank_lines(nl):
    rows = [[0, 1, 2, 10, 20, 30, 40, 50, 60], [1, 1, 1, -10, 5, 0, 3, 2, 1]]
    chans = "Zrotation Xrotation Yrotation"
    ref = parse_bvh(two_joint_bvh(f"Xposition Yposition Zposition {chans}", chans, rows),
                    "ref", 1.0)
    text = two_joint_bvh(f"Xposition Yposition Zposition {chans}", chans, rows, nl=nl)
    # Blank lines, tab separators and a mixed ending in the data.
    text = text.replace("MOTION", nl + "MOTION" + nl)
    text = text.replace("0 1 2 10", "0\t1 \t2  10", 1)
    text = text.replace("Frame Time: 0.04" + nl, "Frame Time:\t0.04" + nl + nl + "  " + nl)
    text = text.replace(nl + "1 1 1", "\r\n1 1 1")
    b = parse_bvh(text, "variant", 1.0)
    np.testing.assert_array_equal(b.frames, ref.frames)
    assert b.names == ["base", "arm"] and b.frame_time == 0.04


def test_end_site_only_and_no_channel_joint():
    text = ("HIERARCHY\nROOT r\n{\nOFFSET 0 0 0\nCHANNELS 3 Xposition Yposition Zposition\n"
            "JOINT fixed\n{\nOFFSET 0 1 0\nCHANNELS 0\nEnd Site\n{\nOFFSET 0 1 0\n}\n}\n}\n"
            "MOTION\nFrames: 2\nFrame Time: 0.5\n1 2 3\n4 5 6\n")
    b = parse_bvh(text, "s", 1.0)
    assert b.channels == [("Xposition", "Yposition", "Zposition"), ()]
    np.testing.assert_allclose(b.world_matrices()[:, 1, :3, 3], [[1, 3, 3], [4, 6, 6]])
    assert b.fps == 2.0


# ---------------------------------------------------------------- malformed
GOOD = two_joint_bvh("Xposition Yposition Zposition Zrotation Yrotation Xrotation",
                     "Zrotation Yrotation Xrotation", [[0] * 9, [1] * 9])


@pytest.mark.parametrize("text,pattern", [
    ("", r"empty"),
    ("\n \r\n\t\n", r"empty"),
    (GOOD.split("MOTION")[0], r"no MOTION"),
    (GOOD.replace("1 1 1 1 1 1 1 1 1", "1 1 1 1 1 1 1 1"), r"line 20: frame 2 has 8 values, expected 9"),
    (GOOD.replace("0 0 0 0 0 0 0 0 0", "0 0 0 0 0 0 0 0 0 0"), r"line 19: frame 1 has 10 values"),
    (GOOD.replace("CHANNELS 3 Zrotation", "CHANNELS 3 Wrotation"), r"line 9: unknown channel name 'Wrotation'"),
    (GOOD.replace("Frames: 2", "Frames: 3"), r"'Frames: 3' but 2 frame lines"),
    (GOOD.replace("Frames: 2", "Frames: two"), r"bad frame count"),
    (GOOD.split("Frames:")[0], r"lacks a 'Frames:' or 'Frame Time:'"),
    (GOOD.replace("Frame Time: 0.04", "Frame Time: 0"), r"frame time must be positive"),
    (GOOD.replace("Frame Time: 0.04\n", ""), r"line 18: expected 'Frame Time:'"),
    (GOOD.replace("1 1 1 1 1 1 1 1 1", "1 1 1 1 x 1 1 1 1"), r"line 20: 'x' is not a number"),
    (GOOD.replace("OFFSET 1 2 3", "OFFSET 1 2 z"), r"line 8: expected a number"),
    (GOOD.replace("\t\t}\n\t}\n}", "\t\t}\n\t}"), r"hierarchy ends early"),
    (GOOD.replace("JOINT arm", "BONE arm"), r"line 6: unexpected 'BONE'"),
    (GOOD.replace("ROOT base", "JOINT base"), r"expected ROOT"),
    (GOOD.replace("CHANNELS 3 Zrotation Yrotation Xrotation",
                  "CHANNELS 3 Zrotation Zrotation Xrotation"), r"repeats a channel"),
    (GOOD.replace("1 1 1 1 1 1 1 1 1", "1 1 1 1 nan 1 1 1 1"), r"line 20: frame contains NaN"),
])
def test_malformed_raises(tmp_path, text, pattern):
    p = tmp_path / "broken.bvh"
    p.write_text(text)
    with pytest.raises(ValueError, match=pattern) as e:
        load_bvh(p)
    assert "broken.bvh" in str(e.value)


def test_good_template_parses():
    b = parse_bvh(GOOD, "good", 1.0)
    assert b.n_frames == 2 and b.n_channels == 9
