"""Mush: the skin around a contact, smoothed with its rest detail kept."""
from __future__ import annotations

import numpy as np

from ..kernels.smoothing import (gather_weights, laplacian_smooth, relax_tangents,
                                 rest_tangents, restore_detail, ring_layout, vertex_faces)
from ..kernels.shape import clearance_caps, dihedral_angles, hold_clear, most_bent
from ..metrics import interior_edges
from .base import Frame, Stage
from .shape import CLEAR_SHARE

#: Where the rest detail bends an edge more than DETAIL_BEND degrees beyond
#: both the smoothed skin and the rest skin, it is faded out at the edge's
#: corners, fully DETAIL_RAMP degrees further. Crushed into a deep crease,
#: each vertex's rest offset turned into its own frame folds the skin
#: between them: the 90k humanoid's deepest squat kept 85 sharp folds (DQS
#: 27) and the 43k's 14 (DQS 21); faded, 21 and 1 (see docs/design.md).
DETAIL_BEND = 30.0
DETAIL_RAMP = 30.0
#: How far one pass of the tangential relaxation (``mush_relax``) slides a
#: vertex of full strength towards where its ring puts it at rest.
RELAX_STEP = 0.5
#: A vertex the relaxation would slide so that the worst of its faces turns
#: further from its normal keeps its place (on skin crushed flat its frame
#: can point anywhere; see :func:`~skin_node.kernels.smoothing.relax_tangents`).
RELAX_GUARD = True


class Mush(Stage):
    """Delta Mush (Mancewicz et al. 2014) over the skin the contact moved.

    Contact projects skin onto the surface where two parts meet; where the two
    sides leave it, at the bottom of a crease, they meet at an edge, and where
    three parts meet (the groin) the projections of one side can leave it
    zig-zagged. Smoothing the posed positions (not the displacement, which
    keeps what skinning made) rounds the crease and irons the zig-zag out; the
    rest skin's own detail, which that smoothing would melt, comes back in each
    vertex's frame (:mod:`skin_node.kernels.smoothing`). Skin that moved
    rigidly comes out unchanged, so only what the contact bent is touched:
    the vertices it moved and ``mush_rings`` rings around them, ``mush_passes``
    weighted Laplacian passes, the zone's border held. Each vertex's step is
    as strong as the contact's move near it (:meth:`Stage.contact_reach`),
    so a vertex the contact starts to move brings its rings in gently: a
    zone of full strength switched them from held to smoothed in one frame,
    a pop of up to 5 mm on the 2k arm's bending elbow. Skin too coarse for
    that to stay local (:attr:`~skin_node.Character.resolved`: CesiumMan's
    40 mm edges around 40 mm limbs, where smoothing a few rings reaches across
    the joint, cuts the bend's corner and loses a fifth of the shoulder
    region's volume) is left alone. Where the detail, crushed into a deep
    crease of fine skin, bends an edge beyond both the smoothed skin and the
    rest skin, it is faded out (:data:`DETAIL_BEND`).
    """

    name = "mush"

    def __init__(self, character, params):
        super().__init__(character, params)
        r = character.rig
        self.V0 = np.ascontiguousarray(character.V)
        self.F = np.ascontiguousarray(character.F, dtype=np.int64)
        n = len(self.V0)
        self._ptr, self._adj = r.adj_ptr, r.adj
        self._w_adj = character.edge_weights
        self._vf_ptr, self._vf = vertex_faces(self.F, n)
        # a neighbour of every vertex, the tangent's direction (a closed
        # surface has one for each; an isolated vertex points at itself)
        has = np.diff(self._ptr) > 0
        self._first = np.where(has, self._adj[np.minimum(self._ptr[:-1], len(self._adj) - 1)],
                               np.arange(n)).astype(np.int64)
        self._SX, self._SV = np.empty((n, 3)), np.empty((n, 3))
        #: how much of the mush each vertex takes (0 where its limb is too coarse)
        self.resolved = character.resolved
        self._fade = np.zeros(n)
        # the mush fades itself out on coarse skin, so its hold is not scaled
        # by resolution as inflation's is (clearance_caps' resolved: ones)
        self._unscaled, self._near = np.ones(n), np.empty(n)
        # the interior edges (as their two faces) a vertex's move bends:
        # those of the faces round it (the pair's corners list each of them
        # once or twice); and their rest angles
        fa, fb, _ = interior_edges(self.F)
        self._fa, self._fb = fa.astype(np.int64), fb.astype(np.int64)
        self._rest_angle = dihedral_angles(self.V0, self.F, self._fa, self._fb)
        self._floor = np.cos(np.minimum(np.pi, self._rest_angle + np.radians(DETAIL_BEND)))
        corners = np.concatenate([self.F[self._fa], self.F[self._fb]], axis=1).ravel()
        order = np.argsort(corners, kind="stable")
        self._eptr = np.r_[0, np.cumsum(np.bincount(corners, minlength=n))].astype(np.int64)
        self._edges = (order // 6).astype(np.int64)
        self._seen = np.zeros(len(fa), dtype=np.bool_)
        self._Y, self._grew = np.empty((n, 3)), np.zeros(n)
        # where each vertex's one ring puts it at rest, along its surface
        self._rest_tangents = rest_tangents(self.V0, self.F, self._vf_ptr, self._vf,
                                            self._first, self._ptr, self._adj, np.empty((n, 2)))

    def __call__(self, fr: Frame) -> None:
        passes = self.passes("mush_passes")
        if not fr.touched or passes == 0:
            fr.counts["mush_vertices"] = 0
            return
        zone, kw = self.contact_reach(fr, self.rings("mush_rings"))
        if not len(zone):
            fr.counts["mush_vertices"] = 0
            return
        ring, loc, lptr, lnbr = ring_layout(zone, self._ptr, self._adj)
        lw = gather_weights(zone, self._ptr, self._w_adj, lptr)
        X, SX, SV = fr.surface, self._SX, self._SV
        SX[ring] = X[ring]
        SV[ring] = self.V0[ring]
        L, buf = np.empty((len(ring), 3)), np.empty((len(zone), 3))
        laplacian_smooth(SX, SX, False, ring, loc, lptr, lnbr, lw, 0.5, kw, passes, L, buf)
        laplacian_smooth(SV, SV, False, ring, loc, lptr, lnbr, lw, 0.5, kw, passes, L, buf)
        self._fade[zone] = self.resolved[zone]
        start = X.copy() if fr.clearance is not None else None
        # the smoothed skin, without the detail: X but on the zone (the edges
        # checked reach corners two rings out of it, past ``ring``)
        Y = self._Y
        np.copyto(Y, X)
        Y[zone] += self._fade[zone, None] * (SX[zone] - Y[zone])
        restore_detail(X, self.V0, SX, SV, zone, self.F, self._vf_ptr, self._vf, self._first,
                       self._fade)
        fr.counts["mush_detail_faded"] = self._fade_folds(X, Y, zone)
        self._fade[zone] = 0.0
        if start is not None:
            # the rest detail comes back round where the contact flattened
            # skin against a part that meets its own at no joint (a forearm
            # across the chest, a shin against the other): there, skin moves
            # no more than inflation may (skin the contact moved out of that
            # part's flesh, not at all)
            fr.counts["mush_held"] = hold_clear(
                X, zone, start, clearance_caps(fr.clearance, self._unscaled, CLEAR_SHARE,
                                               self._near))
        relax = int(self.params["mush_relax"])
        if relax:
            # the triangles at a crease's bottom, crushed into slivers that
            # turn their edges past 90 degrees, get their rest shape back by
            # sliding along the skin (its shape stays)
            relax_tangents(X, zone, kw * self.resolved[zone], self.F, self._vf_ptr, self._vf,
                           self._first, self._ptr, self._adj, self._rest_tangents, RELAX_STEP,
                           relax, RELAX_GUARD, np.empty((len(zone), 3)))
        fr.counts["mush_vertices"] = len(zone)

    def _fade_folds(self, X: np.ndarray, Y: np.ndarray, zone: np.ndarray) -> int:
        """Fades the rest detail out of ``X`` (back towards ``Y``) at the
        corners of edges it bends more than DETAIL_BEND degrees beyond both
        ``Y``'s and the rest skin's; returns how many vertices it faded."""
        grew = self._grew
        most_bent(X, Y, self._rest_angle, self._floor, self.F, self._fa, self._fb, zone,
                  self._eptr, self._edges, self._seen, grew)
        w = np.clip((np.degrees(grew[zone]) - DETAIL_BEND) / DETAIL_RAMP, 0.0, 1.0)
        grew.fill(0.0)          # set on corners up to two rings out
        faded = w > 0.0
        X[zone[faded]] += w[faded, None] * (Y[zone[faded]] - X[zone[faded]])
        return int(faded.sum())
