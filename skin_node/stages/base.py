"""The per-frame state and the interface every stage implements."""
from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from ..kernels.smoothing import cap_relief
from ..kernels.topology import ring_distance, strongest_within

#: Sweeps of :meth:`Stage.cap_relief` (a spike is cut in the first; the
#: others settle the ring around it).
RELIEF_PASSES = 4
#: How far the contact moves a vertex before the stages after it take it as
#: fully in contact, in mean edges (at the counts' resolution, like the rings).
FULL_PUSH = 1.0


@dataclass
class Frame:
    """What flows through the stages for one pose.

    Attributes
    ----------
    q : (C,) float
        The pose (channel vector).
    G, M : (J, 4, 4) float
        World matrices and skinning matrices ``G @ inv(B)``.
    bent : (J,) bool
        Joints whose pose rotation exceeds the active threshold.
    fade : (J,) float
        0 below the threshold, rising to 1 over the fade band: stages scale
        their corrections by it so a joint that starts bending never pops.
    angles : (J,) float
        Rotation angle of every joint's pose rotation, radians.
    surface : (n, 3) float
        Current surface; stages update it in place.
    tet : (k, 3) float
        Current tet-mesh vertices: only rows ``tet_rows`` while the stages run.
    surface_base, tet_base : (n, 3), (k, 3) float
        The stage-1 (skinning) result, kept for the embedding update.
    tet_rows : int array or None
        The tet-mesh vertices the stages after skinning use this frame (see
        :meth:`Stage.tet_vertices`), the only ones stage 1 skins; None for all.
    unskinned : callable or None
        Skins the other rows, set by stage 1 when it left some out
        (:attr:`skin_node.Pipeline.last_frame` calls it).
    seg_A, seg_B : (S, 3) float
        Posed bone segments (see :meth:`Skeleton.bone_segments`).
    counts : dict
        Per-stage counters of this frame (active tets, crossings, ...).
    touched : list of int arrays
        Surface vertices the collision stage moved (skin in contact), so later
        stages leave them where they are.
    pushed : tuple or None
        Set by the contact stage: ``(touched, shift)``, its entry of
        ``touched`` and how far it moved each of those vertices (m). A
        contact fades in from nothing, so ``shift`` is small where
        ``touched`` switches a vertex on; the mush takes its strength from it.
    clearance : (n,) float or None
        Set by the contact stage: at least how far each surface vertex was
        from the flesh of the parts it tests against the vertex's own and that
        meet it at no joint, when it tested them (inf where there are none),
        so later stages do not swell skin into another part's; None without a
        contact stage. (Parts turned less than ``active_threshold`` from each
        other since rest are not tested: the contact takes them to be as far
        apart as at rest. Over the next ``active_fade`` of turn their contact
        comes in, and the clearance still reads their flesh.)
    memo : dict
        Values of the pose alone that several stages need (posed bone
        segments of a joint region, say), computed once per frame.
    """

    q: np.ndarray
    G: np.ndarray
    M: np.ndarray
    bent: np.ndarray
    fade: np.ndarray
    angles: np.ndarray
    surface: np.ndarray
    tet: np.ndarray
    surface_base: np.ndarray
    tet_base: np.ndarray
    seg_A: np.ndarray
    seg_B: np.ndarray
    tet_rows: np.ndarray | None = None
    unskinned: object = None
    counts: dict = field(default_factory=dict)
    touched: list = field(default_factory=list)
    pushed: tuple | None = None
    clearance: np.ndarray | None = None
    memo: dict = field(default_factory=dict)


class Stage:
    """A per-frame stage: built once for a character, then called per frame.

    Subclasses set ``name``, take ``(character, params)`` and implement
    ``__call__(frame)``, which updates the frame in place. ``params`` is the
    pipeline's live parameter dict, so a change applies on the next frame.
    """

    name = "stage"
    #: skins the frame (the one stage that fills ``surface``)
    skinning = False
    #: changes the pose's bones (``G``, ``M``, the segments), before skinning
    poses = False

    def __init__(self, character, params: dict) -> None:
        self.character = character
        self.params = params
        #: the skin weights this pipeline skins with (``weight_scheme``)
        self.weights = character.rig.weights(params["weight_scheme"])
        self._relief = None
        self._full = None
        self._spread = None

    def __call__(self, frame: Frame) -> None:  # pragma: no cover - interface
        raise NotImplementedError

    def rings(self, key: str) -> int:
        """Parameter ``key``, a count of rings, at this character's
        resolution (:attr:`~skin_node.Character.smoothing_scale`)."""
        return int(round(int(self.params[key]) * self.character.smoothing_scale))

    def passes(self, key: str) -> int:
        """Parameter ``key``, a count of Laplacian passes, at this character's
        resolution (grown by the square of its smoothing scale)."""
        return int(round(int(self.params[key]) * self.character.smoothing_scale ** 2))

    def contact_reach(self, fr: Frame, rings: int) -> tuple[np.ndarray, np.ndarray]:
        """The skin within ``rings`` rings of skin the stages before moved into
        contact, sorted, and how fully each vertex of it is near contact
        (0-1): its strongest source within that reach
        (:func:`~skin_node.kernels.topology.strongest_within`). A vertex the
        contact stage projected is as strong as the contact moved it, in
        full from :data:`FULL_PUSH` mean edges: a contact fades in from
        nothing, and so does what the stages after it do round it. Skin
        another stage moved (untangle, the paper's collision) is a source in
        full."""
        push = fr.pushed
        verts = [t for t in fr.touched if push is None or t is not push[0]]
        strength = [np.ones(len(t)) for t in verts]
        if push is not None:
            touched, shift = push
            ch = self.character
            if self._full is None:
                self._full = FULL_PUSH * ch.smoothing_scale * ch.mean_edges
            verts.append(touched)
            strength.append(np.minimum(1.0, shift / self._full[touched]))
        if not verts:
            return np.zeros(0, dtype=np.int64), np.zeros(0)
        src, strength = np.concatenate(verts).astype(np.int64), np.concatenate(strength)
        if self._spread is None:
            n = len(self.character.V)
            self._spread = (np.full(n, 1 << 30, dtype=np.int64), np.empty(n, dtype=np.int64),
                            np.empty(n), np.empty(n), np.empty(n))
        hops, queue, m, nxt, out = self._spread
        rig = self.character.rig
        reached = strongest_within(src, strength, rig.adj_ptr, rig.adj, rings, hops, queue, m,
                                   nxt, out)
        zone = np.sort(queue[:reached])
        hops[zone] = 1 << 30
        return zone, out[zone]

    def cap_relief(self, X: np.ndarray, base: np.ndarray, verts: np.ndarray,
                   scale: float = 1.0) -> int:
        """Cut the spikes of this stage's move ``X - base`` of ``verts`` and
        their one ring: no vertex's move stands out from its neighbours' mean
        by more than ``scale`` times ``relief_limit`` of its mean edge
        (:func:`~skin_node.kernels.smoothing.cap_relief`, up to
        :data:`RELIEF_PASSES` sweeps). Returns the vertices it changed."""
        alpha = float(self.params["relief_limit"]) * scale
        if alpha <= 0.0 or not len(verts):
            return 0
        ch = self.character
        ptr, adj = ch.rig.adj_ptr, ch.rig.adj
        n = len(X)
        if self._relief is None:
            self._relief = (np.full(n, 1 << 30, dtype=np.int64), np.empty(n, dtype=np.int64))
        hops, queue = self._relief
        reached = ring_distance(np.asarray(verts, dtype=np.int64), ptr, adj, hops, 2, queue)
        zone = np.sort(queue[:reached])
        hops[zone] = 1 << 30
        return cap_relief(X, base, zone, ptr, adj, alpha * ch.mean_edges, RELIEF_PASSES)

    def tet_vertices(self, frame: Frame) -> np.ndarray | None:
        """The tet-mesh vertices this stage reads or moves in ``frame``, sorted
        (None: all of them); stage 1 skins only those the stages ask for."""
        return _NONE

    def reset(self) -> None:
        """Forget any state carried between frames."""


_NONE = np.zeros(0, dtype=np.int64)
_NONE.flags.writeable = False


class KeyedCache:
    """Set-up results per key (a set of bent joints, say), the ``size`` most
    recently used kept: a walk swings its hips in and out of the bent set
    every stride, and rebuilding index arrays each time cost whole frames."""

    def __init__(self, size: int = 32) -> None:
        self.size = size
        self._d: OrderedDict = OrderedDict()

    def get(self, key, make):
        """The value for ``key``, from ``make()`` the first time."""
        if key in self._d:
            self._d.move_to_end(key)
            return self._d[key]
        value = self._d[key] = make()
        if len(self._d) > self.size:
            self._d.popitem(last=False)
        return value

    def clear(self) -> None:
        self._d.clear()
