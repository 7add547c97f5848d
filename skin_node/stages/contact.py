"""Contact: skin that skinning pushed into another part's flesh meets it on a
crease instead of passing through it."""
from __future__ import annotations

import math

import numpy as np

from ..kernels.contact import boxed_vertices, contact_pairs, hold_planes, project_contacts
from ..kernels.smoothing import EVEN, gather_weights, laplacian_smooth, ring_layout
from ..kernels.topology import patches, ring_distance
from ..kernels.shape import bent_by_patch, bent_edges, moved_rows
from .base import Frame, Stage
from .untangle import coarse_edges, coarse_triangles
from ..kernels.skinning import matrices_to_dual_quaternions

#: Where two parts' field gradients agree to within these cosines (from
#: fully off to fully on), their skins run on into each other across a cut
#: rather than face each other: contact fades out there.
FACE = (0.9, 0.5)
#: Fixed-point iterations that carry a posed point back into a part's rest flesh.
CARRY_ITERATIONS = 3
#: Newton steps of one projection.
STEPS = 4
#: The contact's relief cap in ``relief_limit``s (:meth:`Stage.cap_relief`):
#: at one, a two-bone capsule meshed as coarsely as CesiumMan and folded to
#: 150 degrees got 10 sharp folds where it had none uncapped (DQS 9); at two,
#: 2, and CesiumMan's sharp folds were as few as at one.
CONTACT_RELIEF = 2.0
#: Coarse skin: where the contact bent an edge by more than EASE_BEND degrees,
#: its move at the edge's corners and EASE_RINGS rings round them is smoothed
#: by EASE_PASSES Laplacian passes. Projected each on its own, the corners of
#: a 40 mm triangle of a hand pressed into the hip creased it past 90 degrees
#: (CesiumMan's walk on automatic weights, every frame: all 4 of its sharp
#: folds, none with the smoothing; see docs/design.md for what it costs). A
#: patch keeps it only where it leaves fewer such edges: on a hinge folded
#: flat it averaged opposite pushes away (a capsule's folds 3 -> 12).
EASE_BEND = 60.0
EASE_RINGS = 1
EASE_PASSES = 2


#: Vertices in a chunk of :func:`_chunks`.
CHUNK = 32


def _chunks(part: np.ndarray, V: np.ndarray, J: int):
    """Each part's vertices in chunks of :data:`CHUNK` nearby ones: ``order``
    (the vertices by part, and within a part along a Morton curve of their
    rest positions), ``pptr`` (J+1,) each part's span of it and ``cptr`` the
    chunks' (no chunk spans two parts)."""
    lo, hi = V.min(axis=0), V.max(axis=0)
    cell = np.floor((V - lo) / max(float((hi - lo).max()), 1e-12) * 1023.999).astype(np.int64)
    code = np.zeros(len(V), dtype=np.int64)
    for bit in range(10):
        for d in range(3):
            code |= ((cell[:, d] >> bit) & 1) << (3 * bit + d)
    order = np.lexsort((code, part)).astype(np.int64)
    pptr = np.searchsorted(part[order], np.arange(J + 1)).astype(np.int64)
    cptr = np.unique(np.concatenate([np.arange(pptr[a], pptr[a + 1], CHUNK)
                                     for a in range(J)] + [pptr[-1:]])).astype(np.int64)
    return order, pptr, cptr


class Contact(Stage):
    """Skin of every part stays out of every other part's flesh.

    Each surface vertex belongs to its heaviest bone's part; each part's flesh
    has a distance field in its rest frame (:mod:`skin_node.rigging.fields`).
    A vertex inside another part's flesh (carried there by skinning, see
    :func:`~skin_node.kernels.contact.worst_contact`) is projected onto its
    own side of the surface where the two parts' fields meet, a margin of
    ``contact_margin`` mean edges short of it, so both sides of a fold keep
    apart. Then Laplacian smoothing of the contact's displacement over
    ``contact_rings`` rings and the constraints' tangent planes alternate
    ``contact_rounds`` times (an obstacle problem solved by projected Jacobi:
    the skin leaves the contact smoothly instead of with a step), a last
    exact projection holds the margin, and ``contact_settle`` passes of the
    smoothing with the tangent planes held spread its steps.
    Which bones meet does not matter: an elbow folding, a heel against a
    thigh, an arm against the chest are the same test. On the way it notes
    how far each vertex is from the parts that meet its own at no joint
    (:attr:`~skin_node.stages.base.Frame.clearance`), so the stages after it
    do not swell skin into theirs.
    """

    name = "contact"

    def __init__(self, character, params):
        super().__init__(character, params)
        r = character.rig
        self.V0 = np.ascontiguousarray(character.V)
        self.part = np.ascontiguousarray(r.part)
        self.fields = r.fields
        J = character.skeleton.n_joints
        self.has = r.field_dims[:, 0] > 1
        # each part's vertices, in chunks of nearby skin (:func:`_chunks`)
        self._order, self._pptr, self._cptr = _chunks(self.part, self.V0, J)
        self._boxed = np.empty(len(self.V0), dtype=np.int64)
        # each part's grid box in its rest frame
        self._lo = r.field_origin
        self._hi = r.field_origin + (np.maximum(r.field_dims, 1) - 1) * r.field_cell[:, None]
        self._edge = character.mean_edges
        # how far a flat triangle of a limb's skin sinks below its round
        # surface: a chord's sagitta, (edge / 2)^2 / (2 radius), radius the
        # skin's rest distance from its bone
        r0 = character.nearest_segments[1][:, 0]
        self._sag = self._edge ** 2 / (8.0 * np.maximum(r0, self._edge))
        # how deep each part's flesh goes (its field's least value): a pair
        # that has just started being tested lets skin lie that deep in it,
        # and its fade takes that to none
        fptr, values = self.fields[3], self.fields[4]
        self._deep = np.array([max(0.0, -float(values[fptr[b]:fptr[b + 1]].min()))
                               if self.has[b] else 0.0 for b in range(J)])
        self._fade = np.zeros((J, J))
        self._edge_max = float(self._edge.max())
        self._sag_max = float(self._sag.max())
        self._ptr, self._adj = r.adj_ptr, r.adj
        self._w_adj = character.edge_weights
        n = len(self.V0)
        self._hops = np.full(n, 1 << 30, dtype=np.int64)
        self._queue = np.empty(n, dtype=np.int64)
        self._label = np.full(n, -2, dtype=np.int64)
        self._moved = np.zeros(n, dtype=np.bool_)
        self._plane = np.zeros((n, 6))
        self._hit = np.full(n, -1, dtype=np.int64)
        self._pre = np.zeros((n, 6))
        self._clear = np.empty(n)
        # parts that meet at no joint: the clearance this stage reports is
        # from their flesh (a joint's own crease is its inflation's business)
        parents = character.skeleton.parents
        self._apart = ~np.eye(J, dtype=np.bool_)
        for j in range(J):
            if parents[j] >= 0:
                self._apart[j, parents[j]] = self._apart[parents[j], j] = False
        self._J = J
        # pairs tested from ``contact_apart_threshold`` on: apart, and not
        # two children of one joint (two thighs, whose skins adjoin at the
        # crotch, where skinning's blend presses them together as they bend
        # alike: tested at no turn, the 90k humanoid's deepest squat kept
        # 36 sharp folds against DQS's 27, 6 with them gated)
        par = np.asarray(parents)
        self._free = self._apart & (par[:, None] != par[None, :])
        # the pairs of coarse skin's triangles that share an edge (none on
        # the built-in characters)
        F, _, coarse = coarse_triangles(character, float(params["coarse_below"]))
        self._coarse = (F, *coarse_edges(F, coarse)) if len(coarse) else None

    def _reach(self) -> float:
        """How far the parts' boxes are grown: contact starts within ``onset``
        of a part's flesh; an edge more covers the flesh's field against the
        skin it was built from."""
        return self._edge_max + float(self.params["contact_onset"]) * self._sag_max

    def pairs(self, fr: Frame):
        """The part pairs to test this frame (:func:`~skin_node.kernels.contact.contact_pairs`):
        ``(cand_ptr (J+1,), cand, Minv (J, 4, 4), box (J, 2, 3))``, parts
        ``cand[cand_ptr[a]:cand_ptr[a+1]]`` for vertices of part ``a``; how
        far each pair's contact has come in (``active_fade`` past
        ``active_threshold``) is left in ``self._fade`` (J, J)."""
        J = self._J
        M = np.ascontiguousarray(fr.M)
        Minv = np.ascontiguousarray(np.linalg.inv(M))
        reach = self._reach()
        box = np.empty((J, 2, 3))
        cand_ptr = np.empty(J + 1, dtype=np.int64)
        cand = np.empty(J * J, dtype=np.int64)
        self._fade[:] = 0.0
        n = contact_pairs(fr.surface, self._order, self._pptr, M, Minv, self.has, self._lo,
                          self._hi, reach, float(self.params["active_threshold"]),
                          float(self.params["active_fade"]), box, cand_ptr, cand, self._fade,
                          self._free, float(self.params["contact_apart_threshold"]))
        return cand_ptr, cand[:n], Minv, box

    def __call__(self, fr: Frame) -> None:
        cand_ptr, cand, Minv, box = self.pairs(fr)
        if not len(cand):
            fr.counts["contact_vertices"] = 0
            return
        parts = np.flatnonzero(np.diff(cand_ptr))
        verts = np.concatenate([self._order[self._pptr[a]:self._pptr[a + 1]] for a in parts])
        X = fr.surface
        # at least how far each vertex is from the other parts' flesh (the
        # tests below lower it; inf where no part is a candidate)
        clear = self._clear
        clear[:] = np.inf
        fr.clearance = clear
        reach = self._reach()
        first = self._boxed[:boxed_vertices(X, self._order, self._pptr, self._cptr, cand_ptr,
                                            cand, Minv, box, reach, self._apart, clear,
                                            self._boxed)]
        X0 = X.copy()
        Q = matrices_to_dual_quaternions(fr.M)
        # in edges of the skin's resolution or, on finer skin, of the one
        # the counts are given at: the gap stays as wide as the crease's
        # rounding (in edges of its own, the 90k humanoid's squat kept 2.8
        # times the intersecting pairs over every 8th frame)
        margin = float(self.params["contact_margin"]) * self.character.smoothing_scale * self._edge
        onset = float(self.params["contact_onset"]) * self._sag
        moved = self._moved
        moved[:] = False
        # what both projections read besides the skin and the vertices to test
        args = (self.part, cand_ptr, cand, Q, Minv, self.fields, box, margin, onset,
                self._deep, self._fade, FACE[0], FACE[1], CARRY_ITERATIONS, STEPS)
        rounds = int(self.params["contact_rounds"])
        rings = self.rings("contact_rings")
        passes = self.passes("contact_smoothing")
        plane, hit = self._plane, self._hit
        hit[verts] = -1
        project_contacts(X, self.V0, first, *args, moved, plane, hit, False, self._pre, clear,
                         reach, self._apart)
        if not moved.any():
            fr.counts["contact_vertices"] = 0
            return
        src = np.flatnonzero(moved)
        reached = ring_distance(src, self._ptr, self._adj, self._hops, rings + 1, self._queue)
        zone = np.sort(self._queue[:reached])
        self._hops[zone] = 1 << 30
        ring, loc, lptr, lnbr = ring_layout(zone, self._ptr, self._adj)
        lw = gather_weights(zone, self._ptr, self._w_adj, lptr)
        L, buf = np.empty((len(ring), 3)), np.empty((len(zone), 3))
        # the zone's skin of parts that have candidates (``verts``, in zone order)
        near = zone[(np.diff(cand_ptr) > 0)[self.part[zone]]]
        exact = max(1, int(self.params["contact_exact_every"]))
        for r in range(rounds):
            # projected Jacobi: smoothing pulls contact skin back in, the
            # constraints push it out again, linearised where the last exact
            # projection left them (a dot product a vertex) between exact
            # projections of the skin near the contact (which find skin that
            # smoothing pushed into contact)
            laplacian_smooth(X, X0, True, ring, loc, lptr, lnbr, lw, 0.5, EVEN, passes, L, buf)
            if (r + 1) % exact == 0 or r == rounds - 1:
                project_contacts(X, self.V0, near, *args, moved, plane, hit, True,
                                 self._pre, clear, reach, self._apart)
            else:
                hold_planes(X, zone, moved, plane)
        settle = self.passes("contact_settle")
        if settle:
            # the last exact projection moved the skin it found in contact on
            # its own; spread those steps over their neighbours, the
            # constraints held by their tangent planes (without it CesiumMan's
            # walk kept three times the sharp folds)
            laplacian_smooth(X, X0, True, ring, loc, lptr, lnbr, lw, 0.5, EVEN, settle, L, buf)
            hold_planes(X, zone, moved, plane)
        # the projections move each vertex in contact on its own: a vertex
        # carried deep into the other side's flesh stands out of its ring as
        # a spike, and neighbours projected onto different sides of a coarse
        # crease fold it. Cut at CONTACT_RELIEF relief limits: the move has a
        # true crease where the contact ends (a hinge folded flat), which a
        # tighter cap rounds into folds
        fr.counts["contact_relief_capped"] = self.cap_relief(X, X0, zone, CONTACT_RELIEF)
        fr.counts["contact_eased"] = self._ease(X, X0) if self._coarse is not None else 0
        touched = np.flatnonzero(moved)
        fr.counts["contact_vertices"] = len(touched)
        fr.touched.append(touched)
        fr.pushed = (touched, np.sqrt(((X[touched] - X0[touched]) ** 2).sum(axis=1)))

    def _ease(self, X: np.ndarray, X0: np.ndarray) -> int:
        """Where the contact's move from ``X0`` bent a coarse edge by more
        than EASE_BEND degrees, the move smoothed at its corners and
        EASE_RINGS rings round. Each connected patch keeps the smoothing only
        if it leaves fewer such edges there: where the two sides of a hinge
        folded flat are pushed apart in opposite directions, smoothing
        averages the pushes away and creases it more. Returns how many
        vertices kept it."""
        F, fa, fb = self._coarse
        limit = math.radians(EASE_BEND)
        hit = np.zeros(len(X), dtype=np.bool_)
        if not bent_edges(X, X0, F, fa, fb, moved_rows(X, X0), limit, hit):
            return 0
        reached = ring_distance(np.flatnonzero(hit), self._ptr, self._adj, self._hops,
                                EASE_RINGS + 1, self._queue)
        zone = np.sort(self._queue[:reached])
        self._hops[zone] = 1 << 30
        label = self._label
        label[zone] = -1
        m = patches(zone, self._ptr, self._adj, label, self._queue)
        before, after = np.zeros(m, dtype=np.int64), np.zeros(m, dtype=np.int64)
        bent_by_patch(X, X0, F, fa, fb, label, limit, before)
        pushed = X[zone]
        ring, loc, lptr, lnbr = ring_layout(zone, self._ptr, self._adj)
        laplacian_smooth(X, X0, True, ring, loc, lptr, lnbr, EVEN, 0.5, EVEN, EASE_PASSES,
                         np.empty((len(ring), 3)), np.empty((len(loc), 3)))
        bent_by_patch(X, X0, F, fa, fb, label, limit, after)
        undo = (after >= before)[label[zone]]
        X[zone[undo]] = pushed[undo]
        label[zone] = -2
        return int(len(zone) - undo.sum())
