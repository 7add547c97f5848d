"""skin_node: joint states in, deformed skin out.

A thin listener in the manner of robot_state_publisher: the JointState callback
validates the message and maps it onto the character's channel vector
(``msg_adapters``), the core deforms the surface (``skin_node.Pipeline``), and
the result is published. No geometry lives here.

Topics (relative, so they can be remapped)
------------------------------------------
``joint_states`` (sub, sensor_msgs/JointState)
    RELIABLE, VOLATILE like robot_state_publisher, so the usual joint state
    publishers match; KEEP_LAST 100 so that a burst waits in DDS for the
    (cheap: validate + map) callback instead of being dropped unseen. The
    callback, not the queue, decides what is skipped, and counts it.
``skin/points`` (pub, sensor_msgs/PointCloud2)
    One per processed frame, stamp copied from the input, ``frame_id`` param.
``skin/mesh`` (pub, shape_msgs/Mesh)
    The rest surface, published once: RELIABLE + TRANSIENT_LOCAL so a late
    subscriber gets the topology (vertex order matches ``skin/points``). Both
    cover every part of the character: the simulated body's vertices, then
    each passenger's in the file's node order (:mod:`skin_node.parts`).
``skin/marker`` (pub, visualization_msgs/Marker TRIANGLE_LIST)
    Only built while someone subscribes.
``skin/diagnostics`` (pub, diagnostic_msgs/DiagnosticArray, 1 Hz)
    ms per stage, frames processed / skipped as stale / rejected by reason,
    frames published by each worker, unknown joint names, jumps back in time,
    and ``parts``: ``name:vertices:kind:gets`` of every part.

Time
----
Stamps must not go back, with one exception: a stamp older than the last
accepted one by more than ``time_jump_tolerance`` seconds is a restart of the
source (a bag replayed or looped, a mocap source restarted, a simulator
resetting its clock), as robot_state_publisher takes it. The node's time
restarts there, the pose is skinned, and the jump is counted
(``time_jumps_back``) and logged. A smaller step back is a reordering, and
rejected as ``stamp_backwards``.

Newest frame first
------------------
The callback stores the newest mapped pose in a one-slot mailbox; a worker
thread deforms whatever is in the slot. A pose that is overwritten before
the worker took it is counted as *skipped as stale*: the node never queues
behind the input, and latency stays one frame. Because mapping happens in
the callback, a skipped frame still updates the channels it carries.

With ``workers`` > 1, that many threads each keep their own pipeline and
take the newest pose whenever they are free, so frames overlap: a pose is
stale only when every worker is busy. Results are published in the order
their poses arrived. The deform kernels release the GIL, so two workers on
two cores answer about 1.4 times as many poses as one (the 24k humanoid at
120 Hz), at some more latency.

With ``isolation:=process`` each worker's pipeline lives in a child process
(:class:`skin_node.remote.RemotePipeline`, fed through shared memory): the
same skin, bitwise, and a worker that crashes fails one frame and is started
again. It buys no measurable speed on two cores (the deform is bound by its
own work, not by the GIL it shares with the executor) and costs a second copy
of the character in memory, so ``thread`` is the default.

With ``correction:=carried`` (config/humanoid.yaml) the one worker answers
each pose at once, at about DQS's cost, with DQS plus the newest correction
a solver behind it has finished (:class:`skin_node.async_pipeline.AsyncPipeline`;
in a thread, or with ``isolation:=process`` in a child process): the pose is
exact, the correction a few poses old (diagnostics ``correction_lag_mean``
and ``_max``). At 120 Hz through ROS it answers nearly every pose where
``inline`` (each pose solved before it is published, the default, exact and
what bag processing wants) answers about two thirds.

Parameter changes pass the set-parameters callback's checks and take effect
at the start of the next frame each worker takes; ``character``,
``surface_vertices``, ``name_map``, ``weights``, ``workers``, ``isolation``,
``correction`` and ``joint_names`` are read-only.
"""
from __future__ import annotations

import sys
import threading
import time
from collections import Counter
from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState, PointCloud2
from shape_msgs.msg import Mesh
from std_msgs.msg import Header
from visualization_msgs.msg import Marker

import skin_node
from msg_adapters import (TIME_JUMP_TOLERANCE_S, ChannelMapper, JointStateError, Reason,
                          StampOrder, diagnostic_array, joint_state_to_arrays, load_name_map,
                          mesh_to_msg, triangle_list_marker_cdr, vertices_to_point_cloud2)
from skin_node.async_pipeline import AsyncPipeline
from skin_node.kernels.threads import allow_concurrent_calls, check_concurrent_calls
from skin_node.processes import build, init_ros, spin_until_shutdown
from skin_node.remote import RemoteError, RemotePipeline

NODE_NAME = "skin_node"
THROTTLE_S = 2.0

QOS_JOINT_STATES = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                              reliability=ReliabilityPolicy.RELIABLE,
                              durability=DurabilityPolicy.VOLATILE)
QOS_STREAM = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=5,
                        reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)
QOS_LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)

_PARAM_TYPES = {int: ParameterType.PARAMETER_INTEGER, float: ParameterType.PARAMETER_DOUBLE,
                bool: ParameterType.PARAMETER_BOOL, str: ParameterType.PARAMETER_STRING,
                list: ParameterType.PARAMETER_STRING_ARRAY}


def _spec_descriptor(name: str, spec: skin_node.ParamSpec) -> ParameterDescriptor:
    """A ParameterDescriptor (type, range, description) from a core ParamSpec."""
    text = spec.description + (f" (one of {list(spec.choices)})" if spec.choices else "")
    d = ParameterDescriptor(name=name, type=_PARAM_TYPES[spec.type], description=text)
    lo, hi = spec.min, spec.max
    if spec.type is int and (lo is not None or hi is not None):
        d.integer_range = [IntegerRange(from_value=int(lo if lo is not None else -2**63),
                                        to_value=int(hi if hi is not None else 2**63 - 1),
                                        step=0)]
    elif spec.type is float and (lo is not None or hi is not None):
        d.floating_point_range = [FloatingPointRange(
            from_value=float(lo if lo is not None else -np.inf),
            to_value=float(hi if hi is not None else np.inf), step=0.0)]
    return d


def _stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


@dataclass(frozen=True)
class LiveConfig:
    """What the node deforms and publishes with, as the set-parameters
    callback accepted it: the stages, the pipeline parameters (checked, a
    read-only mapping) and the frame of the outputs. Never changed: a change
    replaces it whole, under the node's lock, and each worker brings its
    pipeline up to the one it reads before its next frame."""

    stages: tuple
    params: Mapping
    frame_id: str


class SkinNode(Node):
    """Subscribes ``joint_states``, publishes the deformed skin.

    All set-up (character, rig, pipeline, a warm-up deform that compiles the
    numba kernels) happens here, before the first callback can run.
    """

    def __init__(self, **kwargs) -> None:
        super().__init__(NODE_NAME, **kwargs)
        t_start = time.perf_counter()
        self._declare_parameters()
        p = lambda name: self.get_parameter(name).value  # noqa: E731

        workers = p("workers")
        if workers > 1 and p("warm_start"):
            # before the set-up: a conflict of parameters needs no character,
            # and its one-line error must not wait behind set-up progress
            raise ValueError(f"warm_start needs workers:=1 (each of {workers} workers "
                             "would carry the history of only the frames it took)")
        if p("isolation") not in ("process", "thread"):
            raise ValueError(f"isolation must be 'process' or 'thread', got {p('isolation')!r}")
        carried = self._carried = p("correction") == "carried"
        if p("correction") not in ("carried", "inline"):
            raise ValueError(f"correction must be 'carried' or 'inline', got "
                             f"{p('correction')!r}")
        if carried and workers > 1:
            raise ValueError(f"correction:=carried answers each pose in about DQS's time on "
                             f"one worker: workers:=1, not {workers}")
        n, spec, weights = p("surface_vertices"), p("character"), p("weights")
        try:
            self.character = skin_node.load_character(
                spec, weights=weights, **({"surface_vertices": n} if n > 0 else {}))
        except ValueError:
            raise
        except Exception as e:  # noqa: BLE001 - whatever a reader raises, name the file
            raise ValueError(f"{spec}: {type(e).__name__}: {e}") from None
        self.declare_parameter(
            "joint_names", self.character.channel_names,
            ParameterDescriptor(type=ParameterType.PARAMETER_STRING_ARRAY, read_only=True,
                                description="channels accepted on joint_states, in pose "
                                            "order (root_t* metres, *_r* radians)"),
            ignore_override=True)
        name_map = load_name_map(p("name_map")) if p("name_map") else None
        self._mapper = ChannelMapper(self.character.channel_names, name_map)
        kwargs = {k: p(k) for k in skin_node.PIPELINE_PARAMS}
        stages = list(p("pipeline"))
        self._isolated = p("isolation") == "process"
        if self._isolated:
            # checked here first: a bad stage list or value is one line, at once
            skin_node.Pipeline(self.character, stages=stages, **kwargs)
            load = {"spec": spec, "weights": weights, **({"surface_vertices": n} if n > 0 else {})}
            self._pipes = []
            try:
                # each set up and warmed up in its own process, all at once
                self._pipes = [RemotePipeline(self.character, load, stages, wait=False, **kwargs)
                               for _ in range(workers)]
                warm_s = max(pipe.wait_ready() for pipe in self._pipes)
                if carried:
                    self._pipes = [AsyncPipeline(self.character, stages,
                                                 solver_pipeline=self._pipes[0], **kwargs)]
                    warm_s += self._pipes[0].warm_up()
            except (ValueError, RemoteError) as e:
                for pipe in self._pipes:
                    pipe.close()
                raise ValueError(f"{p('character')}: {e}") from None
        else:
            if workers > 1:
                allow_concurrent_calls()            # the workers deform at the same time
            self._pipes = [AsyncPipeline(self.character, stages, **kwargs) if carried else
                           skin_node.Pipeline(self.character, stages=stages, **kwargs)
                           for _ in range(workers)]
            # Every worker's pipeline warms up (after the first, the kernels are
            # compiled and this builds their lazy caches), so the first real frame
            # runs at full speed.
            try:
                warm_s = sum(pipe.warm_up() for pipe in self._pipes)
            except ValueError as e:
                raise ValueError(f"{p('character')}: {e}") from None
            if workers > 1:
                check_concurrent_calls(f"workers:={workers}")

        # Counters (written by the callback or the workers, read by the 1 Hz timer).
        self._rejected: Counter = Counter()
        self._received = self._processed = self._stale = self._failed = 0
        self._worker_frames = [0] * workers
        self._stamps = StampOrder(p("time_jump_tolerance"))
        self._period = {"frames": 0, "deform_ms": 0.0, "latency_ms": 0.0, "lag": 0, "lag_max": 0}
        self._timings: dict = dict(self._pipes[0].timings)
        # One-slot mailbox between the callback and the workers; every pose taken
        # gets a number, and results are published in that order.
        self._cond = threading.Condition()
        self._pending: tuple | None = None
        self._taken = self._published = 0
        # What the set-parameters callback accepted (the pipelines were built
        # with the first), the pipeline it built to check a new stage list (for
        # the first worker that needs one) and the configuration last logged.
        self._live = self._built_with = LiveConfig(
            tuple(stages), MappingProxyType(dict(self._pipes[0].params)), p("frame_id"))
        self._spare: skin_node.Pipeline | None = None
        self._announced = self._live
        self._stopping = False

        self._points_pub = self.create_publisher(PointCloud2, "skin/points", QOS_STREAM)
        self._marker_pub = self.create_publisher(Marker, "skin/marker", QOS_STREAM)
        self._mesh_pub = self.create_publisher(Mesh, "skin/mesh", QOS_LATCHED)
        self._diag_pub = self.create_publisher(DiagnosticArray, "skin/diagnostics", 10)
        self._mesh_pub.publish(mesh_to_msg(self.character.surface_V, self.character.surface_F))
        self.add_on_set_parameters_callback(self._on_set_parameters)
        # stop() joins the workers. Daemon only for a set-up cut short by a signal
        # after this point: no pose ever reaches them then, they wait on the
        # condition (no rclpy frame on their stack), and must not hold the exit.
        self._workers = [threading.Thread(target=self._work, args=(w,), name=f"skin_worker{w}",
                                          daemon=True) for w in range(workers)]
        for t in self._workers:
            t.start()
        self._joint_sub = self.create_subscription(JointState, "joint_states",
                                                   self._on_joint_state, QOS_JOINT_STATES)
        self.create_timer(1.0, self._on_diagnostics_timer)
        # A message type's first conversion costs a few ms (a cloud's 1.5 ms
        # more than the next): spent here, not on the first pose.
        serialize_message(vertices_to_point_cloud2(self.character.surface_V, Header()))
        deserialize_message(serialize_message(JointState(name=["a"], position=[0.0])),
                            JointState)
        ch = self.character
        for line in ch.part_lines():
            self.get_logger().info(line)
        gets = Counter()
        for part in ch.parts:
            gets[part.gets] += part.vertices
        self.get_logger().info(
            f"ready in {time.perf_counter() - t_start:.2f} s (warm-up deform {warm_s:.2f} s): "
            f"character '{ch.name}' {len(ch.surface_V)} vertices {len(ch.surface_F)} "
            f"triangles {ch.n_channels} channels, {len(ch.parts)} "
            f"part{'s' if len(ch.parts) > 1 else ''} (vertices "
            + ", ".join(f"{n} {g}" for g, n in gets.items()) + "), "
            + (f"stages {stages}" if ch.rig is not None else
               f"stages {stages} idle (no skinned part to solve)")
            + f", {workers} worker{'s' if workers > 1 else ''}"
            + (", correction carried (solved behind the answers)" if carried else "")
            + (f" (deform process{'es' if workers > 1 else ''} "
               + ", ".join(str(pipe.pid) for pipe in self._pipes) + ")"
               if self._isolated else ""))

    # ------------------------------------------------------------ parameters
    def _declare_parameters(self) -> None:
        S, SA, I = (ParameterType.PARAMETER_STRING, ParameterType.PARAMETER_STRING_ARRAY,
                    ParameterType.PARAMETER_INTEGER)
        self.declare_parameter("character", "arm", ParameterDescriptor(
            type=S, read_only=True,
            description="built-in character name (arm | humanoid) or a character file path"))
        self.declare_parameter("surface_vertices", 0, ParameterDescriptor(
            type=I, read_only=True, integer_range=[IntegerRange(from_value=0,
                                                                to_value=2_000_000, step=0)],
            description="target surface vertex count of a built-in character; "
                        "0 = the character's default"))
        self.declare_parameter("weights", "automatic", ParameterDescriptor(
            type=S, read_only=True,
            description="skin weights: 'automatic' (computed from the mesh and skeleton) "
                        "or 'file' (the artist's, from a skinned glTF character)"))
        self.declare_parameter("pipeline", list(skin_node.DEFAULT_STAGES), ParameterDescriptor(
            type=SA, description=f"stages in order, from {list(skin_node.STAGE_NAMES)}"))
        self.declare_parameter("workers", 1, ParameterDescriptor(
            type=I, read_only=True, integer_range=[IntegerRange(from_value=1, to_value=16,
                                                                step=0)],
            description="frames deformed at once, each worker with its own pipeline; "
                        "results are published in input order (2 on two cores answer "
                        "about 1.4 times the poses of 1; warm_start needs 1)"))
        self.declare_parameter("isolation", "thread", ParameterDescriptor(
            type=S, read_only=True,
            description="where each worker deforms: 'process' (a child process fed through "
                        "shared memory, so rclpy and the deform never wait on one GIL) or "
                        "'thread' (in this process)"))
        self.declare_parameter("correction", "inline", ParameterDescriptor(
            type=S, read_only=True,
            description="'inline' (each pose's skin solved before it is published) or "
                        "'carried' (each pose answered at once, about DQS's cost: DQS plus "
                        "the newest correction a solver behind it finished, a few frames "
                        "old, carried by each vertex's rotation; needs workers:=1)"))
        self.declare_parameter("frame_id", "world", ParameterDescriptor(
            type=S, description="frame of skin/points and skin/marker"))
        self.declare_parameter("name_map", "", ParameterDescriptor(
            type=S, read_only=True,
            description="YAML file mapping incoming joint names to channel names; "
                        "'' = names are channel names"))
        self.declare_parameter("time_jump_tolerance", TIME_JUMP_TOLERANCE_S, ParameterDescriptor(
            type=ParameterType.PARAMETER_DOUBLE,
            floating_point_range=[FloatingPointRange(from_value=0.0, to_value=3600.0, step=0.0)],
            description="seconds: a stamp older than the last accepted one by more restarts "
                        "time (bag replayed, source restarted: counted in time_jumps_back); "
                        "by this or less, it is rejected as stamp_backwards"))
        for name, spec in skin_node.PIPELINE_PARAMS.items():
            default = list(spec.default) if spec.type is list else spec.default
            self.declare_parameter(name, default, _spec_descriptor(name, spec))

    def _on_set_parameters(self, params: list) -> SetParametersResult:
        """Check a change; a valid one is applied by the workers before their next frame.

        Types, ranges and read-only flags are enforced by the descriptors; the
        core checks the rest (choices, stage order) by validating the values or,
        for ``pipeline``, by building the new pipeline here.
        """
        updates = {p.name: p.value for p in params}
        live = self._live
        try:
            if updates.get("frame_id", "x") == "":
                raise ValueError("frame_id must not be empty")
            core = {k: skin_node.PIPELINE_PARAMS[k].check(k, v) for k, v in updates.items()
                    if k in skin_node.PIPELINE_PARAMS}
            kwargs = {**live.params, **core}
            stages = tuple(updates.get("pipeline", live.stages))
            spare = (skin_node.Pipeline(self.character, stages=list(stages), **kwargs)
                     if "pipeline" in updates else None)
        except ValueError as e:
            return SetParametersResult(successful=False, reason=str(e))
        if self._carried and skin_node.pipeline.skinning_stage(stages) != "dqs":
            return SetParametersResult(successful=False, reason=(
                f"correction:=carried rides on DQS: the skinning stage must be 'dqs', "
                f"got {list(stages)}"))
        if core.get("warm_start") and len(self._pipes) > 1:
            return SetParametersResult(successful=False, reason=(
                f"warm_start needs workers:=1, not {len(self._pipes)}"))
        if "time_jump_tolerance" in updates:
            self._stamps.tolerance_s = updates["time_jump_tolerance"]
        accepted = LiveConfig(stages, MappingProxyType(kwargs),
                              updates.get("frame_id", live.frame_id))
        with self._cond:
            self._live = accepted
            if spare is not None and not self._isolated and not self._carried:
                self._spare = spare
        return SetParametersResult(successful=True)

    def _configure(self, pipe: skin_node.Pipeline, config: LiveConfig):
        """Worker side: bring ``pipe`` (set up for ``config``) up to the live
        configuration. Returns (the pipeline, the configuration it now has)."""
        with self._cond:
            live = self._live
            if live is config:
                return pipe, config
            spare = None
            if tuple(pipe.stage_names) != live.stages and self._spare is not None \
                    and tuple(self._spare.stage_names) == live.stages:
                spare, self._spare = self._spare, None    # the first worker takes the checked one
            announce = self._announced is not live
            self._announced = live
        if tuple(pipe.stage_names) != live.stages and hasattr(pipe, "set_stages"):
            # built and warmed up there (a deform process; a carried correction's solver)
            pipe.set_stages(live.stages, **live.params)
        elif tuple(pipe.stage_names) != live.stages:
            pipe = spare or skin_node.Pipeline(self.character, stages=list(live.stages),
                                               **live.params)
            # as at start-up: new stages compile their kernels (from numba's cache
            # when it has them) here, not in the middle of real frames, where one
            # worker compiling would hold back every frame published after its own
            pipe.warm_up()
        changed = {k: v for k, v in live.params.items() if pipe.params[k] != v}
        if changed:
            pipe.set_params(**changed)
        if announce:
            self.get_logger().info(f"parameters applied: stages {pipe.stage_names}, "
                                   f"{sorted(changed)}")
        return pipe, live

    # ------------------------------------------------------------ callbacks
    def _on_joint_state(self, msg: JointState) -> None:
        """Validate and map; hand the pose to the worker (newest wins)."""
        self._received += 1
        try:
            stamp_ns = _stamp_ns(msg.header.stamp)
            restart = self._stamps.check(stamp_ns)
            names, positions = joint_state_to_arrays(msg)
            q = self._mapper.apply(names, positions).copy()
        except JointStateError as e:
            self._rejected[e.reason.value] += 1
            self.get_logger().warning(f"joint_states rejected ({sum(self._rejected.values())} "
                                      f"so far): {e}", throttle_duration_sec=THROTTLE_S)
            return
        if restart:
            self.get_logger().info(
                f"time jumped back {(self._stamps.last_ns - stamp_ns) * 1e-9:.3f} s "
                f"(stamp {stamp_ns} ns): a restart of the source, time restarts here "
                f"({self._stamps.jumps_back + 1} so far)", throttle_duration_sec=THROTTLE_S)
        self._stamps.accept(stamp_ns, restart)
        with self._cond:
            if self._pending is not None:
                self._stale += 1
            self._pending = (msg.header.stamp, q, time.perf_counter())
            self._cond.notify_all()

    def _work(self, w: int) -> None:
        """Worker ``w``: deform the newest pending pose, publish it in its turn."""
        pipe, config = self._pipes[w], self._built_with
        while True:
            with self._cond:
                while self._pending is None and not self._stopping:
                    self._cond.wait()
                if self._stopping:
                    return
                (stamp, q, t_received), self._pending = self._pending, None
                seq, self._taken = self._taken, self._taken + 1
            V = None
            try:
                pipe, config = self._configure(pipe, config)
                self._pipes[w] = pipe
                restarts = getattr(pipe, "restarts", 0)
                t0 = time.perf_counter()
                # carried: the solver takes the pose once its answer is
                # published (an idle solver woken beside the answer contends
                # with it for the interpreter)
                V = pipe.deform(q, hand_over=False) if self._carried else pipe.deform(q)
                deform_ms = 1e3 * (time.perf_counter() - t0)
                if getattr(pipe, "restarts", 0) != restarts:
                    self.get_logger().warning(
                        f"worker {w}: deform process started again (pid {pipe.pid}, "
                        f"{pipe.restarts} restart{'s' if pipe.restarts > 1 else ''}); that "
                        f"frame took {deform_ms:.0f} ms")
                if not np.all(np.isfinite(V)):
                    V = None
                    self._count_failure()
                    self.get_logger().warning("deformed surface has NaN/Inf; frame dropped",
                                              throttle_duration_sec=THROTTLE_S)
            except Exception as e:  # noqa: BLE001 - a bad frame must not stop the node
                V = None
                if not self._stopping:
                    self._count_failure()
                    self.get_logger().error(f"frame failed: {type(e).__name__}: {e}",
                                            throttle_duration_sec=THROTTLE_S)
            with self._cond:            # wait for the poses taken before this one
                while self._published != seq and not self._stopping:
                    self._cond.wait()
                if self._stopping:
                    return
            try:
                if V is not None:
                    self._publish(w, V, stamp, config.frame_id, pipe, deform_ms, t_received)
            except Exception as e:  # noqa: BLE001
                if not self._stopping:
                    self._count_failure()
                    self.get_logger().error(f"publish failed: {type(e).__name__}: {e}",
                                            throttle_duration_sec=THROTTLE_S)
            finally:
                if self._carried:
                    pipe.hand_over()
                with self._cond:
                    self._published = seq + 1
                    self._cond.notify_all()

    def _count_failure(self) -> None:
        """One more failed frame; under the lock, as several workers may fail at once."""
        with self._cond:
            self._failed += 1

    def _publish(self, w: int, V: np.ndarray, stamp, frame_id: str, pipe, deform_ms: float,
                 t_received: float) -> None:
        header = Header(stamp=stamp, frame_id=frame_id)
        self._points_pub.publish(vertices_to_point_cloud2(V, header))
        if self._marker_pub.get_subscription_count() > 0:
            self._marker_pub.publish(triangle_list_marker_cdr(V, self.character.surface_F,
                                                              header))
        self._timings = dict(pipe.timings)
        with self._cond:                # counted together: diagnostics read them together
            self._processed += 1
            self._worker_frames[w] += 1
            self._period["frames"] += 1
            self._period["deform_ms"] += deform_ms
            self._period["latency_ms"] += 1e3 * (time.perf_counter() - t_received)
            if self._carried:
                lag = pipe.counts.get("correction_lag", -1)
                self._period["lag"] += lag
                self._period["lag_max"] = max(self._period["lag_max"], lag)

    def _on_diagnostics_timer(self) -> None:
        with self._cond:                # one consistent snapshot of the workers' counts
            period, self._period = self._period, {"frames": 0, "deform_ms": 0.0,
                                                  "latency_ms": 0.0, "lag": 0, "lag_max": 0}
            processed, per_worker = self._processed, list(self._worker_frames)
        n = max(period["frames"], 1)
        unknown = self._mapper.unknown_counts
        rejected = {f"rejected_{r.value}": self._rejected[r.value] for r in Reason}
        values = {
            "frames_received": self._received,
            "frames_processed": processed,
            "frames_skipped_stale": self._stale,
            "frames_failed": self._failed,
            "frames_per_worker": ",".join(map(str, per_worker)),
            "rejected_total": sum(self._rejected.values()),
            **rejected,
            "unknown_names": ",".join(sorted(unknown)),
            "unknown_name_count": len(unknown),
            "time_jumps_back": self._stamps.jumps_back,
            "worker_restarts": sum(getattr(pipe, "restarts", 0) for pipe in self._pipes),
            # the joint_states publishers this node's subscription has matched
            # (discovery runs both ways: a publisher may see the node first)
            "joint_state_publishers": self._joint_sub.get_publisher_count(),
            "parts": ",".join(part.summary() for part in self.character.parts),
            "fps": float(period["frames"]),
            "ms_per_frame": period["deform_ms"] / n,
            "ms_receive_to_publish": period["latency_ms"] / n,
            **{f"ms_{k}": float(v) for k, v in self._timings.items()},
        }
        if self._carried:
            # how many poses old the corrections published this second were
            # (-1: none solved yet, plain DQS), and the solves that failed
            pipe = self._pipes[0]
            values.update(correction_lag_mean=period["lag"] / n,
                          correction_lag_max=period["lag_max"],
                          correction_solves=pipe.solved,
                          correction_solves_skipped=pipe.skipped,
                          correction_solves_failed=pipe.failed)
        level = "error" if self._failed else "warn" if values["rejected_total"] or unknown else "ok"
        message = (f"{processed} processed, {self._stale} skipped as stale, "
                   f"{values['rejected_total']} rejected")
        self._diag_pub.publish(diagnostic_array(
            Header(stamp=self.get_clock().now().to_msg()), f"{NODE_NAME}: pipeline",
            self.character.name, level, message, values))
        if period["frames"]:
            stages = " ".join(f"{k} {v:.2f}" for k, v in self._timings.items() if k != "total")
            age = (f" | correction {values['correction_lag_mean']:.1f} poses old "
                   f"(at most {values['correction_lag_max']})" if self._carried else "")
            self.get_logger().info(
                f"{period['frames']} frames/s | {values['ms_per_frame']:.2f} ms per frame "
                f"(last frame: {stages}) | receive->publish "
                f"{values['ms_receive_to_publish']:.2f} ms{age} | {message}")

    def stop(self) -> None:
        """Stop the workers and join them (each finishes the frame it is on).

        A worker must not outlive the node (it would publish through destroyed
        publishers) nor the interpreter (see :class:`skin_node.processes.SpinThread`); a frame is
        short, so the join is not cut short.
        """
        with self._cond:
            self._stopping = True
            self._cond.notify_all()
        for t in self._workers:
            t.join()
        for pipe in self._pipes:
            if hasattr(pipe, "close"):
                pipe.close()


def main(args: list | None = None) -> int:
    """Console script ``skin_node``: exit 0 on SIGINT/SIGTERM, 2 on a set-up error."""
    init_ros(args)
    node, code = build(NODE_NAME, SkinNode)
    if node is None:
        return code
    try:
        spin_until_shutdown(node)
    finally:
        node.stop()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
