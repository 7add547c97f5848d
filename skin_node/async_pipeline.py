"""Every pose answered at the cost of DQS, the correction solved behind it.

A :class:`~skin_node.Pipeline` answers a pose when all its stages have run:
about ten times DQS's cost on the humanoid's walk, more at a squat's deep
contact, where a 120 Hz stream gives 8.3 ms a pose. :class:`AsyncPipeline`
answers every pose at once: DQS of that pose plus the correction its solver
last finished (the stages' skin minus DQS's, kept in each vertex's own
blended frame and turned by that vertex's rotation at the new pose), while a
thread solves the newest pose it was given. The pose is the input's, exact;
the correction is a few frames old (:attr:`AsyncPipeline.lag`).

Why this holds: the correction is a smooth, slow function of the pose
(bulges drawn in, creases where parts meet, volume given back), and kept in
each vertex's frame it travels with the limb. What a few frames change is
how deep a contact is: the last two corrections are extrapolated along the
pose's path (by how far the pose has gone since the last solved one, along
the change between the last two: at most that change again, back as far as
the older one when the motion turns; the change's trend, averaged over each
vertex's rings, not its vertex-to-vertex detail), and a correction whose pose lies far
from the one asked (a jump: a bag restarted) fades to plain DQS until the
solver catches up. Before the solver's first answer the skin is plain DQS.
How far two poses lie apart is how far each joint turned between them, not
how far its Euler channels moved: near a channel's gimbal lock (a knee bent
past 90 degrees in CMU's running mocap) the channels swing by 1.5 rad between
two frames while the joint turns by 5 degrees.

The solver is any object with a pipeline's ``deform``, ``params``,
``set_params``, ``timings``, ``counts`` and ``warm_up``: a
:class:`~skin_node.Pipeline` in a thread of this process (its kernels
release the GIL), or a :class:`~skin_node.remote.RemotePipeline` in a
process of its own.
"""
from __future__ import annotations

import os
import threading
import time

import numba
import numpy as np

from .kernels.skinning import dqs_carry, dqs_offsets, matrices_to_dual_quaternions
from .kernels.smoothing import ring_means
from .kernels.threads import allow_concurrent_calls, check_concurrent_calls
from .pipeline import DEFAULT_STAGES, Pipeline, skinning_stage

#: Niceness of the solver (its thread, or its process): the answers, the
#: executor and DDS come first. Through ROS on two cores (the squat at 120 Hz,
#: 30 s, two runs each) p99 receive-to-publish 8.1 and 7.4 ms, no pose
#: skipped, against 9.1 and 8.2 ms and 1-2 skipped at the same priority; the
#: correction no older.
SOLVER_NICE = 10

#: The largest turn of any joint (rad) between the pose asked and the one a
#: correction was solved for at which that correction still counts in full,
#: and the turn at which it is gone (plain DQS).
STALE = (0.5, 1.5)

#: Passes of one-ring means over the change between the last two corrections
#: before it is extrapolated: its trend (a contact deepening over
#: centimetres) goes on, what changes from vertex to vertex (a crease's fine
#: detail settling differently between two solves where the skin is crushed)
#: does not: extrapolated, that overshot and folded skin the solved skin did
#: not. Each solve taking a fixed number of poses (``skin_bench carried
#: --solve-poses``, the 24k squat, every 4th answer): 3 poses, sharp folds 2
#: -> 0 (solved 0), farthest from the solved skin 1.5 -> 1.2 mm at the median
#: frame; 8 poses, folds 3 -> 2, 2.2 -> 1.8 mm, exact pairs 812 -> 907 (DQS
#: 13,887): a contact deepening fast is tracked a little less closely.
TREND_PASSES = 4


class AsyncPipeline:
    """A pipeline that answers with DQS plus the newest solved correction.

    Parameters
    ----------
    character : Character
    stages : sequence of str
        The solver's stages (:class:`~skin_node.Pipeline`); the first must be
        ``dqs``, the skinning the correction rides on.
    solver_pipeline : object, optional
        What solves; by default a :class:`~skin_node.Pipeline` of ``stages``
        in this process (``solver`` is a pipeline parameter's name).
    **params
        Any of :data:`~skin_node.PIPELINE_PARAMS`.

    Examples
    --------
    >>> pipe = AsyncPipeline(load_character("humanoid"))
    >>> pipe.warm_up()
    >>> V = pipe.deform(q)        # DQS + the newest correction, now
    >>> pipe.lag                  # poses since the one it was solved for
    >>> pipe.wait()               # until the newest pose is solved
    >>> pipe.close()
    """

    def __init__(self, character, stages=DEFAULT_STAGES, solver_pipeline=None, **params) -> None:
        stages = list(stages)
        if skinning_stage(stages) != "dqs":
            raise ValueError(f"the correction rides on DQS: the skinning stage must be 'dqs', "
                             f"got {stages}")
        self.character = character
        # the pose, the passengers and the DQS the correction rides on
        self._front = Pipeline(character, ["dqs"], **params)
        self._local = solver_pipeline is None
        if self._local:
            allow_concurrent_calls()        # the answer's kernels run beside the solver's
        self.solver = solver_pipeline if solver_pipeline is not None else \
            Pipeline(character, stages, **params)
        self._niced = None
        self.stage_names = list(stages)
        self._n = len(character.V)
        self._weights = character.rig.weights(self.params["weight_scheme"]) \
            if character.rig is not None else None
        # the one-ring the change between two corrections is averaged over
        self._ring = (character.rig.adj_ptr, character.rig.adj) \
            if character.rig is not None else None
        self._trend_buf = np.empty((self._n, 3))
        # the joints (not the root: moving the whole body changes no correction)
        skel = character.skeleton
        self._joints = np.array([j for j in range(skel.n_joints) if skel.parents[j] >= 0],
                                dtype=np.int64)
        # the newest correction: (offsets (n, 3), its pose's joint rotations,
        # its number, and since the one before: the offsets' change, each
        # joint's turn as a rotation vector, flat, and its squared length (0
        # when there was none))
        self._last: tuple | None = None
        self._zero = np.zeros((self._n, 3))
        self.timings: dict = {}
        self.counts: dict = {}
        self._given = 0
        #: poses the solver never took (a newer one came before it was free)
        self.skipped = 0
        #: solves that raised or gave non-finite skin (answers go on with the last good one)
        self.failed = 0
        #: solves whose correction the answers took up
        self.solved = 0
        self.last_error: BaseException | None = None
        self._solver_timings: dict = {}
        self._solver_counts: dict = {}
        self._cond = threading.Condition()
        self._pending: tuple | None = None
        self._params_pending: dict = {}
        self._busy = False
        self._held = False
        self._closed = False
        self._generation = 0
        self._started = threading.Event()
        self._thread = threading.Thread(target=self._run, name="skin_solver", daemon=True)
        self._thread.start()
        self._started.wait()

    @property
    def params(self) -> dict:
        return self._front.params

    @property
    def pid(self) -> int | None:
        """The solver's process id when it runs in a process of its own."""
        return getattr(self.solver, "pid", None)

    @property
    def restarts(self) -> int:
        """Times the solver's process was started again (0 in a thread)."""
        return getattr(self.solver, "restarts", 0)

    @property
    def lag(self) -> int:
        """Poses given since the one the newest correction was solved for,
        as of the last :meth:`deform` (-1 before the first solve)."""
        last = self._last
        return -1 if last is None else self._given - 1 - last[2]

    # ------------------------------------------------------------ the answer
    def deform(self, q: np.ndarray, hand_over: bool = True) -> np.ndarray:
        """Pose ``q``'s surface now: DQS plus the newest solved correction,
        carried by each vertex's rotation; the pose goes to the solver (with
        ``hand_over=False`` once :meth:`hand_over` is called: an idle solver
        then starts after the answer is on its way, not beside it).

        Returns
        -------
        (n + p, 3) float64
            As :meth:`Pipeline.deform` (a new array).
        """
        t0 = time.perf_counter()
        front = self._front
        numba.set_num_threads(min(int(front.params["threads"]), numba.config.NUMBA_NUM_THREADS))
        fr = front.frame(q)
        riders = self.character.passengers
        out = np.empty((self._n + (len(riders) if riders else 0), 3))
        p = self._rotations(fr.q)
        last = self._last                   # the solver replaces it, never edits it
        C, D, a, b = self._zero, self._zero, 0.0, 0.0
        if last is not None:
            C, p_last, _, D, step, dd = last
            turn = turns(p_last, p)
            a = _fresh(turn)
            if dd > 1e-12 and a > 0.0:
                b = a * min(1.0, max(-1.0, float(turn.ravel() @ step) / dd))
        w = self._weights
        if w is not None:
            dqs_carry(self.character.V, w.Widx, w.Wval, matrices_to_dual_quaternions(fr.M), C, D,
                      a, b, out[:self._n])
        else:
            out[:self._n] = 0.0
        if riders:
            riders.pose(fr.M, out[self._n:])
        with self._cond:
            if self._pending is not None:
                self.skipped += 1
            self._pending = (fr.q.copy(), p, self._given)
            self._given += 1
            self._held = not hand_over
            self._cond.notify_all()
        total = (time.perf_counter() - t0) * 1e3
        self.timings = {"carry": total, **{f"solve_{k}": v for k, v in
                                           self._solver_timings.items()}, "total": total}
        self.counts = {**self._solver_counts, "correction_lag": self.lag,
                       "correction_share": a}
        return out

    def _rotations(self, q: np.ndarray) -> np.ndarray:
        """(k, 3, 3) the pose rotations of the joints (the root's left out)."""
        return self.character.skeleton.local_rotations(q)[self._joints]

    # ------------------------------------------------------------ the solver
    def _run(self) -> None:
        if self._local:
            _yield_cpu(threading.get_native_id())
        self._started.set()
        while True:
            with self._cond:
                while (self._pending is None or self._held) and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                pending, self._pending = self._pending, None
                params, self._params_pending = self._params_pending, {}
                self._busy = True
                generation = self._generation
            try:
                self._solve(*pending, params, generation)
            except Exception as e:  # noqa: BLE001 - the answers go on with the last one
                with self._cond:
                    self.failed += 1
                    self.last_error = e
            finally:
                with self._cond:
                    self._busy = False
                    self._cond.notify_all()

    def _solve(self, q: np.ndarray, p: np.ndarray, seq: int, params: dict,
               generation: int) -> None:
        s = self.solver
        pid = getattr(s, "pid", None)
        if pid and pid != self._niced:          # a process of its own (started again?)
            _yield_cpu(pid)
            self._niced = pid
        if params:
            s.set_params(**params)
        Y = s.deform(q)
        if not np.all(np.isfinite(Y[:self._n])):
            raise FloatingPointError("the solved skin has NaN or Inf")
        C = np.zeros((self._n, 3))
        w = self._weights
        if w is not None:
            # the pose posed again here (a remote solver has no frame to read)
            M = self._front.frame(q).M
            dqs_offsets(self.character.V, w.Widx, w.Wval, matrices_to_dual_quaternions(M),
                        Y[:self._n], C)
        # the change since the last solve, which the answers extrapolate: its
        # trend (only this thread replaces _last; set_params clears it and
        # moves the generation on, which the check below sees)
        last = self._last
        if last is not None:
            D, step = C - last[0], turns(last[1], p).ravel()
            if self._ring is not None:
                ring_means(D, *self._ring, TREND_PASSES, self._trend_buf)
        else:
            D, step = self._zero, np.zeros(3 * len(p))
        with self._cond:
            self._solver_timings = dict(s.timings)
            self._solver_counts = dict(s.counts)
            if generation == self._generation:      # not solved with parameters since changed
                self._last = (C, p, seq, D, step, float(step @ step))
                self.solved += 1

    def hand_over(self) -> None:
        """Let the solver take the pose the last ``deform(q, hand_over=False)``
        answered."""
        with self._cond:
            self._held = False
            self._cond.notify_all()

    def wait(self, timeout: float | None = None) -> bool:
        """Until the solver has solved the newest pose given (or ``timeout``
        seconds passed: then False); a pose held back is handed over."""
        self.hand_over()
        with self._cond:
            return self._cond.wait_for(
                lambda: self._closed or (self._pending is None and not self._busy), timeout)

    # ------------------------------------------------------------ the rest
    def set_params(self, **params) -> None:
        """Validate and apply: this frame's answer at once, the solver before
        its next solve. A change forgets the corrections solved before it."""
        self._front.set_params(**params)
        with self._cond:
            self._params_pending.update(params)
            self._last = None
            self._generation += 1
        if "weight_scheme" in params and self.character.rig is not None:
            self._weights = self.character.rig.weights(self.params["weight_scheme"])

    def set_stages(self, stages, **params) -> float:
        """A solver with ``stages`` and ``params`` in place of this one (once
        its solve under way is done), warmed up; returns the warm-up's seconds."""
        stages = list(stages)
        if skinning_stage(stages) != "dqs":
            raise ValueError(f"the correction rides on DQS: the skinning stage must be 'dqs', "
                             f"got {stages}")
        self.wait()
        with self._cond:
            self._pending = None
            self._params_pending = {}
        t0 = time.perf_counter()
        if hasattr(self.solver, "set_stages"):
            self.solver.set_stages(stages, **params)
        else:
            self.solver = Pipeline(self.character, stages, **params)
            self.solver.warm_up()
        self.stage_names = stages
        self.set_params(**params)
        return time.perf_counter() - t0

    def warm_up(self, poses=()) -> float:
        """The solver's warm-up (:meth:`Pipeline.warm_up`) and this one's
        kernels; then the corrections start from none again."""
        t0 = time.perf_counter()
        self.wait()
        self.solver.warm_up(*((poses,) if len(poses) else ()))
        w = self._weights
        if w is not None:
            Q = matrices_to_dual_quaternions(self._front.frame(
                self.character.skeleton.rest_pose()).M)
            out = np.empty((self._n, 3))
            dqs_carry(self.character.V, w.Widx, w.Wval, Q, self._zero, self._zero, 0.0, 0.0,
                      out)
            dqs_offsets(self.character.V, w.Widx, w.Wval, Q, out, np.empty((self._n, 3)))
        if self._local:
            check_concurrent_calls("a solver in a thread beside the answers")
        with self._cond:
            self._last = None
            self._given = self.skipped = self.solved = 0
        return time.perf_counter() - t0

    def close(self, timeout: float = 5.0) -> None:
        """Stop the solver thread (a solve under way finishes first) and close
        the solver when it can be (a process of its own)."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout)
        if hasattr(self.solver, "close"):
            self.solver.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def turns(A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """(k, 3) rotation vectors of the turns ``A_j^T B_j`` that take each
    rotation of ``A`` (k, 3, 3) to ``B``'s: axis times angle, the angle in
    [0, pi] and free of any Euler angles' gimbal lock."""
    R = np.einsum("jba,jbc->jac", A, B)
    v = 0.5 * np.stack([R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0],
                        R[:, 1, 0] - R[:, 0, 1]], axis=1)       # axis times sin(angle)
    s = np.sqrt((v * v).sum(axis=1))
    angle = np.arctan2(s, 0.5 * (np.trace(R, axis1=1, axis2=2) - 1.0))
    return v * np.where(s > 1e-12, angle / np.maximum(s, 1e-300), 1.0)[:, None]


def _fresh(turn: np.ndarray) -> float:
    """How much a correction counts whose pose's joints are each turned by
    ``turn`` (rotation vectors, :func:`turns`) from the pose asked
    (:data:`STALE`)."""
    if not len(turn):
        return 1.0
    d = float(np.sqrt((turn * turn).sum(axis=1)).max())
    x = min(1.0, max(0.0, (STALE[1] - d) / (STALE[1] - STALE[0])))
    return x * x * (3.0 - 2.0 * x)


def _yield_cpu(tid: int) -> None:
    """Lower thread or process ``tid`` to :data:`SOLVER_NICE` (best effort: a
    system that refuses leaves it as it was, and only the tail suffers)."""
    try:
        os.setpriority(os.PRIO_PROCESS, tid, max(os.getpriority(os.PRIO_PROCESS, tid),
                                                 SOLVER_NICE))
    except (AttributeError, OSError):        # pragma: no cover - not Linux, or refused
        pass
