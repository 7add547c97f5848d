"""DCC export: USD point caches and glTF morph targets reload with the same points,
from arrays, from a clip on a glTF character, and from a recorded bag."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pxr")
pytest.importorskip("pygltflib")

from skin_node.io.export import (GltfMorphWriter, UsdPointCacheWriter, main,  # noqa: E402
                                 read_bag_points, read_gltf_morph, read_usd_point_cache,
                                 write_gltf_morph, write_usd_point_cache)

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def rigged(name: str) -> Path:
    p = DATA / "rigged" / name
    if not p.exists():
        pytest.skip(f"test data {p} is absent")
    return p


def tetra_frames(T: int = 5):
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    t = np.arange(T)[:, None, None]
    X = V[None] + 0.1 * np.sin(t + np.arange(4)[None, :, None] + np.arange(3)[None, None, :])
    return X, F


@pytest.mark.parametrize("suffix", [".usda", ".usdc"])
def test_usd_round_trip(tmp_path, suffix):
    X, F = tetra_frames()
    p = write_usd_point_cache(tmp_path / f"c{suffix}", X, F, fps=24.0)
    Y, G, fps = read_usd_point_cache(p)
    assert fps == 24.0 and np.array_equal(G, F)
    assert Y.shape == X.shape and np.abs(Y - X).max() < 1e-6     # float32 points
    from pxr import Usd, UsdGeom
    stage = Usd.Stage.Open(str(p))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.z
    assert UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    assert stage.GetEndTimeCode() == len(X) - 1


def test_gltf_morph_round_trip(tmp_path):
    X, F = tetra_frames(7)
    p = write_gltf_morph(tmp_path / "c.glb", X, F, fps=30.0, quantize=False)
    Y, G, fps = read_gltf_morph(p)
    assert np.array_equal(G, F) and fps == pytest.approx(30.0, rel=1e-6)
    assert Y.shape == X.shape and np.abs(Y - X).max() < 1e-6
    # another reader sees the base mesh, turned to glTF's y up
    import trimesh
    scene = trimesh.load(p, process=False)
    m = next(iter(scene.geometry.values())) if hasattr(scene, "geometry") else scene
    assert np.allclose(np.asarray(m.vertices), X[0][:, [0, 2, 1]] * [1, 1, -1], atol=1e-6)


def walking_blob(T: int = 40, n: int = 300, seed: int = 0):
    """A closed-ish point set walking 6 m along x while it deforms by up to 5 cm."""
    rng = np.random.default_rng(seed)
    V = rng.standard_normal((n, 3)) * [0.2, 0.15, 0.8] + [0, 0, 1]
    F = np.stack([np.arange(n - 2), np.arange(1, n - 1), np.arange(2, n)], 1)
    t = np.arange(T)[:, None, None] / T
    X = V[None] + [6.0, 0.0, 0.0] * t + 0.05 * np.sin(7 * t + V[None, :, :1] * 3)
    return X, F


def test_quantized_targets_error_is_what_the_writer_reports(tmp_path):
    """16-bit targets: the translation carries the walk, so the step is set by the
    5 cm deformation, not the 6 m travel; the reported error is the real one."""
    X, F = walking_blob()
    with GltfMorphWriter(tmp_path / "q.glb", F, 30.0) as w:
        for x in X:
            w.add(x)
    st = w.close()
    Y, G, fps = read_gltf_morph(tmp_path / "q.glb")
    err = np.abs(Y - X).max() * 1000.0
    assert st["quantized"] and st["frames"] == 40 and fps == pytest.approx(30.0)
    import pygltflib
    doc = pygltflib.GLTF2().load_binary(str(tmp_path / "q.glb"))
    scale = doc.nodes[0].scale[0]         # the targets' range: the deformation, not the walk
    assert 0.05 < scale < 0.2, scale
    assert st["error_mm"] <= 1000 * scale / (2 * 32767) * (1 + 1e-6)      # half a step
    # float32 positions 7 m from the origin are 0.0005 mm apart: the rest of the error
    assert err < st["error_mm"] + 0.001, (err, st["error_mm"])
    assert np.array_equal(G, F)
    lossless = write_gltf_morph(tmp_path / "f.glb", X, F, 30.0, quantize=False)
    assert np.abs(read_gltf_morph(lossless)[0] - X).max() < 1e-5
    # int16 with a 4-byte stride against float32: 8 against 12 bytes a point
    ratio = st["bytes"] / lossless.stat().st_size
    assert 0.6 < ratio < 0.75, ratio
    assert doc.extensionsRequired == ["KHR_mesh_quantization"]
    assert doc.accessors[doc.meshes[0].primitives[0].targets[0]["POSITION"]].normalized


def test_a_target_where_little_moves_is_sparse(tmp_path):
    X, F = walking_blob(T=6)
    X = np.repeat(X[:1], 6, axis=0)
    X[1:, :5] += 0.01 * np.arange(1, 6)[:, None, None]          # five points move
    sparse = write_gltf_morph(tmp_path / "s.glb", X, F, 30.0)
    Y = read_gltf_morph(sparse)[0]
    assert np.abs(Y - X).max() < 1e-5
    import pygltflib
    doc = pygltflib.GLTF2().load_binary(str(sparse))
    accs = [doc.accessors[t["POSITION"]] for t in doc.meshes[0].primitives[0].targets]
    assert [a.sparse.count for a in accs] == [5] * 5 and all(a.bufferView is None for a in accs)
    # the weights' keys: one 1 per frame, sparse, not a 6 x 5 table
    w = doc.accessors[doc.animations[0].samplers[1].output]
    assert w.count == 30 and w.sparse.count == 5
    dense = write_gltf_morph(tmp_path / "d.glb", walking_blob(T=6)[0], F, 30.0)
    assert sparse.stat().st_size < 0.5 * dense.stat().st_size


def test_usd_writers_stream_and_save_as_they_go(tmp_path, monkeypatch):
    import skin_node.io.export as ex
    monkeypatch.setattr(ex, "USD_SAVE_EVERY", 4)
    X, F = walking_blob(T=10, n=50)
    for suffix in (".usdc", ".usda"):
        sizes = []
        with UsdPointCacheWriter(tmp_path / f"w{suffix}", F, 24.0) as w:
            for x in X:
                w.add(x)
                sizes.append(w.path.stat().st_size if w.path.exists() else 0)
        if suffix == ".usdc":     # saved after frames 4 and 8: the file grew then only
            grew = [k + 1 for k in range(1, len(sizes)) if sizes[k] > sizes[k - 1]]
            assert grew == [4, 8], sizes
        else:                     # the text file is written whole at the end
            assert sizes == [0] * len(X)
        Y, G, fps = read_usd_point_cache(tmp_path / f"w{suffix}")
        assert fps == 24.0 and np.array_equal(G, F) and np.abs(Y - X).max() < 1e-6
    with pytest.raises(ValueError, match="frame 1 has shape"):
        with UsdPointCacheWriter(tmp_path / "bad.usdc", F, 24.0) as w:
            w.add(X[0])
            w.add(X[0][:10])
    assert not (tmp_path / "bad.usdc").exists()               # no half-written file left


def test_single_frame_and_bad_input(tmp_path):
    X, F = tetra_frames(1)
    Y, _, _ = read_gltf_morph(write_gltf_morph(tmp_path / "one.glb", X, F, fps=30.0))
    assert np.allclose(Y, X, atol=1e-6)
    with pytest.raises(ValueError, match="NaN"):
        write_usd_point_cache(tmp_path / "nan.usda", np.full((1, 4, 3), np.nan), F, 30.0)
    with pytest.raises(ValueError, match=r"faces must be"):
        write_gltf_morph(tmp_path / "f.glb", X, F + 10, 30.0)
    with pytest.raises(ValueError, match=r"x\.obj: a USD point cache"):
        write_usd_point_cache(tmp_path / "x.obj", X, F, 30.0)


def test_cli_exports_a_gltf_characters_own_clip(tmp_path, monkeypatch, capsys):
    """RiggedFigure driven by its own animation under LBS with the file's weights:
    both files reload with the file's vertex order and the pipeline's points."""
    monkeypatch.setenv("SKIN_NODE_CACHE", str(tmp_path / "cache"))
    path = rigged("RiggedFigure.glb")
    usd, glb = tmp_path / "fig.usdc", tmp_path / "fig.glb"
    assert main(["--character", str(path), "--clip", "file", "--fps", "30", "--weights", "file",
                 "--pipeline", "lbs", "--step", "3", "--frames", "6",
                 "-o", str(usd), "-o", str(glb)]) == 0
    out = capsys.readouterr().out
    assert "6 frames of 370 points" in out and out.count("kB a frame") == 2
    assert "targets quantized to 16 bits (largest error" in out
    from skin_node import Pipeline, load_character
    from skin_node.io.gltf import load_gltf
    g = load_gltf(path)
    ch = load_character(str(path), weights="file", progress=False)
    q = g.clip(fps=30.0).frames[::3][:6]
    pipe = Pipeline.preset(ch, "lbs")
    want = g.to_file_order(np.stack([pipe.deform(x) for x in q]))
    for reader, f in ((read_usd_point_cache, usd), (read_gltf_morph, glb)):
        X, faces, fps = reader(f)
        assert np.array_equal(faces, g.file_faces)
        assert fps == pytest.approx(10.0, rel=1e-6)
        assert np.abs(X - want).max() < 1e-5


def test_cli_errors_name_the_problem(tmp_path, capsys):
    assert main(["--character", str(tmp_path / "none.glb"), "--clip", "file",
                 "-o", str(tmp_path / "x.glb")]) == 2
    assert "none.glb: no such file" in capsys.readouterr().err


def write_points_bag(path: Path, frames: np.ndarray, hz: float = 50.0) -> None:
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore
    ts = get_typestore(Stores.ROS2_JAZZY)
    PC2, PF = ts.types["sensor_msgs/msg/PointCloud2"], ts.types["sensor_msgs/msg/PointField"]
    Header, Time = ts.types["std_msgs/msg/Header"], ts.types["builtin_interfaces/msg/Time"]
    fields = [PF(name=k, offset=4 * i, datatype=7, count=1) for i, k in enumerate("xyz")]
    with Writer(path, version=8) as w:
        conn = w.add_connection("/skin/points", PC2.__msgtype__, typestore=ts)
        for k, X in enumerate(frames):
            t = 10**18 + int(k * 1e9 / hz)
            data = np.ascontiguousarray(X, dtype="<f4").view(np.uint8).ravel()
            msg = PC2(header=Header(stamp=Time(sec=t // 10**9, nanosec=t % 10**9), frame_id="w"),
                      height=1, width=len(X), fields=fields, is_bigendian=False, point_step=12,
                      row_step=12 * len(X), data=data, is_dense=True)
            w.write(conn, t, ts.serialize_cdr(msg, PC2.__msgtype__))


def test_cli_exports_a_recorded_bag(tmp_path, monkeypatch):
    pytest.importorskip("rosbags")
    monkeypatch.setenv("SKIN_NODE_CACHE", str(tmp_path / "cache"))
    path = rigged("RiggedFigure.glb")
    from skin_node.io.gltf import load_gltf
    g = load_gltf(path)
    rng = np.random.default_rng(0)
    frames = g.V[None] + 0.01 * rng.standard_normal((4,) + g.V.shape)
    bag = tmp_path / "rec"
    write_points_bag(bag, frames)
    X, fps = read_bag_points(bag)
    assert fps == pytest.approx(50.0) and np.abs(X - frames).max() < 1e-6
    out = tmp_path / "rec.usda"
    assert main(["--character", str(path), "--bag", str(bag), "-o", str(out)]) == 0
    Y, faces, fps = read_usd_point_cache(out)
    assert fps == pytest.approx(50.0) and np.array_equal(faces, g.file_faces)
    assert np.abs(Y - g.to_file_order(frames)).max() < 1e-6
    with pytest.raises(ValueError, match="no sensor_msgs/msg/PointCloud2 topic"):
        read_bag_points(bag, "skin/other")
