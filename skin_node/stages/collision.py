"""Post-processing: skin passing through skin in the joint regions."""
from __future__ import annotations

import numpy as np

from ..rigging.regions import RegionSearch
from .base import Frame, KeyedCache, Stage


class Collision(Stage):
    """The paper's self-collision handling, joint regions of bent joints only.

    A crossed vertex is projected onto the plane through the joint ``j`` that is
    perpendicular to the plane of the two bones and passes through the farthest
    crossing point ``q`` (``collision_plane: paper``) or bisects the two bones
    (``bisector``, the contact plane of two limbs of equal girth):
    ``p' = p - (n . (p - j)) n``, then nudged ``eps`` to its own side so it does
    not sit exactly on the other skin. Detection and
    projection repeat up to ``collision_passes`` times.
    """

    name = "collision"

    def __init__(self, character, params):
        super().__init__(character, params)
        self.F, self.V0 = character.F, character.V
        self.regions = character.regions(params["weight_scheme"])
        self.search = RegionSearch(self.regions)
        self.child = self.regions.child
        # surface vertices the solve can move, per joint: embedded in a tet of its zone
        self._szone = self.regions.surface_zone
        self._moved = KeyedCache()
        self._active = KeyedCache()

    def _fold_ends(self, fr: Frame, j: int):
        """Joint ``j``'s posed centre and the far ends of its two bones: its
        parent and its child (or its bone's tip)."""
        skel = self.character.skeleton
        P = fr.G[:, :3, 3]
        if self.child[j] >= 0:
            end = P[self.child[j]]
        else:
            end = fr.M[j, :3, :3] @ skel.tips[j] + fr.M[j, :3, 3]
        return (np.ascontiguousarray(P[j]), np.ascontiguousarray(P[skel.parents[j]]),
                np.ascontiguousarray(end))

    def __call__(self, fr: Frame) -> None:
        if not self.params["self_collision"]:
            return
        X = fr.surface
        regs = self.regions
        eps = 0.5e-3
        projected = pushed = 0
        folded = fr.bent & (fr.angles > self.params["collision_angle"])
        # the joints of the folded joints' regions, per set of folded joints
        joints = self._active.get(folded.tobytes(), lambda: [
            j for j in np.flatnonzero(folded) if len(regs.verts[j])])
        fr.counts["collision_joints"] = joints
        # A folding joint also pushes skin into its siblings' regions (lowered arms into
        # the neck's): those are checked too, with push-out only (they have no fold plane).
        skel = self.character.skeleton
        near = np.zeros_like(folded)
        for j in joints:
            near |= skel.parents == skel.parents[j]
        near &= ~folded
        near[skel.parents < 0] = False
        siblings = [j for j in np.flatnonzero(near) if len(regs.verts[j])]
        # The parent's region (the chest under lowered arms) is checked too, but only
        # where the folding joints' solve moved its skin.
        up = {int(skel.parents[j]) for j in joints} - set(int(j) for j in joints) - set(siblings)
        parents = [j for j in sorted(up) if skel.parents[j] >= 0 and len(regs.verts[j])] \
            if self.params["collision_parent"] else []
        fr.counts["collision_joints"] = list(joints) + siblings + parents
        p = self.params
        paper = p["collision_plane"] == "paper"
        upfront = not paper and bool(p["collision_halfspace"])
        for j in list(joints) + siblings + parents:
            pos = regs.every[j]      # the first pass tests them all
            if j in parents:
                pos = self._moved.get((j, folded.tobytes()), lambda: np.flatnonzero(
                    self._szone[regs.verts[j]][:, list(joints)].any(axis=1)))
                if not len(pos):
                    continue
            posed = regs.posed_segments(j, fr.M, fr.memo)
            moved, k, n = self.search.resolve(
                X, self.V0, self.F, fr.M, j, pos, posed, self._fold_ends(fr, j),
                planar=j in joints, paper=paper, upfront=upfront,
                halfspace=bool(p["collision_halfspace"]), pushout=bool(p["collision_pushout"]),
                passes=int(p["collision_passes"]), eps=eps)
            fr.touched.append(moved)
            projected += k
            pushed += n
        fr.counts["projected"] = projected
        fr.counts["pushed"] = pushed
