"""Export a deformed animation for DCC tools: a USD point cache and a glTF with morph targets.

Both files hold the character's surface in every frame, so Blender, Maya or
Houdini play the skinning result without skin_node:

* **USD** (``.usda`` text, ``.usdc`` binary; written with ``usd-core``): one
  ``UsdGeom.Mesh`` at ``/Character/Skin`` whose ``points`` carry one time
  sample per frame (time code = frame index, ``timeCodesPerSecond`` = the
  clip's rate), with ``upAxis = Z`` and ``metersPerUnit = 1`` (the project's
  frame, no conversion). A glTF character is written in the file's vertex
  order with the file's triangles (seam vertices duplicated again), so the
  file's UVs still apply; built-ins and YAML characters in their own order.
* **glTF 2.0** (``.glb``): the first frame is the base mesh, every frame
  after it is a morph target (its displacement from the base), and one
  animation on the node's morph ``weights`` switches target ``k`` on at
  frame ``k`` (LINEAR, so players in between interpolate two frames).
  Points are turned from the project's z up to glTF's y up. Blender imports
  the targets as shape keys driven by the animation.

Command line (``python -m skin_node.io.export``)::

    python -m skin_node.io.export --character ../shared/data/rigged/CesiumMan.glb \\
        --bvh ../shared/data/bvh/cmu_02_01_walk.bvh -o walk.usdc -o walk.glb
    python -m skin_node.io.export --character humanoid --clip walk -o walk.usda
    python -m skin_node.io.export --character humanoid --bag recorded_bag -o rec.glb

The clip is a built-in one (``--clip NAME``), a glTF character's own animation
(``--clip NAME`` or ``gltf:NAME``, ``--clip file`` for the first, which is also
the default; sampled at ``--fps``, 120 by default), a BVH retargeted through
``--mapping`` (default
``config/cmu_to_<character name>.yaml``), or the ``skin/points`` messages of a
recorded rosbag2 bag (``--bag``; no deformation is run, the points are the
recorded ones, in the character's vertex order).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

#: The project's z up to glTF's y up (inverse of :data:`skin_node.io.gltf.Y_UP_TO_Z_UP`).
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


def _check_frames(frames: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    frames = np.asarray(frames, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64)
    if frames.ndim != 3 or frames.shape[2] != 3 or len(frames) == 0:
        raise ValueError(f"frames must have shape (T, n, 3) with T >= 1, got {frames.shape}")
    if not np.all(np.isfinite(frames)):
        raise ValueError("frames contain NaN or Inf")
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.min() < 0 or \
            faces.max() >= frames.shape[1]:
        raise ValueError(f"faces must be (m, 3) indices into the {frames.shape[1]} points")
    return frames, faces


# ---------------------------------------------------------------------- USD
def write_usd_point_cache(path: str | Path, frames: np.ndarray, faces: np.ndarray,
                          fps: float, name: str = "Skin") -> Path:
    """Write a USD point cache (``.usda`` or ``.usdc`` by suffix).

    Parameters
    ----------
    path : str or Path
    frames : (T, n, 3) float
        Points per frame, metres, z up.
    faces : (m, 3) int
    fps : float
        Frames per second (``timeCodesPerSecond``).
    name : str
        Prim name of the mesh under ``/Character``.

    Returns
    -------
    Path
    """
    from pxr import Gf, Sdf, Usd, UsdGeom, Vt
    path = Path(path)
    if path.suffix.lower() not in (".usda", ".usdc", ".usd"):
        raise ValueError(f"{path}: a USD point cache needs a .usda, .usdc or .usd name")
    frames, faces = _check_frames(frames, faces)
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 1.0)
    stage.SetTimeCodesPerSecond(float(fps))
    stage.SetFramesPerSecond(float(fps))
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(len(frames) - 1)
    root = UsdGeom.Xform.Define(stage, "/Character")
    stage.SetDefaultPrim(root.GetPrim())
    mesh = UsdGeom.Mesh.Define(stage, Sdf.Path(f"/Character/{name}"))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(faces)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(faces.ravel().tolist()))
    mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
    pts = mesh.CreatePointsAttr()
    lo, hi = frames.min(axis=(0, 1)), frames.max(axis=(0, 1))
    mesh.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*lo), Gf.Vec3f(*hi)]))
    for t, X in enumerate(frames):
        pts.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(X, dtype=np.float32)), float(t))
    stage.GetRootLayer().Save()
    return path


def read_usd_point_cache(path: str | Path) -> tuple[np.ndarray, np.ndarray, float]:
    """Read back :func:`write_usd_point_cache`'s file: (frames (T,n,3), faces (m,3), fps)."""
    from pxr import Usd, UsdGeom
    path = Path(path)
    stage = Usd.Stage.Open(str(path))
    if stage is None:
        raise ValueError(f"{path}: not a readable USD file")
    mesh = next((UsdGeom.Mesh(p) for p in stage.Traverse() if p.IsA(UsdGeom.Mesh)), None)
    if mesh is None:
        raise ValueError(f"{path}: holds no mesh")
    attr = mesh.GetPointsAttr()
    times = attr.GetTimeSamples() or [Usd.TimeCode.Default()]
    frames = np.stack([np.asarray(attr.Get(t), dtype=np.float64) for t in times])
    counts = np.asarray(mesh.GetFaceVertexCountsAttr().Get())
    if np.any(counts != 3):
        raise ValueError(f"{path}: only triangle meshes are read back")
    faces = np.asarray(mesh.GetFaceVertexIndicesAttr().Get(), dtype=np.int64).reshape(-1, 3)
    return frames, faces, float(stage.GetTimeCodesPerSecond())


# --------------------------------------------------------------------- glTF
def write_gltf_morph(path: str | Path, frames: np.ndarray, faces: np.ndarray,
                     fps: float, name: str = "Skin") -> Path:
    """Write a ``.glb`` whose morph targets replay ``frames``.

    Parameters
    ----------
    path : str or Path
        Output ``.glb``.
    frames : (T, n, 3) float
        Points per frame, metres, z up (written y up).
    faces : (m, 3) int
    fps : float

    Returns
    -------
    Path
    """
    import pygltflib as gl
    path = Path(path)
    if path.suffix.lower() != ".glb":
        raise ValueError(f"{path}: the glTF export writes binary .glb files")
    frames, faces = _check_frames(frames, faces)
    Y = (frames @ Z_UP_TO_Y_UP.T).astype(np.float32)
    base, T = Y[0], len(Y)
    blobs: list[bytes] = []
    views, accessors = [], []

    def add(arr: np.ndarray, kind: str, comp: int, target: int | None, minmax: bool = False):
        data = np.ascontiguousarray(arr).tobytes()
        off = sum(len(b) for b in blobs)
        blobs.append(data + b"\0" * (-len(data) % 4))
        views.append(gl.BufferView(buffer=0, byteOffset=off, byteLength=len(data), target=target))
        kw = {}
        if minmax:
            kw = {"min": arr.reshape(len(arr), -1).min(0).tolist(),
                  "max": arr.reshape(len(arr), -1).max(0).tolist()}
        accessors.append(gl.Accessor(bufferView=len(views) - 1, componentType=comp,
                                     count=len(arr), type=kind, **kw))
        return len(accessors) - 1

    pos = add(base, "VEC3", gl.FLOAT, gl.ARRAY_BUFFER, minmax=True)
    idx = add(faces.astype(np.uint32).ravel(), "SCALAR", gl.UNSIGNED_INT, gl.ELEMENT_ARRAY_BUFFER)
    targets = [{"POSITION": add(Y[k] - base, "VEC3", gl.FLOAT, gl.ARRAY_BUFFER, minmax=True)}
               for k in range(1, T)]
    prim = gl.Primitive(attributes=gl.Attributes(POSITION=pos), indices=idx, mode=gl.TRIANGLES,
                        targets=targets or None)
    mesh = gl.Mesh(name=name, primitives=[prim], weights=[0.0] * (T - 1) if T > 1 else None,
                   extras={"targetNames": [f"frame{k}" for k in range(1, T)]} if T > 1 else {})
    g = gl.GLTF2(asset=gl.Asset(version="2.0", generator="skin_node export"),
                 scene=0, scenes=[gl.Scene(nodes=[0])], nodes=[gl.Node(name=name, mesh=0)],
                 meshes=[mesh])
    if T > 1:
        times = (np.arange(T) / float(fps)).astype(np.float32)
        W = np.zeros((T, T - 1), dtype=np.float32)
        W[np.arange(1, T), np.arange(T - 1)] = 1.0
        t_acc = add(times, "SCALAR", gl.FLOAT, None, minmax=True)
        w_acc = add(W.ravel(), "SCALAR", gl.FLOAT, None)
        g.animations = [gl.Animation(name="deformation",
                                     samplers=[gl.AnimationSampler(input=t_acc, output=w_acc,
                                                                   interpolation="LINEAR")],
                                     channels=[gl.AnimationChannel(
                                         sampler=0, target=gl.AnimationChannelTarget(
                                             node=0, path="weights"))])]
    blob = b"".join(blobs)
    g.buffers = [gl.Buffer(byteLength=len(blob))]
    g.bufferViews, g.accessors = views, accessors
    g.set_binary_blob(blob)
    g.save_binary(str(path))
    return path


def read_gltf_morph(path: str | Path) -> tuple[np.ndarray, np.ndarray, float]:
    """Read back :func:`write_gltf_morph`'s file: (frames (T,n,3) z up, faces, fps).

    Frame ``k`` is the base plus the targets weighted by the animation's
    ``k``-th key (any morph animation of the first mesh node is evaluated at
    its keys).
    """
    from .gltf import Y_UP_TO_Z_UP, _read_document, _Reader
    path = Path(path)
    g = _read_document(path)
    rd = _Reader(path, g)
    prim = g.meshes[0].primitives[0]
    base = rd.read(prim.attributes.POSITION, "POSITION")
    faces = rd.read(prim.indices, "indices").reshape(-1, 3)
    D = np.stack([rd.read(t["POSITION"], "target") for t in (prim.targets or [])]) \
        if prim.targets else np.zeros((0,) + base.shape)
    frames, fps = base[None], 0.0
    if g.animations and len(D):
        a = g.animations[0]
        s = a.samplers[a.channels[0].sampler]
        times = rd.read(s.input, "times").ravel()
        W = rd.read(s.output, "weights").reshape(len(times), len(D))
        frames = base[None] + np.einsum("tk,knc->tnc", W, D)
        fps = 1.0 / float(np.median(np.diff(times))) if len(times) > 1 else 0.0
    return frames @ Y_UP_TO_Z_UP.T, faces, fps


# --------------------------------------------------------------------- bags
def read_bag_points(path: str | Path, topic: str = "skin/points") -> tuple[np.ndarray, float]:
    """(frames (T, n, 3), fps) of the PointCloud2 messages of a bag (rosbag2 or
    ROS 1, :class:`~skin_node.io.bags.BagReader`).

    The rate is the median rate of the messages' log times.
    """
    from .bags import BagReader
    cloud = "sensor_msgs/msg/PointCloud2"
    out, stamps = [], []
    with BagReader(path) as reader:
        for _, t, raw in reader.messages(cloud, topic):
            msg = reader.deserialize(raw, cloud)
            off = {f.name: f.offset for f in msg.fields}
            if not {"x", "y", "z"} <= set(off) or msg.is_bigendian:
                raise ValueError(f"{path}: {topic} messages need little-endian x, y, z fields")
            n = msg.width * msg.height
            data = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(n, msg.point_step)
            xyz = np.stack([data[:, off[k]:off[k] + 4].copy().view("<f4")[:, 0]
                            for k in "xyz"], axis=1)
            out.append(xyz.astype(np.float64))
            stamps.append(t)
        if not out and not any(m == cloud and t.lstrip("/") == topic.lstrip("/")
                               for t, m in reader.connections):
            raise ValueError(f"{path}: no {cloud} topic {topic}; it holds {reader.describe()}")
    if not out:
        raise ValueError(f"{path}: no messages on {topic}")
    if len({len(x) for x in out}) != 1:
        raise ValueError(f"{path}: {topic} messages differ in point count")
    dt = np.median(np.diff(stamps)) * 1e-9 if len(stamps) > 1 else 0.0
    return np.stack(out), (1.0 / dt if dt > 0 else 30.0)


# ---------------------------------------------------------------------- CLI
def deform_clip(character, frames: np.ndarray, pipeline: str = "default",
                **params) -> np.ndarray:
    """(T, n, 3) surfaces of ``character`` over pose ``frames`` (T, C)."""
    from ..pipeline import Pipeline
    pipe = Pipeline.preset(character, pipeline, **params)
    return np.stack([pipe.deform(q) for q in frames])


def _load_motion(args, ch) -> tuple[str, np.ndarray, float]:
    from ..motion import GLTF_PREFIX, load_motion
    clip = f"{GLTF_PREFIX}0" if args.clip == "file" else args.clip
    c = load_motion(args.character, clip, args.bvh, args.mapping, args.fps or None,
                    skeleton=ch.skeleton)
    return c.name, np.asarray(c.frames), float(c.fps)


def _parse(argv):
    ap = argparse.ArgumentParser(prog="python -m skin_node.io.export",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--character", required=True, help="arm | humanoid | character file")
    ap.add_argument("--weights", default="automatic", choices=("automatic", "file"))
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--clip", default="", help="built-in clip, or a glTF character's "
                     "animation (NAME, gltf:NAME; 'file' for its first)")
    src.add_argument("--bvh", default="", help="BVH file to retarget")
    src.add_argument("--bag", default="", help="rosbag2 bag with recorded skin/points")
    ap.add_argument("--mapping", default="", help="retarget mapping YAML for --bvh")
    ap.add_argument("--topic", default="skin/points", help="points topic of --bag")
    ap.add_argument("--pipeline", default="default", help="preset: lbs, dqs, paper, default")
    ap.add_argument("--step", type=int, default=1, help="keep every N-th frame")
    ap.add_argument("--frames", type=int, default=0, help="stop after N frames (0: all)")
    ap.add_argument("--fps", type=float, default=0.0,
                    help="sampling rate of a glTF animation (default 120)")
    ap.add_argument("-o", "--output", action="append", required=True,
                    help=".usda/.usdc/.usd and/or .glb (repeatable)")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    """Entry point; 0 on success, 2 on bad input."""
    args = _parse(sys.argv[1:] if argv is None else argv)
    try:
        from ..character import load_character
        ch = load_character(args.character, weights=args.weights)
        if args.step < 1:
            raise ValueError(f"--step must be >= 1, got {args.step}")
        if args.bag:
            X, fps = read_bag_points(args.bag, args.topic)
            if X.shape[1] != len(ch.V):
                raise ValueError(f"{args.bag}: {X.shape[1]} points per message, but "
                                 f"{args.character} has {len(ch.V)} vertices")
            name = Path(args.bag).name
        else:
            name, q, fps = _load_motion(args, ch)
            q = q[::args.step][:args.frames or None]
            X = deform_clip(ch, q, args.pipeline)
        if args.bag:
            X = X[::args.step][:args.frames or None]
        fps = fps / args.step
        faces = ch.F
        if Path(args.character).suffix.lower() in (".glb", ".gltf"):
            from .gltf import load_gltf
            g = load_gltf(args.character)
            X, faces = g.to_file_order(X), g.file_faces
        for out in args.output:
            suffix = Path(out).suffix.lower()
            if suffix == ".glb":
                write_gltf_morph(out, X, faces, fps, name=ch.name)
            elif suffix in (".usda", ".usdc", ".usd"):
                write_usd_point_cache(out, X, faces, fps, name=_prim_name(ch.name))
            else:
                raise ValueError(f"{out}: unknown output type (use .usda, .usdc, .usd or .glb)")
            print(f"export: {out}: {len(X)} frames of {X.shape[1]} points at {fps:g} fps "
                  f"({name})")
    except (ValueError, OSError, KeyError) as e:
        print(f"export: error: {e}", file=sys.stderr)
        return 2
    return 0


def _prim_name(name: str) -> str:
    s = "".join(c if c.isalnum() or c == "_" else "_" for c in name) or "Skin"
    return s if not s[0].isdigit() else f"_{s}"


if __name__ == "__main__":
    sys.exit(main())
