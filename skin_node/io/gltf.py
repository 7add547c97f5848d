"""Skinned glTF 2.0 characters (.glb / .gltf): surface, skeleton, weights, animation.

The file is parsed with ``pygltflib`` (structure) and decoded with numpy
(accessors). What is read, and how it becomes a project character:

* **Mesh**: every triangle primitive of the skinned mesh node(s) using the
  first skin. glTF splits vertices at UV seams and normal creases; they are
  merged by position (within ``1e-6`` times the bounding-box diagonal) so the
  surface is closed for tet meshing. :attr:`GltfCharacter.vertex_map` takes
  the merged order back to the file's: ``X_file = X_merged[vertex_map]``.
  Triangles that collapse when merging are dropped.
* **Frame and units**: glTF is metres, y up. Points and joints are taken in
  the glTF *world* frame (the skinned result ``G_j @ IBM_j @ v`` a viewer
  shows, so scene-level nodes above the skeleton, such as a 0.01 scale or an
  axis-conversion matrix, are applied), then turned to the project's z up by
  a +90 degree rotation about x (``x, y, z -> x, -z, y``). For CesiumMan the
  two cancel exactly: its root node already converts its z-up content to y
  up, so the character comes out as authored (z up, arms along y).
* **Skeleton**: the skin's joints, reordered parents first (the skin's
  index order is kept in :attr:`GltfCharacter.joint_nodes`). A joint's parent
  is its nearest ancestor node that is also a joint; exactly one joint may
  have none. Nodes without a name are called ``joint<k>`` with ``k`` the skin
  joint index (the same numbers as ``JOINTS_0``); duplicated names get a
  ``_<k>`` suffix.
* **Rest (bind) pose**: the vertices are bound by the inverse bind matrices
  (IBMs), so the rest pose is ``B_j = world_of_skeleton_parent @
  inv(IBM_j)``, rotations orthonormalised. :class:`~skin_node.skeleton.Skeleton`
  gets these as ``rest_positions`` and ``rest_rotations`` (each joint's bind
  rotation relative to its parent's), so ``q = 0`` is the glTF bind pose.
  The node hierarchy's own rest transforms are compared with the IBMs
  (:attr:`GltfCharacter.bind_mismatch`); when they disagree by more than
  0.1 mm or 1e-3 rad the IBMs win (the vertices were bound to them) and a
  :class:`UserWarning` says by how much. The file's animation is then still
  exact in joint rotations, but bone offsets are the bind pose's.
* **Tips of leaf joints**: a leaf's bone runs from the joint along its
  direction ``d`` to the farthest of its vertices (file weight for the joint
  at least 0.5) projected on ``d``, at least 1 cm. ``d`` points from the
  joint to the weighted centroid of those vertices (a toe points forward
  rather than along its parent's line into the floor). With no such
  vertices the parent's bone is extended by half its length (or the joint's
  local +y when it sits on its parent).
* **Weights**: ``JOINTS_0/WEIGHTS_0`` (and ``_1`` sets, if present), as
  (n, k) joint indices in the *skeleton's* order and renormalised values.
  Vertices merged from several file vertices take the mean of their weights.
* **Animation**: :func:`gltf_clip` samples an animation at any rate, as the
  glTF specification interpolates (LINEAR: lerp, and slerp for rotations;
  STEP: hold the key before; CUBICSPLINE: cubic Hermite through the keys
  with the file's in- and out-tangents scaled by the key interval,
  rotations normalised; before the first key and after the last, the end
  key), evaluates every node's world matrix, and converts the joints'
  world rotations to the project's pose channels exactly: the root's
  translation, and per joint the Euler angles ``R = Rz Ry Rx`` of
  ``W_parent^T W_j Rrest_j^T`` (so the skeleton posed from them has the
  file's world rotations, animated nodes between joints included), made
  continuous in time. Animated translations of non-root joints and all
  scales are not followed (the skeleton is rigid): the largest change of a
  joint's offset from its parent is reported in
  :attr:`GltfClip.ignored_translation` (3 mm on CesiumMan's walk, under
  0.003 mm on RiggedFigure and RiggedSimple).

:func:`load_gltf_scene` reads every mesh of the scene instead (skinned meshes
on any number of skins joined into one skeleton, meshes without a skin as
rigid parts of the joint above them, each part reported with its vertex count,
open or closed), and :meth:`GltfScene.split_body` makes one character of
them: that is what :func:`~skin_node.load_character` reads.

Supported glTF features
-----------------------
``load_character("FILE.glb")`` (and ``.gltf``, with embedded ``data:``
buffers or ``.bin`` files beside it; glTF 2.0 only) poses every mesh of the
file's default scene (all nodes when it has no scene) on one skeleton:

* **Skinned meshes on any number of skins**, ``JOINTS_n/WEIGHTS_n`` (up to
  four sets of four), with inverse bind matrices (identity when absent): the
  skins' joints are joined into one skeleton, a joint two skins share once,
  separate trees under their nearest common ancestor node. Joints must be
  rigid (no non-uniform scale in the bind pose).
* **Meshes without a skin** are rigid parts of the nearest joint above them
  (through any non-joint nodes, whose rest transforms are kept) and follow it
  exactly; with no joint above them they are static. A file with no skin at
  all (a robot of rigid links) makes every mesh node and the nodes above it
  joints.
* **What each part gets**: the closed skinned meshes are the simulated body
  (every stage of the pipeline: volume, contact between its meshes);
  skinned meshes that share vertex positions are joined first, so a
  character split into meshes is solved whole. Open skinned meshes and
  closed ones under 1% of the largest one's volume (eyes, teeth) are
  skinned by dual quaternions with the file's weights; rigid meshes are
  carried by their joint; static ones stay at rest. Without any closed
  skinned mesh, every part is posed so and no stage runs. The published
  surface is the body's vertices, then every other part's in node order
  (:mod:`skin_node.parts`).
* **Primitives**: triangle lists, strips and fans, indexed or not; float,
  normalized or integer accessors (``KHR_mesh_quantization``), sparse
  accessors, interleaved buffer views. Vertices split at UV seams are merged
  by position per part; the exporter writes the file's own vertices again.
* **Animation**: as :func:`gltf_clip` says (LINEAR, STEP, CUBICSPLINE).
* **Not read, with a start-up line saying so**: points and lines primitives,
  meshes left without triangles, morph targets (the base shape is posed),
  mesh nodes outside the scene. **Refused by name**: files that require
  ``KHR_draco_mesh_compression``, ``EXT_meshopt_compression`` or
  ``EXT_mesh_gpu_instancing``. Materials, textures, cameras and lights are
  ignored.

Errors are :class:`~skin_node.io.character_file.CharacterFileError`
(a ``ValueError``) whose message starts with the file path.
"""
from __future__ import annotations

import base64
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ..builtin.clips import Clip
from ..metrics import mesh_volume, shells
from ..parts import Part, Passengers
from ..retarget import continuous_euler
from ..skeleton import Skeleton, matrix_to_euler_xyz
from .character_file import CharacterFileError, check_surface, crossing_shells, surface_problem

#: glTF world (y up) to the project's world (z up): +90 degrees about x.
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])

_COMPONENTS = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16,
               5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
_MERGE_TOL = 1e-6
_MISMATCH_POS, _MISMATCH_ROT = 1e-4, 1e-3
#: Required extensions whose geometry this reader cannot decode.
_UNREAD_EXTENSIONS = {"KHR_draco_mesh_compression": "Draco-compressed meshes",
                      "EXT_meshopt_compression": "meshopt-compressed buffers",
                      "EXT_mesh_gpu_instancing": "instanced meshes"}
#: A closed skinned mesh with less than this share of the largest closed one's
#: volume (eyes, teeth, buttons) rides along with the body instead of being solved.
BODY_MIN_SHARE = 0.01


def _fail(path, msg: str):
    raise CharacterFileError(f"{path}: {msg}")


# ------------------------------------------------------------------ decoding
class _Reader:
    """Accessor decoding of one glTF document."""

    def __init__(self, path: Path, gltf) -> None:
        self.path, self.g = path, gltf
        self._buffers: dict = {}

    def buffer(self, i: int) -> bytes:
        if i not in self._buffers:
            if not 0 <= i < len(self.g.buffers):
                _fail(self.path, f"buffer {i} does not exist")
            b = self.g.buffers[i]
            if b.uri is None:
                data = self.g.binary_blob()
                if data is None:
                    _fail(self.path, f"buffer {i} has no uri and the file has no binary chunk")
            elif b.uri.startswith("data:"):
                data = base64.b64decode(b.uri.split(",", 1)[1])
            else:
                f = self.path.parent / unquote(b.uri)
                try:
                    data = f.read_bytes()
                except OSError as e:
                    _fail(self.path, f"buffer {i} file {f} cannot be read ({e})")
            self._buffers[i] = bytes(data)
        return self._buffers[i]

    def _view(self, view: int, offset: int, dt, width: int, count: int, what: str,
              strided: bool = True) -> np.ndarray:
        """(count, width) elements of ``dt`` from buffer view ``view`` at ``offset``."""
        g = self.g
        if not 0 <= view < len(g.bufferViews):
            _fail(self.path, f"{what}: buffer view {view} does not exist")
        bv = g.bufferViews[view]
        data = self.buffer(bv.buffer)
        start = (bv.byteOffset or 0) + (offset or 0)
        item = np.dtype(dt).itemsize * width
        stride = (bv.byteStride or item) if strided else item
        need = start + (count - 1) * stride + item if count else start
        if need > len(data) or need > (bv.byteOffset or 0) + bv.byteLength:
            _fail(self.path, f"{what}: data runs past the end of buffer view {view}")
        raw = np.frombuffer(data, dtype=np.uint8, count=max(need - start, 0), offset=start)
        if stride == item:
            return raw[:count * item].view(dt).reshape(count, width)
        rows = np.lib.stride_tricks.as_strided(raw, (count, item), (stride, 1))
        return np.ascontiguousarray(rows).view(dt).reshape(count, width)

    def read(self, index: int | None, what: str) -> np.ndarray:
        """Accessor ``index`` as a float64 or int64 array of shape (count, width),
        sparse substitution applied and normalised integers mapped to [-1, 1]."""
        g = self.g
        if index is None or not 0 <= index < len(g.accessors):
            _fail(self.path, f"{what}: accessor {index} does not exist")
        acc = g.accessors[index]
        dt = _COMPONENTS.get(acc.componentType)
        width = _WIDTH.get(acc.type)
        if dt is None or width is None:
            _fail(self.path, f"{what}: unknown accessor type {acc.type}/{acc.componentType}")
        count = int(acc.count)
        if acc.bufferView is None:
            out = np.zeros((count, width), dtype=dt)
        else:
            out = self._view(acc.bufferView, acc.byteOffset, dt, width, count, what).copy()
        if acc.sparse is not None:
            sp = acc.sparse
            idt = _COMPONENTS.get(sp.indices.componentType)
            if idt not in (np.uint8, np.uint16, np.uint32):
                _fail(self.path, f"{what}: sparse indices of type {sp.indices.componentType}")
            n = int(sp.count)
            where = self._view(sp.indices.bufferView, sp.indices.byteOffset, idt, 1, n,
                               what, strided=False).ravel().astype(np.int64)
            if n and (where.min() < 0 or where.max() >= count or np.any(np.diff(where) <= 0)):
                _fail(self.path, f"{what}: sparse indices must increase within 0..{count - 1}")
            out[where] = self._view(sp.values.bufferView, sp.values.byteOffset, dt, width, n,
                                    what, strided=False)
        if dt == np.float32:
            return out.astype(np.float64)
        if acc.normalized:
            x = out.astype(np.float64) / float(np.iinfo(dt).max)
            return np.maximum(x, -1.0) if np.issubdtype(dt, np.signedinteger) else x
        return out.astype(np.int64)


def _node_matrix(node) -> np.ndarray:
    """The 4x4 local matrix of a node (``matrix`` or T @ R @ S)."""
    if node.matrix is not None:
        return np.asarray(node.matrix, dtype=np.float64).reshape(4, 4).T
    M = np.eye(4)
    M[:3, :3] = _quat_to_matrix(np.asarray(node.rotation or [0, 0, 0, 1], float)) \
        * np.asarray(node.scale or [1, 1, 1], float)[None, :]
    M[:3, 3] = node.translation or [0, 0, 0]
    return M


def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(..., 4) quaternions (x, y, z, w), normalised here, to (..., 3, 3)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), 1e-300)
    x, y, z, w = np.moveaxis(q, -1, 0)
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - z * w)
    R[..., 0, 2] = 2 * (x * z + y * w)
    R[..., 1, 0] = 2 * (x * y + z * w)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - x * w)
    R[..., 2, 0] = 2 * (x * z - y * w)
    R[..., 2, 1] = 2 * (y * z + x * w)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def _orthonormal(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest rotations of (..., 3, 3) ``A`` and their singular values (scales)."""
    U, s, Vt = np.linalg.svd(A)
    R = U @ Vt
    flip = np.linalg.det(R) < 0
    if np.any(flip):
        U = U.copy()
        U[flip, :, -1] *= -1
        R = U @ Vt
    return R, s


def _rotation_angle(R: np.ndarray) -> np.ndarray:
    c = (np.trace(R, axis1=-2, axis2=-1) - 1.0) * 0.5
    return np.arccos(np.clip(c, -1.0, 1.0))


# --------------------------------------------------------------- the result
@dataclass
class GltfClip(Clip):
    """An animation of the file as project pose channels (a :class:`Clip`).

    Attributes
    ----------
    name : str
    channel_names : list of str
    frames : (T, C) float
        Root translation (metres) then rx, ry, rz per joint (radians); frame
        ``k`` is the animation at time ``k / fps``, from 0 to its last key.
    fps : float
    ignored_translation : float
        Largest change of a non-root joint's offset from its parent that the
        rigid skeleton cannot follow, metres.
    """

    ignored_translation: float = 0.0


@dataclass
class GltfCharacter:
    """A skinned glTF character, merged and converted to the project's conventions.

    Attributes
    ----------
    path : Path
    V : (n, 3) float
        Merged rest surface, metres, z up.
    F : (m, 3) int
        Triangles over ``V`` (closed, outward facing).
    skeleton : Skeleton
        ``q = 0`` is the bind pose.
    Widx, Wval : (n, k) int, float
        The file's weights per merged vertex, skeleton joint indices, rows
        summing to 1, sorted by decreasing weight.
    vertex_map : (n_file,) int
        Merged index of every file vertex (all skinned primitives, in order).
    file_faces : (m_file, 3) int
        The file's triangles over its own vertices.
    joint_nodes : (J,) int
        glTF node of every skeleton joint.
    skin_joint : (J,) int
        Index of every skeleton joint in the skin's ``joints`` list.
    bind_mismatch : tuple of float
        (metres, radians): largest difference between the node hierarchy's
        rest pose and the IBMs' bind pose.
    """

    path: Path
    V: np.ndarray
    F: np.ndarray
    skeleton: Skeleton
    Widx: np.ndarray
    Wval: np.ndarray
    vertex_map: np.ndarray
    file_faces: np.ndarray
    joint_nodes: np.ndarray
    skin_joint: np.ndarray
    bind_mismatch: tuple = (0.0, 0.0)
    _gltf: object = field(default=None, repr=False)
    _to_world: np.ndarray = field(default=None, repr=False)

    @property
    def n_file_vertices(self) -> int:
        return len(self.vertex_map)

    def to_file_order(self, X: np.ndarray) -> np.ndarray:
        """(..., n, 3) merged-order points to (..., n_file, 3) in the file's vertex order."""
        return np.asarray(X)[..., self.vertex_map, :]

    def dense_weights(self) -> np.ndarray:
        """(n, J) file weights as a dense matrix."""
        W = np.zeros((len(self.V), self.skeleton.n_joints))
        np.add.at(W, (np.repeat(np.arange(len(self.V)), self.Widx.shape[1]), self.Widx.ravel()),
                  self.Wval.ravel())
        return W

    @property
    def animation_names(self) -> list:
        """Names of the file's animations (``animation<k>`` for unnamed ones)."""
        return _animation_names(self._gltf)

    def clip(self, which: int | str = 0, fps: float = 30.0) -> GltfClip:
        """:func:`gltf_clip` of this character."""
        return gltf_clip(self, which, fps)


# ------------------------------------------------------------------ loading
def _read_document(path: Path):
    import pygltflib            # deferred: only glTF files need it
    if not path.exists():
        _fail(path, "no such file")
    if path.stat().st_size == 0:
        _fail(path, "file is empty")
    if path.suffix.lower() not in (".glb", ".gltf"):
        _fail(path, "expected a .glb or .gltf file")
    head = path.read_bytes()[:4]
    try:
        if head == b"glTF":
            g = pygltflib.GLTF2().load_binary(str(path))
        else:
            g = pygltflib.GLTF2().load_json(str(path))
    except Exception as e:  # pygltflib raises many kinds for bad input
        _fail(path, f"not a readable glTF 2.0 file ({e.__class__.__name__}: {e})")
    if g is None:
        _fail(path, "not a readable glTF 2.0 file")
    version = str(getattr(g.asset, "version", "") or "")
    if not version.startswith("2"):
        _fail(path, f"glTF version {version or '?'} is not supported (expected 2.0)")
    unread = [e for e in g.extensionsRequired or [] if e in _UNREAD_EXTENSIONS]
    if unread:      # their geometry is not in the accessors this reader decodes
        what = ", ".join(f"{e} ({_UNREAD_EXTENSIONS[e]})" for e in unread)
        _fail(path, f"needs {what}, which is not read; export the file without it")
    return g


def _parents_of_nodes(path: Path, g) -> np.ndarray:
    """(N,) parent node of every node (-1 for none); errors for bad children and cycles."""
    N = len(g.nodes)
    parent = np.full(N, -1, dtype=np.int64)
    for i, n in enumerate(g.nodes):
        for c in n.children or []:
            if not isinstance(c, int) or not 0 <= c < N:
                _fail(path, f"node {i} lists child {c}, which is not a node of the file "
                            f"(0..{N - 1}): unknown parent link")
            if c == i:
                _fail(path, f"node {i} is its own child (a cycle in the node hierarchy)")
            if parent[c] >= 0:
                _fail(path, f"node {c} has two parents ({parent[c]} and {i}); glTF nodes form "
                            "a tree")
            parent[c] = i
    for i in range(N):  # walking up must end; a cycle without a root never does
        seen, a = set(), i
        while a >= 0:
            if a in seen:
                _fail(path, f"the node hierarchy has a cycle through node {i}")
            seen.add(a)
            a = parent[a]
    return parent


def _world_matrices(g, parent: np.ndarray, local: np.ndarray | None = None) -> np.ndarray:
    """(N, 4, 4) world matrices from (N, 4, 4) local ones (rest TRS when None)."""
    N = len(g.nodes)
    if local is None:
        local = np.stack([_node_matrix(n) for n in g.nodes]) if N else np.zeros((0, 4, 4))
    W = np.full_like(local, np.nan)
    done = np.zeros(N, dtype=bool)

    def world(i):
        chain = []
        while i >= 0 and not done[i]:
            chain.append(i)
            i = parent[i]
        for k in reversed(chain):
            p = parent[k]
            W[k] = local[k] if p < 0 else W[p] @ local[k]
            done[k] = True

    for i in range(N):
        world(i)
    return W


def _merge_by_position(V: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """(representative (n_file,) merged index, merged points) for points within ``tol``."""
    pairs = cKDTree(V).query_pairs(tol, output_type="ndarray")
    n = len(V)
    G = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, label = connected_components(G, directed=False)
    # Number the merged points in order of first appearance in the file.
    first = np.full(label.max() + 1, n, dtype=np.int64)
    np.minimum.at(first, label, np.arange(n))
    order = np.argsort(first)
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    vmap = rank[label]
    Vm = np.zeros((len(order), 3))
    np.add.at(Vm, vmap, V)
    Vm /= np.bincount(vmap)[:, None]
    return vmap, Vm


#: Primitive modes that are not triangles: skipped by :func:`load_gltf_scene`.
_NOT_TRIANGLES = {0: "points", 1: "lines", 2: "a line loop", 3: "a line strip"}


def _triangles(idx: np.ndarray, mode: int | None) -> np.ndarray:
    """(t, 3) triangles of a TRIANGLES (4), TRIANGLE_STRIP (5) or TRIANGLE_FAN (6)
    index list, as glTF 2.0 (3.7.2.1) orders their corners."""
    if mode in (None, 4):
        return idx.reshape(-1, 3)
    i = np.arange(max(len(idx) - 2, 0))
    if mode == 5:       # p_i = (v_i, v_{i + 1 + i%2}, v_{i + 2 - i%2}): every other one flipped
        return np.stack([idx[i], idx[i + 1 + i % 2], idx[i + 2 - i % 2]], axis=1)
    return np.stack([idx[i + 1], idx[i + 2], np.full_like(i, idx[0] if len(idx) else 0)],
                    axis=1)


def _mesh_primitives(path: Path, rd: _Reader, g, node: int, skinned: bool,
                     notes: list | None = None):
    """(positions (p, 3), triangles (t, 3), joints (p, k) or None, weights (p, k) or
    None) of every triangle primitive of node ``node``'s mesh (triangle lists,
    strips and fans); with ``skinned`` each must have JOINTS_0/WEIGHTS_0 (and any
    further sets). Points and lines are refused, or, given ``notes``, skipped
    with a line there (as morph targets are)."""
    mi = g.nodes[node].mesh
    if not 0 <= mi < len(g.meshes):
        _fail(path, f"node {node} refers to mesh {mi}, which does not exist")
    for pk, prim in enumerate(g.meshes[mi].primitives):
        where = f"mesh {mi} primitive {pk}"
        if prim.mode in _NOT_TRIANGLES and notes is not None:
            notes.append(f"{where} (node {node}) skipped: it is {_NOT_TRIANGLES[prim.mode]}, "
                         "not triangles")
            continue
        if prim.mode not in (None, 4, 5, 6):
            _fail(path, f"{where} has mode {prim.mode}; only triangles (mode 4, strips 5 and "
                        "fans 6) are supported")
        if prim.targets and notes is not None:
            notes.append(f"{where} (node {node}): its {len(prim.targets)} morph targets are "
                         "not applied (the base shape is posed)")
        at = prim.attributes
        if at.POSITION is None:
            _fail(path, f"{where} has no POSITION")
        P = rd.read(at.POSITION, f"{where} POSITION")
        if P.shape[1] != 3:
            _fail(path, f"{where} POSITION is not VEC3")
        idx = rd.read(prim.indices, f"{where} indices").ravel() if prim.indices is not None \
            else np.arange(len(P))
        if prim.mode in (None, 4) and len(idx) % 3:
            _fail(path, f"{where}: {len(idx)} indices is not a multiple of 3")
        if len(idx) and (idx.min() < 0 or idx.max() >= len(P)):
            _fail(path, f"{where}: indices reach vertex {idx.max()} of {len(P)}")
        tri = _triangles(idx, prim.mode)
        if not skinned:
            yield P, tri, None, None
            continue
        sets = []
        for k in range(4):
            ja, wa = getattr(at, f"JOINTS_{k}", None), getattr(at, f"WEIGHTS_{k}", None)
            if ja is None and wa is None:
                continue
            if ja is None or wa is None:
                _fail(path, f"{where} has JOINTS_{k} without WEIGHTS_{k} or the reverse")
            sets.append((rd.read(ja, f"{where} JOINTS_{k}"),
                         rd.read(wa, f"{where} WEIGHTS_{k}").astype(np.float64)))
        if not sets:
            _fail(path, f"{where} has no JOINTS_0/WEIGHTS_0: the mesh is not skinned")
        ji = np.concatenate([a for a, _ in sets], axis=1)
        wv = np.concatenate([b for _, b in sets], axis=1)
        if ji.shape != wv.shape or len(ji) != len(P):
            _fail(path, f"{where}: JOINTS/WEIGHTS do not match POSITION in size")
        yield P, tri, ji, wv


def _open(path) -> tuple:
    """(path, document, reader, parent node of every node) of a glTF file with nodes."""
    path = Path(path)
    g = _read_document(path)
    if not g.nodes:
        _fail(path, "has no nodes (no mesh and no skeleton)")
    return path, g, _Reader(path, g), _parents_of_nodes(path, g)


def load_gltf(path: str | Path) -> GltfCharacter:
    """Read a skinned glTF 2.0 character.

    Parameters
    ----------
    path : str or Path
        A ``.glb`` or ``.gltf`` file with one skinned, triangle mesh.

    Returns
    -------
    GltfCharacter

    Raises
    ------
    CharacterFileError
        ``"<path>: <problem>"`` for a missing, empty or unreadable file, no
        skinned mesh, a broken node hierarchy (cycles, unknown children),
        a skin whose joints are not one tree, missing or bad weights, NaN
        coordinates, or a surface that is open, non-manifold or inside out
        even after merging seam vertices.
    """
    path, g, rd, parent = _open(path)
    if not g.skins:
        _fail(path, "has no skin: a skinned mesh with JOINTS_0/WEIGHTS_0 is needed")
    mesh_nodes = [i for i, n in enumerate(g.nodes) if n.mesh is not None and n.skin == 0]
    if not mesh_nodes:
        _fail(path, "no node uses skin 0 with a mesh")
    skin = g.skins[0]
    skin_nodes = [int(j) for j in (skin.joints or [])]
    Jf = len(skin_nodes)
    if Jf == 0:
        _fail(path, "skin 0 has no joints")
    bad = [j for j in skin_nodes if not 0 <= j < len(g.nodes)]
    if bad:
        _fail(path, f"skin 0 lists joints {bad} that are not nodes of the file")
    if len(set(skin_nodes)) != Jf:
        _fail(path, "skin 0 lists a joint node twice")

    # ---- skeleton: joint parents through non-joint nodes, parents first
    in_skin = {n: k for k, n in enumerate(skin_nodes)}
    jparent = np.full(Jf, -1, dtype=np.int64)
    for k, n in enumerate(skin_nodes):
        a = parent[n]
        while a >= 0 and a not in in_skin:
            a = parent[a]
        jparent[k] = in_skin.get(a, -1) if a >= 0 else -1
    roots = np.flatnonzero(jparent < 0)
    if len(roots) != 1:
        _fail(path, f"skin 0's joints form {len(roots)} trees (roots: nodes "
                    f"{[skin_nodes[r] for r in roots]}); the skeleton needs exactly one root")
    order = [int(roots[0])]
    for k in order:  # breadth first: parents before children
        order.extend(int(c) for c in np.flatnonzero(jparent == k))
    order = np.asarray(order, dtype=np.int64)
    new_of_skin = np.empty(Jf, dtype=np.int64)
    new_of_skin[order] = np.arange(Jf)
    parents = np.array([-1 if jparent[k] < 0 else new_of_skin[jparent[k]] for k in order])
    names, used = [], set()
    for k in order:
        nm = g.nodes[skin_nodes[k]].name or f"joint{k}"
        if nm in used:
            nm = f"{nm}_{k}"
        used.add(nm)
        names.append(nm)

    # ---- frames: glTF world, then z up
    Wn = _world_matrices(g, parent)
    Cz = np.eye(4)
    Cz[:3, :3] = Y_UP_TO_Z_UP
    if skin.inverseBindMatrices is not None:
        IBM = rd.read(skin.inverseBindMatrices, "inverseBindMatrices")
        if IBM.shape != (Jf, 16):
            _fail(path, f"inverseBindMatrices has {len(IBM)} matrices for {Jf} joints")
        IBM = IBM.reshape(Jf, 4, 4).transpose(0, 2, 1)
    else:
        IBM = np.tile(np.eye(4), (Jf, 1, 1))
    if not np.all(np.isfinite(IBM)):
        _fail(path, "inverseBindMatrices contain NaN or Inf")
    root_node = skin_nodes[order[0]]
    above = Wn[parent[root_node]] if parent[root_node] >= 0 else np.eye(4)
    to_world = Cz @ above                    # skin (mesh) space -> project world
    try:
        Bw = to_world @ np.linalg.inv(IBM)   # bind world matrices, skin order
    except np.linalg.LinAlgError:
        _fail(path, "an inverse bind matrix is singular")
    Rb, sb = _orthonormal(Bw[:, :3, :3])
    scale0 = float(np.cbrt(abs(np.linalg.det(to_world[:3, :3]))))
    if np.any(np.abs(sb / scale0 - 1.0) > 1e-2):
        _fail(path, "joints have non-uniform or non-unit scale in the bind pose "
                    f"(singular values {sb.min():.4g}..{sb.max():.4g}); rigid skeletons only")
    Rb, Pb = Rb[order], Bw[order, :3, 3]
    Rn = Cz @ Wn[np.asarray(skin_nodes)[order]]
    Rn_rot, _ = _orthonormal(Rn[:, :3, :3])
    mis_p = float(np.abs(Rn[:, :3, 3] - Pb).max())
    mis_r = float(_rotation_angle(np.swapaxes(Rn_rot, 1, 2) @ Rb).max())
    if mis_p > _MISMATCH_POS * max(scale0, 1e-9) or mis_r > _MISMATCH_ROT:
        warnings.warn(f"{path}: the node hierarchy's rest pose differs from the inverse bind "
                      f"matrices by up to {mis_p * 1000:.2f} mm / {np.degrees(mis_r):.2f} deg; "
                      "using the inverse bind matrices (the vertices are bound to them)",
                      UserWarning, stacklevel=2)
    rest_rot = np.empty_like(Rb)
    for j in range(Jf):
        p = parents[j]
        rest_rot[j] = Rb[j] if p < 0 else Rb[p].T @ Rb[j]

    # ---- mesh
    Vf, Ff, Jidx, Jw = [], [], [], []
    nv = 0
    for mi in mesh_nodes:
        for P, tri, ji, wv in _mesh_primitives(path, rd, g, mi, skinned=True):
            Vf.append(P)
            Ff.append(tri + nv)
            Jidx.append(ji)
            Jw.append(wv)
            nv += len(P)
    Vfile = np.concatenate(Vf)
    Ffile = np.concatenate(Ff).astype(np.int64)
    ji, wv = np.concatenate(Jidx), np.concatenate(Jw)
    if len(Vfile) == 0 or len(Ffile) == 0:
        _fail(path, "the skinned mesh has no triangles")
    if not np.all(np.isfinite(Vfile)):
        _fail(path, f"{int((~np.isfinite(Vfile)).any(1).sum())} vertices have NaN or Inf "
                    "coordinates")
    if not np.all(np.isfinite(wv)) or np.any(wv < -1e-6):
        _fail(path, "WEIGHTS contain NaN, Inf or negative values")
    if np.any((ji < 0) | (ji >= Jf)) and np.any(wv[(ji < 0) | (ji >= Jf)] > 0):
        _fail(path, f"JOINTS refer to joints outside the skin's 0..{Jf - 1}")
    ji = np.clip(ji, 0, Jf - 1)
    wsum = wv.sum(1)
    if np.any(wsum <= 1e-9):
        _fail(path, f"{int((wsum <= 1e-9).sum())} vertices have all-zero weights")
    Vw = Vfile @ to_world[:3, :3].T + to_world[:3, 3]
    diag = float(np.linalg.norm(Vw.max(0) - Vw.min(0)))
    vmap, V = _merge_by_position(Vw, _MERGE_TOL * max(diag, 1e-12))
    F = vmap[Ffile]
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])]
    check_surface(path, V, F)

    # ---- weights per merged vertex (mean over merged file vertices), skeleton order
    W = np.zeros((len(V), Jf))
    np.add.at(W, (np.repeat(vmap, ji.shape[1]), new_of_skin[ji].ravel()),
              (wv / wsum[:, None]).ravel())
    W /= W.sum(1, keepdims=True)
    k = min(ji.shape[1], Jf)
    Widx = np.argsort(-W, axis=1, kind="stable")[:, :k]
    Wval = np.take_along_axis(W, Widx, axis=1)

    tips = _leaf_tips(Pb, Rb, parents, V, W)
    try:
        skel = Skeleton(names, parents, Pb, rest_rotations=rest_rot, tips=tips)
    except ValueError as e:
        _fail(path, f"skeleton: {e}")
    return GltfCharacter(path=path, V=V, F=F, skeleton=skel, Widx=Widx.astype(np.int64),
                         Wval=Wval, vertex_map=vmap, file_faces=Ffile,
                         joint_nodes=np.asarray(skin_nodes)[order], skin_joint=order,
                         bind_mismatch=(mis_p, mis_r), _gltf=g, _to_world=to_world)


def _leaf_tips(P: np.ndarray, R: np.ndarray, parents: np.ndarray, V: np.ndarray,
               W: np.ndarray) -> np.ndarray:
    """(J, 3) tip of every leaf joint (NaN for the others); see the module docstring."""
    J = len(P)
    tips = np.full((J, 3), np.nan)
    has_child = np.zeros(J, dtype=bool)
    has_child[parents[parents >= 0]] = True
    for j in np.flatnonzero(~has_child):
        p = parents[j]
        d = P[j] - P[p] if p >= 0 else np.zeros(3)
        parent_len = float(np.linalg.norm(d))
        d = d / parent_len if parent_len > 1e-6 else R[j][:, 1]
        mine = W[:, j] >= 0.5
        if mine.any():
            # The joint's direction: towards the weighted centroid of its own skin
            # (a toe points forward, not down its parent's line into the floor).
            c = (W[mine, j, None] * V[mine]).sum(0) / W[mine, j].sum() - P[j]
            if np.linalg.norm(c) > 1e-3:
                d = c / np.linalg.norm(c)
            reach = float(((V[mine] - P[j]) @ d).max())
            tips[j] = P[j] + d * max(reach, 0.01)
        else:
            tips[j] = P[j] + d * max(0.5 * parent_len, 0.01)
    return tips


def _animation_names(g) -> list:
    return [a.name or f"animation{i}" for i, a in enumerate(g.animations or [])]


def gltf_animation_names(path: str | Path) -> list:
    """Names of a glTF file's animations, reading only its JSON (no mesh or skin)."""
    return _animation_names(_read_document(Path(path)))


def load_gltf_character(path: str | Path):
    """``(V, F, skeleton)`` of a skinned glTF file, as :func:`load_character_file` returns."""
    c = load_gltf(path)
    return c.V, c.F, c.skeleton


# ---------------------------------------------------------------- animation
def _sample(times: np.ndarray, values: np.ndarray, t: np.ndarray, interp: str,
            rotation: bool) -> np.ndarray:
    """Values of one animation sampler at times ``t``, as glTF 2.0 interpolates.

    Parameters
    ----------
    times : (K,) float
        Key times, seconds, increasing.
    values : (K, w) float, or (3K, w) for CUBICSPLINE
        Key values; CUBICSPLINE stores (in-tangent, value, out-tangent) per key.
    t : (T,) float
        Sample times; before the first key and after the last the end key holds.
    interp : str
        ``LINEAR``, ``STEP`` or ``CUBICSPLINE``.
    rotation : bool
        Quaternions (x, y, z, w): LINEAR is a slerp, results are unit length.

    Returns
    -------
    (T, w) float
    """
    K = len(times)
    i = np.clip(np.searchsorted(times, t, side="right") - 1, 0, K - 1)
    i1 = np.minimum(i + 1, K - 1)
    dt = np.maximum(times[i1] - times[i], 1e-12)
    u = np.clip((t - times[i]) / dt, 0.0, 1.0)[:, None]
    if interp == "CUBICSPLINE":
        # p(u) = h00 v_k + h10 dt b_k + h01 v_k+1 + h11 dt a_k+1 (glTF 2.0, Appendix C)
        key = values.reshape(K, 3, -1)
        a, v, b = key[:, 0], key[:, 1], key[:, 2]
        u2, u3 = u * u, u * u * u
        h00, h10 = 2 * u3 - 3 * u2 + 1, u3 - 2 * u2 + u
        h01, h11 = -2 * u3 + 3 * u2, u3 - u2
        d = dt[:, None]
        p = h00 * v[i] + h10 * d * b[i] + h01 * v[i1] + h11 * d * a[i1]
        p = np.where((i == i1)[:, None], v[i], p)     # past the last key: hold it
        return p / np.linalg.norm(p, axis=1, keepdims=True) if rotation else p
    if interp == "STEP":
        u = np.zeros_like(u)
    a, b = values[i], values[i1]
    if not rotation:
        return a + u * (b - a)
    a = a / np.linalg.norm(a, axis=1, keepdims=True)
    b = b / np.linalg.norm(b, axis=1, keepdims=True)
    dot = (a * b).sum(1, keepdims=True)
    b = np.where(dot < 0, -b, b)
    dot = np.abs(dot)
    th = np.arccos(np.clip(dot, -1.0, 1.0))
    s = np.sin(th)
    small = s < 1e-6
    wa = np.where(small, 1.0 - u, np.sin((1.0 - u) * th) / np.where(small, 1.0, s))
    wb = np.where(small, u, np.sin(u * th) / np.where(small, 1.0, s))
    q = wa * a + wb * b
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def gltf_clip(char: GltfCharacter, which: int | str = 0, fps: float = 30.0) -> GltfClip:
    """Sample one of the file's animations as a clip of the character's pose channels.

    Parameters
    ----------
    char : GltfCharacter
    which : int or str
        Animation index or name.
    fps : float
        Sampling rate (any, > 0); frame ``k`` is time ``k / fps``, from 0 to the
        last key.

    Returns
    -------
    GltfClip
    """
    g, path = char._gltf, char.path
    anims = g.animations or []
    names = char.animation_names
    if isinstance(which, str) and not which.isdigit():
        if which not in names:
            _fail(path, f"no animation named '{which}' (animations: {names})")
        which = names.index(which)
    which = int(which)
    if not 0 <= which < len(anims):
        _fail(path, f"animation {which} does not exist (the file has {len(anims)})")
    if not fps > 0:
        _fail(path, f"animation sampling rate must be > 0, got {fps}")
    anim = anims[which]
    rd = _Reader(path, g)
    N = len(g.nodes)
    T_rest = np.array([n.translation or [0, 0, 0] for n in g.nodes], dtype=float)
    Q_rest = np.array([n.rotation or [0, 0, 0, 1] for n in g.nodes], dtype=float)
    S_rest = np.array([n.scale or [1, 1, 1] for n in g.nodes], dtype=float)
    tracks = []
    t_end = 0.0
    for ch in anim.channels:
        if ch.target.node is None or ch.target.path not in ("translation", "rotation", "scale"):
            continue                    # morph weights and extension targets do not move joints
        smp = anim.samplers[ch.sampler]
        times = rd.read(smp.input, "animation input").ravel()
        vals = rd.read(smp.output, "animation output")
        if len(times) == 0:
            continue
        interp = smp.interpolation or "LINEAR"
        per_key = 3 if interp == "CUBICSPLINE" else 1
        if interp not in ("LINEAR", "STEP", "CUBICSPLINE") or len(vals) != per_key * len(times):
            _fail(path, f"animation '{names[which]}' sampler {ch.sampler}: {interp} with "
                        f"{len(times)} keys needs {per_key * len(times)} values, has {len(vals)}")
        if np.any(np.diff(times) < 0):
            _fail(path, f"animation '{names[which]}' sampler {ch.sampler}: key times decrease")
        if g.nodes[ch.target.node].matrix is not None:
            _fail(path, f"node {ch.target.node} is animated but has a matrix (glTF forbids it)")
        tracks.append((ch.target.node, ch.target.path, times, vals, interp))
        t_end = max(t_end, float(times.max()))
    n_frames = int(np.floor(t_end * fps + 1e-6)) + 1
    t = np.arange(n_frames) / fps
    Tt = np.broadcast_to(T_rest, (n_frames, N, 3)).copy()
    Qt = np.broadcast_to(Q_rest, (n_frames, N, 4)).copy()
    St = np.broadcast_to(S_rest, (n_frames, N, 3)).copy()
    for node, kind, times, vals, interp in tracks:
        v = _sample(times, vals, t, interp, kind == "rotation")
        {"translation": Tt, "rotation": Qt, "scale": St}[kind][:, node] = v
    local = np.zeros((n_frames, N, 4, 4))
    local[..., :3, :3] = _quat_to_matrix(Qt) * St[..., None, :]
    local[..., :3, 3] = Tt
    local[..., 3, 3] = 1.0
    for i, n in enumerate(g.nodes):
        if n.matrix is not None:
            local[:, i] = _node_matrix(n)
    parent = _parents_of_nodes(path, g)
    Cz = np.eye(4)
    Cz[:3, :3] = Y_UP_TO_Z_UP
    Wt = np.empty_like(local)
    for i in _topological(parent):
        p = parent[i]
        Wt[:, i] = local[:, i] if p < 0 else Wt[:, p] @ local[:, i]
    Gj = Cz @ Wt[:, char.joint_nodes]                       # (T, J, 4, 4), project world
    Rj, _ = _orthonormal(Gj[..., :3, :3])
    skel = char.skeleton
    J = skel.n_joints
    q = np.zeros((n_frames, skel.n_channels))
    ignored = 0.0
    for j in range(J):
        p = skel.parents[j]
        Rp = np.eye(3) if p < 0 else Rj[:, p]
        Rq = np.swapaxes(Rp, -1, -2) @ Rj[:, j] @ skel.rest_rotations[j].T
        q[:, 3 + 3 * j: 6 + 3 * j] = matrix_to_euler_xyz(Rq)
        if p >= 0:
            off = np.einsum("tji,tj->ti", Rp, Gj[:, j, :3, 3] - Gj[:, p, :3, 3])
            ignored = max(ignored, float(np.abs(off - skel.offsets[j]).max()))
    q[:, 3:] = continuous_euler(q[:, 3:].reshape(n_frames, J, 3), 0).reshape(n_frames, 3 * J)
    q[:, :3] = Gj[:, 0, :3, 3] - skel.rest_positions[0]
    return GltfClip(name=names[which], channel_names=skel.channel_names, frames=q,
                    fps=float(fps), ignored_translation=ignored)


def _topological(parent: np.ndarray) -> list:
    order, seen = [], np.zeros(len(parent), dtype=bool)
    for i in range(len(parent)):
        chain = []
        while i >= 0 and not seen[i]:
            chain.append(i)
            i = parent[i]
        for k in reversed(chain):
            seen[k] = True
            order.append(k)
    return order


# ------------------------------------------------------- whole scenes (parts)
@dataclass
class GltfPart:
    """One mesh of a glTF scene as a part of the character (:func:`load_gltf_scene`).

    Attributes
    ----------
    name : str
        The mesh node's name (``node<k>`` when it has none).
    node, mesh : int
        glTF node and mesh index.
    kind : str
        ``"skinned"`` (bound to a skin's joints) or ``"rigid"`` (carried whole
        by one joint, or ``"static"`` when no joint is above it).
    V : (n, 3) float
        Rest surface in the project's world (metres, z up), merged by position.
    F : (m, 3) int
    vertex_map : (n_file,) int
        Merged index of every file vertex of the part.
    open_edges : int
        Edges with one triangle (0: closed); ``closed`` says the same.
    skin : int or None
        The skin of a skinned part.
    Widx, Wval : (n, k) int, float or None
        A skinned part's file weights, skeleton joint indices, rows summing to 1.
    joint : int
        The skeleton joint a rigid part follows (-1: static).
    local : (4, 4) float or None
        A rigid part's mesh frame in its joint's bind frame: posed points are
        ``G_joint @ local @ p_mesh``.
    file_V : (n_file, 3) float
        The file's vertices (every triangle primitive, in order), rest frame as ``V``.
    file_F : (m_file, 3) int
        The file's triangles over ``file_V`` (collapsed ones kept).
    file_joints, file_weights : (n_file, k) int, float or None
        A skinned part's weights per file vertex: skeleton joints, rows summing to 1.
    """

    name: str
    node: int
    mesh: int
    kind: str
    V: np.ndarray
    F: np.ndarray
    vertex_map: np.ndarray
    open_edges: int
    skin: int | None = None
    Widx: np.ndarray | None = None
    Wval: np.ndarray | None = None
    joint: int = -1
    local: np.ndarray | None = None
    file_V: np.ndarray | None = field(default=None, repr=False)
    file_F: np.ndarray | None = field(default=None, repr=False)
    file_joints: np.ndarray | None = field(default=None, repr=False)
    file_weights: np.ndarray | None = field(default=None, repr=False)

    @property
    def closed(self) -> bool:
        return self.open_edges == 0

    @property
    def n_file_vertices(self) -> int:
        return len(self.vertex_map)


@dataclass
class GltfScene:
    """Every mesh of a glTF scene on one skeleton (:func:`load_gltf_scene`).

    Attributes
    ----------
    path : Path
    skeleton : Skeleton
        The joints of every skin, joined (a joint two skins share is one
        joint), under one root; ``q = 0`` is the bind pose.
    joint_nodes : (J,) int
        glTF node of every skeleton joint.
    parts : list of GltfPart
    warnings : list of str
        Disagreements kept rather than refused (a joint two skins bind
        differently: the first skin's bind is used; a node hierarchy whose rest
        pose is not the inverse bind matrices' bind pose: the IBMs are used).
    notes : list of str
        What was not read, and why: primitives that are points or lines, morph
        targets, meshes without triangles, mesh nodes outside the scene.
    """

    path: Path
    skeleton: Skeleton
    joint_nodes: np.ndarray
    parts: list
    warnings: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    _gltf: object = field(default=None, repr=False)
    _bind_rotations: np.ndarray = field(default=None, repr=False)

    @property
    def animation_names(self) -> list:
        return _animation_names(self._gltf)

    def clip(self, which: int | str = 0, fps: float = 30.0) -> GltfClip:
        """:func:`gltf_clip` of the joined skeleton."""
        return gltf_clip(self, which, fps)

    def posed(self, q: np.ndarray) -> list:
        """(n, 3) points of every part under pose ``q``: skinned parts by linear
        blend skinning with the file's weights, rigid ones by their joint."""
        M = self.skeleton.skinning_matrices(q)
        out = []
        for p in self.parts:
            Vh = np.c_[p.V, np.ones(len(p.V))]
            if p.kind == "skinned":
                X = np.einsum("nk,nkij,nj->ni", p.Wval, M[p.Widx], Vh)[:, :3]
            elif p.joint >= 0:
                X = Vh @ M[p.joint].T[:, :3]
            else:
                X = p.V.copy()
            out.append(X)
        return out

    def report(self) -> list:
        """One line per part: vertices, closed or open, skinned or rigid (and on what)."""
        return [f"part '{p.name}' (node {p.node}, mesh {p.mesh}): {self._source(p)}, "
                f"{len(p.V)} vertices ({p.n_file_vertices} in the file), {len(p.F)} triangles, "
                f"{_shape(p)}" for p in self.parts]

    def _source(self, p: GltfPart) -> str:
        return (f"skinned on skin {p.skin}" if p.kind == "skinned" else
                f"rigid on joint '{self.skeleton.names[p.joint]}'" if p.kind == "rigid" else
                "static (no joint above it)")

    def split_body(self, min_share: float = BODY_MIN_SHARE) -> "GltfBody":
        """The scene as one character: its simulated body and its passengers.

        The body is the union of the skinned parts that form closed surfaces:
        parts that share vertex positions (a character split into meshes, or
        over two skins) are joined first, and a joined group that is closed,
        manifold and outward facing, whose shells (connected pieces) do not
        pass through each other at rest and are not each bound wholly to one
        joint (rigid pieces), with at least ``min_share`` of the
        largest such group's volume, is body. Of a group that is no such
        surface joined, the largest part that is one alone is a candidate
        alone; of candidates that pass through each other at rest, the larger
        is body. Every other part is a passenger
        (:mod:`skin_node.parts`): skinned ones by dual quaternions, rigid ones by
        their joint, static ones at rest. The body's vertices come first in the
        surface (merged over its parts, in the order of the file's vertices),
        then every passenger's, in node order. For a file of one closed
        skinned mesh, the body is what :func:`load_gltf` reads.

        Returns
        -------
        GltfBody
        """
        parts, J = self.parts, self.skeleton.n_joints
        shape = {i: _shape(p) for i, p in enumerate(parts)}
        candidates = []
        for group in _touching(parts):
            p0 = parts[group[0]]
            V, F, _, Widx, Wval = (p0.V, p0.F, None, p0.Widx, p0.Wval) if len(group) == 1 else \
                _join([parts[i] for i in group], J)[:5]
            problem = _body_problem(V, F, Widx, Wval)
            for i in group:
                others = _names([parts[j].name for j in group if j != i])
                also = f" (joined with {others})" if others else ""
                shape[i] = f"not a body part: {problem}{also}" if problem else f"closed{also}"
            if not problem:
                candidates.append((group, mesh_volume(V, F), V, F))
            elif len(group) > 1:
                # parts that touch but do not join into one surface (a robot's
                # shell and the joint caps set into it, sharing a few vertex
                # positions): the largest that is a surface on its own is a
                # body part alone, the others ride along
                alone = []
                for i in group:
                    own = _body_problem(parts[i].V, parts[i].F, parts[i].Widx, parts[i].Wval)
                    if own is None:
                        alone.append((mesh_volume(parts[i].V, parts[i].F), i))
                    else:
                        shape[i] += f"; alone, {own}"
                if alone:
                    vol, i = max(alone)
                    shape[i] = (f"closed (alone: joined with the parts it touches, {problem})")
                    candidates.append(([i], vol, parts[i].V, parts[i].F))
        largest = max((c[1] for c in candidates), default=0.0)
        kept = []
        for group, vol, V, F in candidates:
            if vol >= min_share * largest:
                kept.append((group, vol, V, F))
                continue
            for i in group:
                shape[i] = (f"closed but tiny ({vol / largest:.2%} of the largest closed "
                            f"part's volume, under {min_share:.0%})")
        # closed parts that pass through each other at rest (a shirt's hem
        # over the trousers, a helmet set into the head): the larger is body
        kept.sort(key=lambda c: -c[1])
        body = []
        for k, crossed in enumerate(_crossed_by_larger([(V, F) for _, _, V, F in kept])):
            group = kept[k][0]
            if crossed is None:
                body += group
                continue
            names = _names([parts[i].name for i in kept[crossed[0]][0]])
            for i in group:
                shape[i] = (f"not a body part: passes through {names} at rest ({crossed[1]} "
                            "intersecting triangle pairs)")
        body.sort()
        skel = self.skeleton
        if body:
            V, F, vmap, Widx, Wval, file_off = _join([parts[i] for i in body], J)
            check_surface(self.path, V, F)
            W = np.zeros((len(V), J))
            np.put_along_axis(W, Widx, Wval, axis=1)
            tips = _leaf_tips(skel.rest_positions, self._bind_rotations, skel.parents, V, W)
            try:
                skel = Skeleton(skel.names, skel.parents, skel.rest_positions,
                                rest_rotations=skel.rest_rotations, tips=tips,
                                limits=skel.limits)
            except ValueError as e:
                _fail(self.path, f"skeleton: {e}")
        else:
            V, F, vmap = np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
            Widx, Wval, file_off = np.zeros((0, 1), np.int64), np.zeros((0, 1)), [0]
        rows = {i: vmap[file_off[k]:file_off[k + 1]] for k, i in enumerate(body)}

        # ---- passengers, after the body in node order
        riders = [i for i in range(len(parts)) if i not in rows]
        k = max([parts[i].Widx.shape[1] for i in riders if parts[i].kind == "skinned"],
                default=1)
        PV, PF, skinned, pidx, pval, rigid, joint = [], [], [], [], [], [], []
        n = 0
        for i in riders:
            p = parts[i]
            rows[i] = len(V) + n + p.vertex_map
            PV.append(p.V)
            PF.append(p.F + n)
            local = n + np.arange(len(p.V))
            if p.kind == "skinned":
                skinned.append(local)
                pidx.append(np.pad(p.Widx, ((0, 0), (0, k - p.Widx.shape[1]))))
                pval.append(np.pad(p.Wval, ((0, 0), (0, k - p.Wval.shape[1]))))
            elif p.kind == "rigid":
                rigid.append(local)
                joint.append(np.full(len(p.V), p.joint))
            n += len(p.V)
        cat = lambda a, empty: np.concatenate(a) if a else np.zeros(empty)  # noqa: E731
        passengers = Passengers(cat(PV, (0, 3)), cat(PF, (0, 3)), cat(skinned, 0),
                                cat(pidx, (0, k)), cat(pval, (0, k)), cat(rigid, 0),
                                cat(joint, 0))
        info = [Part(p.name, p.kind, "solved" if i in body else p.kind, rows[i], len(p.V),
                     len(p.F), self._source(p), shape[i]) for i, p in enumerate(parts)]
        order = body + riders                   # the file's vertices: the body's, then the rest
        n_file = np.cumsum([0] + [parts[i].n_file_vertices for i in order])
        file_faces = np.concatenate([parts[i].file_F + o for i, o in zip(order, n_file)])
        notes = list(self.notes)
        if not body:
            notes.append("no skinned part to solve (each part's line says why): the whole "
                         "character is posed without the pipeline's stages (skinned parts by "
                         "dual quaternions)")
        return GltfBody(V=V, F=F, Widx=Widx, Wval=Wval, skeleton=skel, passengers=passengers,
                        parts=info, file_order=np.concatenate([rows[i] for i in order]),
                        file_faces=file_faces, notes=notes)


@dataclass
class GltfBody:
    """A glTF scene as one character (:meth:`GltfScene.split_body`).

    Attributes
    ----------
    V, F : (n, 3) float, (m, 3) int
        The simulated body: its closed skinned parts joined (empty when it
        has none).
    Widx, Wval : (n, k) int, float
        The body's file weights, skeleton joints, rows summing to 1.
    skeleton : Skeleton
        The scene's, leaf joints' tips taken from the body's vertices (from
        every part's when there is no body).
    passengers : Passengers
        Every other part, posed after the body.
    parts : list of Part
        Every part in node order: its rows of the surface (body, then
        passengers) and what it gets.
    file_order : (n_file,) int
        Row of the surface of every file vertex: the body parts' (node order),
        then the passengers' (node order).
    file_faces : (m_file, 3) int
        The file's triangles over the vertices of ``file_order``.
    notes : list of str
        What was not read and why (:attr:`GltfScene.notes`), and a line when
        there is no body.
    """

    V: np.ndarray
    F: np.ndarray
    Widx: np.ndarray
    Wval: np.ndarray
    skeleton: Skeleton
    passengers: Passengers
    parts: list
    file_order: np.ndarray
    file_faces: np.ndarray
    notes: list = field(default_factory=list)


def _shape(p: GltfPart) -> str:
    return "closed" if p.closed else f"open ({p.open_edges} edges with one triangle)"


def _names(names: list, most: int = 3) -> str:
    """``'a', 'b', 'c' and 4 more``: a part's line stays a line when it is
    joined with dozens (Khronos's BrainStem joins 41 meshes)."""
    shown = ", ".join(repr(n) for n in names[:most])
    return shown + (f" and {len(names) - most} more" if len(names) > most else "")


def _crossed_by_larger(surfaces: list) -> list:
    """For each closed surface ``(V, F)`` of ``surfaces`` (largest first):
    None if it passes through none of the larger ones kept, else ``(k, n)``,
    the first such ``surfaces[k]`` and their intersecting triangle pairs at
    rest. A surface crossed is not kept, so what it crosses counts no more."""
    out = [None] * len(surfaces)
    if len(surfaces) < 2:
        return out
    from ..kernels.intersect import SelfIntersections
    off = np.cumsum([0] + [len(V) for V, _ in surfaces])
    V = np.concatenate([V for V, _ in surfaces])
    F = np.concatenate([F + o for (_, F), o in zip(surfaces, off)])
    owner = np.repeat(np.arange(len(surfaces)), [len(f) for _, f in surfaces])
    P = owner[SelfIntersections(V, F, 0.0).pairs(V)]
    P = np.sort(P[P[:, 0] != P[:, 1]], axis=1)          # (larger, smaller) surfaces
    kept = np.ones(len(surfaces), dtype=bool)
    for k in range(1, len(surfaces)):
        hit = P[(P[:, 1] == k) & kept[P[:, 0]]]
        if len(hit):
            kept[k] = False
            first = int(hit[:, 0].min())
            out[k] = (first, int(np.count_nonzero(hit[:, 0] == first)))
    return out


#: A vertex with at least this weight on one joint is bound wholly to it.
_WHOLLY = 0.999


def _rigid_pieces(F: np.ndarray, Widx: np.ndarray, Wval: np.ndarray) -> str | None:
    """What makes a closed skinned surface no body: each of its shells bound
    wholly to one joint, a robot's rigid pieces (Khronos's BrainStem). No
    joint bends skin there, so no stage has anything to correct; solved, the
    contact and volume stages bent the pieces (BrainStem on its own weights:
    27 sharp folds against DQS's 0, volume 0.66). None when any vertex blends
    joints or any shell spans two."""
    if Wval is None or not len(Wval) or Wval.max(axis=1).min() < _WHOLLY:
        return None
    count, label = shells(F, len(Wval))
    top = Widx[np.arange(len(Widx)), Wval.argmax(axis=1)]
    joints = {(int(a), int(b)) for a, b in zip(label, top)}
    if len(joints) != count:
        return None
    return (f"rigid pieces: each of its {count} shell{'s' if count > 1 else ''} is bound "
            "wholly to one joint (no skin bends)")


def _body_problem(V: np.ndarray, F: np.ndarray, Widx: np.ndarray,
                  Wval: np.ndarray) -> str | None:
    """What keeps a closed skinned surface (weights ``Widx, Wval``) from being
    body: :func:`~skin_node.io.character_file.surface_problem`, else
    :func:`~skin_node.io.character_file.crossing_shells`, else
    :func:`_rigid_pieces` (None: nothing)."""
    return surface_problem(V, F) or crossing_shells(V, F) or _rigid_pieces(F, Widx, Wval)


def _touching(parts: list) -> list:
    """Groups (lists of indices, in node order) of the skinned parts that share
    vertex positions (within ``1e-6`` of their bounding-box diagonal)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    skinned = [i for i, p in enumerate(parts) if p.kind == "skinned"]
    if len(skinned) < 2:
        return [[i] for i in skinned]
    P = np.concatenate([parts[i].V for i in skinned])
    owner = np.repeat(np.arange(len(skinned)), [len(parts[i].V) for i in skinned])
    diag = float(np.linalg.norm(P.max(0) - P.min(0)))
    label, _ = _merge_by_position(P, _MERGE_TOL * max(diag, 1e-12))
    B = coo_matrix((np.ones(len(P)), (owner, label)), shape=(len(skinned), label.max() + 1))
    _, group = connected_components((B @ B.T).tocsr(), directed=False)
    return [[skinned[k] for k in np.flatnonzero(group == c)]
            for c in dict.fromkeys(group.tolist())]


def _join(parts: list, J: int) -> tuple:
    """:func:`_merge_part` of several skinned parts' file vertices together, and
    where each part's file vertices start: ``(V, F, vertex_map, Widx, Wval,
    offsets)``."""
    k = max(p.file_joints.shape[1] for p in parts)
    off = np.cumsum([0] + [p.n_file_vertices for p in parts])
    pad = lambda a: np.pad(a, ((0, 0), (0, k - a.shape[1])))  # noqa: E731
    return (*_merge_part(np.concatenate([p.file_V for p in parts]),
                         np.concatenate([p.file_F + o for p, o in zip(parts, off)]),
                         np.concatenate([pad(p.file_joints) for p in parts]),
                         np.concatenate([pad(p.file_weights) for p in parts]), J), off)


def _merge_part(Vw: np.ndarray, Ff: np.ndarray, joints: np.ndarray | None,
                weights: np.ndarray | None, J: int) -> tuple:
    """A mesh's file points ``Vw`` (n_file, 3) merged by position (within
    ``1e-6`` of their bounding-box diagonal) and its file triangles ``Ff`` over
    them, collapsed ones dropped: ``(V, F, vertex_map, Widx, Wval)``. With
    ``joints, weights`` (n_file, k) (skeleton joints, rows summing to 1), a
    merged vertex takes the mean of its file vertices' weights, its ``k``
    largest kept (``Widx, Wval`` are None without)."""
    diag = float(np.linalg.norm(Vw.max(0) - Vw.min(0))) if len(Vw) else 0.0
    vmap, V = _merge_by_position(Vw, _MERGE_TOL * max(diag, 1e-12))
    F = vmap[Ff]
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])]
    if joints is None:
        return V, F, vmap, None, None
    W = np.zeros((len(V), J))
    np.add.at(W, (np.repeat(vmap, joints.shape[1]), joints.ravel()), weights.ravel())
    W /= W.sum(1, keepdims=True)
    Widx = np.argsort(-W, axis=1, kind="stable")[:, :min(joints.shape[1], J)].astype(np.int64)
    return V, F, vmap, Widx, np.take_along_axis(W, Widx, axis=1)


def _moving_points(parts: list, J: int) -> tuple[np.ndarray, np.ndarray]:
    """(points (n, 3), dense weights (n, J)) of parts: skinned ones by their
    weights, rigid ones wholly on their joint, static ones on none."""
    V = np.concatenate([p.V for p in parts])
    W = np.zeros((len(V), J))
    row = 0
    for p in parts:
        if p.kind == "skinned":
            np.put_along_axis(W[row:row + len(p.V)], p.Widx, p.Wval, axis=1)
        elif p.kind == "rigid":
            W[row:row + len(p.V), p.joint] = 1.0
        row += len(p.V)
    return V, W


def _open_edges(F: np.ndarray) -> int:
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    _, counts = np.unique(E, axis=0, return_counts=True)
    return int((counts == 1).sum())


def _scene_nodes(g) -> list:
    """Nodes of the default scene (all nodes when the file has no scene)."""
    if not g.scenes:
        return list(range(len(g.nodes)))
    out, todo = [], list(g.scenes[g.scene or 0].nodes or [])
    while todo:
        i = todo.pop()
        out.append(i)
        todo.extend(g.nodes[i].children or [])
    return sorted(out)


def load_gltf_scene(path: str | Path) -> GltfScene:
    """Every mesh of a glTF file's scene, on one skeleton.

    * **Skinned meshes** on any number of skins: the skins' joints are joined
      into one skeleton (a joint's parent is its nearest ancestor node that is
      a joint of any skin; several trees are joined under their nearest common
      ancestor node, which becomes the root). A joint's bind pose comes from
      the inverse bind matrices of the first skin that lists it (another
      skin's differing by more than 0.1 mm or 1e-3 rad is reported in
      :attr:`GltfScene.warnings`); a joint no skin lists (the common
      ancestor), from the node hierarchy's rest pose. Each part's vertices are
      in its skin's space, as :func:`load_gltf` takes them.
    * **Meshes without a skin** are rigid parts of the joint nearest above
      their node (the node itself when it is a joint), with their mesh frame
      in that joint's bind frame (an animation of non-joint nodes between the
      two is not followed); with no joint above them they are static. Without
      any skin (a robot of rigid links), the mesh nodes and every node above
      them are the joints, each link following its own node.
    * Each part is merged by position on its own and reported open or closed;
      nothing is refused for being open (that is for the caller to decide).

    Raises
    ------
    CharacterFileError
        ``"<path>: <problem>"`` for an unreadable file, a broken node
        hierarchy, no mesh in the scene, joints with no common ancestor, bad
        primitives, weights or non-uniformly scaled joints.
    """
    path, g, rd, parent = _open(path)
    in_scene = _scene_nodes(g)
    mesh_nodes = [i for i in in_scene if g.nodes[i].mesh is not None]
    if not mesh_nodes:
        _fail(path, "its scene has no mesh")
    skins = sorted({g.nodes[i].skin for i in mesh_nodes if g.nodes[i].skin is not None})
    for s in skins:
        if not 0 <= s < len(g.skins or []) or not g.skins[s].joints:
            _fail(path, f"skin {s} does not exist or has no joints")
    joints = []
    for s in skins:
        joints += [int(j) for j in g.skins[s].joints if int(j) not in joints]
    if not skins:            # rigid links only: the mesh nodes and those above are joints
        for i in mesh_nodes:
            a = i
            while a >= 0:
                if a not in joints:
                    joints.append(int(a))
                a = parent[a]
    if not joints:
        _fail(path, "no skin and no node above its meshes: nothing to pose")
    bad = [j for j in joints if not 0 <= j < len(g.nodes)]
    if bad:
        _fail(path, f"skins list joints {bad} that are not nodes of the file")

    def ancestors(i):
        out = []
        while i >= 0:
            out.append(int(i))
            i = parent[i]
        return out

    def joint_parent(n):
        a = parent[n]
        while a >= 0 and a not in joints:
            a = parent[a]
        return int(a)

    roots = [j for j in joints if joint_parent(j) < 0]
    if len(roots) > 1:      # join the trees under their nearest common ancestor node
        common = set(ancestors(roots[0]))
        for r in roots[1:]:
            common &= set(ancestors(r))
        if not common:
            _fail(path, f"the joints form {len(roots)} trees (roots: nodes {roots}) with no "
                        "common ancestor node; one skeleton needs one root")
        joints.append(max(common, key=lambda a: len(ancestors(a))))
    root = next(j for j in joints if joint_parent(j) < 0)
    order = [root]
    for j in order:             # breadth first: parents before children
        order.extend(k for k in joints if joint_parent(k) == j)
    index = {n: k for k, n in enumerate(order)}
    parents = np.array([-1 if joint_parent(n) < 0 else index[joint_parent(n)] for n in order])
    # Names as load_gltf gives them: an unnamed joint is joint<k>, k its index in
    # the (first) skin listing it, as in JOINTS_0; other nodes node<n>.
    in_skin = {}
    for s in skins:
        for k, n in enumerate(g.skins[s].joints):
            in_skin.setdefault(int(n), k)
    names, used = [], set()
    for n in order:
        k = in_skin.get(n, n)
        nm = g.nodes[n].name or (f"joint{k}" if n in in_skin else f"node{n}")
        nm = nm if nm not in used else f"{nm}_{k}"
        used.add(nm)
        names.append(nm)

    # ---- bind pose: the first skin's IBMs, else the node's rest
    Wn = _world_matrices(g, parent)
    Cz = np.eye(4)
    Cz[:3, :3] = Y_UP_TO_Z_UP
    J = len(order)
    B = np.array([Cz @ Wn[n] for n in order])
    bound = np.zeros(J, dtype=bool)
    skin_space, warn = {}, []
    for s in skins:
        sj = [int(j) for j in g.skins[s].joints]
        if g.skins[s].inverseBindMatrices is not None:
            IBM = rd.read(g.skins[s].inverseBindMatrices, f"skin {s} inverseBindMatrices")
            if IBM.shape != (len(sj), 16):
                _fail(path, f"skin {s}: {len(IBM)} inverse bind matrices for {len(sj)} joints")
            IBM = IBM.reshape(-1, 4, 4).transpose(0, 2, 1)
        else:
            IBM = np.tile(np.eye(4), (len(sj), 1, 1))
        if not np.all(np.isfinite(IBM)):
            _fail(path, f"skin {s}: inverse bind matrices contain NaN or Inf")
        top = next(j for j in sj if all(a not in sj for a in ancestors(j)[1:]))
        to_world = Cz @ (Wn[parent[top]] if parent[top] >= 0 else np.eye(4))
        skin_space[s] = to_world
        try:
            Bs = to_world @ np.linalg.inv(IBM)
        except np.linalg.LinAlgError:
            _fail(path, f"skin {s}: an inverse bind matrix is singular")
        Rn = Cz @ Wn[sj]            # the node hierarchy's rest pose, as load_gltf checks it
        mis_p = float(np.abs(Rn[:, :3, 3] - Bs[:, :3, 3]).max())
        mis_r = float(_rotation_angle(np.swapaxes(_orthonormal(Rn[:, :3, :3])[0], 1, 2)
                                      @ _orthonormal(Bs[:, :3, :3])[0]).max())
        scale = float(np.cbrt(abs(np.linalg.det(to_world[:3, :3]))))
        if mis_p > _MISMATCH_POS * max(scale, 1e-9) or mis_r > _MISMATCH_ROT:
            warn.append(f"the node hierarchy's rest pose differs from skin {s}'s inverse bind "
                        f"matrices by up to {mis_p * 1000:.2f} mm / {np.degrees(mis_r):.2f} "
                        "deg; using the inverse bind matrices (the vertices are bound to them)")
        for k, n in enumerate(sj):
            j = index[n]
            if not bound[j]:
                B[j], bound[j] = Bs[k], True
                continue
            dp = float(np.abs(B[j][:3, 3] - Bs[k][:3, 3]).max())
            dr = float(_rotation_angle(_orthonormal(B[j][:3, :3])[0].T
                                       @ _orthonormal(Bs[k][:3, :3])[0]))
            if dp > _MISMATCH_POS or dr > _MISMATCH_ROT:
                warn.append(f"joint '{names[j]}': skin {s} binds it {dp * 1000:.2f} mm / "
                            f"{np.degrees(dr):.2f} deg away from the first skin's bind; "
                            "using the first")
    Rb, sv = _orthonormal(B[:, :3, :3])
    if np.any(np.abs(sv / np.maximum(sv.mean(1, keepdims=True), 1e-12) - 1.0) > 1e-2):
        _fail(path, "joints have non-uniform scale in the bind pose; rigid skeletons only")
    Pb = B[:, :3, 3]
    Bn = np.tile(np.eye(4), (J, 1, 1))      # the bind frames, rotations orthonormal
    Bn[:, :3, :3], Bn[:, :3, 3] = Rb, Pb
    rest_rot = np.array([Rb[j] if parents[j] < 0 else Rb[parents[j]].T @ Rb[j]
                         for j in range(J)])

    # ---- parts
    parts, notes = [], []
    for i in mesh_nodes:
        node = g.nodes[i]
        skinned = node.skin is not None
        name = node.name or (g.meshes[node.mesh].name if g.meshes[node.mesh].name else f"node{i}")
        prims = list(_mesh_primitives(path, rd, g, i, skinned=skinned, notes=notes))
        if not sum(len(t) for _, t, _, _ in prims):
            notes.append(f"part '{name}' (node {i}, mesh {node.mesh}) skipped: it has no "
                         "triangles")
            continue
        P = np.concatenate([p for p, _, _, _ in prims])
        off = np.cumsum([0] + [len(p) for p, _, _, _ in prims])
        Ff = np.concatenate([t + o for (_, t, _, _), o in zip(prims, off)]).astype(np.int64)
        if not np.all(np.isfinite(P)):
            _fail(path, f"mesh {node.mesh}: vertices have NaN or Inf coordinates")
        Mw = skin_space[node.skin] if skinned else Cz @ Wn[i]
        Vw = P @ Mw[:3, :3].T + Mw[:3, 3]
        fj = fw = None
        if skinned:
            sj = [index[int(n)] for n in g.skins[node.skin].joints]
            ji = np.concatenate([a for _, _, a, _ in prims])
            wv = np.concatenate([b for _, _, _, b in prims])
            if not np.all(np.isfinite(wv)) or np.any(wv < -1e-6):
                _fail(path, f"mesh {node.mesh}: WEIGHTS contain NaN, Inf or negative values")
            out = (ji < 0) | (ji >= len(sj))
            if np.any(wv[out] > 0):
                _fail(path, f"mesh {node.mesh}: JOINTS refer to joints outside skin "
                            f"{node.skin}'s 0..{len(sj) - 1}")
            wsum = wv.sum(1)
            if np.any(wsum <= 1e-9):
                _fail(path, f"mesh {node.mesh}: {int((wsum <= 1e-9).sum())} vertices have "
                            "all-zero weights")
            fj, fw = np.asarray(sj)[np.clip(ji, 0, len(sj) - 1)], wv / wsum[:, None]
        V, F, vmap, Widx, Wval = _merge_part(Vw, Ff, fj, fw, J)
        if not len(F):
            notes.append(f"part '{name}' (node {i}, mesh {node.mesh}) skipped: all its "
                         "triangles collapse when vertices are merged by position")
            continue
        part = GltfPart(name, i, int(node.mesh), "skinned" if skinned else "rigid", V, F, vmap,
                        _open_edges(F), file_V=Vw, file_F=Ff, file_joints=fj, file_weights=fw)
        if skinned:
            part.skin, part.Widx, part.Wval = int(node.skin), Widx, Wval
        else:
            above = i if i in index else joint_parent(i)
            if above >= 0:
                part.joint = index[above]
                part.local = np.linalg.inv(Bn[part.joint]) @ (Cz @ Wn[i])
            else:
                part.kind, part.local = "static", Cz @ Wn[i]
        parts.append(part)
    if not parts:
        _fail(path, "no mesh of its scene has triangles (" + "; ".join(notes) + ")")
    outside = [i for i, n in enumerate(g.nodes) if n.mesh is not None and i not in in_scene]
    if outside:
        notes.append(f"mesh nodes {outside} are not in the scene and are not read")

    # ---- tips of leaf joints from every part that moves with them
    tips = _leaf_tips(Pb, Rb, parents, *_moving_points(parts, J))
    try:
        skel = Skeleton(names, parents, Pb, rest_rotations=rest_rot, tips=tips)
    except ValueError as e:
        _fail(path, f"skeleton: {e}")
    return GltfScene(path=path, skeleton=skel, joint_nodes=np.asarray(order), parts=parts,
                     warnings=warn, notes=notes, _gltf=g, _bind_rotations=Rb)
