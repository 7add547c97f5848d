"""Once per character: tet mesh, embedding, regions, weights, constraint rest
values and colourings, gathered in a :class:`Rig` and cached on disk."""
from __future__ import annotations

import hashlib
import os
import sys
import time
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from ..metrics import mesh_volume
from ..skeleton import Skeleton
from .tetra import greedy_colour, lattice_for_count, signed_volumes, tet_edges
from .weights import bone_distances, inverse_distance_weights, joint_radii, joint_regions

RIG_VERSION = 6


@dataclass
class RigOptions:
    """Set-up choices that change the rig (all part of the cache key).

    Attributes
    ----------
    tet_count : int
        Target number of tets of the lattice (about; the cube size is fitted).
    region_scale : float
        A joint's region holds points closer to it than ``region_scale`` times
        its local limb radius (the paper's per-joint threshold).
    zone_weight : float
        A tet vertex is in joint ``j``'s zone, simulated while ``j`` is bent,
        when it takes more than this weight both from bones below ``j`` and from
        bones above it: only there does bending ``j`` make LBS non-rigid.
    weight_power : float
        The exponent of the inverse-distance weights (the paper's 4).
    neighbours_only : bool
        Restrict a point's bones to the nearest bone and its tree neighbours.
    """

    tet_count: int = 12000
    region_scale: float = 1.6
    zone_weight: float = 0.05
    weight_power: float = 4.0
    neighbours_only: bool = True


@dataclass
class Rig:
    """Everything the per-frame stages need, as plain arrays.

    Surface (n vertices): ``Widx, Wval`` (n,3) weights; ``region`` (n,) joint
    region or -1; ``Etet, Ebary`` (n,4) embedding; ``adj_ptr, adj`` one-ring CSR.
    Tets (k vertices, t tets, e edges): ``TV`` (k,3), ``T`` (t,4), ``E`` (e,2),
    ``TWidx, TWval`` (k,3), ``mass`` (k,), ``vol0`` (t,), ``len0`` (e,),
    ``erest`` (t,4) energy spring rest lengths, ``bseg, brest`` (k,) bind
    segment and rest distance, ``zone`` (k,J) bool, ``tcol, ecol`` colours.
    Joints: ``radius``, ``threshold`` (J,).
    """

    Widx: np.ndarray
    Wval: np.ndarray
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
    tcol: np.ndarray
    ecol: np.ndarray
    radius: np.ndarray
    threshold: np.ndarray
    cube: np.ndarray

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
    below = np.zeros((J, J), dtype=bool)          # below[j, b]: bone b is in j's subtree
    for b in range(J):
        a = b
        while a >= 0:
            below[a, b] = True
            a = skel.parents[a]
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


def rig_key(V: np.ndarray, F: np.ndarray, skel: Skeleton, opt: RigOptions) -> str:
    h = hashlib.sha1(f"rig{RIG_VERSION}".encode())
    for a in (V, F, skel.parents, skel.rest_positions, skel.rest_rotations, skel.tips):
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    h.update(repr(sorted(vars(opt).items())).encode())
    return h.hexdigest()[:20]


def build_rig(V: np.ndarray, F: np.ndarray, skel: Skeleton, opt: RigOptions,
              steps: Steps | None = None) -> Rig:
    """Compute the :class:`Rig` of a closed surface ``V, F`` and skeleton ``skel``."""
    steps = steps or Steps("rig", enabled=False)
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
    D, _ = bone_distances(V, skel)
    region = joint_regions(V, skel, threshold)
    Widx, Wval = inverse_distance_weights(D, region, skel, opt.weight_power, opt.neighbours_only)
    TD, tnearest = bone_distances(TV, skel)
    tregion = joint_regions(TV, skel, threshold)
    TWidx, TWval = inverse_distance_weights(TD, tregion, skel, opt.weight_power,
                                            opt.neighbours_only)
    steps("regions and weights")

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
    from .weights import point_segment_distance
    Ds = point_segment_distance(TV, A, B)
    bseg = np.argmin(Ds, axis=1)
    brest = Ds[np.arange(len(TV)), bseg]
    zone = weight_zones(TWidx, TWval, skel, opt.zone_weight)
    tcol = greedy_colour(T, len(TV))
    ecol = greedy_colour(E, len(TV))
    adj_ptr, adj = one_ring(F, n)
    steps(f"constraints: {len(E)} edges, {int(tcol.max()) + 1} tet colours")
    return Rig(Widx=Widx, Wval=Wval, region=region, Etet=Etet, Ebary=Ebary, adj_ptr=adj_ptr,
               adj=adj, TV=TV, T=T, E=E, TWidx=TWidx, TWval=TWval, tregion=tregion, mass=mass,
               vol0=vol0, len0=len0, erest=erest, bseg=bseg.astype(np.int64), brest=brest,
               zone=zone, tcol=tcol, ecol=ecol, radius=radius, threshold=threshold,
               cube=np.array(cube))


def cached_rig(V: np.ndarray, F: np.ndarray, skel: Skeleton, opt: RigOptions,
               steps: Steps | None = None, use_cache: bool = True) -> Rig:
    """:func:`build_rig`, loaded from the on-disk cache when its inputs match."""
    path = cache_dir() / f"rig-{rig_key(V, F, skel, opt)}.npz"
    if use_cache and path.exists():
        try:
            rig = Rig.load(path)
            if steps:
                steps(f"rig from cache {path.name}")
            return rig
        except Exception:  # a truncated or stale file: rebuild it
            pass
    rig = build_rig(V, F, skel, opt, steps)
    if use_cache:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            rig.save(path)
        except OSError:
            pass
    return rig
