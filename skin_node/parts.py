"""A character's parts, and its passengers: the parts outside the simulated body.

A character from a file may be several meshes (a glTF scene:
:func:`skin_node.io.gltf.load_gltf_scene`). Its **body** is the union of its
closed skinned meshes, ``Character.V, F``: the closed surface the pipeline's
stages are built for (tet mesh, volume, contact), so contact between two of
its meshes is handled. Every other part is a **passenger**, posed each frame
from the same skeleton after the stages, without them:

* a *skinned* passenger (an open or tiny skinned mesh) by dual-quaternion
  skinning with the file's weights;
* a *rigid* one (a mesh under a joint) by that joint's skinning matrix
  ``M_j = G_j B_j^-1``, exactly as the joint moves;
* a *static* one (no joint above it) stays at rest.

The published surface (``Character.surface_V, surface_F``, what
:meth:`skin_node.Pipeline.deform` returns, ``skin/points`` and ``skin/mesh``) is
the body's vertices first, then each passenger's, in the file's node order.
:attr:`Part.rows` says where each vertex of a part went.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .kernels.skinning import dqs, matrices_to_dual_quaternions

#: What each kind of treatment means, as start-up lines say it.
GETS = {"solved": "solved (the body: every stage of the pipeline)",
        "skinned": "skinned (dual quaternions, the file's weights; no stage after skinning)",
        "rigid": "rigid (carried exactly by its joint)",
        "static": "static (stays at rest)"}


@dataclass(frozen=True)
class Part:
    """One mesh of a character and what posing it gets.

    Attributes
    ----------
    name : str
    kind : str
        What the file makes it: ``"skinned"``, ``"rigid"`` or ``"static"``.
    gets : str
        ``"solved"`` (part of the body), ``"skinned"``, ``"rigid"`` or
        ``"static"`` (a passenger); see :data:`GETS`.
    rows : (n_file,) int
        Row of the surface (``Character.surface_V``) of each of the part's
        vertices, in the file's vertex order (seam vertices share a row).
    vertices, triangles : int
        Distinct vertices (merged by position) and triangles.
    source : str
        Where it hangs, e.g. ``"skinned on skin 1"``, ``"rigid on joint 'head'"``.
    shape : str
        ``"closed"``, or what makes it open, tiny or otherwise no part of the body.
    """

    name: str
    kind: str
    gets: str
    rows: np.ndarray = field(repr=False)
    vertices: int
    triangles: int
    source: str = ""
    shape: str = "closed"

    def describe(self) -> str:
        """One line: name, vertex count, kind, shape and what it gets."""
        src = f", {self.source}" if self.source else ""
        return (f"part '{self.name}': {self.vertices} vertices, {self.triangles} triangles"
                f"{src}, {self.shape} -> {GETS[self.gets]}")

    def summary(self) -> str:
        """``name:vertices:kind:gets`` (the node's diagnostics)."""
        return f"{self.name}:{self.vertices}:{self.kind}:{self.gets}"


@dataclass
class Passengers:
    """The parts of a character posed without the stages, as one point set.

    Attributes
    ----------
    V : (p, 3) float
        Rest points, metres, in the order they follow the body in the surface.
    F : (f, 3) int
        Triangles over ``V``.
    skinned : (s,) int
        Rows of ``V`` posed by dual-quaternion skinning with ``Widx, Wval``
        (s, k): skeleton joints and weights (zero-padded, rows summing to 1).
    rigid : (r,) int
        Rows of ``V`` carried by the skeleton joint ``joint`` (r,) each.

    Rows in neither stay at rest.
    """

    V: np.ndarray
    F: np.ndarray
    skinned: np.ndarray
    Widx: np.ndarray
    Wval: np.ndarray
    rigid: np.ndarray
    joint: np.ndarray

    def __post_init__(self) -> None:
        self.V = np.ascontiguousarray(self.V, dtype=np.float64).reshape(-1, 3)
        self.F = np.ascontiguousarray(self.F, dtype=np.int64).reshape(-1, 3)
        self.skinned = np.asarray(self.skinned, dtype=np.int64)
        self.Widx = np.ascontiguousarray(self.Widx, dtype=np.int64)
        self.Wval = np.ascontiguousarray(self.Wval, dtype=np.float64)
        if self.Widx.ndim != 2 or self.Widx.shape != self.Wval.shape or \
                len(self.Widx) != len(self.skinned):
            raise ValueError(f"passenger weights have shapes {self.Widx.shape} / "
                             f"{self.Wval.shape}, expected ({len(self.skinned)}, k) each")
        self.rigid = np.asarray(self.rigid, dtype=np.int64)
        self.joint = np.asarray(self.joint, dtype=np.int64)
        self._Vs = np.ascontiguousarray(self.V[self.skinned])
        self._Vr = self.V[self.rigid]

    def __len__(self) -> int:
        return len(self.V)

    def pose(self, M: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Posed points under skinning matrices ``M`` (J, 4, 4) (``Frame.M``).

        Returns
        -------
        (p, 3) float
            ``out`` when given (a view of the whole surface, say), else a new array.
        """
        out = np.empty_like(self.V) if out is None else out
        out[:] = self.V
        if len(self.skinned):
            X = np.empty_like(self._Vs)
            dqs(self._Vs, self.Widx, self.Wval, matrices_to_dual_quaternions(M), X)
            out[self.skinned] = X
        if len(self.rigid):
            R = M[self.joint]
            out[self.rigid] = np.einsum("nij,nj->ni", R[:, :3, :3], self._Vr) + R[:, :3, 3]
        return out
