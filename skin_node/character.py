"""The Character: rest surface, skeleton and rig, built or loaded once."""
from __future__ import annotations

import hashlib
import inspect
import sys
import warnings
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from .builtin import characters as chars
from .io.character_file import load_character_file, read_closed_mesh
from .io.gltf import load_gltf_scene
from .kernels.smoothing import adjacency_weights
from .parts import Part, Passengers
from .rigging.build import Rig, RigOptions, Steps, cache_dir, cached_rig
from .rigging.embed import fit_template
from .rigging.regions import JointRegions
from .rigging.weights import nearest_segments
from .skeleton import Skeleton

#: Edges across a limb's radius (skin to bone at rest) from which its skin
#: counts as coarse (:attr:`Character.resolved` 0) and as fine (1).
RESOLUTION = (2.0, 3.5)

#: Edges across a limb's radius at which the stages' ring and pass counts
#: (``contact_rings``, ``mush_passes``...) are given: the built-in arm and
#: humanoid at their default resolutions (8.2 and 7.2).
SMOOTHING_RESOLUTION = 8.0

#: Default tet counts: the paper's human has 51,110 tets; the arm prototype 12k.
DEFAULT_TETS = {"arm": 12000, "humanoid": 52000}


@dataclass
class Character:
    """A skinnable character.

    Attributes
    ----------
    name : str
    V : (n, 3) float
        The simulated body's rest surface, metres (empty when a file has no
        closed skinned mesh).
    F : (m, 3) int
        Its closed surface triangles, outward facing.
    skeleton : Skeleton
    rig : Rig or None
        Tet mesh, embedding, weights and constraint rest values of the body
        (None without a body).
    options : RigOptions
    passengers : Passengers or None
        Parts posed after the body without the stages (:mod:`skin_node.parts`).
    parts : list of Part
        Every mesh of the character, in the file's node order, and what it
        gets (a built-in or YAML character: one part, the body).
    notes : list of str
        What of the file was not read and why, for start-up lines.
    file_order, file_faces : (n_file,) int, (m_file, 3) int or None
        A glTF character's own vertex layout: the surface row of every file
        vertex (body parts, then passengers, each in node order) and the
        file's triangles over them, so ``surface_V[file_order]`` carries the
        file's UVs again (what the exporter writes).
    """

    name: str
    V: np.ndarray
    F: np.ndarray
    skeleton: Skeleton
    rig: Rig | None
    options: RigOptions
    passengers: Passengers | None = None
    parts: list = field(default_factory=list)
    notes: list = field(default_factory=list)
    file_order: np.ndarray | None = None
    file_faces: np.ndarray | None = None
    _regions: dict = field(default_factory=dict, init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.parts:
            self.parts = [Part(self.name, "skinned", "solved", np.arange(len(self.V)),
                               len(self.V), len(self.F), "the character's mesh")]

    @cached_property
    def surface_V(self) -> np.ndarray:
        """(n + p, 3) rest points of the whole surface: the body's, then the
        passengers' (``V`` itself when there are none); the rows of
        :meth:`skin_node.Pipeline.deform`, ``skin/points`` and ``skin/mesh``."""
        if not self.passengers:
            return self.V
        return np.concatenate([self.V, self.passengers.V])

    @cached_property
    def surface_F(self) -> np.ndarray:
        """Triangles over :attr:`surface_V` (``F`` itself without passengers)."""
        if not self.passengers:
            return self.F
        return np.concatenate([self.F, self.passengers.F + len(self.V)])

    @cached_property
    def edge_weights(self) -> np.ndarray:
        """``1 / |edge|`` at rest for every entry of the rig's one-ring CSR
        (``rig.adj_ptr``/``rig.adj``), built once and read by every stage
        that smooths (:func:`~skin_node.kernels.smoothing.gather_weights`)."""
        return adjacency_weights(self.V, self.rig.adj_ptr, self.rig.adj)

    @cached_property
    def mean_edges(self) -> np.ndarray:
        """(n,) the mean length at rest of the edges of each body vertex's
        triangles (each edge once per triangle): the local resolution the
        contact margin and the mush are measured in."""
        F = self.F
        e = np.linalg.norm(self.V[F] - self.V[np.roll(F, 1, axis=1)], axis=2)   # (m, 3)
        esum, ecount = np.zeros(len(self.V)), np.zeros(len(self.V))
        for k in range(3):
            np.add.at(esum, F[:, k], e[:, k])
            np.add.at(ecount, F[:, k], 1)
        return esum / np.maximum(ecount, 1)

    @cached_property
    def resolved(self) -> np.ndarray:
        """(n,) how finely the skin resolves its limb, 0 to 1: the body
        vertex's rest distance from its nearest bone in mean edges, from
        :data:`RESOLUTION`'s first (0) to its second (1). A few rings of a
        fine limb's skin are local; on a coarse one (CesiumMan's 40 mm edges
        around 40 mm limbs) they reach across the joint."""
        radius = self.nearest_segments[1][:, 0]
        x = np.clip((radius / np.maximum(self.mean_edges, 1e-12) - RESOLUTION[0])
                    / (RESOLUTION[1] - RESOLUTION[0]), 0.0, 1.0)
        return x * x * (3.0 - 2.0 * x)

    @cached_property
    def smoothing_scale(self) -> float:
        """How many times finer than :data:`SMOOTHING_RESOLUTION` the skin
        resolves its limbs (the median body vertex's rest distance from its
        bone in mean edges), at least 1. The stages' ring counts grow by it
        and their Laplacian pass counts by its square (a diffusion reaches
        the square root of its passes), so a crease is rounded over the same
        width in millimetres on finer skin (at the given counts the 43k
        humanoid's squat kept 1,172 sharp folds over every 4th frame, DQS
        900; scaled, 598). Coarser skin keeps the counts: scaled down, the
        12k humanoid's squat crossed itself where it had not."""
        radius = self.nearest_segments[1][:, 0]
        x = float(np.median(radius / np.maximum(self.mean_edges, 1e-12)))
        return max(1.0, x / SMOOTHING_RESOLUTION)

    @cached_property
    def nearest_segments(self) -> tuple:
        """``(seg, r0, hold)`` of the body's rest surface
        (:func:`~skin_node.rigging.weights.nearest_segments`), built once and
        read by the bulge and inflate stages."""
        return nearest_segments(self.V, self.skeleton)

    def part_lines(self) -> list:
        """One line per part (:meth:`Part.describe`), then the notes."""
        return [p.describe() for p in self.parts] + list(self.notes)

    def regions(self, scheme: str = "character") -> JointRegions:
        """The :class:`~skin_node.rigging.regions.JointRegions` of the weighting
        ``scheme`` (:data:`~skin_node.rigging.build.WEIGHT_SCHEMES`), built on
        first use and shared by every pipeline and stage of this character."""
        if scheme not in self._regions:
            self._regions[scheme] = JointRegions(self, self.rig.weights(scheme))
        return self._regions[scheme]

    @property
    def channel_names(self) -> list:
        """Every JointState name this character accepts, in pose-vector order."""
        return self.skeleton.channel_names

    @property
    def n_channels(self) -> int:
        return self.skeleton.n_channels

    def pose(self, **channels: float) -> np.ndarray:
        """A pose vector from keyword channels, e.g. ``pose(elbow_rz=2.6)``."""
        return self.skeleton.pose(**channels)


def _builtin_mesh(name: str, surface_vertices: int, steps: Steps, use_cache: bool):
    if name not in chars.BUILTIN_CHARACTERS:
        raise ValueError(f"unknown built-in character '{name}' "
                         f"(expected one of {sorted(chars.BUILTIN_CHARACTERS)} or a file path)")
    make = chars.BUILTIN_CHARACTERS[name]
    src = hashlib.sha1(inspect.getsource(chars).encode()).hexdigest()[:12]
    path = cache_dir() / f"mesh-{name}-{surface_vertices}-{src}.npz"
    if use_cache and path.exists():
        try:
            with np.load(path) as z:
                V, F = z["V"], z["F"]
                skel = Skeleton([str(n) for n in z["names"]], z["parents"], z["rest_positions"],
                                rest_rotations=z["rest_rotations"], tips=z["tips"],
                                limits=z["limits"])
            steps(f"{name} mesh from cache")
            return V, F, skel
        except Exception:  # an older or truncated file: make it again
            pass
    V, F, skel = make(surface_vertices=surface_vertices)
    steps(f"{name} mesh: {len(V)} vertices, {len(F)} triangles")
    if use_cache:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(".tmp.npz")
            np.savez(tmp, V=V, F=F, names=np.array(skel.names), parents=skel.parents,
                     rest_positions=skel.rest_positions, rest_rotations=skel.rest_rotations,
                     tips=skel.tips, limits=skel.limits)
            tmp.replace(path)
        except OSError:
            pass
    return V, F, skel


def load_character(spec: str, surface_vertices: int | None = None, tet_count: int | None = None,
                   options: RigOptions | None = None, cache: bool = True,
                   progress: bool = True, weights: str = "automatic") -> Character:
    """Build a built-in character or load one from a file, with its rig.

    Parameters
    ----------
    spec : str
        ``"arm"``, ``"humanoid"``, or a path to a character file: ``.yaml``
        (:mod:`skin_node.io.character_file`) or a ``.glb`` / ``.gltf``: every
        mesh of its scene (:meth:`skin_node.io.gltf.GltfScene.split_body`), the
        closed skinned ones as the simulated body ``V, F`` (seam vertices merged,
        in the file's order), every other one as a passenger (:mod:`skin_node.parts`).
    surface_vertices : int, optional
        Target surface vertex count of a built-in (its default when None or 0).
    tet_count : int, optional
        Target tet count (default :data:`DEFAULT_TETS`, or ``options.tet_count``).
    options : RigOptions, optional
    cache : bool
        Read and write the on-disk cache (``$SKIN_NODE_CACHE`` or
        ``~/.cache/skin_node``), so a restart skips the set-up.
    progress : bool
        Print set-up steps to stderr when set-up takes more than 2 s.
    weights : str
        ``"automatic"`` (the paper's weights) or ``"file"`` (the artist's
        weights of a glTF file); ``"automatic"`` leaves ``options.weights`` as
        it is.

    Raises
    ------
    ValueError
        ``"<spec>: <what is wrong>"`` for an unknown name or a bad file.
    """
    steps = Steps(f"set-up of {spec}", enabled=progress)
    spec = str(spec)
    file_w, layout = None, {}
    if not (("/" in spec) or ("." in spec)):
        if spec not in chars.DEFAULT_SURFACE_VERTICES:
            raise ValueError(f"{spec}: unknown character (expected 'arm', 'humanoid' "
                             "or the path of a character file)")
        n = int(surface_vertices or chars.DEFAULT_SURFACE_VERTICES[spec])
        if n < 100:
            raise ValueError(f"{spec}: surface_vertices must be at least 100, got {n}")
        V, F, skel = _builtin_mesh(spec, n, steps, cache)
        name = spec
        default_tets = DEFAULT_TETS[spec]
    elif Path(spec).suffix.lower() in (".glb", ".gltf"):
        scene = load_gltf_scene(Path(spec))
        for w in scene.warnings:
            warnings.warn(f"{spec}: {w}", UserWarning, stacklevel=2)
        g = scene.split_body()
        V, F, skel, file_w = g.V, g.F, g.skeleton, (g.Widx, g.Wval)
        layout = {"passengers": g.passengers, "parts": g.parts, "notes": g.notes,
                  "file_order": g.file_order, "file_faces": g.file_faces}
        name = Path(spec).stem
        default_tets = max(6000, 2 * len(V))
    else:
        V, F, skel = load_character_file(Path(spec), verbose=progress)
        name = Path(spec).stem
        default_tets = max(6000, 2 * len(V))
    opt = options or RigOptions()
    opt = replace(opt, tet_count=int(tet_count or (opt.tet_count if options else default_tets)),
                  weights=weights if weights != "automatic" else opt.weights)
    if opt.weights == "file" and file_w is None:
        raise ValueError(f"{spec}: weights 'file' needs a skinned glTF character "
                         "(this one has no skin weights)")
    rig = None
    try:
        if len(V):          # without a closed body, no tets: every part is a passenger
            rig = cached_rig(V, F, skel, opt, steps, use_cache=cache, weights=file_w)
    except ValueError as e:
        raise ValueError(f"{spec}: {e}") from None
    steps("ready")
    return Character(name=name, V=V, F=F, skeleton=skel, rig=rig, options=opt, **layout)


def load_embedded(mesh_path: str | Path, template: str | Path = "humanoid", up=None,
                  forward=None, tet_count: int | None = None, options=None,
                  cache: bool = True, progress: bool = False):
    """A :class:`Character` from a bare closed mesh: the
    template skeleton is embedded automatically, then rigged as any character.

    Parameters
    ----------
    mesh_path : str or Path
        A closed mesh file (OBJ, PLY, STL, OFF, glTF/GLB: its first mesh in its
        scene pose), metres.
    template : str or Path
        ``"humanoid"``, ``"quadruped"`` or a template YAML file.
    up, forward : optional
        See :func:`embed_skeleton`.
    tet_count : int, optional
        Target tet count (default ``max(6000, 2 * vertices)``, as for character files).
    options : RigOptions, optional
    cache : bool
        Use the on-disk rig cache.
    progress : bool
        Print set-up steps to stderr when set-up is slow.

    Raises
    ------
    ValueError
        ``"<path>: <problem>"`` for a bad mesh or template.
    """
    steps = Steps(f"set-up of {mesh_path}", enabled=progress)
    V, F = read_closed_mesh(mesh_path)
    try:
        emb = fit_template(V, F, template, up=up, forward=forward)
    except ValueError as e:
        raise ValueError(f"{mesh_path}: {e}") from None
    if not emb.passed:
        raise ValueError(f"{mesh_path}: {emb.failure()}")
    if progress:
        print(f"[skin_node] {mesh_path}: {emb.summary()}", file=sys.stderr, flush=True)
    skel = emb.skeleton
    steps(f"skeleton embedded ({skel.n_joints} joints)")
    opt = options or RigOptions()
    opt = replace(opt, tet_count=int(tet_count or (opt.tet_count if options
                                                   else max(6000, 2 * len(V)))))
    try:
        rig = cached_rig(V, F, skel, opt, steps, use_cache=cache)
    except ValueError as e:
        raise ValueError(f"{mesh_path}: {e}") from None
    steps("ready")
    return Character(name=Path(mesh_path).stem, V=V, F=F, skeleton=skel, rig=rig, options=opt)
