"""A pipeline is a list of stages built from names; it deforms poses and times
every stage. LBS-only, DQS, the paper's method and our default are the same
code path with different lists and parameters, so they benchmark side by side."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numba
import numpy as np

from .stages.base import Frame, Stage
from .kernels.pose import pose_frame
from .kernels.solver import CONSTRAINTS
from .rigging.build import WEIGHT_SCHEMES
from .stages.collision import Collision
from .stages.contact import Contact
from .stages.mush import Mush
from .stages.pbd import PBD
from .stages.shape import Bulge, Inflate
from .stages.skinning import DQS, LBS
from .stages.smooth import Smooth
from .stages.turn import Turn
from .stages.untangle import Untangle
from .stages.volume import Volume

STAGES = {s.name: s for s in (LBS, DQS, PBD, Bulge, Inflate, Contact, Mush, Untangle,
                               Collision, Smooth, Volume, Turn)}
STAGE_NAMES = tuple(STAGES)

#: Our default: a limb the pose drives deep into another part turned out of
#: it, DQS start (no candy wrapper) with smooth weights, the bulge drawn in,
#: skin kept out of other parts' flesh, coarse skin's triangles that still
#: pass through another part's pushed apart, the volume given back, and the
#: crease the contact leaves rounded with the rest skin's detail kept.
DEFAULT_STAGES = ("turn", "dqs", "bulge", "contact", "untangle", "inflate", "mush")

#: Named stage lists with the parameters that make them what they are.
PRESETS = {
    "lbs": (("lbs",), {}),
    "dqs": (("dqs",), {}),
    # Abu Rumman & Fratarcangeli 2015: PBD without the energy constraint.
    "pbs": (("lbs", "pbd"), {"solver": "pbd", "constraints": ["stretch", "volume", "bind"],
                             "weight_scheme": "inverse_distance",
                             "active_regions": False, "active_threshold": 0.0,
                             "iterations": 5, "warm_start": False}),
    # Chen & Pan 2017 as published: LBS start, plain PBD, its four constraints.
    "paper": (("lbs", "pbd", "collision", "smooth"),
              {"solver": "pbd", "active_regions": False, "active_threshold": 0.0,
               "weight_scheme": "inverse_distance",
               "iterations": 5, "warm_start": False, "collision_halfspace": False, "collision_angle": 0.0,
               "smooth_mode": "position", "smoothing": 0.3, "smoothing_iterations": 1,
               "collision_pushout": False, "collision_parent": False,
               "collision_plane": "paper", "volume_preserve": False,
               "constraints": ["stretch", "volume", "bind", "energy"]}),
    "default": (DEFAULT_STAGES, {}),
}


@dataclass(frozen=True)
class ParamSpec:
    """A pipeline parameter: type, default, range and a description."""

    type: type
    default: object
    min: float | None = None
    max: float | None = None
    description: str = ""
    choices: tuple = ()

    def check(self, name: str, value):
        if self.type is bool:
            if not isinstance(value, (bool, np.bool_)):
                raise ValueError(f"{name} must be a bool, got {value!r}")
            return bool(value)
        if self.type is list:
            if isinstance(value, str) or not all(isinstance(v, str) for v in value):
                raise ValueError(f"{name} must be a list of strings, got {value!r}")
            bad = [v for v in value if self.choices and v not in self.choices]
            if bad:
                raise ValueError(f"{name}: unknown {bad}, expected some of {list(self.choices)}")
            return list(value)
        if self.type is str:
            if not isinstance(value, str) or (self.choices and value not in self.choices):
                raise ValueError(f"{name} must be one of {list(self.choices)}, got {value!r}")
            return value
        if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
            raise ValueError(f"{name} must be a number, got {value!r}")
        if self.type is int and int(value) != value:
            raise ValueError(f"{name} must be an integer, got {value!r}")
        value = self.type(value)
        if not np.isfinite(value) or (self.min is not None and value < self.min) or \
                (self.max is not None and value > self.max):
            raise ValueError(f"{name} = {value} is outside [{self.min}, {self.max}]")
        return value


#: The counts of rings and Laplacian passes below (``contact_rings``,
#: ``mush_passes``...) and ``contact_margin`` are given for skin about
#: :data:`~skin_node.character.SMOOTHING_RESOLUTION` edges across a limb's
#: radius; finer skin scales them (:attr:`~skin_node.Character.smoothing_scale`).
PIPELINE_PARAMS = {
    "weight_scheme": ParamSpec(str, "character", description="skin weights: 'character' (the "
                               "character's own: smooth bone heat, or a file's) or "
                               "'inverse_distance' (the paper's, 3 bones in joint regions, 2 "
                               "elsewhere)", choices=WEIGHT_SCHEMES),
    "contact_margin": ParamSpec(float, 0.75, 0.0, 3.0, "gap each side of a fold keeps from the "
                                "surface where the two parts meet, in mean edges"),
    "contact_onset": ParamSpec(float, 2.0, 0.0, 8.0, "how far outside the other part's flesh "
                               "contact starts, in sagittas of the local edges' chords (each "
                               "side's flat triangles sink below its round surface by one)"),
    "contact_rounds": ParamSpec(int, 4, 0, 50, "projection and smoothing rounds of the contact "
                                "stage"),
    "contact_exact_every": ParamSpec(int, 2, 1, 50, "rounds between exact projections of the "
                                     "contact stage (tangent planes hold the skin between)"),
    "contact_settle": ParamSpec(int, 1, 0, 50, "Laplacian passes over the contact's "
                                "displacement after its last exact projection, the skin held "
                                "by the constraints' tangent planes"),
    "contact_apart_threshold": ParamSpec(float, 0.0, 0.0, 3.2, "parts that meet at no "
                                         "joint and hang from different joints (a shin and "
                                         "the other shin, a hand and the chest) are tested "
                                         "for contact once their bones turned this far from "
                                         "each other since rest (rad; 0: at any turn); the "
                                         "others from active_threshold"),
    "contact_rings": ParamSpec(int, 3, 0, 20, "rings around skin in contact that follow it"),
    "contact_smoothing": ParamSpec(int, 4, 0, 50, "Laplacian passes over the contact's "
                                   "displacement per round"),
    "mush_rings": ParamSpec(int, 3, 0, 20, "rings around the skin the contact moved that "
                            "the mush smooths"),
    "mush_passes": ParamSpec(int, 8, 0, 100, "Laplacian passes of the mush over the posed "
                             "skin (its rest detail comes back; 0 leaves it alone)"),
    "mush_relax": ParamSpec(int, 2, 0, 50, "passes of tangential relaxation over the mush's "
                            "skin: each vertex slides along the surface towards where its "
                            "one ring puts it at rest, so triangles crushed into slivers at "
                            "a crease's bottom get their shape back (0: none)"),
    "relief_limit": ParamSpec(float, 0.1, 0.0, 10.0, "the most a vertex's move by the "
                              "contact or the inflation may stand out from its neighbours' "
                              "mean move, in mean edges (cuts spikes and creases a vertex "
                              "wide; 0 leaves the moves as they are)"),
    # Half-way: the humanoid at 8k and 12k vertices, whose shoulders and
    # knees or forearms and feet (2.8 to 3.5 edges across a limb's radius)
    # were coarse at 1 too, came out with the same measures at 0.5 over the
    # built-in walk and squat and five CMU clips (the 12k's skin within 0.24
    # mm) and 7-27% faster; at 6k (1.7 to 2.7 edges) CMU's punch crossed skin
    # without the coarse checks (33 pairs, 0 with them). See docs/design.md.
    "coarse_below": ParamSpec(float, 0.5, 0.0, 1.0, "a part whose median vertex resolves its "
                              "limb less than this (Character.resolved: 0 at 2 edges across "
                              "the limb's radius, 1 at 3.5) is coarse: the untangle, the "
                              "contact's easing and inflation's checks of bent edges and "
                              "crossings run on its skin (0: on no part)"),
    "untangle_rounds": ParamSpec(int, 6, 0, 50, "rounds of pushing apart coarse skin's "
                                 "triangles that pass through another part's"),
    "untangle_gap": ParamSpec(float, 0.05, 0.0, 1.0, "how far in front of the other "
                              "triangle's plane the untangle puts a corner, in mean edges"),
    "untangle_depth": ParamSpec(float, 0.5, 0.0, 5.0, "corners further than this behind the "
                                "other triangle's plane are left to the contact, in mean "
                                "edges"),
    "untangle_spread": ParamSpec(float, 0.5, 0.0, 1.0, "share of a pushed corner's move "
                                 "its unpushed neighbours take (a corner pushed alone "
                                 "folds its edges)"),
    "untangle_reach": ParamSpec(float, 2.0, 0.0, 20.0, "coarse skin this near another part's "
                                "flesh is tested, in mean edges"),
    "untangle_unfold": ParamSpec(int, 2, 0, 50, "Laplacian passes over the corners of coarse "
                                 "skin's triangles that cross others a few rings away (skin "
                                 "skinning folded through itself at a joint); a patch keeps "
                                 "them where they leave fewer crossings (0: none)"),
    "untangle_shift": ParamSpec(float, 3.0, 0.0, 10.0, "the farthest one turn moves skin "
                                "when a coarse limb still passing through another part (after "
                                "the untangle's rounds, or inflation) is turned out of it "
                                "about a joint up its chain, in the limb's radii (skin to "
                                "bone at rest; 0: never)"),
    "turn_depth": ParamSpec(float, 0.5, 0.0, 10.0, "the turn stage turns a limb (a forearm, a "
                            "hand, a shin, a foot) out of another part's flesh it lies deeper "
                            "in than this, in the limb's radii (skin to bone at rest), until "
                            "it lies no deeper (0: never)"),
    "turn_shift": ParamSpec(float, 4.0, 0.0, 10.0, "the farthest one turn of the turn stage "
                            "moves skin, in the turned limb's radii (a limb that would need "
                            "more is turned this far and the contact does the rest)"),
    "turn_rate": ParamSpec(float, 1.0, 0.0, 100.0, "the most the turn stage's turn of a joint "
                           "changes from one frame to the next, in shares of the most any "
                           "channel of the pose turned between them (0: no limit, each pose "
                           "turned on its own)"),
    "bulge_limit": ParamSpec(float, 0.1, 0.001, 2.0, "the most skin stands out from its bone "
                             "beyond its rest distance, in rest distances"),
    "bulge_smoothing": ParamSpec(int, 2, 0, 100, "Laplacian passes over the bulge limit's "
                                 "pull"),
    "inflate_rings": ParamSpec(int, 3, 0, 20, "rings around skin in contact over which "
                               "inflation fades in"),
    "inflate_zone": ParamSpec(str, "region", description="what inflation keeps: the paper's "
                              "joint 'region', the skin within 'reach' (inflate_reach limb "
                              "radii) of the joint, or the skin whose 'weights' the joint "
                              "splits", choices=("region", "reach", "weights")),
    "inflate_reach": ParamSpec(float, 2.5, 0.5, 10.0, "with inflate_zone 'reach': how far "
                               "from the joint, in limb radii"),
    "inflate_slack": ParamSpec(float, 0.02, 0.0, 1.0, "the whole mesh may keep this share of "
                               "its volume lost (what the joint regions do not take back); "
                               "1 leaves it alone"),
    "inflate_smoothing": ParamSpec(int, 4, 0, 100, "Laplacian passes over the whole mesh's "
                                   "inflation"),
    "inflate_max": ParamSpec(float, 0.25, 0.0, 2.0, "the most inflation moves skin, in limb "
                             "radii of the joint"),
    "iterations": ParamSpec(int, 1, 0, 200, "Gauss-Seidel iterations of the PBD solve per frame "
                            "(more come closer to the converged reference but flicker more in "
                            "crushed folds: skin_bench run --iterations 1,2,3)"),
    "stiffness": ParamSpec(float, 0.5, 0.0, 1.0,
                           "energy-conservation spring constant k (the paper's 0.5)"),
    "solver": ParamSpec(str, "xpbd", description="'pbd' (stiffness scales each step, the paper) "
                        "or 'xpbd' (compliance; result independent of the iteration count)",
                        choices=("pbd", "xpbd")),
    # Energy before volume: the tet volumes, solved last but bind, come out
    # closer to rest (lowered shoulders: region volume 0.95 the other way round).
    # No stretch: where stage 1 pressed tet vertices through each other, an edge
    # constraint pushes them apart the way they now face, against the volume
    # constraint, and which one wins flips from frame to frame (the humanoid
    # walk's jitter: 5.5 mm median with stretch, 2.8 without). The energy
    # springs already hold each tet's shape.
    "constraints": ParamSpec(list, ["energy", "volume", "bind"],
                             description="constraint types solved, in this order",
                             choices=tuple(CONSTRAINTS)),
    "stretch_stiffness": ParamSpec(float, 1.0, 0.0, 1.0, "PBD stiffness of tet edges"),
    "volume_stiffness": ParamSpec(float, 1.0, 0.0, 1.0, "PBD stiffness of tet volumes"),
    "bind_stiffness": ParamSpec(float, 0.5, 0.0, 1.0, "PBD stiffness of bone bindings"),
    "stretch_compliance": ParamSpec(float, 0.0, 0.0, 1e6, "XPBD compliance of tet edges (m/unit)"),
    "volume_compliance": ParamSpec(float, 0.0, 0.0, 1e6, "XPBD compliance of tet volumes"),
    "bind_compliance": ParamSpec(float, 0.0, 0.0, 1e6, "XPBD compliance of bone bindings"),
    "energy_compliance": ParamSpec(float, 0.0, 0.0, 1e6, "XPBD compliance of energy springs"),
    "contact_angle": ParamSpec(float, 1.0, 0.0, 3.2,
                               "joints bent past this (rad) get a contact plane in the solve"),
    # Off: started from stage 1 every frame, the skin is a function of the pose
    # alone. Warm-started, the one-iteration solve carries its history, and in
    # crushed folds a 1e-9 rad change of the pose grew to centimetres (squat: 21
    # crossings, 1 cold; walk jitter 12.9 mm median, 5.5 cold).
    "warm_start": ParamSpec(bool, False, description="start the solve from the last frame's "
                            "correction, carried by each vertex's main bone (closer to the "
                            "converged reference, but the result depends on the frames "
                            "before it)"),
    "tolerance": ParamSpec(float, 0.0, 0.0, 1.0,
                           "stop iterating once no vertex moved more than this (m); 0 = never"),
    "active_regions": ParamSpec(bool, True, description="simulate only the zones of bent joints"),
    "active_threshold": ParamSpec(float, 0.35, 0.0, 3.2,
                                  "a joint is simulated above this rotation (rad); below it "
                                  "stage 1 is left as it is"),
    "active_fade": ParamSpec(float, 0.2, 1e-3, 3.2, "corrections fade in over this much rotation "
                             "past the threshold (rad), so nothing pops"),
    "threads": ParamSpec(int, 1, 1, 64, "threads of the numba kernels: skinning, the collision "
                         "test, smoothing, the embedding; the skin comes out the same on any "
                         "number (2: 7.5 against 9.6 ms on the humanoid walk alone, but "
                         "through ROS on two cores, shared with the executor and DDS, 2 "
                         "answered 40% fewer poses of a 120 Hz walk than 1)"),
    "solve_slabs": ParamSpec(bool, False, description="with threads > 1, also split the solve "
                             "into one slab of the tet mesh per thread: faster, but it reorders "
                             "the Gauss-Seidel sweep, so the skin then depends on threads"),
    "self_collision": ParamSpec(bool, True, description="run the collision stage"),
    "collision_angle": ParamSpec(float, 1.0, 0.0, 3.2, "joints bent less than this (rad) cannot "
                                 "fold skin onto skin and are not checked"),
    "collision_passes": ParamSpec(int, 8, 1, 20, "detect-and-resolve passes per joint"),
    "collision_pushout": ParamSpec(bool, True, description="after the plane projection, push "
                                   "each still-crossed vertex out in front of the skin it crossed"),
    "collision_parent": ParamSpec(bool, True, description="also check the folding joints' "
                                  "parent region (the chest under lowered arms) where their "
                                  "solve moved it (0.1 to 2.5 ms on the humanoid walk in four "
                                  "runs of skin_bench ablation)"),
    "collision_plane": ParamSpec(str, "bisector", description="contact plane: 'paper' (through "
                                 "the farthest crossing point) or 'bisector' (of the two bones)",
                                 choices=("paper", "bisector")),
    "collision_halfspace": ParamSpec(bool, True, description="also project every vertex of the "
                                     "interpenetration zone on the wrong side of the plane"),
    "volume_preserve": ParamSpec(bool, True, description="run the volume stage"),
    "volume_regions": ParamSpec(str, "joints", description="what the volume stage keeps: "
                                "'joints', each bent joint's region volume, moving that region; "
                                "or the whole mesh's volume, moving skin 'inside' the bent "
                                "joints' zones (regions included) or only 'outside' their "
                                "joint regions", choices=("joints", "inside", "outside")),
    "volume_max_bulge": ParamSpec(float, 0.5, 0.0, 2.0, "with volume_regions 'joints': the "
                                  "most any skin moves to give a region its volume back, in "
                                  "limb radii of the joint, up to a right angle; falling to "
                                  "0 at a full fold"),
    "volume_checked_below": ParamSpec(float, 0.01, 0.0, 1.0, "with volume_regions 'joints': "
                                      "a region still this far below its rest volume may "
                                      "also swell skin near the other side's flesh, keeping "
                                      "only moves that cross no skin (checked like the "
                                      "collision stage); 1 turns the check off"),
    "smoothing": ParamSpec(float, 0.5, 0.0, 1.0, "Laplacian smoothing strength k"),
    "smoothing_iterations": ParamSpec(int, 4, 0, 50, "Laplacian smoothing passes"),
    "smooth_mode": ParamSpec(str, "displacement", description="'position' (the paper: smooth "
                             "the skin) or 'displacement' (smooth the solve's correction)",
                             choices=("position", "displacement")),
}


def skinning_stage(stages) -> str | None:
    """The stage of ``stages`` that skins (after the stages on the pose), or
    None."""
    return next((s for s in stages if s in STAGES and STAGES[s].skinning), None)


def default_params() -> dict:
    return {k: (list(s.default) if s.type is list else s.default)
            for k, s in PIPELINE_PARAMS.items()}


class Pipeline:
    """Stages built from names, run in order on every pose.

    Parameters
    ----------
    character : Character
    stages : sequence of str
        Stage names from :data:`STAGE_NAMES`: stages on the pose (``turn``)
        first, then one skinning stage (``lbs`` or ``dqs``), then the rest.
    **params
        Any of :data:`PIPELINE_PARAMS`.

    Examples
    --------
    >>> ch = load_character("arm")
    >>> pipe = Pipeline(ch, ["dqs", "pbd", "collision", "smooth"], iterations=5)
    >>> V = pipe.deform(ch.pose(elbow_rz=2.6))
    >>> pipe.timings          # ms per stage of the last frame
    """

    def __init__(self, character, stages=DEFAULT_STAGES, **params) -> None:
        stages = list(stages)
        bad = [s for s in stages if s not in STAGES]
        if bad:
            raise ValueError(f"unknown stage(s) {bad}; stages are {list(STAGE_NAMES)}")
        lead = 0
        while lead < len(stages) and STAGES[stages[lead]].poses:
            lead += 1
        if lead == len(stages) or not STAGES[stages[lead]].skinning:
            raise ValueError(f"the first stage must be 'lbs' or 'dqs' (after the stages on "
                             f"the pose, {stages[:lead]}), got {stages[lead:lead + 1]}")
        if any(STAGES[s].skinning or STAGES[s].poses for s in stages[lead + 1:]):
            raise ValueError(f"only the first stage may skin, and the stages on the pose come "
                             f"before it, got {stages}")
        self.character = character
        self.params = default_params()
        self.set_params(**params)
        self.stage_names = stages
        self.stages: list[Stage] = self._build_stages()
        skel = character.skeleton
        self._seg_joint, self._segA, self._segB = skel.bone_segments()
        self._parents = np.asarray(skel.parents, dtype=np.int64)
        n, k = len(character.V), len(character.rig.TV) if character.rig is not None else 0
        self._buf = [np.empty((n, 3)), np.empty((k, 3)), np.empty((n, 3)), np.empty((k, 3))]
        self.timings: dict = {}
        self.counts: dict = {}
        self._last_frame: Frame | None = None

    @classmethod
    def preset(cls, character, name: str, **params) -> "Pipeline":
        """A pipeline from :data:`PRESETS` (``lbs``, ``dqs``, ``pbs``, ``paper``, ``default``)."""
        if name not in PRESETS:
            raise ValueError(f"unknown preset '{name}'; presets are {list(PRESETS)}")
        stages, p = PRESETS[name]
        return cls(character, stages, **{**p, **params})

    def set_params(self, **params) -> None:
        """Validate and apply parameters; they take effect on the next frame."""
        checked = {}
        for k, v in params.items():
            if k not in PIPELINE_PARAMS:
                raise ValueError(f"unknown parameter '{k}'; parameters are {list(PIPELINE_PARAMS)}")
            checked[k] = PIPELINE_PARAMS[k].check(k, v)
        rebuild = any(k in checked and checked[k] != self.params.get(k)
                      for k in ("weight_scheme", "coarse_below"))
        self.params.update(checked)
        if rebuild and getattr(self, "stages", None):
            self.stages = self._build_stages()
        for s in getattr(self, "stages", []):
            s.reset()

    def _build_stages(self) -> list:
        """The stages on the character's body; none when it has no body (no
        closed skinned mesh: every part is a passenger)."""
        if self.character.rig is None:
            return []
        return [STAGES[s](self.character, self.params) for s in self.stage_names]

    def frame(self, q: np.ndarray) -> Frame:
        """Forward kinematics of pose ``q`` into a fresh :class:`Frame`."""
        skel = self.character.skeleton
        q = np.asarray(q, dtype=np.float64)
        if q.shape != (skel.n_channels,):
            raise ValueError(f"pose has shape {q.shape}, expected ({skel.n_channels},) "
                             f"channels {skel.channel_names[:4]}...")
        if not np.all(np.isfinite(q)):
            raise ValueError("pose contains NaN or Inf")
        J = skel.n_joints
        G, M, angles, fade = np.empty((J, 4, 4)), np.empty((J, 4, 4)), np.empty(J), np.empty(J)
        A, B = np.empty_like(self._segA), np.empty_like(self._segB)
        pose_frame(q, self._parents, skel.offsets, skel.rest_rotations, skel.bind_inv,
                   float(self.params["active_threshold"]), float(self.params["active_fade"]),
                   self._seg_joint, self._segA, self._segB, G, M, angles, fade, A, B)
        bent = fade > 0.0
        s, t, sb, tb = self._buf
        return Frame(q=q, G=G, M=M, bent=bent, fade=fade, angles=angles, surface=s, tet=t,
                     surface_base=sb, tet_base=tb, seg_A=A, seg_B=B)

    def deform(self, q: np.ndarray) -> np.ndarray:
        """Deform the surface into pose ``q``.

        The stages deform the body (``character.V``); the passengers
        (``character.passengers``: :mod:`skin_node.parts`) are then posed
        from the same frame and follow it.

        Returns
        -------
        (n + p, 3) float64
            The whole surface, in the order of ``character.surface_V`` (the
            body's vertices, then the passengers'; a new array).
        """
        t0 = time.perf_counter()
        # numba's thread count is per calling thread (the node deforms in a worker)
        numba.set_num_threads(min(int(self.params["threads"]), numba.config.NUMBA_NUM_THREADS))
        fr = self.frame(q)
        fr.tet_rows = self._tet_rows(fr)
        t = {"fk": (time.perf_counter() - t0) * 1e3}
        for name, stage in zip(self.stage_names, self.stages):
            a = time.perf_counter()
            stage(fr)
            # (a stage named twice gets the sum of its runs)
            t[name] = t.get(name, 0.0) + (time.perf_counter() - a) * 1e3
        riders = self.character.passengers
        if riders:
            a = time.perf_counter()
            n = len(fr.surface)
            out = np.empty((n + len(riders), 3))
            out[:n] = fr.surface
            riders.pose(fr.M, out[n:])
            t["passengers"] = (time.perf_counter() - a) * 1e3
        else:
            out = fr.surface.copy()
        t["total"] = (time.perf_counter() - t0) * 1e3
        self.timings = t
        self.counts = fr.counts
        self._last_frame = fr
        return out

    def warm_up(self, poses=()) -> float:
        """Deform the poses that run every kernel the stages use, so that numba
        compiling them (or loading them from its cache) and the stages' lazy
        set-up land here and not in a real frame; then forget the state carried
        between frames (:meth:`set_params`). Returns the seconds it took.

        Bent joints wake the solver and collision stages, and joints at their
        limits fold skin through skin (push-out, rechecks): the middle of the
        skeleton's limits (limits of +-pi, a glTF skeleton's, have it at rest),
        every channel bent by 1 rad within its limits and every channel at its
        upper limit, with the volume stage's checked swelling forced on (it
        runs only where a region stays short); then ``poses`` (a motion's own,
        say) and the rest pose, with the parameters as they are.

        Raises
        ------
        ValueError
            When a warm-up pose deforms to non-finite vertices.
        """
        limits = self.character.skeleton.limits
        root = np.zeros(3)
        bent = [np.concatenate([root, limits.mean(axis=-1).ravel()]),
                np.concatenate([root, np.clip(1.0, limits[..., 0], limits[..., 1]).ravel()]),
                np.concatenate([root, limits[..., 1].ravel()])]
        checked = self.params["volume_checked_below"]
        t0 = time.perf_counter()
        try:
            self.set_params(volume_checked_below=0.0)
            for q in bent:
                self._warm(q)
        finally:
            self.set_params(volume_checked_below=checked)
        for q in [*poses, self.character.skeleton.rest_pose()]:
            self._warm(q)
        self.set_params()
        return time.perf_counter() - t0

    def _warm(self, q: np.ndarray) -> None:
        if not np.all(np.isfinite(self.deform(q))):
            raise ValueError("warm-up pose deforms to non-finite vertices")

    def _tet_rows(self, fr: Frame) -> np.ndarray | None:
        """The tet-mesh vertices the stages after skinning use in ``fr``."""
        need = [s.tet_vertices(fr) for s in self.stages if not (s.skinning or s.poses)]
        if any(n is None for n in need):
            return None
        need = [n for n in need if len(n)] or [np.zeros(0, dtype=np.int64)]
        return need[0] if len(need) == 1 else np.unique(np.concatenate(need))

    @property
    def last_frame(self) -> Frame | None:
        """The :class:`Frame` of the last :meth:`deform` (None before the
        first), its tet mesh complete: the vertices no stage needed are
        skinned now, on first access (the buffers are reused by the next
        :meth:`deform`)."""
        fr = self._last_frame
        if fr is not None and fr.unskinned is not None:
            fr.unskinned()
            fr.unskinned = None
        return fr

