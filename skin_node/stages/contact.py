"""Contact: skin that skinning pushed into another part's flesh meets it on a
crease instead of passing through it."""
from __future__ import annotations

import numpy as np

from ..kernels.contact import project_contacts
from ..kernels.solver import edge_weights, laplacian_smooth, ring_layout
from ..kernels.topology import ring_distance
from .base import Frame, Stage
from .skinning import matrices_to_dual_quaternions

#: Where two parts' field gradients agree to within these cosines (from
#: fully off to fully on), their skins run on into each other across a cut
#: rather than face each other: contact fades out there.
FACE = (0.9, 0.5)
#: Fixed-point iterations that carry a posed point back into a part's rest flesh.
CARRY_ITERATIONS = 3
#: Newton steps of one projection.
STEPS = 4
#: A part pair is tested only once its bones have turned this far (rad) or
#: moved this far (m) from each other since rest: before that skinning keeps
#: the two sides as they were.
PAIR_ANGLE = 0.2
PAIR_SHIFT = 0.01


class Contact(Stage):
    """Skin of every part stays out of every other part's flesh.

    Each surface vertex belongs to its heaviest bone's part; each part's flesh
    has a distance field in its rest frame (:mod:`skin_node.rigging.fields`).
    A vertex inside another part's flesh (carried there by skinning, see
    :func:`~skin_node.kernels.contact.worst_contact`) is projected onto its
    own side of the surface where the two parts' fields meet, a margin of
    ``contact_margin`` mean edges short of it, so both sides of a fold keep
    apart. Projection and Laplacian smoothing of the contact's displacement
    over ``contact_rings`` rings alternate ``contact_rounds`` times (an
    obstacle problem solved by projected Jacobi: the skin leaves the contact
    smoothly instead of with a step), and a last projection holds the margin.
    Which bones meet does not matter: an elbow folding, a heel against a
    thigh, an arm against the chest are the same test.
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
        order = np.argsort(self.part, kind="stable")
        self._order = order.astype(np.int64)
        self._pptr = np.searchsorted(self.part[order], np.arange(J + 1)).astype(np.int64)
        # each part's grid box in its rest frame
        self._lo = r.field_origin
        self._hi = r.field_origin + (np.maximum(r.field_dims, 1) - 1) * r.field_cell[:, None]
        F = character.F
        e = np.linalg.norm(self.V0[F] - self.V0[np.roll(F, 1, axis=1)], axis=2)   # (m, 3)
        esum, ecount = np.zeros(len(self.V0)), np.zeros(len(self.V0))
        for k in range(3):
            np.add.at(esum, F[:, k], e[:, k])
            np.add.at(ecount, F[:, k], 1)
        self._edge = esum / np.maximum(ecount, 1)           # mean edge at each vertex
        self._ptr, self._adj = r.adj_ptr, r.adj
        n = len(self.V0)
        self._hops = np.full(n, 1 << 30, dtype=np.int64)
        self._queue = np.empty(n, dtype=np.int64)
        self._moved = np.zeros(n, dtype=np.bool_)
        self._J = J

    def pairs(self, fr: Frame):
        """The part pairs to test this frame, as (cand_ptr (J+1,), cand):
        parts ``cand[cand_ptr[a]:cand_ptr[a+1]]`` for vertices of part ``a``;
        with ``Minv`` (J, 4, 4) and each part's posed skin carried back by its
        bone, bounded, grown by ``reach``: ``box`` (J, 2, 3)."""
        J, M = self._J, fr.M
        R = M[:, :3, :3]
        # relative rotation angle and shift of every pair since rest
        rel = np.einsum("aji,bjk->abik", R, R)
        cos = np.clip((np.trace(rel, axis1=2, axis2=3) - 1.0) * 0.5, -1.0, 1.0)
        Minv = np.linalg.inv(M)
        X = fr.surface
        # each part's posed box, carried into every other part's rest frame
        lo = np.full((J, 3), np.inf)
        hi = np.full((J, 3), -np.inf)
        for a in range(J):
            v = self._order[self._pptr[a]:self._pptr[a + 1]]
            if len(v):
                P = X[v]
                lo[a], hi[a] = P.min(0), P.max(0)
        corners = np.stack([np.where(np.array([(c >> k) & 1 for k in range(3)], bool), hi, lo)
                            for c in range(8)], axis=1)                       # (J, 8, 3)
        box = np.zeros((J, 2, 3))
        box[:, 0], box[:, 1] = np.inf, -np.inf
        reach = float(self.params["contact_margin"]) * self._edge.max() + self._edge.max()
        for b in range(J):
            v = self._order[self._pptr[b]:self._pptr[b + 1]]
            if len(v):
                P = X[v] @ Minv[b, :3, :3].T + Minv[b, :3, 3]
                box[b, 0], box[b, 1] = P.min(0) - reach, P.max(0) + reach
        cand = [[] for _ in range(J)]
        skinned = np.isfinite(lo[:, 0])
        corners[~skinned] = 0.0                        # parts without skin: never tested
        for b in np.flatnonzero(self.has):
            C = corners @ Minv[b, :3, :3].T + Minv[b, :3, 3]                  # (J, 8, 3)
            clo, chi = C.min(1), C.max(1)
            overlap = np.all((clo <= self._hi[b]) & (chi >= self._lo[b]), axis=1)
            for a in np.flatnonzero(overlap & skinned):
                if a == b:
                    continue
                shift = np.linalg.norm((Minv[b] @ M[a])[:3, 3])
                if np.arccos(cos[a, b]) < PAIR_ANGLE and shift < PAIR_SHIFT:
                    continue
                cand[a].append(b)
        ptr = np.zeros(J + 1, dtype=np.int64)
        ptr[1:] = np.cumsum([len(c) for c in cand])
        flat = np.array([b for c in cand for b in c], dtype=np.int64)
        return ptr, flat, np.ascontiguousarray(Minv), box

    def __call__(self, fr: Frame) -> None:
        cand_ptr, cand, Minv, box = self.pairs(fr)
        if not len(cand):
            fr.counts["contact_vertices"] = 0
            return
        parts = np.flatnonzero(np.diff(cand_ptr))
        verts = np.concatenate([self._order[self._pptr[a]:self._pptr[a + 1]] for a in parts])
        X = fr.surface
        X0 = X.copy()
        Q = matrices_to_dual_quaternions(fr.M)
        margin = float(self.params["contact_margin"]) * self._edge
        moved = self._moved
        moved[:] = False
        args = (self.V0, verts, self.part, cand_ptr, cand, Q, Minv, self.fields, box, margin,
                FACE[0], FACE[1], CARRY_ITERATIONS, STEPS)
        rounds = int(self.params["contact_rounds"])
        rings = int(self.params["contact_rings"])
        passes = int(self.params["contact_smoothing"])
        test = verts
        for _ in range(rounds):
            project_contacts(X, self.V0, test, *args[2:], moved)
            if not moved.any():
                fr.counts["contact_vertices"] = 0
                return
            src = np.flatnonzero(moved)
            reached = ring_distance(src, self._ptr, self._adj, self._hops, rings + 1,
                                    self._queue)
            zone = np.sort(self._queue[:reached])
            self._hops[zone] = 1 << 30
            ring, loc, lptr, lnbr = ring_layout(zone, self._ptr, self._adj)
            lw = edge_weights(self.V0, ring, loc, lptr, lnbr)
            laplacian_smooth(X, X0, True, ring, loc, lptr, lnbr, lw, 0.5, passes,
                             np.empty((len(ring), 3)), np.empty((len(zone), 3)))
            # after the first round only the skin near a contact can change
            test = np.intersect1d(zone, verts, assume_unique=True)
        project_contacts(X, self.V0, test, *args[2:], moved)
        touched = np.flatnonzero(moved)
        fr.counts["contact_vertices"] = len(touched)
        fr.touched.append(touched)
