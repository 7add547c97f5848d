"""The stamp of a serialized message, read without deserializing it."""
from __future__ import annotations

import struct

_STAMP = {0: struct.Struct(">iI"), 1: struct.Struct("<iI")}


def header_stamp_ns(cdr: bytes) -> int:
    """Header stamp, in ns, of a CDR-serialized message whose first field is a
    ``std_msgs/Header`` (JointState, PointCloud2, Marker...).

    The stamp's ``sec`` (int32) and ``nanosec`` (uint32) follow the 4-byte
    encapsulation header, whose second byte says the byte order. Reading them
    costs the same for a 12-byte message and a 300 kB point cloud.

    Raises
    ------
    ValueError
        When ``cdr`` is too short or its encapsulation is not plain CDR.
    """
    if len(cdr) < 12 or cdr[0] != 0 or cdr[1] not in _STAMP:
        raise ValueError(f"not a plain CDR message with a header ({len(cdr)} bytes, "
                         f"encapsulation {bytes(cdr[:2]).hex() or 'none'})")
    sec, nanosec = _STAMP[cdr[1]].unpack_from(cdr, 4)
    return sec * 1_000_000_000 + nanosec
