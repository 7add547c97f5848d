"""Vertex arrays <-> sensor_msgs/PointCloud2 (x, y, z float32, unorganised)."""
from __future__ import annotations

import array

import numpy as np
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

_XYZ_FIELDS = [PointField(name=n, offset=4 * i, datatype=PointField.FLOAT32, count=1)
               for i, n in enumerate("xyz")]
_POINT_STEP = 12


def vertices_to_point_cloud2(V: np.ndarray, header: Header) -> PointCloud2:
    """Pack vertices into an unorganised little-endian PointCloud2.

    Parameters
    ----------
    V : (n, 3) float
        Vertex positions, metres.
    header : std_msgs.msg.Header
        Stamp and frame of the cloud.

    Returns
    -------
    sensor_msgs.msg.PointCloud2
        Fields x, y, z float32, ``point_step`` 12, ``height`` 1, ``width`` n;
        ``is_dense`` is true when every coordinate is finite.
    """
    V = np.ascontiguousarray(V, dtype="<f4")
    if V.ndim != 2 or V.shape[1] != 3:
        raise ValueError(f"V must have shape (n, 3), got {V.shape}")
    n = V.shape[0]
    msg = PointCloud2(
        header=header, height=1, width=n, fields=list(_XYZ_FIELDS), is_bigendian=False,
        point_step=_POINT_STEP, row_step=_POINT_STEP * n, is_dense=bool(np.isfinite(V).all()))
    # Set after construction: the constructor copies ``data`` byte by byte into
    # a new array (0.35 ms for 24k points), the setter keeps an array as it is.
    data = array.array("B")
    data.frombytes(V.reshape(-1).view(np.uint8))
    msg.data = data
    return msg


def point_cloud2_to_vertices(msg: PointCloud2) -> np.ndarray:
    """Read the x, y, z float32 fields of any PointCloud2 layout.

    Returns
    -------
    V : (height * width, 3) float32
    """
    offsets = {f.name: f for f in msg.fields}
    missing = [c for c in "xyz" if c not in offsets]
    if missing:
        raise ValueError(f"PointCloud2 lacks fields {missing}")
    if any(offsets[c].datatype != PointField.FLOAT32 or offsets[c].count != 1 for c in "xyz"):
        raise ValueError("PointCloud2 fields x, y, z must be single FLOAT32 values")
    endian = ">" if msg.is_bigendian else "<"
    dtype = np.dtype({"names": list("xyz"), "formats": [endian + "f4"] * 3,
                      "offsets": [offsets[c].offset for c in "xyz"],
                      "itemsize": msg.point_step})
    n = msg.height * msg.width
    rows = np.frombuffer(msg.data, dtype=np.uint8).reshape(msg.height, msg.row_step)
    pts = rows[:, :msg.width * msg.point_step].copy().view(dtype).reshape(n)
    return np.stack([pts["x"], pts["y"], pts["z"]], axis=1).astype(np.float32)
