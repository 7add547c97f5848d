"""Character files: a closed surface mesh plus a skeleton, described in YAML.

A character file names its mesh (any format trimesh reads: OBJ, PLY, STL, OFF,
glTF without a skin; a relative path is relative to the YAML file) and lists
the skeleton's joints, parents first, in metres::

    mesh: arm.obj            # or inline: vertices: [[x, y, z], ...], faces: [[i, j, k], ...]
    scale: 1.0               # optional, applied to the mesh and the joints
    joints:
      - {name: shoulder, position: [0.0, 0.0, 0.0]}
      - {name: elbow, parent: shoulder, position: [0.27, 0.0, 0.0]}
      - {name: wrist, parent: elbow, position: [0.50, 0.0, 0.0], tip: [0.60, 0.0, 0.0]}

Every leaf joint needs a ``tip`` (where its bone ends). Optional per joint:
``limits: [[min, max], [min, max], [min, max]]`` in radians for rx, ry, rz.
Instead of ``joints``, ``template: humanoid`` (or ``quadruped``, or a template
YAML path) embeds that template skeleton in the mesh automatically
(:mod:`skin_node.rigging.embed`); optional ``up:`` / ``forward:`` (``y``,
``-z``, ...) say how the mesh is oriented when detection would get it wrong.
The fit is checked; its figures are printed in one line at start-up, and a fit
that fails its checks is refused with the check and the hint that would help.
Errors name the file and say what is wrong with it: a bad mesh names the mesh
file first, then the character file that named it.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import yaml

from ..metrics import shells
from ..rigging.embed import fit_template, load_template
from ..skeleton import Skeleton


class CharacterFileError(ValueError):
    """A character file that cannot be used, with the reason."""


def _fail(path: Path, msg: str):
    raise CharacterFileError(f"{path}: {msg}")


def file_template(path: Path):
    """The :class:`~skin_node.rigging.embed.Template` the character file
    ``path`` fits its skeleton from, None for hand-placed joints or a file
    that cannot say (loading it reports why)."""
    try:
        doc = yaml.safe_load(Path(path).read_text())
        if isinstance(doc, dict) and "template" in doc and "joints" not in doc:
            return load_template(str(doc["template"]))
    except (OSError, UnicodeDecodeError, yaml.YAMLError, ValueError):
        pass
    return None


def file_clip_name(path: Path) -> str | None:
    """The built-in clip the character of file ``path`` plays when none is
    named: its skeleton template's (``clip:`` of ``config/templates/*.yaml``;
    a quadruped walks as a quadruped), None as for :func:`file_template`."""
    t = file_template(path)
    return t.clip if t is not None else None


def load_character_file(path: Path, verbose: bool = True):
    """Read a character file.

    With ``template:``, the embedded skeleton's checks and their figures are
    printed to stderr in one line (``verbose``), and a fit that fails them is
    refused (:mod:`skin_node.rigging.embed`).

    Returns
    -------
    V : (n, 3) float, F : (m, 3) int, skeleton : Skeleton

    Raises
    ------
    CharacterFileError
        ``"<path>: <problem>"`` for a missing, empty or malformed file, an open,
        non-manifold or degenerate mesh, NaN coordinates, or a skeleton with
        unknown parents, cycles or duplicate names.
    """
    path = Path(path)
    if not path.exists():
        _fail(path, "no such file")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        _fail(path, f"cannot be read ({e.__class__.__name__}: {e})")
    if not text.strip():
        _fail(path, "file is empty")
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark else ""
        _fail(path, f"malformed YAML{where}: {getattr(e, 'problem', e)}")
    if not isinstance(doc, dict):
        _fail(path, "expected a mapping with 'mesh' (or 'vertices' and 'faces') and 'joints'")
    scale = float(doc.get("scale", 1.0))
    V, F, mesh_path = _mesh(path, doc)
    V = V * scale
    if mesh_path is None:
        check_surface(path, V, F)
    else:
        # A bad surface is the mesh file's fault: name it first, and the YAML that named it.
        try:
            check_surface(mesh_path, V, F)
        except CharacterFileError as e:
            raise CharacterFileError(f"{e} (the mesh of {path})") from None
    return V, F, _skeleton(path, doc, scale, V, F, verbose)


def _mesh(path: Path, doc: dict):
    """(V, F, mesh file or None for an inline mesh) of a character file."""
    mesh_path = None
    if "mesh" in doc:
        mesh_path = (path.parent / str(doc["mesh"])).resolve()
        named = f"(the mesh of {path})"
        if not mesh_path.exists():
            _fail(mesh_path, f"mesh file does not exist {named}")
        import trimesh          # deferred: a heavy import (0.2-0.5 s) only mesh files need
        try:
            m = trimesh.load(mesh_path, force="mesh", process=False)
        except Exception as e:  # trimesh raises many kinds for bad files
            _fail(mesh_path, f"cannot be read as a mesh ({e}) {named}")
        V, F = np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)
        if V.ndim != 2 or V.shape[1:] != (3,) or len(V) == 0 or F.ndim != 2 \
                or F.shape[1:] != (3,) or len(F) == 0:
            _fail(mesh_path, f"holds no triangles ({len(V)} vertices, {len(F)} faces) {named}")
        # Exporters split vertices at UV seams: merge by position for a closed surface.
        V, inv = np.unique(np.round(V, 9), axis=0, return_inverse=True)
        F = inv.reshape(-1)[F]
    elif "vertices" in doc and "faces" in doc:
        try:
            V = np.asarray(doc["vertices"], dtype=float)
            F = np.asarray(doc["faces"], dtype=np.int64)
        except (TypeError, ValueError) as e:
            _fail(path, f"vertices/faces are not numeric arrays ({e})")
    else:
        _fail(path, "needs 'mesh: <file>' or inline 'vertices' and 'faces'")
    if mesh_path is not None:
        return V, F, mesh_path
    if V.ndim != 2 or V.shape[1] != 3 or len(V) == 0:
        _fail(path, f"vertices must be an (n, 3) array, got shape {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3 or len(F) == 0:
        _fail(path, f"faces must be an (m, 3) array of triangles, got shape {F.shape}")
    return V, F, None


def crossing_shells(V: np.ndarray, F: np.ndarray) -> str | None:
    """What keeps a closed surface of several shells (connected pieces) from
    being one body's skin: shells that pass through each other at rest, as a
    robot's plates or a limb modelled stuck into the torso do (None: nothing).
    The stages keep each part's skin out of the others' flesh; flesh that
    overlaps at rest is contact everywhere (Mixamo's Y Bot solved whole: 0.2 s
    a frame and nearly four times DQS's sharp folds)."""
    count, label = shells(F, len(V))
    if count < 2:
        return None
    from ..kernels.intersect import SelfIntersections
    P = SelfIntersections(V, F, 0.0).pairs(V)
    tl = label[F[:, 0]]
    crossing = int(np.count_nonzero(tl[P[:, 0]] != tl[P[:, 1]]))
    if not crossing:
        return None
    return (f"its {count} shells pass through each other at rest ({crossing} intersecting "
            "triangle pairs)")


def check_surface(path, V: np.ndarray, F: np.ndarray) -> None:
    """Raise :class:`CharacterFileError` unless ``V, F`` is a closed, manifold,
    consistently oriented surface with finite coordinates, and one skin: its
    shells do not pass through each other (:func:`crossing_shells`)."""
    problem = surface_problem(V, F)
    if not problem:
        crossing = crossing_shells(V, F)
        if crossing:
            problem = (f"{crossing}: the deformer needs one skin round the body's flesh; "
                       "join the pieces into one surface")
    if problem:
        _fail(path, problem)


def surface_problem(V: np.ndarray, F: np.ndarray) -> str | None:
    """What keeps ``V, F`` from being a closed, manifold, consistently oriented
    surface with finite coordinates and positive volume (None: nothing)."""
    if not np.all(np.isfinite(V)):
        return f"{int((~np.isfinite(V)).any(1).sum())} vertices have NaN or Inf coordinates"
    if len(F) == 0:
        return "surface has no triangles"
    if F.min() < 0 or F.max() >= len(V):
        return f"faces index vertices outside 0..{len(V) - 1}"
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    key = np.sort(E, axis=1)
    _, counts = np.unique(key, axis=0, return_counts=True)
    if np.any(counts == 1):
        return (f"surface is open: {int((counts == 1).sum())} edges have one triangle "
                "(the deformer needs a closed surface)")
    if np.any(counts > 2):
        return (f"surface is non-manifold: {int((counts > 2).sum())} edges have more "
                "than two triangles")
    _, dcounts = np.unique(E, axis=0, return_counts=True)
    if np.any(dcounts > 1):
        return "triangles are not consistently oriented"
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    vol = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0)
    if not vol > 0:
        return (f"surface encloses no positive volume ({vol:.3g} m^3): flip its triangles "
                "to face outwards")
    return None


def read_closed_mesh(path: str | Path):
    """A mesh file (any format trimesh reads) merged by position and checked closed.

    Returns
    -------
    V : (n, 3) float, F : (m, 3) int

    Raises
    ------
    ValueError
        ``"<path>: <problem>"`` for a missing, unreadable, open or inward mesh.
    """
    path = Path(path)
    if not path.exists():
        raise ValueError(f"{path}: no such mesh file")
    import trimesh              # deferred: a heavy import (0.2-0.5 s) only mesh files need
    try:
        m = trimesh.load(path, force="mesh", process=False)
    except Exception as e:  # trimesh raises many kinds for bad files
        raise ValueError(f"{path}: cannot be read as a mesh ({e})") from None
    V, F = np.asarray(m.vertices, float), np.asarray(m.faces, np.int64)
    if len(V) == 0 or len(F) == 0:
        raise ValueError(f"{path}: the mesh has no triangles")
    # Exporters split vertices at UV seams: merge by position for a closed surface.
    V, inv = np.unique(np.round(V, 9), axis=0, return_inverse=True)
    F = inv.reshape(-1)[F]
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 2] != F[:, 0])]
    check_surface(path, V, F)
    return V, F


def _skeleton(path: Path, doc: dict, scale: float, V=None, F=None,
              verbose: bool = True) -> Skeleton:
    if "template" in doc and "joints" not in doc and V is not None:
        # No hand-placed joints: embed a template skeleton in the (scaled) mesh.
        try:
            emb = fit_template(V, F, str(doc["template"]), up=doc.get("up"),
                               forward=doc.get("forward"))
        except ValueError as e:
            _fail(path, f"template '{doc['template']}': {e}")
        if not emb.passed:
            _fail(path, emb.failure())
        if verbose:
            print(f"[skin_node] {path}: {emb.summary()}", file=sys.stderr, flush=True)
        return emb.skeleton
    joints = doc.get("joints")
    if not isinstance(joints, list) or not joints:
        _fail(path, "needs a non-empty 'joints' list")
    names, parents, pos, tips, limits = [], [], [], [], []
    index = {}
    for k, j in enumerate(joints):
        if not isinstance(j, dict) or "name" not in j or "position" not in j:
            _fail(path, f"joint {k} needs 'name' and 'position'")
        name = str(j["name"])
        if name in index:
            _fail(path, f"joint '{name}' is listed twice")
        parent = j.get("parent")
        if parent is None:
            if k != 0:
                _fail(path, f"joint '{name}' has no parent; only the first joint is the root")
            parents.append(-1)
        else:
            if str(parent) == name:
                _fail(path, f"joint '{name}' is its own parent (a cycle)")
            if str(parent) not in index:
                later = {str(x.get("name")) for x in joints[k + 1:] if isinstance(x, dict)}
                why = "is listed after it (list parents first; a cycle cannot be ordered)" \
                    if str(parent) in later else "is not a joint of this file"
                _fail(path, f"joint '{name}': parent '{parent}' {why}")
            parents.append(index[str(parent)])
        index[name] = k
        names.append(name)
        try:
            pos.append(np.asarray(j["position"], float).reshape(3) * scale)
            tips.append(np.asarray(j["tip"], float).reshape(3) * scale if "tip" in j
                        else np.full(3, np.nan))
            limits.append(np.asarray(j["limits"], float).reshape(3, 2) if "limits" in j
                          else np.tile([-np.pi, np.pi], (3, 1)))
        except (TypeError, ValueError) as e:
            _fail(path, f"joint '{name}': position, tip and limits must be numbers ({e})")
    try:
        return Skeleton(names, np.array(parents), np.array(pos), tips=np.array(tips),
                        limits=np.array(limits))
    except ValueError as e:
        _fail(path, f"skeleton: {e}")
