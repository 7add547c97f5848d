"""Automatic skeleton embedding: place a template skeleton inside a closed mesh,
and check the fit.

The paper's first set-up step (it used Baran & Popović's Pinocchio). This is a
lighter, deterministic method in the same spirit:

1. **Frame.** The template has a known forward, left and up axis (x, y, z of its
   unit box). The mesh's left axis is its mirror-symmetry axis, tested among the
   coordinate axes and the mesh's principal axes (a coordinate axis wins ties:
   meshes are modelled in their own axes); up and forward lie in the symmetry
   plane, along its coordinate or principal axes, told apart by the template's
   ``long_axis`` (the longer extent), the up sign by ground contact (the end
   with more separate parts is the bottom: feet or hooves) and the forward sign
   by the template's ``forward_cue``. This gives up to eight candidate frames,
   likeliest first; ``up=`` / ``forward=`` fix either or both.
2. **Scale.** Template positions (normalised to a unit box) are scaled per axis
   to the mesh's bounding box in that frame: a first guess.
3. **Interior.** The mesh is voxelised (ray parity along z) and a distance
   field is computed inside; a graph over interior voxels whose edges cost
   ``length / depth^2`` makes shortest paths follow the medial axis.
4. **Trunk joints** (the root and every joint with several children) move to the
   centroid of the mesh's cross-section through them, perpendicular to their
   bone, restricted to the connected piece around the joint.
5. **Limbs.** Each leaf's far end is the interior extremity around the scaled
   template tip in the direction of its bone; its tip is pulled back from that
   extremity by the local radius. The chain from the nearest trunk joint to the
   tip is laid along the medial path between them, each joint at the fraction
   of the path's length that it has of the template chain's length. Joints
   between two trunk joints are laid on the medial path between those.
6. **Symmetry and inside.** On a mirror-symmetric mesh, left/right pairs are
   made exactly symmetric; every joint and tip is then checked inside with the
   generalised winding number and moved to the nearest deep voxel if not.
7. **Checks** (:func:`check_fit`): every joint inside the surface, the
   template's ``above`` chains descending along up (head above pelvis above
   knees above ankles), left and right limbs apart and mirror images within a
   tolerance, every bone inside the body. The candidate frames are fitted in
   turn until one passes; a fit that passes none is refused with one line
   naming the failed check, its figure and the hint that would help
   (:class:`EmbeddingError`). :meth:`Embedding.summary` gives every check's
   figure for the start-up output.

The skeleton's root gets the rest rotation whose columns are the mesh's forward,
left and up axes, so every rotation channel turns about the template's axes
(``*_ry`` swings a leg fore and aft) whatever way the mesh faces; the root
translation channels stay in world axes.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numba
import numpy as np
import scipy.ndimage as ndi
import scipy.sparse as sp
import yaml
from scipy.sparse.csgraph import dijkstra
from scipy.spatial import cKDTree

from ..kernels.collision import _closest_on_triangle
from ..retarget import bone_direction
from ..skeleton import Skeleton

#: Where template names (``"humanoid"``, ``"quadruped"``) are looked up.
TEMPLATE_DIRS = (Path(__file__).resolve().parents[2] / "config" / "templates",)

#: Interior voxels aimed at: enough to resolve a humanoid's wrist, fast to path.
TARGET_VOXELS = 60000
#: Degrees a fitted bone of a template's ``pose_reference`` may lie from the
#: template's rest direction before its clips are turned for it: a mesh
#: modelled in the template's pose is fitted within a few degrees (our
#: humanoid's arms within 0.1, its legs within 3.6), an A-pose's arms lie
#: 20-45 apart (CesiumMan's 26, our humanoid's lowered 35 degrees 34-35).
REFERENCE_TOL = 10.0


# ------------------------------------------------------------------ templates
@dataclass
class Template:
    """A template skeleton in a unit box (x forward, y left, z up).

    Attributes
    ----------
    name : str
    names : list of str, (J,)
    parents : (J,) int
    positions : (J, 3) float
        Joint positions normalised to the character's bounding box, in [0, 1].
    tips : (J, 3) float
        Normalised tips of leaf joints, NaN for the others.
    limits : (J, 3, 2) float
        Channel limits, radians.
    long_axis : str
        ``"up"`` or ``"forward"``: the longer extent within the symmetry plane.
    forward_cue : str
        ``"feet"`` (the bottom points forward) or ``"head"`` (the top end is the front).
    limb_root : (J,) bool
        Joints placed where their limb leaves the trunk (where the limb's
        thickness along its medial path rises above 1.4 times its typical
        radius) instead of at a fraction of the chain: right for legs whose
        length differs a lot from the template's (a cow's stubby legs).
    above : list of list of str
        Chains of joints that must descend along up in a fit (``checks: above:``
        in the file), e.g. head, pelvis, knee, ankle.
    clip : str
        The built-in clip a character embedded with it plays when none is
        named (``clip:`` in the file; ``walk`` if absent).
    pose_reference : list of str
        Bones whose direction in the template's rest pose its clips assume
        (``pose_reference:`` in the file: the humanoid's arms, out level). A
        fit whose bone lies more than :data:`REFERENCE_TOL` degrees from it
        (a mesh modelled in an A-pose) records the template's
        direction in :attr:`Skeleton.reference`, and built-in clips are
        turned to it (:func:`skin_node.retarget.conform_clip`).
    """

    name: str
    names: list
    parents: np.ndarray
    positions: np.ndarray
    tips: np.ndarray
    limits: np.ndarray
    long_axis: str = "up"
    forward_cue: str = "feet"
    limb_root: np.ndarray | None = None
    above: list = field(default_factory=list)
    clip: str = "walk"
    pose_reference: list = field(default_factory=list)


def template_path(template: str | Path) -> Path:
    """The file of a template given by name (``"quadruped"``) or path."""
    p = Path(template)
    if p.suffix in (".yaml", ".yml") or p.exists():
        return p
    for d in TEMPLATE_DIRS + _installed_template_dirs():
        if (d / f"{template}.yaml").exists():
            return d / f"{template}.yaml"
    raise ValueError(f"{template}: unknown skeleton template (known: {known_templates()}, "
                     "or a YAML path)")


def known_templates() -> list[str]:
    """Names of the templates shipped with the package."""
    return sorted({f.stem for d in TEMPLATE_DIRS + _installed_template_dirs()
                   if d.is_dir() for f in d.glob("*.yaml")})


def _installed_template_dirs() -> tuple:
    try:  # an installed package keeps its templates in share/
        # deferred: ament_index_python comes with a ROS install, which is optional
        from ament_index_python.packages import get_package_share_directory
        return (Path(get_package_share_directory("skin_node")) / "config" / "templates",)
    except Exception:
        return ()


def load_template(template: str | Path) -> Template:
    """Read a template skeleton file (see ``config/templates/*.yaml``).

    Raises
    ------
    ValueError
        ``"<file>: <problem>"`` for a missing or malformed template.
    """
    path = template_path(template)
    if not path.exists():
        raise ValueError(f"{path}: no such template file")
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as e:
        raise ValueError(f"{path}: cannot be read as YAML ({e})") from None
    if not isinstance(doc, dict) or not isinstance(doc.get("joints"), list) or not doc["joints"]:
        raise ValueError(f"{path}: a template needs a non-empty 'joints' list")
    names, parents, pos, tips, lim, root = [], [], [], [], [], []
    for k, j in enumerate(doc["joints"]):
        if not isinstance(j, dict) or "name" not in j or "position" not in j:
            raise ValueError(f"{path}: joint {k} needs 'name' and 'position'")
        name = str(j["name"])
        if name in names:
            raise ValueError(f"{path}: joint '{name}' is listed twice")
        par = j.get("parent")
        if (par is None) != (k == 0):
            raise ValueError(f"{path}: joint '{name}': only the first joint has no parent")
        if par is not None and str(par) not in names:
            raise ValueError(f"{path}: joint '{name}': parent '{par}' is not listed before it")
        names.append(name)
        root.append(bool(j.get("limb_root", False)))
        parents.append(-1 if par is None else names.index(str(par)))
        try:
            pos.append(np.asarray(j["position"], float).reshape(3))
            tips.append(np.asarray(j["tip"], float).reshape(3) if "tip" in j else np.full(3, np.nan))
            lim.append(np.asarray(j["limits"], float).reshape(3, 2) if "limits" in j
                       else np.tile([-np.pi, np.pi], (3, 1)))
        except (TypeError, ValueError) as e:
            raise ValueError(f"{path}: joint '{name}': position, tip and limits must be "
                             f"numbers ({e})") from None
    long_axis = str(doc.get("long_axis", "up"))
    cue = str(doc.get("forward_cue", "feet"))
    if long_axis not in ("up", "forward") or cue not in ("feet", "head"):
        raise ValueError(f"{path}: long_axis must be up|forward and forward_cue feet|head")
    above = (doc.get("checks") or {}).get("above", [])
    if not isinstance(above, list) or not all(isinstance(c, list) and len(c) >= 2
                                              for c in above):
        raise ValueError(f"{path}: checks: above: must be a list of joint-name lists")
    unknown = sorted({str(n) for c in above for n in c} - set(names))
    if unknown:
        raise ValueError(f"{path}: checks: above: names joints {unknown} it does not list")
    ref = doc.get("pose_reference") or []
    if not isinstance(ref, list) or sorted({str(n) for n in ref} - set(names)):
        raise ValueError(f"{path}: pose_reference: must list joints of the template")
    t = Template(str(doc.get("name", path.stem)), names, np.array(parents), np.array(pos),
                 np.array(tips), np.array(lim), long_axis, cue, np.array(root),
                 [[str(n) for n in c] for c in above], str(doc.get("clip", "walk")),
                 [str(n) for n in ref])
    has_child = np.zeros(len(names), bool)
    has_child[t.parents[1:]] = True
    bad = [n for n, c, tp in zip(names, has_child, t.tips) if not c and not np.isfinite(tp).all()]
    if bad:
        raise ValueError(f"{path}: leaf joints {bad} need a 'tip'")
    return t


# ------------------------------------------------------------------ interior
@numba.njit(cache=True)
def _ray_hits(V, F, x0, y0, h, nx, ny):
    """z of every crossing of the mesh by vertical rays through voxel columns."""
    cols = []
    zs = []
    for t in range(F.shape[0]):
        a, b, c = V[F[t, 0]], V[F[t, 1]], V[F[t, 2]]
        i0 = max(int(np.ceil((min(a[0], b[0], c[0]) - x0) / h)), 0)
        i1 = min(int(np.floor((max(a[0], b[0], c[0]) - x0) / h)), nx - 1)
        j0 = max(int(np.ceil((min(a[1], b[1], c[1]) - y0) / h)), 0)
        j1 = min(int(np.floor((max(a[1], b[1], c[1]) - y0) / h)), ny - 1)
        det = (b[0] - a[0]) * (c[1] - a[1]) - (c[0] - a[0]) * (b[1] - a[1])
        if det == 0.0:
            continue
        for i in range(i0, i1 + 1):
            px = x0 + i * h
            for j in range(j0, j1 + 1):
                py = y0 + j * h
                u = ((b[0] - px) * (c[1] - py) - (c[0] - px) * (b[1] - py)) / det
                v = ((c[0] - px) * (a[1] - py) - (a[0] - px) * (c[1] - py)) / det
                w = 1.0 - u - v
                if u >= 0.0 and v >= 0.0 and w >= 0.0:
                    cols.append(i * ny + j)
                    zs.append(u * a[2] + v * b[2] + w * c[2])
    return np.array(cols, dtype=np.int64), np.array(zs, dtype=np.float64)


def _voxelize(V, F, lo, h, shape):
    """(nx, ny, nz) bool: voxel centres inside the closed surface (ray parity along z)."""
    nx, ny, nz = shape
    cols, zs = _ray_hits(V, F, lo[0], lo[1], h, nx, ny)
    inside = np.zeros(shape, dtype=bool)
    order = np.lexsort((zs, cols))
    cols, zs = cols[order], zs[order]
    starts = np.flatnonzero(np.r_[True, cols[1:] != cols[:-1]])
    ends = np.r_[starts[1:], len(cols)]
    zc = lo[2] + h * np.arange(nz)
    for s, e in zip(starts, ends):
        if (e - s) % 2:          # a ray grazing an edge: skip the column, rare
            continue
        i, j = divmod(int(cols[s]), ny)
        k = np.searchsorted(zs[s:e], zc)
        inside[i, j] = (k % 2) == 1
    return inside


@numba.njit(cache=True)
def _winding_numbers(P, V, F):
    """Generalised winding number of each point (Jacobson et al. 2013): the sum
    over triangles of their signed solid angle over 4 pi, each by Van Oosterom
    and Strackee's formula ``tan(omega / 2) = a . (b x c) / (|a||b||c| + (a.b)|c|
    + (b.c)|a| + (c.a)|b|)`` with ``a, b, c`` the corners relative to the point."""
    out = np.empty(P.shape[0])
    for i in range(P.shape[0]):
        total = 0.0
        for t in range(F.shape[0]):
            ax, ay, az = V[F[t, 0], 0] - P[i, 0], V[F[t, 0], 1] - P[i, 1], V[F[t, 0], 2] - P[i, 2]
            bx, by, bz = V[F[t, 1], 0] - P[i, 0], V[F[t, 1], 1] - P[i, 1], V[F[t, 1], 2] - P[i, 2]
            cx, cy, cz = V[F[t, 2], 0] - P[i, 0], V[F[t, 2], 1] - P[i, 1], V[F[t, 2], 2] - P[i, 2]
            la = np.sqrt(ax * ax + ay * ay + az * az)
            lb = np.sqrt(bx * bx + by * by + bz * bz)
            lc = np.sqrt(cx * cx + cy * cy + cz * cz)
            det = ax * (by * cz - bz * cy) + ay * (bz * cx - bx * cz) + az * (bx * cy - by * cx)
            den = (la * lb * lc + (ax * bx + ay * by + az * bz) * lc
                   + (bx * cx + by * cy + bz * cz) * la + (cx * ax + cy * ay + cz * az) * lb)
            total += np.arctan2(det, den)
        out[i] = total / (2.0 * np.pi)
    return out


def winding_numbers(P: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(k,) generalised winding number of points ``P`` (k, 3): ~1 inside, ~0 outside."""
    return _winding_numbers(np.ascontiguousarray(np.atleast_2d(P), dtype=np.float64),
                            np.ascontiguousarray(V, dtype=np.float64),
                            np.ascontiguousarray(F, dtype=np.int64))


@numba.njit(cache=True)
def _surface_distance(P, V, F):
    out = np.empty(P.shape[0])
    for i in range(P.shape[0]):
        best = np.inf
        px, py, pz = P[i, 0], P[i, 1], P[i, 2]
        for t in range(F.shape[0]):
            a, b, c = F[t, 0], F[t, 1], F[t, 2]
            qx, qy, qz, _ = _closest_on_triangle(px, py, pz, V[a, 0], V[a, 1], V[a, 2],
                                                 V[b, 0], V[b, 1], V[b, 2],
                                                 V[c, 0], V[c, 1], V[c, 2])
            d = (qx - px) ** 2 + (qy - py) ** 2 + (qz - pz) ** 2
            if d < best:
                best = d
        out[i] = np.sqrt(best)
    return out


def surface_distance(P: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(k,) distance from points ``P`` (k, 3) to the surface ``V, F``, metres (brute force:
    meant for a skeleton's few dozen points)."""
    P = np.ascontiguousarray(np.atleast_2d(P), dtype=np.float64)
    return _surface_distance(P, np.ascontiguousarray(V, dtype=np.float64),
                             np.ascontiguousarray(F, dtype=np.int64))


class _Interior:
    """Voxel interior of a closed mesh with a distance field and a medial graph."""

    def __init__(self, V, F, target_voxels=TARGET_VOXELS):
        vol = abs(float(np.einsum("ij,ij->i", V[F[:, 0]],
                                  np.cross(V[F[:, 1]], V[F[:, 2]])).sum()) / 6.0)
        ext = V.max(0) - V.min(0)
        h = max((vol / target_voxels) ** (1.0 / 3.0), float(ext.max()) / 256.0)
        # An irrational offset keeps rays off vertices and edges of axis-aligned meshes.
        self.h = h
        self.lo = V.min(0) - 1.5 * h + h * np.array([0.2137, 0.3719, 0.1])
        shape = tuple(int(n) for n in np.ceil((V.max(0) + 1.5 * h - self.lo) / h) + 1)
        self.inside = _voxelize(V, F, self.lo, h, shape)
        if self.inside.sum() < 8:
            raise ValueError("the mesh encloses too little volume to embed a skeleton in")
        self.dist = ndi.distance_transform_edt(self.inside) * h
        self.idx = np.argwhere(self.inside)                    # (N, 3) voxel indices
        self.pts = self.lo + h * self.idx                      # (N, 3) voxel centres
        self.d = self.dist[self.inside]                        # (N,) depth
        lut = -np.ones(shape, dtype=np.int64)
        lut[self.inside] = np.arange(len(self.idx))
        self.lut = lut
        self._graph = None

    def graph(self):
        if self._graph is None:
            rows, cols, w = [], [], []
            shape = np.array(self.inside.shape)
            for off in np.argwhere(np.ones((3, 3, 3))) - 1:
                if tuple(off) <= (0, 0, 0):
                    continue            # each undirected edge once
                nb = self.idx + off
                ok = np.all((nb >= 0) & (nb < shape), axis=1)
                a = np.flatnonzero(ok)
                b = self.lut[tuple(nb[ok].T)]
                keep = b >= 0
                a, b = a[keep], b[keep]
                depth = 0.5 * (self.d[a] + self.d[b])
                # length / depth^2: the cheapest path hugs the medial axis.
                rows.append(a)
                cols.append(b)
                w.append(self.h * np.linalg.norm(off) / depth ** 2)
            r, c, ww = np.concatenate(rows), np.concatenate(cols), np.concatenate(w)
            n = len(self.idx)
            self._graph = sp.coo_matrix((ww, (r, c)), shape=(n, n)).tocsr()
        return self._graph

    def nearest(self, p, min_depth=0.0):
        """Index of the interior voxel nearest to ``p`` with depth >= ``min_depth``."""
        ok = self.d >= min_depth
        cand = np.flatnonzero(ok) if ok.any() else np.arange(len(self.d))
        return int(cand[np.argmin(((self.pts[cand] - p) ** 2).sum(1))])

    def paths(self, src: int, dst: list) -> list:
        """Medial paths (voxel index arrays, src first) from ``src`` to each of ``dst``."""
        _, pred = dijkstra(self.graph(), directed=False, indices=src, return_predecessors=True)
        out = []
        for t in dst:
            path = [t]
            while path[-1] != src and pred[path[-1]] >= 0:
                path.append(pred[path[-1]])
            out.append(np.array(path[::-1]))
        return out

    def section_centre(self, p, d, radius):
        """Medial centre of the interior's slab through ``p`` perpendicular to unit
        ``d``: the mean of its deepest voxels (within half a voxel of the deepest),
        among those within ``radius`` of ``p`` in the connected piece nearest ``p``."""
        rel = self.pts - p
        along = rel @ d
        near = np.flatnonzero((np.abs(along) <= 0.75 * self.h)
                              & ((rel ** 2).sum(1) <= radius ** 2))
        if len(near) == 0:
            return p
        sub = self.idx[near]
        mn = sub.min(0)
        mask = np.zeros(tuple(sub.max(0) - mn + 1), dtype=bool)
        mask[tuple((sub - mn).T)] = True
        lab, _ = ndi.label(mask, structure=np.ones((3, 3, 3)))
        labels = lab[tuple((sub - mn).T)]
        seed = np.argmin((rel[near] ** 2).sum(1))
        piece = near[labels == labels[seed]]
        deep = piece[self.d[piece] >= self.d[piece].max() - 0.5 * self.h]
        c = self.pts[deep].mean(0)
        c -= ((c - p) @ d) * d          # stay in the plane through p
        return c


# ------------------------------------------------------------------ the frame
_AXES = np.eye(3)


def _unit(v, what):
    v = np.asarray(v, float).reshape(3)
    n = np.linalg.norm(v)
    if not n > 0:
        raise ValueError(f"{what} must be a non-zero 3-vector, got {v}")
    return v / n


def _axis_arg(v, what):
    if v is None:
        return None
    if isinstance(v, str):
        s = v.strip().lower()
        sign = -1.0 if s.startswith("-") else 1.0
        s = s.lstrip("+-")
        if s not in ("x", "y", "z"):
            raise ValueError(f"{what} must be x, y, z (optionally signed) or a vector, got {v!r}")
        return sign * _AXES["xyz".index(s)]
    return _unit(v, what)


def _mirror_error(V, axis):
    """Mean distance from the vertices mirrored about the plane normal to unit
    ``axis`` through the middle of their extent along it to the nearest vertex."""
    s = V @ axis
    M = V - 2.0 * np.outer(s - 0.5 * (s.min() + s.max()), axis)
    return float(cKDTree(V).query(M)[0].mean())


def _end_parts(V, F, axis, end, frac=0.06):
    """Connected surface pieces within ``frac`` of the extent at one end of ``axis``."""
    s = V @ axis
    lo, hi = s.min(), s.max()
    sel = s <= lo + frac * (hi - lo) if end < 0 else s >= hi - frac * (hi - lo)
    tri = F[sel[F].all(1)]
    if len(tri) == 0:
        return int(sel.sum() > 0), V[sel].mean(0) if sel.any() else V.mean(0)
    n = len(V)
    g = sp.coo_matrix((np.ones(3 * len(tri)), (tri.ravel(), np.roll(tri, 1, 1).ravel())),
                      shape=(n, n))
    _, lab = sp.csgraph.connected_components(g, directed=False)
    used = np.unique(tri)
    return len(np.unique(lab[used])), V[sel].mean(0)


def _principal_axes(V) -> np.ndarray:
    """(3, 3) rows: the principal axes of the vertices, longest first."""
    X = V - V.mean(0)
    w, U = np.linalg.eigh(X.T @ X)
    return U[:, ::-1].T


def _left_axis(V, given=None) -> np.ndarray:
    """The mirror-symmetry axis: among the coordinate and principal axes (those
    perpendicular to ``given``, if any), the one whose mirror image of the
    vertices lies nearest them. A coordinate axis within 10% of the best wins:
    meshes are modelled in their own axes, and noise should not tilt them."""
    cand = [(a, True) for a in _AXES] + [(a, False) for a in _principal_axes(V)]
    if given is not None:
        cand = [(a - (a @ given) * given, c) for a, c in cand]
        cand = [(a / np.linalg.norm(a), c) for a, c in cand if np.linalg.norm(a) > 0.9]
    err = [(_mirror_error(V, a), a, c) for a, c in cand]
    best = min(e for e, _, _ in err)
    coord = [(e, a) for e, a, c in err if c and e <= 1.1 * best + 1e-12]
    return min(coord, key=lambda x: x[0])[1] if coord else min(err, key=lambda x: x[0])[1]


def _plane_axes(V, left) -> tuple[np.ndarray, np.ndarray]:
    """Two orthogonal axes spanning the plane normal to ``left`` (the coordinate
    axes when ``left`` is one, else the principal axes of the vertices in the
    plane), the one of larger extent first."""
    if np.max(np.abs(left)) > 1 - 1e-9:
        a, b = [x for x in _AXES if abs(x @ left) < 0.5]
    else:
        e1 = np.cross(left, _AXES[np.argmin(np.abs(left))])
        e1 /= np.linalg.norm(e1)
        E = np.column_stack([e1, np.cross(left, e1)])
        P = V @ E
        P -= P.mean(0)
        _, U = np.linalg.eigh(P.T @ P)
        a, b = (E @ U[:, ::-1]).T
    return (a, b) if np.ptp(V @ a) >= np.ptp(V @ b) else (b, a)


def _frame(forward, up) -> np.ndarray:
    left = np.cross(up, forward)
    return np.column_stack([forward, left / np.linalg.norm(left), up])


def frame_candidates(V, F, tmpl: Template, up=None, forward=None) -> list[np.ndarray]:
    """(3, 3) rotations whose columns are the mesh's forward, left and up axes,
    the likeliest first (see the module docstring); with both ``up`` and
    ``forward`` given, that one frame.

    ``up`` / ``forward``: ``"x"``, ``"-z"``, ... or vectors.
    """
    up, forward = _axis_arg(up, "up"), _axis_arg(forward, "forward")
    if up is not None and forward is not None:
        forward = forward - (forward @ up) * up
        if np.linalg.norm(forward) < 1e-6:
            raise ValueError("up and forward must not be parallel")
        return [_frame(forward / np.linalg.norm(forward), up)]
    if up is not None:
        other = np.cross(_left_axis(V, up), up)
        f = _forward_sign(V, F, tmpl, other / np.linalg.norm(other), up)
        return [_frame(f, up), _frame(-f, up)]
    if forward is not None:
        other = np.cross(forward, _left_axis(V, forward))
        u = _up_sign(V, F, other / np.linalg.norm(other))
        return [_frame(forward, u), _frame(forward, -u)]
    longer, shorter = _plane_axes(V, _left_axis(V))
    ups = (longer, shorter) if tmpl.long_axis == "up" else (shorter, longer)
    out = []
    for axis in ups:                       # the template's guess of the axis first
        u = _up_sign(V, F, axis)
        for uu in (u, -u):                 # ... with the sign the feet tell first
            fwd = ups[1] if axis is ups[0] else ups[0]
            out.append(_frame(_forward_sign(V, F, tmpl, fwd, uu), uu))
    # The forward sign is the weakest cue and no check sees it: last resort.
    return out + [_frame(-A[:, 0], A[:, 2]) for A in out]


def mesh_frame(V, F, tmpl: Template, up=None, forward=None) -> np.ndarray:
    """The likeliest of :func:`frame_candidates`."""
    return frame_candidates(V, F, tmpl, up, forward)[0]


def _up_sign(V, F, axis):
    """``axis`` or its opposite: the bottom has more separate parts (feet, hooves)."""
    n_lo, _ = _end_parts(V, F, axis, -1)
    n_hi, _ = _end_parts(V, F, axis, +1)
    if n_lo != n_hi:
        return axis if n_lo > n_hi else -axis
    # A tie: the centroid of the surface is nearer the top (heavier trunk, thin legs).
    s = V @ axis
    return axis if s.mean() >= 0.5 * (s.min() + s.max()) else -axis


def _forward_sign(V, F, tmpl, axis, up):
    """``axis`` or its opposite, by the template's cue: feet point forward, or the
    top end of the body is the head."""
    _, c_end = _end_parts(V, F, up, -1 if tmpl.forward_cue == "feet" else +1)
    return axis if (c_end - V.mean(0)) @ axis >= 0 else -axis


# ------------------------------------------------------------------ embedding
def _arc(P):
    return np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(P, axis=0), axis=1))]


def _at_fraction(P, s, f):
    """Point at arc-length fraction ``f`` of the polyline ``P`` with arc lengths ``s``."""
    if s[-1] <= 0:
        return P[0].copy()
    t = f * s[-1]
    k = int(np.clip(np.searchsorted(s, t) - 1, 0, len(P) - 2))
    u = (t - s[k]) / max(s[k + 1] - s[k], 1e-12)
    return P[k] + np.clip(u, 0, 1) * (P[k + 1] - P[k])


def _smooth(P, passes=3):
    """Soften a voxel staircase path (ends fixed)."""
    P = P.astype(float).copy()
    for _ in range(passes):
        if len(P) > 2:
            P[1:-1] = 0.25 * P[:-2] + 0.5 * P[1:-1] + 0.25 * P[2:]
    return P


@dataclass
class Check:
    """One check of a fitted skeleton: its name, whether it passed, its figure
    (what was measured, in words and numbers) and the hint that would help."""

    name: str
    passed: bool
    figure: str
    hint: str


@dataclass
class Embedding:
    """A template skeleton fitted to a mesh, with the checks of the fit.

    Attributes
    ----------
    skeleton : Skeleton
    frame : (3, 3) float
        The mesh's forward, left and up axes as columns.
    given : tuple of str
        Which of ``up`` / ``forward`` were given rather than detected.
    checks : list of Check
    tried : int
        Orientations fitted before this one passed (or all that were tried).
    others : list of str
        Other templates to suggest when no orientation fitted.
    """

    template: str
    skeleton: Skeleton
    frame: np.ndarray
    given: tuple
    checks: list
    tried: int = 1
    others: list = field(default_factory=list)

    @property
    def passed(self) -> bool:
        return all(c.passed for c in self.checks)

    def orientation(self) -> str:
        how = lambda k: "given" if k in self.given else "detected"  # noqa: E731
        return (f"up {_word(self.frame[:, 2])} ({how('up')}), "
                f"forward {_word(self.frame[:, 0])} ({how('forward')})")

    def summary(self) -> str:
        """One line: the orientation and every check's figure."""
        tried = f", after {self.tried - 1} other orientation(s) failed" if self.tried > 1 else ""
        return (f"template '{self.template}' embedded, {self.orientation()}{tried}; "
                + "; ".join(f"{c.name}: {c.figure}" for c in self.checks))

    def failure(self) -> str:
        """One line: the first failed check, its figure and the hint that helps."""
        c = next(c for c in self.checks if not c.passed)
        tried = f" (and in {self.tried - 1} other orientation(s))" if self.tried > 1 else ""
        other = (f"; or the mesh is no {self.template}: template: {' or '.join(self.others)}"
                 if self.others else "")
        return (f"template '{self.template}' does not fit this mesh, {self.orientation()}"
                f"{tried}: check '{c.name}' failed: {c.figure}; {c.hint}{other}")


class EmbeddingError(ValueError):
    """A template fit that failed its checks; the message is one line."""

    def __init__(self, embedding: Embedding) -> None:
        super().__init__(embedding.failure())
        self.embedding = embedding


def embed_skeleton(V: np.ndarray, F: np.ndarray, template: str | Path | Template,
                   up=None, forward=None, symmetric: bool | None = None) -> Skeleton:
    """Place a template skeleton inside a closed mesh, checked (:func:`fit_template`).

    Parameters
    ----------
    V : (n, 3) float
        Closed surface vertices, metres (merged by position).
    F : (m, 3) int
        Outward triangles.
    template : str, Path or Template
        ``"humanoid"``, ``"quadruped"`` or a template YAML file.
    up, forward : str or (3,) float, optional
        The mesh's up and forward directions (``"y"``, ``"-z"`` or vectors);
        detected when not given.
    symmetric : bool, optional
        Make left/right joint pairs mirror images; default: when the mesh is
        mirror-symmetric about its left axis (within 1% of its size).

    Returns
    -------
    Skeleton
        The template's joints, limits and tips placed inside the mesh; the root's
        rest rotation has the mesh's forward, left and up axes as columns.

    Raises
    ------
    EmbeddingError
        When no orientation's fit passes its checks: one line naming the check
        that failed, its figure and the hint that would help.
    """
    emb = fit_template(V, F, template, up, forward, symmetric)
    if not emb.passed:
        raise EmbeddingError(emb)
    return emb.skeleton


def fit_template(V: np.ndarray, F: np.ndarray, template: str | Path | Template,
                 up=None, forward=None, symmetric: bool | None = None) -> Embedding:
    """Fit a template skeleton in each candidate orientation (:func:`frame_candidates`,
    likeliest first) until one passes its checks (:func:`check_fit`).

    Returns
    -------
    Embedding
        The first fit that passed, or, when none did, the likeliest one's
        (``passed`` is False; :meth:`Embedding.failure` says why). Parameters
        as for :func:`embed_skeleton`.
    """
    V = np.asarray(V, float)
    F = np.asarray(F, np.int64)
    tmpl = template if isinstance(template, Template) else load_template(template)
    given = tuple(k for k, v in (("up", up), ("forward", forward)) if v is not None)
    frames = frame_candidates(V, F, tmpl, up, forward)
    vol = _Interior(V, F)
    first = None
    for k, A in enumerate(frames, 1):
        raw_pos, raw_tips = _place(V, tmpl, A, vol)
        sym = symmetric if symmetric is not None else \
            _mirror_error(V, A[:, 1]) < 0.01 * np.linalg.norm(np.ptp(V, 0))
        pos, tips = (_symmetrise(tmpl.names, raw_pos, raw_tips, A, V @ A) if sym
                     else (raw_pos, raw_tips))
        pos, tips, moved = _keep_inside(vol, V, F, pos, tips)
        rest = np.tile(np.eye(3), (len(pos), 1, 1))
        rest[0] = A
        skel = Skeleton(list(tmpl.names), tmpl.parents.copy(), pos, rest_rotations=rest,
                        tips=tips, limits=tmpl.limits.copy())
        skel = replace(skel, reference=_pose_reference(V, tmpl, A, skel))
        checks = check_fit(V, F, tmpl, skel, vol, raw_pos, moved, given)
        emb = Embedding(tmpl.name, skel, A, given, checks, k)
        if emb.passed:
            return emb
        first = first or emb
    first.tried = len(frames)
    if not given:       # every orientation failed: perhaps the wrong kind of body
        first.others = [t for t in known_templates() if t != tmpl.name]
    return first


def _template_in(V, tmpl: Template, A) -> tuple[np.ndarray, np.ndarray]:
    """(J, 3) joints and tips of the template scaled to the mesh's box in
    frame ``A`` (tips NaN where the template has none)."""
    Q = V @ A                                   # template-frame coordinates
    qlo, qhi = Q.min(0), Q.max(0)

    def scaled(p):
        return (qlo + np.asarray(p) * (qhi - qlo)) @ A.T

    return (scaled(tmpl.positions),
            np.where(np.isfinite(tmpl.tips), scaled(np.nan_to_num(tmpl.tips)), np.nan))


def _pose_reference(V, tmpl: Template, A, skel: Skeleton) -> np.ndarray | None:
    """(J, 3) :attr:`Skeleton.reference` of a fit ``skel``: the template's
    rest direction of each ``pose_reference`` bone that lies more than
    REFERENCE_TOL degrees from the fitted one; None if none does."""
    if not tmpl.pose_reference:
        return None
    guess, tip_guess = _template_in(V, tmpl, A)
    ref = np.full((skel.n_joints, 3), np.nan)
    for name in tmpl.pose_reference:
        j = skel.index(name)
        d, kids = bone_direction(skel, j), skel.children(j)   # the template's tree
        if d is None:
            continue
        t = (guess[kids[0]] if kids else tip_guess[j]) - guess[j]
        if np.linalg.norm(t) < 1e-12:
            continue
        t = t / np.linalg.norm(t)
        if np.degrees(np.arccos(np.clip(d @ t, -1.0, 1.0))) > REFERENCE_TOL:
            ref[j] = t
    return ref if np.isfinite(ref).any() else None


def _place(V, tmpl: Template, A, vol) -> tuple[np.ndarray, np.ndarray]:
    """(J, 3) joints and tips of the template fitted in frame ``A`` (steps 2 to 5
    of the module docstring), before symmetry and the inside check."""
    J = len(tmpl.names)
    par = tmpl.parents
    kids = [[] for _ in range(J)]
    for j in range(1, J):
        kids[par[j]].append(j)
    guess, tip_guess = _template_in(V, tmpl, A)
    h = vol.h

    pos = np.full((J, 3), np.nan)
    tips = np.full((J, 3), np.nan)
    anchors = [j for j in range(J) if j == 0 or len(kids[j]) > 1]
    # Trunk joints: the cross-section centre, perpendicular to their bone.
    for j in anchors:
        if j == 0:
            heavy = max(kids[0], key=lambda c: _subtree_size(kids, c)) if kids[0] else None
            d = guess[heavy] - guess[0] if heavy is not None else A[:, 2]
        else:
            d = guess[j] - guess[par[j]]
        d = d / (np.linalg.norm(d) + 1e-12)
        k = vol.nearest(guess[j], min_depth=0.5 * vol.d.max() * 0.25)
        radius = 2.5 * vol.d[k] + 2 * h
        c = vol.section_centre(vol.pts[k], d, radius)
        pos[j] = vol.pts[vol.nearest(c)] if not _inside_voxel(vol, c) else c

    # Chains: from an anchor down to the next anchor or to a leaf's tip.
    for a in anchors:
        ends, chains = [], []
        for c in kids[a]:
            chain = [c]
            while len(kids[chain[-1]]) == 1 and chain[-1] not in anchors:
                chain.append(kids[chain[-1]][0])
            last = chain[-1]
            if last in anchors:
                chains.append((chain[:-1], last, None))
                ends.append(vol.nearest(pos[last]))
            else:
                e = _extremity(vol, guess[last], tip_guess[last], guess[a])
                chains.append((chain, None, e))
                ends.append(e)
        if not chains:
            continue
        src = vol.nearest(pos[a])
        for (chain, end_anchor, e), path in zip(chains, vol.paths(src, ends)):
            P = _smooth(vol.pts[path])
            P[0] = pos[a]
            if end_anchor is not None:
                P[-1] = pos[end_anchor]
                ref = np.vstack([guess[a], guess[chain], guess[end_anchor]])
            else:
                P = _pull_back(vol, P, path)
                tips[chain[-1]] = P[-1]
                ref = np.vstack([guess[a], guess[chain], tip_guess[chain[-1]]])
            if end_anchor is None and tmpl.limb_root is not None and tmpl.limb_root[chain[0]]:
                k = _limb_root(vol.d[path[:len(P)]])
                pos[chain[0]] = P[k]
                P, ref, chain = P[k:], ref[1:], chain[1:]
            sref, s = _arc(ref), _arc(P)
            for i, j in enumerate(chain):
                pos[j] = _at_fraction(P, s, sref[i + 1] / max(sref[-1], 1e-12))
    return pos, tips


# ------------------------------------------------------------------ the checks
#: Smallest drop between consecutive joints of an ``above`` chain, of the height.
ORDER_MARGIN = 0.01
#: Smallest left/right spacing of a limb's joint pair, of the limbs' mean radius.
SPACING_MIN = 1.0
#: Largest mirror mismatch of a pair before symmetrising, of the body's size.
MIRROR_MAX = 0.05
#: Points checked along every bone.
BONE_SAMPLES = 9


def _pairs(names) -> list[tuple[int, int]]:
    idx = {n: i for i, n in enumerate(names)}
    return [(i, idx["r_" + n[2:]]) for n, i in idx.items()
            if n.startswith("l_") and "r_" + n[2:] in idx]


def check_fit(V, F, tmpl: Template, skel: Skeleton, vol, raw_pos, moved: int,
              given=()) -> list[Check]:
    """The checks of a fitted skeleton, each with its figure.

    * **inside**: every joint and tip inside the surface (generalised winding
      number above 1/2); the figure also counts those moved in from outside.
    * **order along up**: the template's ``above`` chains (head above pelvis
      above knees above ankles) descend along up, each step by at least
      :data:`ORDER_MARGIN` of the height.
    * **left/right apart**: every ``l_*`` joint of a limb (below the joint where
      the limb leaves the trunk) lies left of its ``r_*`` twin by at least
      :data:`SPACING_MIN` times the limbs' mean radius there: two limbs, not
      one limb twice (a humanoid's legs fitted into one leg of a cow).
    * **mirror**: before symmetrising, each pair mirrors across the symmetry
      plane within :data:`MIRROR_MAX` of the body's size.
    * **bones inside**: :data:`BONE_SAMPLES` points along every bone inside the
      surface, or within half a voxel outside it (a bone may graze thin skin).
    """
    A = skel.rest_rotations[0]
    fwd, left, up = A.T
    P = skel.rest_positions
    names = skel.names
    idx = {n: i for i, n in enumerate(names)}
    Q = V @ A
    ext = np.ptp(Q, 0)
    size = float(np.linalg.norm(ext))
    mm = lambda x: f"{1000 * x:.0f} mm"  # noqa: E731
    want = [k for k in ("up", "forward") if k not in given]
    example = {"up": "up: y", "forward": "forward: -z"}
    orient = (f"say {' and '.join(w + ':' for w in want)} (e.g. "
              f"{', '.join(example[w] for w in want)})" if want else "check up: and forward:")
    checks = []

    tips = skel.tips[np.isfinite(skel.tips).all(1)]
    pts = np.vstack([P, tips])
    w = winding_numbers(pts, V, F)
    out = int((w < 0.5).sum())
    depth = surface_distance(pts, V, F)
    checks.append(Check("inside", out == 0,
                        f"{len(pts) - out} of {len(pts)} joints and tips inside "
                        f"({moved} moved in), the shallowest {mm(depth.min())} deep",
                        "list the joints explicitly (joints:) for this mesh"))

    steps = []
    for chain in tmpl.above:
        h = P[[idx[n] for n in chain]] @ up
        steps += [(h[k] - h[k + 1], chain[k], chain[k + 1]) for k in range(len(chain) - 1)]
    if steps:
        d, a, b = min(steps)
        checks.append(Check("order along up", d >= ORDER_MARGIN * ext[2],
                            f"{a} above {b} by {mm(d)} the least (need {mm(ORDER_MARGIN * ext[2])})",
                            f"the mesh's up is not {_word(up)}: {orient}"))

    pairs = _pairs(names)
    if pairs:
        # A limb's own joints (below the joint where it leaves the trunk) must sit
        # in two limbs: apart by at least the limbs' mean radius (the depth there).
        trunk = {0} | {j for j in range(len(names)) if len(skel.children(j)) > 1}
        limb = [(i, k) for i, k in pairs if skel.parents[i] not in trunk] or pairs
        r = {j: vol.d[vol.nearest(P[j])] for ik in limb for j in ik}
        ratio = [((P[i] - P[k]) @ left) / max(0.5 * (r[i] + r[k]), 1e-9) for i, k in limb]
        j = int(np.argmin(ratio))
        i, k = limb[j]
        checks.append(Check("left/right apart", ratio[j] >= SPACING_MIN,
                            f"{names[i]} and {names[k]} {mm((P[i] - P[k]) @ left)} apart, "
                            f"{ratio[j]:.2f} times the limbs' radius there "
                            f"({mm(0.5 * (r[i] + r[k]))}) the least (need {SPACING_MIN:g})",
                            f"the limbs are not where a {tmpl.name}'s are: {orient}, or list "
                            "the joints (joints:)"))
        c = 0.5 * (Q[:, 1].min() + Q[:, 1].max())
        mis = [np.linalg.norm(raw_pos[i] - (raw_pos[k] - 2 * ((raw_pos[k] @ left) - c) * left))
               for i, k in pairs]
        j = int(np.argmax(mis))
        checks.append(Check("mirror", mis[j] <= MIRROR_MAX * size,
                            f"{names[pairs[j][0]]} and {names[pairs[j][1]]} mirror within "
                            f"{mm(mis[j])} the most (allowed {mm(MIRROR_MAX * size)})",
                            f"left and right limbs differ: {orient}, or list the joints "
                            "(joints:) for an asymmetric pose"))

    seg_joint, a, b = skel.bone_segments()
    t = (np.arange(BONE_SAMPLES) + 1.0) / (BONE_SAMPLES + 1.0)
    S = (a[:, None] + t[None, :, None] * (b - a)[:, None]).reshape(-1, 3)
    ws = winding_numbers(S, V, F)
    outside = ws < 0.5
    if outside.any():
        far = surface_distance(S[outside], V, F) > 0.5 * vol.h
        outside[np.flatnonzero(outside)[~far]] = False
    bones = outside.reshape(len(seg_joint), BONE_SAMPLES).any(1)
    worst = ", ".join(sorted({names[j] for j in seg_joint[bones]})[:3])
    checks.append(Check("bones inside", not bones.any(),
                        f"{int(outside.sum())} of {len(S)} points along {len(seg_joint)} bones "
                        "outside the surface" + (f" ({worst})" if bones.any() else ""),
                        f"bones leave the body: {orient}, or list the joints (joints:)"))
    return checks


def _word(v) -> str:
    for i, a in enumerate(_AXES):
        for sgn in (1, -1):
            if np.allclose(v, sgn * a, atol=1e-9):
                return f"{'+-'[sgn < 0]}{'xyz'[i]}"
    return "[" + ", ".join(f"{x:.3f}" for x in v) + "]"


def _subtree_size(kids, j):
    return 1 + sum(_subtree_size(kids, c) for c in kids[j])


def _inside_voxel(vol, p):
    i = np.round((p - vol.lo) / vol.h).astype(int)
    if np.any(i < 0) or np.any(i >= vol.inside.shape):
        return False
    return bool(vol.inside[tuple(i)])


def _extremity(vol, leaf, tip, base):
    """Interior voxel farthest along the leaf's bone near its scaled template tip,
    penalising sideways offset (so the neighbouring limb does not win)."""
    d = tip - leaf
    d /= np.linalg.norm(d) + 1e-12
    reach = max(2.0 * np.linalg.norm(tip - leaf), 0.6 * np.linalg.norm(tip - base))
    rel = vol.pts - tip
    near = np.flatnonzero((rel ** 2).sum(1) <= reach ** 2)
    if len(near) == 0:
        return vol.nearest(tip)
    along = rel[near] @ d
    side = np.linalg.norm(rel[near] - np.outer(along, d), axis=1)
    return int(near[np.argmax(along - side)])


def _limb_root(depth):
    """Index along a trunk-to-tip medial path where the limb joins the trunk: the
    last point deeper than 1.4 times the limb's typical radius (the median depth
    of the path's last 40%)."""
    n = len(depth)
    r = np.median(depth[int(0.6 * n):])
    thick = np.flatnonzero(depth[: max(n - 2, 1)] > 1.4 * r)
    return int(thick[-1]) if len(thick) else 0


def _pull_back(vol, P, path):
    """Cut the path back from the extremity by the local radius: the tip sits in
    the end cap's centre, not at the skin."""
    s = _arc(P)
    rem = s[-1] - s
    # The local radius, but at most a fifth of the path: a bulge (a belly) is
    # deep yet its bone must still reach into it.
    d = np.minimum(vol.d[path], 0.2 * s[-1])
    ok = np.flatnonzero(rem >= d)
    k = ok[-1] if len(ok) else 0
    return P[:max(k, 1) + 1]


def _symmetrise(names, pos, tips, A, Q):
    """Mirror-average left/right pairs (``l_*`` / ``r_*``) and centre the others."""
    c = 0.5 * (Q[:, 1].min() + Q[:, 1].max())
    left = A[:, 1]

    def mirror(p):
        return p - 2.0 * ((p @ left) - c)[..., None] * left

    pos, tips = pos.copy(), tips.copy()
    idx = {n: i for i, n in enumerate(names)}
    for n, i in idx.items():
        if n.startswith("l_") and "r_" + n[2:] in idx:
            k = idx["r_" + n[2:]]
            for arr in (pos, tips):
                if np.isfinite(arr[i]).all() and np.isfinite(arr[k]).all():
                    a = 0.5 * (arr[i] + mirror(arr[k]))
                    arr[i], arr[k] = a, mirror(a)
        elif not n.startswith("r_"):
            for arr in (pos, tips):
                if np.isfinite(arr[i]).all():
                    arr[i] = arr[i] - ((arr[i] @ left) - c) * left
    return pos, tips


def _keep_inside(vol, V, F, pos, tips):
    """Move any joint or tip outside (or within a quarter voxel of) the skin to
    the nearest voxel at least a voxel deep; returns (pos, tips, how many moved)."""
    pts = np.vstack([pos, tips])
    fin = np.isfinite(pts).all(1)
    P = pts[fin]
    w = winding_numbers(P, V, F)
    depth = surface_distance(P, V, F)
    bad = (w < 0.5) | (depth < 0.25 * vol.h)
    for i in np.flatnonzero(bad):
        P[i] = vol.pts[vol.nearest(P[i], min_depth=min(vol.h, 0.5 * vol.d.max()))]
    pts[fin] = P
    J = len(pos)
    return pts[:J], pts[J:], int(bad.sum())
