"""Benchmarks of skin_node's pipelines: speed, accuracy, stability, memory, ROS latency.

The measuring functions live in :mod:`skin_node.bench.measure` (speed and
accuracy over clips and pose sweeps) and :mod:`skin_node.bench.stability`
(failure cases); :mod:`skin_node.bench.charts` draws the PNG charts,
:mod:`skin_node.bench.ros_latency` measures the node end to end, and
:mod:`skin_node.bench.cli` is the ``skin_bench`` console script::

    skin_bench run --pipelines lbs,dqs,default --scenes arm:2000 --clips elbow_bend
    skin_bench report            # regenerates bench_results/
"""
from .measure import (Method, Motion, Scene, SceneMetrics, load_scene, make_motion,
                      parse_method, parse_scene, run_method)

__all__ = ["Method", "Motion", "Scene", "SceneMetrics", "load_scene", "make_motion",
           "parse_method", "parse_scene", "run_method"]
