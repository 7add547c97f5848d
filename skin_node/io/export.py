"""Export a deformed animation for DCC tools: a USD point cache and a glTF with morph targets.

Both files hold the character's surface in every frame, so Blender, Maya or
Houdini play the skinning result without skin_node. Frames are written as
they are made (:class:`UsdPointCacheWriter`, :class:`GltfMorphWriter`), so
memory stays flat in the number of frames:

* **USD** (``.usda`` text, ``.usdc`` / ``.usd`` binary): one ``UsdGeom.Mesh``
  at ``/Character/Skin`` whose ``points`` carry one time sample per frame
  (time code = frame index, ``timeCodesPerSecond`` = the clip's rate), with
  ``upAxis = Z`` and ``metersPerUnit = 1`` (the project's frame, no
  conversion). The binary file is written with ``usd-core`` and saved every
  :data:`USD_SAVE_EVERY` frames (a crate file appends what is new and lets go
  of the saved samples); the text file is streamed by this module, since a
  text layer is only ever written whole. A glTF character is written in the
  file's vertex order with the file's triangles (seam vertices duplicated
  again), so the file's UVs still apply: every part of it, the simulated
  body's meshes first, then the passengers' (``Character.file_order``), each
  in the file's node order; built-ins and YAML characters in their own order.
* **glTF 2.0** (``.glb``): the first frame is the base mesh, every frame
  after it is a morph target, and one animation switches target ``k`` on at
  frame ``k`` (LINEAR, so players in between interpolate two frames). Each
  frame's median displacement goes into the node's translation (animated
  alongside), so a walk's forward travel does not widen the targets' range.
  Targets are quantized (``KHR_mesh_quantization``: signed 16-bit
  normalized, scaled by the node's scale to the largest displacement of the
  take), with an error of at most half a step (reported: a few hundredths of
  a millimetre on a walk); ``quantize=False`` keeps float32. A target in
  which most vertices do not move is stored sparse (only those that do).
  The morph weights' keys are a sparse accessor too (one 1 per frame, not a
  T x T table). Displacements go to a temporary file next to the output as
  frames come; the ``.glb`` is assembled from it at the end. Points are
  turned from the project's z up to glTF's y up. Blender imports the targets
  as shape keys driven by the animation.

Command line (``python -m skin_node.io.export``)::

    python -m skin_node.io.export --character ../shared/data/rigged/CesiumMan.glb \\
        --bvh ../shared/data/bvh/cmu_02_01_walk.bvh -o walk.usdc -o walk.glb
    python -m skin_node.io.export --character humanoid --clip walk -o walk.usda
    python -m skin_node.io.export --character humanoid --bag recorded_bag -o rec.glb

The clip is a built-in one (``--clip NAME``), a glTF character's own animation
(``--clip NAME`` or ``gltf:NAME``, ``--clip file`` for the first, which is also
the default; sampled at ``--fps``, 120 by default), a BVH retargeted through
``--mapping`` (default ``config/cmu_to_<character name>.yaml``, else for a
mesh fitted to a template the template's), or the
``skin/points`` messages of a recorded bag (rosbag2 or ROS 1; ``--bag``; no
deformation is run, the points are the recorded ones, in the character's
vertex order). Each output's line reports its size per frame (and for a
quantized glTF, its largest error).
"""
from __future__ import annotations

import argparse
import json
import struct
import sys
import tempfile
import time
from pathlib import Path
from typing import Iterator

import numpy as np

from ..character import load_character
from ..motion import GLTF_PREFIX, load_motion
from ..pipeline import Pipeline
from .bags import BagReader
from .gltf import Y_UP_TO_Z_UP, _read_document, _Reader

#: The project's z up to glTF's y up (inverse of :data:`skin_node.io.gltf.Y_UP_TO_Z_UP`).
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
#: Frames between saves of a binary USD file: each save appends, then frees, them.
USD_SAVE_EVERY = 32
#: Largest value of a signed 16-bit normalized component.
_Q = 32767


def _check_faces(faces, n: int | None = None) -> np.ndarray:
    faces = np.asarray(faces, dtype=np.int64)
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0 or faces.min() < 0 or \
            (n is not None and faces.max() >= n):
        raise ValueError(f"faces must be (m, 3) indices into the {n if n else '?'} points")
    return faces


def _check_frames(frames: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    frames = np.asarray(frames, dtype=np.float64)
    if frames.ndim != 3 or frames.shape[2] != 3 or len(frames) == 0:
        raise ValueError(f"frames must have shape (T, n, 3) with T >= 1, got {frames.shape}")
    if not np.all(np.isfinite(frames)):
        raise ValueError("frames contain NaN or Inf")
    return frames, _check_faces(faces, frames.shape[1])


class _Writer:
    """What both writers share: per-frame checks, the file's size, cleanup on failure."""

    def __init__(self, path: str | Path, faces, fps: float, suffixes: tuple, what: str) -> None:
        self.path = Path(path)
        if self.path.suffix.lower() not in suffixes:
            raise ValueError(f"{self.path}: {what} needs a {' or '.join(suffixes)} name")
        if not fps > 0:
            raise ValueError(f"{self.path}: frame rate must be > 0, got {fps}")
        self.faces, self.fps = _check_faces(faces), float(fps)
        self.frames, self.n = 0, None
        self.lo, self.hi = np.full(3, np.inf), np.full(3, -np.inf)
        self._closed = None             # the figures, once closed

    def _frame(self, X) -> np.ndarray:
        X = np.asarray(X, dtype=np.float64)
        if self.n is None:
            if X.ndim != 2 or X.shape[1] != 3:
                raise ValueError(f"a frame must have shape (n, 3), got {X.shape}")
            self.n = len(X)
            _check_faces(self.faces, self.n)
        if X.shape != (self.n, 3):
            raise ValueError(f"frame {self.frames} has shape {X.shape}, expected ({self.n}, 3)")
        if not np.all(np.isfinite(X)):
            raise ValueError(f"frame {self.frames} contains NaN or Inf")
        self.lo, self.hi = np.minimum(self.lo, X.min(0)), np.maximum(self.hi, X.max(0))
        self.frames += 1
        return X

    def stats(self, **extra) -> dict:
        size = self.path.stat().st_size
        return {"path": str(self.path), "frames": self.frames, "points": self.n, "bytes": size,
                "bytes_per_frame": size / max(self.frames, 1), **extra}

    def close(self) -> dict:
        """Finish the file (once); returns its figures (frames, bytes, bytes per frame)."""
        if self._closed is None:
            if not self.frames:
                raise ValueError(f"{self.path}: no frames to write")
            self._closed = self._finish()
        return self._closed

    def __enter__(self):
        return self

    def __exit__(self, kind, value, tb) -> None:
        if kind is None:
            self.close()
        else:
            self.abort()

    def abort(self) -> None:
        """Drop a file that will not be finished."""
        self.path.unlink(missing_ok=True)


# ---------------------------------------------------------------------- USD
class UsdPointCacheWriter(_Writer):
    """A USD point cache written frame by frame (``.usda``, ``.usdc`` or ``.usd``).

    Parameters
    ----------
    path : str or Path
    faces : (m, 3) int
    fps : float
        Frames per second (``timeCodesPerSecond``).
    name : str
        Prim name of the mesh under ``/Character``.

    Call :meth:`add` with each frame's (n, 3) points (metres, z up), then
    :meth:`close`, which returns the file's figures.
    """

    def __init__(self, path: str | Path, faces, fps: float, name: str = "Skin") -> None:
        super().__init__(path, faces, fps, (".usda", ".usdc", ".usd"), "a USD point cache")
        self.name = name
        self.text = self.path.suffix.lower() == ".usda"
        if self.text:
            self._body = tempfile.TemporaryFile("w+", dir=self.path.parent, suffix=".usda.part")
            return
        from pxr import Sdf, Usd, UsdGeom, Vt    # deferred: usd-core, only binary USD needs it
        self._Vt = Vt
        self.path.unlink(missing_ok=True)
        self._stage = Usd.Stage.CreateNew(str(self.path))
        UsdGeom.SetStageUpAxis(self._stage, UsdGeom.Tokens.z)
        UsdGeom.SetStageMetersPerUnit(self._stage, 1.0)
        self._stage.SetTimeCodesPerSecond(self.fps)
        self._stage.SetFramesPerSecond(self.fps)
        self._stage.SetStartTimeCode(0)
        root = UsdGeom.Xform.Define(self._stage, "/Character")
        self._stage.SetDefaultPrim(root.GetPrim())
        self._mesh = UsdGeom.Mesh.Define(self._stage, Sdf.Path(f"/Character/{name}"))
        self._mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
        self._mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(self.faces)))
        self._mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(self.faces.ravel().tolist()))
        self._mesh.CreateOrientationAttr(UsdGeom.Tokens.rightHanded)
        self._points = self._mesh.CreatePointsAttr()

    def add(self, X: np.ndarray) -> None:
        """Write one frame's (n, 3) points."""
        k = self.frames
        X = np.ascontiguousarray(self._frame(X), dtype=np.float32)
        if self.text:
            self._body.write(f"            {k}: [" + _usda_points(X) + "],\n")
            return
        self._points.Set(self._Vt.Vec3fArray.FromNumpy(X), float(k))
        if self.frames % USD_SAVE_EVERY == 0:
            self._stage.GetRootLayer().Save()

    def _finish(self) -> dict:
        if self.text:
            self._write_text()
        else:
            from pxr import Gf                   # deferred: usd-core, as above
            self._mesh.CreateExtentAttr(self._Vt.Vec3fArray([Gf.Vec3f(*self.lo),
                                                             Gf.Vec3f(*self.hi)]))
            self._stage.SetEndTimeCode(self.frames - 1)
            self._stage.GetRootLayer().Save()
            self._stage = self._mesh = self._points = None
        return self.stats()

    def _write_text(self) -> None:
        fps = f"{self.fps:.17g}"
        lo, hi = (", ".join(f"{float(np.float32(v)):.9g}" for v in b) for b in (self.lo, self.hi))
        head = (f'#usda 1.0\n(\n    defaultPrim = "Character"\n    endTimeCode = '
                f'{self.frames - 1}\n    framesPerSecond = {fps}\n    metersPerUnit = 1\n'
                f'    startTimeCode = 0\n    timeCodesPerSecond = {fps}\n    upAxis = "Z"\n)\n\n'
                f'def Xform "Character"\n{{\n    def Mesh "{self.name}"\n    {{\n'
                f"        float3[] extent = [({lo}), ({hi})]\n"
                f"        int[] faceVertexCounts = [{', '.join(['3'] * len(self.faces))}]\n"
                f"        int[] faceVertexIndices = [{', '.join(map(str, self.faces.ravel()))}]\n"
                f'        uniform token orientation = "rightHanded"\n'
                f"        point3f[] points.timeSamples = {{\n")
        tail = '        }\n        uniform token subdivisionScheme = "none"\n    }\n}\n\n'
        self._body.seek(0)
        with open(self.path, "w") as out:
            out.write(head)
            while chunk := self._body.read(1 << 20):
                out.write(chunk)
            out.write(tail)
        self._body.close()

    def abort(self) -> None:
        if self.text:
            self._body.close()
        self._stage = None
        super().abort()


def _usda_points(X: np.ndarray) -> str:
    """``(x, y, z), ...`` of float32 points, each value printed so it reads back exactly."""
    return ("(%.9g, %.9g, %.9g), " * len(X) % tuple(X.ravel().tolist()))[:-2]


def write_usd_point_cache(path: str | Path, frames: np.ndarray, faces: np.ndarray,
                          fps: float, name: str = "Skin") -> Path:
    """Write a USD point cache (``.usda`` or ``.usdc`` by suffix) of (T, n, 3) ``frames``
    (metres, z up) with :class:`UsdPointCacheWriter`.

    Returns
    -------
    Path
    """
    frames, faces = _check_frames(frames, faces)
    with UsdPointCacheWriter(path, faces, fps, name) as w:
        for X in frames:
            w.add(X)
    return w.path


def read_usd_point_cache(path: str | Path) -> tuple[np.ndarray, np.ndarray, float]:
    """Read back :func:`write_usd_point_cache`'s file: (frames (T,n,3), faces (m,3), fps)."""
    from pxr import Usd, UsdGeom                 # deferred: usd-core, only USD files need it
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
class GltfMorphWriter(_Writer):
    """A ``.glb`` whose morph targets replay the frames, written frame by frame.

    Parameters
    ----------
    path : str or Path
        Output ``.glb``.
    faces : (m, 3) int
    fps : float
    name : str
        Mesh and node name.
    quantize : bool
        Targets as 16-bit integers (``KHR_mesh_quantization``); False: float32.

    :meth:`add` takes each frame's (n, 3) points (metres, z up); :meth:`close`
    writes the file and returns its figures, with ``error_mm``, the largest
    difference between a written and a given displacement.
    """

    def __init__(self, path: str | Path, faces, fps: float, name: str = "Skin",
                 quantize: bool = True) -> None:
        super().__init__(path, faces, fps, (".glb",), "the glTF export")
        self.name, self.quantize = name, bool(quantize)
        self.base = None
        self.shift: list = []           # (3,) translation of each frame, glTF y up
        self.span = 0.0                 # largest |displacement| beyond the translation
        self._tmp = tempfile.TemporaryFile(dir=self.path.parent, suffix=".glb.part")

    def add(self, X: np.ndarray) -> None:
        """Write one frame's (n, 3) points (the first is the base mesh)."""
        Y = self._frame(X) @ Z_UP_TO_Y_UP.T
        if self.base is None:
            self.base = Y.astype(np.float32)
            self.shift.append(np.zeros(3))
            return
        if self.frames > 65535:
            raise ValueError(f"{self.path}: a glTF morph export holds at most 65535 frames "
                             "(its weight keys index frame x target); use --step or USD")
        d = Y - self.base
        # The median, not the mean: a still body with one moving arm keeps zeros
        # (sparse targets), a walk's travel goes to the translation.
        c = np.median(d, axis=0)
        D = (d - c).astype(np.float32)
        self.shift.append(c)
        self.span = max(self.span, float(np.abs(D).max()))
        self._tmp.write(D.tobytes())

    def _targets(self, scale: float) -> Iterator[tuple[np.ndarray, np.ndarray, float]]:
        """(stored values (n, 3), moved rows, largest error m) of every target in order."""
        self._tmp.seek(0)
        for _ in range(self.frames - 1):
            D = np.frombuffer(self._tmp.read(12 * self.n), dtype=np.float32).reshape(self.n, 3)
            if self.quantize:
                D = D.astype(np.float64)        # float32 arithmetic would add 0.2% of a step
                q = np.clip(np.rint(D / scale * _Q), -_Q, _Q).astype(np.int16)
                err = float(np.abs(q * (scale / _Q) - D).max())
                yield q, np.flatnonzero(q.any(1)), err
            else:
                yield D, np.flatnonzero(D.any(1)), 0.0

    def _finish(self) -> dict:
        """Assemble the ``.glb``; its figures add error_mm, sparse_targets, quantized."""
        n, T, K = self.n, self.frames, self.frames - 1
        scale = self.span if self.quantize and self.span > 0 else 1.0
        comp, esize, dense_stride = ((5122, 6, 8) if self.quantize else (5126, 12, 12))
        isize = 2 if n < 65536 else 4
        # Pass 1: what each target holds decides how it is stored, and where.
        plan, err_max = [], 0.0
        for vals, rows, err in self._targets(scale):
            err_max = max(err_max, err)
            lo, hi = vals.min(0).tolist(), vals.max(0).tolist()   # unmoved rows are zeros
            sparse = len(rows) * (isize + esize) < n * dense_stride
            plan.append((len(rows), sparse, lo, hi))
        views, accessors, blob_size = [], [], 0

        def view(nbytes: int, **kw) -> int:
            nonlocal blob_size
            views.append({"buffer": 0, "byteOffset": blob_size, "byteLength": nbytes, **kw})
            blob_size += nbytes + (-nbytes % 4)
            return len(views) - 1

        def accessor(**kw) -> int:
            accessors.append(kw)
            return len(accessors) - 1

        base = self.base / np.float32(scale)
        pos = accessor(bufferView=view(12 * n, target=34962), componentType=5126, count=n,
                       type="VEC3", min=base.min(0).tolist(), max=base.max(0).tolist())
        idx = accessor(bufferView=view(12 * len(self.faces), target=34963), componentType=5125,
                       count=3 * len(self.faces), type="SCALAR")
        targets = []
        for moved, sparse, lo, hi in plan:
            acc = {"componentType": comp, "count": n, "type": "VEC3", "min": lo, "max": hi}
            if self.quantize:
                acc["normalized"] = True
            if sparse and moved:
                acc["sparse"] = {"count": moved,
                                 "indices": {"bufferView": view(isize * moved),
                                             "componentType": 5123 if isize == 2 else 5125},
                                 "values": {"bufferView": view(esize * moved)}}
            elif not sparse:
                acc["bufferView"] = view(dense_stride * n, target=34962,
                                         **({"byteStride": 8} if self.quantize else {}))
            targets.append({"POSITION": accessor(**acc)})
        times = (np.arange(T) / self.fps).astype(np.float32)
        shift = np.asarray(self.shift, dtype=np.float32)
        t_acc = accessor(bufferView=view(4 * T), componentType=5126, count=T, type="SCALAR",
                         min=[float(times[0])], max=[float(times[-1])])
        s_acc = accessor(bufferView=view(12 * T), componentType=5126, count=T, type="VEC3")
        node = {"name": self.name, "mesh": 0}
        if scale != 1.0:
            node["scale"] = [scale] * 3
        samplers = [{"input": t_acc, "output": s_acc, "interpolation": "LINEAR"}]
        channels = [{"sampler": 0, "target": {"node": 0, "path": "translation"}}]
        if K:
            # Key k is 1 for target k (frame k) and 0 elsewhere: T*K values, K of them 1.
            w_acc = accessor(componentType=5126, count=T * K, type="SCALAR",
                             sparse={"count": K,
                                     "indices": {"bufferView": view(4 * K), "componentType": 5125},
                                     "values": {"bufferView": view(4 * K)}})
            samplers.append({"input": t_acc, "output": w_acc, "interpolation": "LINEAR"})
            channels.append({"sampler": 1, "target": {"node": 0, "path": "weights"}})
        prim = {"attributes": {"POSITION": pos}, "indices": idx, "mode": 4}
        mesh = {"name": self.name, "primitives": [prim]}
        if K:
            prim["targets"] = targets
            mesh["weights"] = [0.0] * K
            mesh["extras"] = {"targetNames": [f"frame{k}" for k in range(1, T)]}
        doc = {"asset": {"version": "2.0", "generator": "skin_node export"}, "scene": 0,
               "scenes": [{"nodes": [0]}], "nodes": [node], "meshes": [mesh],
               "animations": [{"name": "deformation", "samplers": samplers,
                               "channels": channels}],
               "buffers": [{"byteLength": blob_size}], "bufferViews": views,
               "accessors": accessors}
        if self.quantize and K:
            doc["extensionsUsed"] = doc["extensionsRequired"] = ["KHR_mesh_quantization"]
        text = json.dumps(doc, separators=(",", ":")).encode()
        text += b" " * (-len(text) % 4)
        with open(self.path, "wb") as out:
            out.write(struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(text) + 8 + blob_size))
            out.write(struct.pack("<I4s", len(text), b"JSON") + text)
            out.write(struct.pack("<I4s", blob_size, b"BIN\0"))
            put = lambda b: out.write(b + b"\0" * (-len(b) % 4))  # noqa: E731
            put(base.astype(np.float32).tobytes())
            put(self.faces.astype(np.uint32).tobytes())
            # Pass 2: the targets, as planned.
            for (moved, sparse, _, _), (vals, rows, _) in zip(plan, self._targets(scale)):
                if sparse and moved:
                    put(rows.astype(np.uint16 if isize == 2 else np.uint32).tobytes())
                    put(np.ascontiguousarray(vals[rows]).tobytes())
                elif not sparse:
                    put(np.c_[vals, np.zeros(n, np.int16)].tobytes() if self.quantize
                        else vals.tobytes())
            put(times.tobytes())
            put(shift.tobytes())
            if K:
                k = np.arange(1, T, dtype=np.uint32)
                put((k * K + k - 1).astype(np.uint32).tobytes())
                put(np.ones(K, np.float32).tobytes())
        self._tmp.close()
        return self.stats(error_mm=1000.0 * err_max * (1.0 if self.quantize else 0.0),
                          sparse_targets=sum(1 for m, sp, _, _ in plan if sp),
                          quantized=self.quantize and bool(K))

    def abort(self) -> None:
        self._tmp.close()
        super().abort()


def write_gltf_morph(path: str | Path, frames: np.ndarray, faces: np.ndarray,
                     fps: float, name: str = "Skin", quantize: bool = True) -> Path:
    """Write a ``.glb`` whose morph targets replay (T, n, 3) ``frames`` (metres, z up)
    with :class:`GltfMorphWriter`.

    Returns
    -------
    Path
    """
    frames, faces = _check_frames(frames, faces)
    with GltfMorphWriter(path, faces, fps, name, quantize) as w:
        for X in frames:
            w.add(X)
    return w.path


def read_gltf_morph(path: str | Path) -> tuple[np.ndarray, np.ndarray, float]:
    """Read back :func:`write_gltf_morph`'s file: (frames (T,n,3) z up, faces, fps).

    Frame ``k`` is the first mesh node's translation and scale applied to its
    base plus its targets weighted by the animation's ``k``-th key.
    """
    path = Path(path)
    g = _read_document(path)
    rd = _Reader(path, g)
    ni = next(i for i, nd in enumerate(g.nodes) if nd.mesh is not None)
    node = g.nodes[ni]
    prim = g.meshes[node.mesh].primitives[0]
    base = rd.read(prim.attributes.POSITION, "POSITION")
    faces = rd.read(prim.indices, "indices").reshape(-1, 3)
    D = np.stack([rd.read(t["POSITION"], "target") for t in (prim.targets or [])]) \
        if prim.targets else np.zeros((0,) + base.shape)
    scale = np.asarray(node.scale or [1.0, 1.0, 1.0])
    shift = np.asarray(node.translation or [0.0, 0.0, 0.0])[None]
    frames, fps = (base * scale + shift), 0.0
    if g.animations:
        a = g.animations[0]
        by_path = {c.target.path: a.samplers[c.sampler] for c in a.channels
                   if c.target.node == ni}
        times = rd.read(next(iter(by_path.values())).input, "times").ravel()
        W = np.zeros((len(times), len(D)))
        if "weights" in by_path and len(D):
            W = rd.read(by_path["weights"].output, "weights").reshape(len(times), len(D))
        if "translation" in by_path:
            shift = rd.read(by_path["translation"].output, "translation")
        frames = shift[:, None] + scale * (base[None] + np.einsum("tk,knc->tnc", W, D))
        fps = 1.0 / float(np.median(np.diff(times))) if len(times) > 1 else 0.0
    else:
        frames = frames[None]
    return frames @ Y_UP_TO_Z_UP.T, faces, fps


# --------------------------------------------------------------------- bags
def bag_points(path: str | Path, topic: str = "skin/points") -> tuple[Iterator, int, float]:
    """(iterator of (n, 3) frames, message count, fps) of the PointCloud2 messages
    of a bag (rosbag2 or ROS 1, :class:`~skin_node.io.bags.BagReader`), read one
    message at a time. The rate is the median rate of the messages' log times.
    """
    cloud = "sensor_msgs/msg/PointCloud2"
    with BagReader(path) as reader:
        stamps = [t for _, t, _ in reader.messages(cloud, topic)]
        if not stamps:
            if not any(m == cloud and t.lstrip("/") == topic.lstrip("/")
                       for t, m in reader.connections):
                raise ValueError(f"{path}: no {cloud} topic {topic}; it holds "
                                 f"{reader.describe()}")
            raise ValueError(f"{path}: no messages on {topic}")
    dt = np.median(np.diff(stamps)) * 1e-9 if len(stamps) > 1 else 0.0

    def frames():
        n = None
        with BagReader(path) as reader:
            for _, _, raw in reader.messages(cloud, topic):
                msg = reader.deserialize(raw, cloud)
                off = {f.name: f.offset for f in msg.fields}
                if not {"x", "y", "z"} <= set(off) or msg.is_bigendian:
                    raise ValueError(f"{path}: {topic} messages need little-endian x, y, z "
                                     "fields")
                k = msg.width * msg.height
                if n is not None and k != n:
                    raise ValueError(f"{path}: {topic} messages differ in point count")
                n = k
                data = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(k, msg.point_step)
                yield np.stack([data[:, off[c]:off[c] + 4].copy().view("<f4")[:, 0]
                                for c in "xyz"], axis=1).astype(np.float64)
    return frames(), len(stamps), (1.0 / dt if dt > 0 else 30.0)


def read_bag_points(path: str | Path, topic: str = "skin/points") -> tuple[np.ndarray, float]:
    """(frames (T, n, 3), fps) of the PointCloud2 messages of a bag (all in memory;
    :func:`bag_points` streams them)."""
    frames, _, fps = bag_points(path, topic)
    return np.stack(list(frames)), fps


# ---------------------------------------------------------------------- CLI
def deform_frames(character, frames: np.ndarray, pipeline: str = "default",
                  **params) -> Iterator[np.ndarray]:
    """(n, 3) whole surface (``character.surface_V``'s rows) of ``character`` for
    each pose of ``frames`` (T, C), one at a time."""
    pipe = Pipeline.preset(character, pipeline, **params)
    for q in frames:
        yield pipe.deform(q)


def _load_motion(args, ch) -> tuple[str, np.ndarray, float]:
    clip = f"{GLTF_PREFIX}0" if args.clip == "file" else args.clip
    c = load_motion(args.character, clip, args.bvh, args.mapping, args.fps or None,
                    skeleton=ch.skeleton)
    return c.name, np.asarray(c.frames), float(c.fps)


def open_writer(path: str | Path, faces, fps: float, name: str, quantize: bool = True):
    """The writer for ``path``'s suffix: :class:`GltfMorphWriter` or :class:`UsdPointCacheWriter`."""
    suffix = Path(path).suffix.lower()
    if suffix == ".glb":
        return GltfMorphWriter(path, faces, fps, name=name, quantize=quantize)
    if suffix in (".usda", ".usdc", ".usd"):
        return UsdPointCacheWriter(path, faces, fps, name=_prim_name(name))
    raise ValueError(f"{path}: unknown output type (use .usda, .usdc, .usd or .glb)")


def _parse(argv):
    ap = argparse.ArgumentParser(prog="python -m skin_node.io.export",
                                 description=__doc__.splitlines()[0])
    ap.add_argument("--character", required=True, help="arm | humanoid | character file")
    ap.add_argument("--weights", default="automatic", choices=("automatic", "file"))
    src = ap.add_mutually_exclusive_group()
    src.add_argument("--clip", default="", help="built-in clip, or a glTF character's "
                     "animation (NAME, gltf:NAME; 'file' for its first)")
    src.add_argument("--bvh", default="", help="BVH file to retarget")
    src.add_argument("--bag", default="", help="bag (rosbag2 or ROS 1) with recorded skin/points")
    ap.add_argument("--mapping", default="", help="retarget mapping YAML for --bvh")
    ap.add_argument("--topic", default="skin/points", help="points topic of --bag")
    ap.add_argument("--pipeline", default="default", help="preset: lbs, dqs, paper, default")
    ap.add_argument("--step", type=int, default=1, help="keep every N-th frame")
    ap.add_argument("--frames", type=int, default=0, help="stop after N frames (0: all)")
    ap.add_argument("--fps", type=float, default=0.0,
                    help="sampling rate of a glTF animation (default 120)")
    ap.add_argument("--float", dest="quantize", action="store_false",
                    help="glTF morph targets as float32, not 16-bit quantized")
    ap.add_argument("-o", "--output", action="append", required=True,
                    help=".usda/.usdc/.usd and/or .glb (repeatable)")
    return ap.parse_args(argv)


def _report(st: dict, fps: float, name: str) -> str:
    mb, kb = st["bytes"] / 1e6, st["bytes_per_frame"] / 1e3
    line = (f"export: {st['path']}: {st['frames']} frames of {st['points']} points at {fps:g} "
            f"fps ({name}), {mb:.1f} MB, {kb:.1f} kB a frame")
    if st.get("quantized"):
        line += f", targets quantized to 16 bits (largest error {st['error_mm']:.4f} mm)"
    if st.get("sparse_targets"):
        line += f", {st['sparse_targets']} sparse targets"
    return line


def main(argv: list[str] | None = None) -> int:
    """Entry point; 0 on success, 2 on bad input."""
    args = _parse(sys.argv[1:] if argv is None else argv)
    writers = []
    try:
        for out in args.output:                 # a bad name fails before any work
            if Path(out).suffix.lower() not in (".glb", ".usda", ".usdc", ".usd"):
                raise ValueError(f"{out}: unknown output type (use .usda, .usdc, .usd or .glb)")
        if args.step < 1:
            raise ValueError(f"--step must be >= 1, got {args.step}")
        ch = load_character(args.character, weights=args.weights)
        if args.bag:
            frames, total, fps = bag_points(args.bag, args.topic)
            name = Path(args.bag).name

            def stepped(it=frames):
                for k, X in enumerate(it):
                    if X.shape[0] != len(ch.surface_V):
                        raise ValueError(f"{args.bag}: {X.shape[0]} points per message, but "
                                         f"{args.character} has {len(ch.surface_V)} vertices")
                    if k % args.step == 0:
                        yield X
            source = stepped()
            total = (total + args.step - 1) // args.step
        else:
            name, q, fps = _load_motion(args, ch)
            q = q[::args.step]
            source, total = deform_frames(ch, q[:args.frames or None], args.pipeline), len(q)
        total = min(total, args.frames) if args.frames else total
        fps = fps / args.step
        faces, to_file = ch.surface_F, (lambda X: X)
        if ch.file_order is not None:       # a glTF file's own vertices, so its UVs apply
            faces, to_file = ch.file_faces, (lambda X: X[ch.file_order])
        writers = [open_writer(out, faces, fps, ch.name, args.quantize) for out in args.output]
        t0 = last = time.monotonic()
        for k, X in enumerate(source):
            if args.frames and k >= args.frames:
                break
            Xf = to_file(X)
            for w in writers:
                w.add(Xf)
            if time.monotonic() - last > 5.0:
                last = time.monotonic()
                print(f"export: {k + 1}/{total} frames ({last - t0:.0f} s)", file=sys.stderr,
                      flush=True)
        for w in writers:
            print(_report(w.close(), fps, name))
        writers = []
    except (ValueError, OSError, KeyError) as e:
        for w in writers:
            w.abort()
        print(f"export: error: {e}", file=sys.stderr)
        return 2
    return 0


def _prim_name(name: str) -> str:
    s = "".join(c if c.isalnum() or c == "_" else "_" for c in name) or "Skin"
    return s if not s[0].isdigit() else f"_{s}"


if __name__ == "__main__":
    sys.exit(main())
