"""Once per character: tet mesh, embedding, regions, weights, constraint rest
values, gathered in a :class:`Rig` and cached on disk."""
from __future__ import annotations

import hashlib
import os
import sys
import time
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from typing import NamedTuple

from ..metrics import mesh_volume
from ..skeleton import Skeleton
from .embed import winding_numbers
from .fields import lattice_sampler, part_fields
from .heat import bone_heat, continuous_top_k, dense_weights, lattice_extension
from .tetra import lattice_for_count, signed_volumes, tet_edges
from .weights import (bone_distances, inverse_distance_weights, joint_radii, joint_regions,
                      point_segment_distance)

RIG_VERSION = 11


@dataclass
class RigOptions:
    """Set-up choices that change the rig (all part of the cache key).

    Attributes
    ----------
    tet_count : int
        Target number of tets of the lattice (about; the cube size is fitted).
    region_scale : float
        A joint's region holds points closer to it than ``region_scale`` times
        its local limb radius (the paper's per-joint threshold); a joint
        outside the body, further from it than half the bone leading to it,
        has none (:func:`build_rig`).
    zone_weight : float
        A tet vertex is in joint ``j``'s zone, simulated while ``j`` is bent,
        when it takes more than this weight both from bones below ``j`` and from
        bones above it: only there does bending ``j`` make LBS non-rigid.
    weight_power : float
        The exponent of the paper's inverse-distance weights (its 4).
    neighbours_only : bool
        Restrict a point's paper weights to the nearest bone and its tree
        neighbours.
    weights : str
        The character's own weights: ``"automatic"`` (bone heat, smooth: see
        :mod:`skin_node.rigging.heat`) or ``"file"`` (the artist's weights of
        the character file, see :func:`file_weights`). The paper's
        inverse-distance weights are kept beside them either way (pipeline
        parameter ``weight_scheme``).
    influences : int
        Bones per vertex of the character's weights.
    heat : float
        Strength of bone heat's sources (Baran & Popovic's 1).
    field_cell : float
        Node spacing of the parts' distance fields, in mean surface edges.
    """

    tet_count: int = 12000
    region_scale: float = 1.6
    zone_weight: float = 0.1
    weight_power: float = 4.0
    neighbours_only: bool = True
    weights: str = "automatic"
    influences: int = 4
    heat: float = 1.0
    field_cell: float = 0.6


#: Where the character's skin weights come from (:attr:`RigOptions.weights`).
WEIGHT_SOURCES = ("automatic", "file")


class Weights(NamedTuple):
    """One weighting of a rig: surface ``Widx, Wval`` (n, K), tet-mesh
    ``TWidx, TWval`` (k, K) and the tet vertices' joint zones ``zone`` (k, J)
    (see :func:`weight_zones`)."""

    Widx: np.ndarray
    Wval: np.ndarray
    TWidx: np.ndarray
    TWval: np.ndarray
    zone: np.ndarray


#: The weightings a pipeline can skin with (``weight_scheme``): the
#: character's own, or the paper's inverse-distance ones.
WEIGHT_SCHEMES = ("character", "inverse_distance")


@dataclass
class Rig:
    """Everything the per-frame stages need, as plain arrays.

    Surface (n vertices): ``Widx, Wval`` (n,K) the character's weights;
    ``part`` (n,) the bone each vertex belongs to (its heaviest); ``region``
    (n,) joint region or -1; ``Etet, Ebary`` (n,4) embedding; ``adj_ptr, adj``
    one-ring CSR.
    Tets (k vertices, t tets, e edges): ``TV`` (k,3), ``T`` (t,4), ``E`` (e,2),
    ``TWidx, TWval`` (k,K), ``mass`` (k,), ``vol0`` (t,), ``len0`` (e,),
    ``erest`` (t,4) energy spring rest lengths, ``bseg, brest`` (k,) bind
    segment and rest distance, ``zone`` (k,J) bool.
    ``pid_*``: the paper's inverse-distance weights (3 and 2 bones) and zones.
    ``field_*``: the parts' distance fields (:class:`~skin_node.rigging.fields.PartFields`).
    Joints: ``radius``, ``threshold`` (J,).
    """

    Widx: np.ndarray
    Wval: np.ndarray
    part: np.ndarray
    region: np.ndarray
    Etet: np.ndarray
    Ebary: np.ndarray
    adj_ptr: np.ndarray
    adj: np.ndarray
    TV: np.ndarray
    T: np.ndarray
    E: np.ndarray
    TWidx: np.ndarray
    TWval: np.ndarray
    tregion: np.ndarray
    mass: np.ndarray
    vol0: np.ndarray
    len0: np.ndarray
    erest: np.ndarray
    bseg: np.ndarray
    brest: np.ndarray
    zone: np.ndarray
    radius: np.ndarray
    threshold: np.ndarray
    cube: np.ndarray
    pid_Widx: np.ndarray
    pid_Wval: np.ndarray
    pid_TWidx: np.ndarray
    pid_TWval: np.ndarray
    pid_zone: np.ndarray
    field_origin: np.ndarray
    field_cell: np.ndarray
    field_dims: np.ndarray
    field_ptr: np.ndarray
    field_values: np.ndarray
    field_sptr: np.ndarray
    field_sets: np.ndarray
    field_wdims: np.ndarray
    field_wptr: np.ndarray
    field_wvalues: np.ndarray
    field_wreach: np.ndarray

    def weights(self, scheme: str = "character") -> Weights:
        """The :class:`Weights` of ``scheme`` (:data:`WEIGHT_SCHEMES`)."""
        if scheme == "character":
            return Weights(self.Widx, self.Wval, self.TWidx, self.TWval, self.zone)
        if scheme == "inverse_distance":
            return Weights(self.pid_Widx, self.pid_Wval, self.pid_TWidx, self.pid_TWval,
                           self.pid_zone)
        raise ValueError(f"weight scheme must be one of {list(WEIGHT_SCHEMES)}, got {scheme!r}")

    @property
    def fields(self) -> tuple:
        """The part fields as the tuple :func:`skin_node.kernels.contact.skinned_field`
        takes."""
        return (self.field_origin, self.field_cell, self.field_dims, self.field_ptr,
                self.field_values, self.field_sptr, self.field_sets, self.field_wdims,
                self.field_wptr, self.field_wvalues, self.field_wreach)

    def save(self, path: Path) -> None:
        tmp = Path(str(path) + f".{os.getpid()}.tmp.npz")
        np.savez(tmp, **{f.name: getattr(self, f.name) for f in fields(self)})
        os.replace(tmp, path)

    @classmethod
    def load(cls, path: Path) -> "Rig":
        with np.load(path) as z:
            return cls(**{f.name: z[f.name] for f in fields(cls)})


class Steps:
    """Progress for set-up: each step is printed to stderr once the whole set-up
    has taken more than ``after`` seconds (quiet for fast, cached starts)."""

    def __init__(self, what: str, after: float = 2.0, stream=None, enabled: bool = True):
        self.what, self.after, self.enabled = what, after, enabled
        self.stream = stream or sys.stderr
        self.t0 = self.t = time.perf_counter()
        self.pending: list[str] = []

    def __call__(self, step: str) -> None:
        now = time.perf_counter()
        line = f"[skin_node] {self.what}: {step} ({now - self.t:.2f} s)"
        self.t = now
        if not self.enabled:
            return
        if now - self.t0 > self.after:
            for p in self.pending:
                print(p, file=self.stream, flush=True)
            self.pending = []
            print(line, file=self.stream, flush=True)
        else:
            self.pending.append(line)


def weight_zones(Widx: np.ndarray, Wval: np.ndarray, skel: Skeleton, eps: float) -> np.ndarray:
    """(n, J) bool: points whose weights straddle joint ``j`` (more than ``eps``
    from bones in ``j``'s subtree and more than ``eps`` from the rest)."""
    J = skel.n_joints
    below = skel.subtree()          # below[j, b]: bone b is in j's subtree
    zone = np.zeros((len(Widx), J), dtype=bool)
    for j in range(1, J):
        wb = (Wval * below[j][Widx]).sum(1)
        zone[:, j] = (wb > eps) & (wb < 1.0 - eps)
    return zone


def one_ring(F: np.ndarray, n: int):
    """One-ring neighbours of every vertex in CSR form (ptr (n+1,), nbr)."""
    E = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    E = np.unique(np.concatenate([E, E[:, ::-1]]), axis=0)
    ptr = np.zeros(n + 1, dtype=np.int64)
    np.add.at(ptr, E[:, 0] + 1, 1)
    return np.cumsum(ptr), E[:, 1].astype(np.int64)


def cache_dir() -> Path:
    d = os.environ.get("SKIN_NODE_CACHE") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "skin_node")
    return Path(d)


def rig_key(V: np.ndarray, F: np.ndarray, skel: Skeleton, opt: RigOptions,
            weights: tuple | None = None) -> str:
    """Cache key of a rig: its inputs, options and, for file weights, the weights."""
    h = hashlib.sha1(f"rig{RIG_VERSION}".encode())
    arrays = [V, F, skel.parents, skel.rest_positions, skel.rest_rotations, skel.tips]
    if opt.weights == "file" and weights is not None:
        arrays += list(weights)
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    h.update(repr(sorted(vars(opt).items())).encode())
    return h.hexdigest()[:20]


def file_weights(widx: np.ndarray, wval: np.ndarray, n_joints: int, n: int) -> np.ndarray:
    """(n, J) dense weights of ``n`` surface vertices from a file's per-vertex
    weights ``widx, wval`` (n, k) (bone ids and weights; rows need not sum
    to 1, they are normalised).

    Raises
    ------
    ValueError
        For mismatched shapes, bones outside ``0..n_joints-1`` or a vertex
        with no positive weight.
    """
    widx = np.asarray(widx, dtype=np.int64)
    wval = np.asarray(wval, dtype=np.float64)
    if widx.shape != wval.shape or widx.ndim != 2 or len(widx) != n:
        raise ValueError(f"file weights have shapes {widx.shape} / {wval.shape}, expected "
                         f"({n}, k) each")
    if widx.size and (widx.min() < 0 or widx.max() >= n_joints):
        raise ValueError(f"file weights name joints outside 0..{n_joints - 1}")
    W = dense_weights(widx, np.maximum(wval, 0.0), n_joints)
    s = W.sum(1)
    if np.any(s <= 0):
        raise ValueError(f"{int((s <= 0).sum())} vertices have no positive file weight")
    return W / s[:, None]


def build_rig(V: np.ndarray, F: np.ndarray, skel: Skeleton, opt: RigOptions,
              steps: Steps | None = None, weights: tuple | None = None) -> Rig:
    """Compute the :class:`Rig` of a closed surface ``V, F`` and skeleton ``skel``.

    ``weights`` are the file's ``(Widx, Wval)`` (n, k) per surface vertex,
    used when ``opt.weights == "file"`` (see :func:`file_weights`).
    """
    steps = steps or Steps("rig", enabled=False)
    if opt.weights not in WEIGHT_SOURCES:
        raise ValueError(f"weights must be one of {list(WEIGHT_SOURCES)}, got {opt.weights!r}")
    if opt.weights == "file" and weights is None:
        raise ValueError("weights: 'file' needs a character file with skin weights (glTF)")
    n = len(V)
    volume = mesh_volume(V, F)
    if not volume > 0:
        raise ValueError(f"surface encloses no positive volume ({volume:.3g} m^3): it must be "
                         "closed with outward-facing triangles")
    TV, T, Etet, Ebary, cube = lattice_for_count(V, F, opt.tet_count, volume)
    steps(f"tet lattice: {len(T)} tets, {len(TV)} vertices, cube {cube * 1000:.1f} mm")
    E = tet_edges(T)

    radius = joint_radii(V, skel)
    threshold = opt.region_scale * radius
    # a joint outside the body, further from its skin than half the bone that
    # leads to it, has no skin round it, so no region: an elbow or a hip where
    # only a robot's hands are skin (its radius, the distance to the nearest
    # skin, reached into a hand, and the hands' volume stage chased regions of
    # no volume: Three.js's RobotExpressive walking, 311 intersecting pairs
    # against DQS's 0). A joint an artist set just outside the skin keeps its.
    P = skel.rest_positions
    lead = np.array([np.linalg.norm(P[j] - P[p]) if p >= 0 else 0.0
                     for j, p in enumerate(skel.parents)])
    threshold[(winding_numbers(P, V, F) < 0.5) & (radius > 0.5 * lead)] = 0.0
    D, _ = bone_distances(V, skel)
    region = joint_regions(V, skel, threshold)
    TD, _ = bone_distances(TV, skel)
    tregion = joint_regions(TV, skel, threshold)
    # the paper's weights, kept for the pipelines that reproduce it
    pWidx, pWval = inverse_distance_weights(D, region, skel, opt.weight_power,
                                            opt.neighbours_only)
    pTWidx, pTWval = inverse_distance_weights(TD, tregion, skel, opt.weight_power,
                                              opt.neighbours_only)
    # the character's own: one smooth field for the surface and the tets
    if opt.weights == "file":
        W = file_weights(weights[0], weights[1], skel.n_joints, n)
    else:
        W = bone_heat(V, F, skel, opt.heat)
    TW = lattice_extension(W, E, len(TV), Etet, Ebary)
    Widx, Wval = continuous_top_k(W, opt.influences)
    TWidx, TWval = continuous_top_k(TW, opt.influences)
    steps(f"regions, {opt.weights} weights ({opt.influences} bones a vertex) and the "
          "paper's")
    edge = float(np.linalg.norm(V[F[:, 0]] - V[F[:, 1]], axis=1).mean())
    pf = part_fields(V, F, W, lattice_sampler(TV, cube, TW), cell=opt.field_cell * edge,
                     pad=6.0 * edge, influences=opt.influences)
    steps(f"part fields: {len(pf.values)} nodes")

    vol0 = signed_volumes(TV, T)
    mass = np.zeros(len(TV))
    np.add.at(mass, T.ravel(), np.repeat(np.abs(vol0) / 4.0, 4))
    # Mean vertex mass 1: only mass ratios matter to the solve, and this keeps
    # compliances in plain numbers whatever the lattice's cube size.
    mass /= mass.mean()
    len0 = np.linalg.norm(TV[E[:, 0]] - TV[E[:, 1]], axis=1)
    mt = mass[T]
    centroid = (mt[..., None] * TV[T]).sum(1) / mt.sum(1, keepdims=True)
    erest = np.linalg.norm(TV[T] - centroid[:, None, :], axis=2)
    seg_joint, A, B = skel.bone_segments()
    Ds = point_segment_distance(TV, A, B)
    bseg = np.argmin(Ds, axis=1)
    brest = Ds[np.arange(len(TV)), bseg]
    adj_ptr, adj = one_ring(F, n)
    steps(f"constraints: {len(T)} tets, {len(E)} edges")
    return Rig(Widx=Widx, Wval=Wval, part=np.argmax(W, axis=1).astype(np.int64),
               region=region, Etet=Etet, Ebary=Ebary, adj_ptr=adj_ptr,
               adj=adj, TV=TV, T=T, E=E, TWidx=TWidx, TWval=TWval, tregion=tregion, mass=mass,
               vol0=vol0, len0=len0, erest=erest, bseg=bseg.astype(np.int64), brest=brest,
               zone=weight_zones(TWidx, TWval, skel, opt.zone_weight), radius=radius,
               threshold=threshold, cube=np.array(cube),
               pid_Widx=pWidx, pid_Wval=pWval, pid_TWidx=pTWidx, pid_TWval=pTWval,
               pid_zone=weight_zones(pTWidx, pTWval, skel, opt.zone_weight),
               field_origin=pf.origin, field_cell=pf.cell, field_dims=pf.dims,
               field_ptr=pf.ptr, field_values=pf.values, field_sptr=pf.sptr,
               field_sets=pf.sets, field_wdims=pf.wdims, field_wptr=pf.wptr,
               field_wvalues=pf.wvalues, field_wreach=pf.wreach)


def cached_rig(V: np.ndarray, F: np.ndarray, skel: Skeleton, opt: RigOptions,
               steps: Steps | None = None, use_cache: bool = True,
               weights: tuple | None = None) -> Rig:
    """:func:`build_rig`, loaded from the on-disk cache when its inputs match
    (file ``weights`` are part of the key when ``opt.weights == "file"``)."""
    path = cache_dir() / f"rig-{rig_key(V, F, skel, opt, weights)}.npz"
    if use_cache and path.exists():
        try:
            rig = Rig.load(path)
            if steps:
                steps(f"rig from cache {path.name}")
            return rig
        except Exception:  # a truncated or stale file: rebuild it
            pass
    rig = build_rig(V, F, skel, opt, steps, weights)
    if use_cache:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            rig.save(path)
        except OSError:
            pass
    return rig
