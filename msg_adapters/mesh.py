"""Triangle meshes (V, F) -> shape_msgs/Mesh and visualization_msgs/Marker."""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Point
from rclpy.serialization import deserialize_message, serialize_message
from shape_msgs.msg import Mesh, MeshTriangle
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker

# A point no mesh holds; its bytes mark where the points sequence sits in CDR.
_SENTINEL = np.array([1.2345678901234567e300, -7.654321e-300, 3.1415926535e299], "<f8")


def _as_mesh(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3:
        raise ValueError(f"need V (n, 3) and F (m, 3), got {V.shape} and {F.shape}")
    if F.size and (F.min() < 0 or F.max() >= len(V)):
        raise ValueError(f"F indexes vertices outside 0..{len(V) - 1}")
    return V, F


def mesh_to_msg(V: np.ndarray, F: np.ndarray) -> Mesh:
    """A shape_msgs/Mesh of the triangle mesh (V, F).

    The message layout needs one Python object per vertex and triangle, so
    this is for the one-off topology message, not per frame.

    Parameters
    ----------
    V : (n, 3) float
        Vertices, metres.
    F : (m, 3) int
        Triangles, counter-clockwise seen from outside.
    """
    V, F = _as_mesh(V, F)
    return Mesh(vertices=[Point(x=x, y=y, z=z) for x, y, z in V.tolist()],
                triangles=[MeshTriangle(vertex_indices=f) for f in F.astype(np.uint32)])


def msg_to_mesh(msg: Mesh) -> tuple[np.ndarray, np.ndarray]:
    """(V (n, 3) float64, F (m, 3) int64) of a shape_msgs/Mesh."""
    V = np.array([(p.x, p.y, p.z) for p in msg.vertices], dtype=np.float64).reshape(-1, 3)
    F = np.array([t.vertex_indices for t in msg.triangles], dtype=np.int64).reshape(-1, 3)
    return V, F


def triangle_list_marker_cdr(V: np.ndarray, F: np.ndarray, header: Header,
                             ns: str = "skin", marker_id: int = 0,
                             color: tuple = (0.9, 0.7, 0.6, 1.0)) -> bytes:
    """A serialized visualization_msgs/Marker TRIANGLE_LIST of (V, F), for
    ``Publisher.publish(bytes)``.

    Building one ``geometry_msgs/Point`` per corner costs about 0.1 s for
    10k triangles; instead a one-point marker is serialized and its points
    sequence replaced by ``V[F]`` as raw float64 triples, which is exactly the
    CDR of ``Point[]`` (24 bytes each, 8-aligned).

    Parameters
    ----------
    V : (n, 3) float
        Vertices, metres.
    F : (m, 3) int
        Triangles.
    header : std_msgs.msg.Header
    ns, marker_id : marker namespace and id.
    color : RGBA in [0, 1].

    Returns
    -------
    bytes
        CDR with its encapsulation header, 3 m points.
    """
    V, F = _as_mesh(V, F)
    template = Marker(header=header, ns=ns, id=marker_id, type=Marker.TRIANGLE_LIST,
                      action=Marker.ADD, frame_locked=False,
                      color=ColorRGBA(r=color[0], g=color[1], b=color[2], a=color[3]),
                      points=[Point(x=_SENTINEL[0], y=_SENTINEL[1], z=_SENTINEL[2])])
    template.pose.orientation.w = 1.0
    template.scale.x = template.scale.y = template.scale.z = 1.0
    raw = serialize_message(template)
    at = raw.find(_SENTINEL.tobytes())
    # The uint32 length sits just before the data, or before 4 bytes of padding.
    count_at = at - 4 if raw[at - 4:at] == (1).to_bytes(4, "little") else at - 8
    corners = np.ascontiguousarray(V[F].reshape(-1, 3), dtype="<f8")
    return b"".join((raw[:count_at], len(corners).to_bytes(4, "little"),
                     raw[count_at + 4:at], corners.tobytes(), raw[at + 24:]))


def triangle_list_marker(V: np.ndarray, F: np.ndarray, header: Header, **kw) -> Marker:
    """:func:`triangle_list_marker_cdr` as a Marker message object."""
    return deserialize_message(triangle_list_marker_cdr(V, F, header, **kw), Marker)
