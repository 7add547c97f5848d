"""ROS message <-> numpy adapters: the only code that knows message layouts.

Everything here is vectorised over points; the node only calls these.
"""
from msg_adapters.diagnostics import diagnostic_array, diagnostic_values
from msg_adapters.header import header_stamp_ns
from msg_adapters.joint_state import (MAX_ABS_POSITION, TIME_JUMP_TOLERANCE_S, ChannelMapper,
                                      JointStateError, Reason, StampOrder,
                                      channels_to_joint_state, joint_state_to_arrays,
                                      load_name_map)
from msg_adapters.mesh import (mesh_to_msg, msg_to_mesh, triangle_list_marker,
                               triangle_list_marker_cdr)
from msg_adapters.point_cloud import point_cloud2_to_vertices, vertices_to_point_cloud2

__all__ = [
    "MAX_ABS_POSITION", "TIME_JUMP_TOLERANCE_S", "ChannelMapper", "JointStateError", "Reason",
    "StampOrder",
    "channels_to_joint_state", "joint_state_to_arrays", "load_name_map",
    "mesh_to_msg", "msg_to_mesh", "triangle_list_marker", "triangle_list_marker_cdr",
    "point_cloud2_to_vertices", "vertices_to_point_cloud2",
    "diagnostic_array", "diagnostic_values", "header_stamp_ns",
]
