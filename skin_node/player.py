"""mocap_player: publish a motion clip as sensor_msgs/JointState on ``joint_states``.

The clip is a built-in one (``--clip``, default per character), one of a glTF
character's own animations (``--clip NAME``; a glTF character plays its first
by default; ``--list-clips`` names what a character can play) sampled at
``--fps``, or a BVH file (``--bvh``) retargeted onto the character's skeleton,
played at its own frame rate times ``--rate``. Every option is also a ROS
parameter of the same name (``--ros-args -p clip:=walk``)::

    mocap_player --character humanoid --clip walk --loop
    mocap_player --character CesiumMan.glb --list-clips
    mocap_player --character CesiumMan.glb --clip animation0 --fps 60 --loop
    mocap_player --character humanoid --bvh walk.bvh --mapping config/cmu_to_humanoid.yaml
"""
from __future__ import annotations

import argparse
import sys

import numpy as np
import rclpy
from rclpy.node import Node
from rclpy.task import Future
from sensor_msgs.msg import JointState

from msg_adapters import channels_to_joint_state, load_name_map
from skin_node.motion import FPS, character_skeleton, clip_names  # noqa: F401 (re-exported)
from skin_node.motion import load_motion as _load_clip
from skin_node.node import QOS_JOINT_STATES
from skin_node.processes import build, init_ros, spin_until_shutdown


def load_motion(character: str, clip: str = "", bvh: str = "", mapping: str = "",
                fps: float = 0.0) -> tuple[str, list[str], np.ndarray, float]:
    """(name, channel names, (T, C) frames, fps) of what ``character`` plays
    (:func:`skin_node.motion.load_motion`; ``fps`` samples a glTF animation)."""
    c = _load_clip(character, clip, bvh, mapping, fps or None)
    return c.name, list(c.channel_names), np.asarray(c.frames), float(c.fps)


class MocapPlayer(Node):
    """Publishes one clip frame per timer tick; ``done`` completes at the end."""

    def __init__(self, defaults: argparse.Namespace) -> None:
        super().__init__("mocap_player")
        p = {k: self.declare_parameter(k, v).value for k, v in vars(defaults).items()}
        self.clip_name, names, self.frames, fps = load_motion(
            p["character"], p["clip"], p["bvh"], p["mapping"], p["fps"])
        if p["name_map"]:
            # The map reads incoming -> channel; the player speaks the incoming names.
            inverse = {ch: src for src, ch in load_name_map(p["name_map"]).items()}
            names = [inverse.get(n, n) for n in names]
        self.names, self.loop = names, p["loop"]
        if p["rate"] <= 0:
            raise ValueError(f"rate must be > 0, got {p['rate']}")
        self.limit = p["frames"] if p["frames"] > 0 else (None if self.loop else len(self.frames))
        self.sent = 0
        self.done = Future()
        self.pub = self.create_publisher(JointState, "joint_states", QOS_JOINT_STATES)
        self.create_timer(1.0 / (fps * p["rate"]), self._tick)
        self.get_logger().info(
            f"playing '{self.clip_name}': {len(self.frames)} frames at {fps * p['rate']:.1f} Hz"
            f"{', looping' if self.loop else ''}"
            f"{f', {self.limit} frames' if self.limit else ''}")

    def _tick(self) -> None:
        if self.sent == 0 and self.pub.get_subscription_count() == 0:
            # Frames sent before anyone listens are lost (volatile): start when heard.
            self.get_logger().info("waiting for a subscriber on joint_states",
                                   once=True)
            return
        if self.limit is not None and self.sent >= self.limit:
            self.done.set_result(self.sent)
            return
        q = self.frames[self.sent % len(self.frames)]
        self.pub.publish(channels_to_joint_state(self.names, q,
                                                 self.get_clock().now().to_msg()))
        self.sent += 1


def _parse(argv: list[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="mocap_player", description=__doc__.splitlines()[0])
    ap.add_argument("--character", default="humanoid", help="arm | humanoid | character file")
    ap.add_argument("--clip", default="",
                    help="built-in clip, or a glTF character's animation (NAME or gltf:NAME); "
                         "default: the file's first animation, else the character's clip")
    ap.add_argument("--list-clips", action="store_true",
                    help="print the clips the character can play and exit")
    ap.add_argument("--fps", type=float, default=float(FPS),
                    help="sampling rate of a glTF animation (default: %(default)g)")
    ap.add_argument("--bvh", default="", help="BVH file to retarget and play instead")
    ap.add_argument("--mapping", default="",
                    help="retarget mapping YAML (default: config/cmu_to_<character name>.yaml, "
                         "else for a mesh fitted to a template the template's)")
    ap.add_argument("--name-map", dest="name_map", default="",
                    help="publish under the incoming names of this name map")
    ap.add_argument("--rate", type=float, default=1.0, help="speed factor")
    ap.add_argument("--frames", type=int, default=0, help="stop after N frames (0: clip end)")
    ap.add_argument("--loop", action="store_true", help="repeat the clip")
    args = ap.parse_args(argv)
    if args.fps <= 0:
        ap.error(f"--fps must be > 0, got {args.fps:g}")
    if args.list_clips:
        try:
            print("\n".join(clip_names(args.character)))
        except ValueError as e:
            ap.exit(2, f"mocap_player: error: {e}\n")
        ap.exit(0)
    del args.list_clips             # not a parameter of the running player
    return args


def main(argv: list[str] | None = None) -> int:
    """Console script ``mocap_player``: 0 when done or interrupted, 2 on bad input."""
    args_ros = sys.argv if argv is None else ["mocap_player", *argv]
    defaults = _parse(rclpy.utilities.remove_ros_args(args_ros)[1:])
    init_ros(args_ros)
    node, code = build("mocap_player", lambda: MocapPlayer(defaults))
    if node is None:
        return code
    try:
        spin_until_shutdown(node, node.done)
        if node.done.done():
            node.get_logger().info(f"sent {node.sent} frames")
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
