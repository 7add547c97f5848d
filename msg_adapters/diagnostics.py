"""Flat key/value figures -> diagnostic_msgs/DiagnosticArray."""
from __future__ import annotations

from typing import Mapping

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from std_msgs.msg import Header

LEVELS = {"ok": DiagnosticStatus.OK, "warn": DiagnosticStatus.WARN,
          "error": DiagnosticStatus.ERROR, "stale": DiagnosticStatus.STALE}


def diagnostic_array(header: Header, name: str, hardware_id: str, level: str,
                     message: str, values: Mapping[str, object]) -> DiagnosticArray:
    """One DiagnosticStatus in an array; values are formatted with ``str``
    (floats with 3 decimals)."""
    kv = [KeyValue(key=k, value=f"{v:.3f}" if isinstance(v, float) else str(v))
          for k, v in values.items()]
    status = DiagnosticStatus(level=LEVELS[level], name=name, message=message,
                              hardware_id=hardware_id, values=kv)
    return DiagnosticArray(header=header, status=[status])


def diagnostic_values(msg: DiagnosticArray, name: str | None = None) -> dict[str, str]:
    """The key/values of the first status (or of the status called ``name``)."""
    for status in msg.status:
        if name is None or status.name == name:
            return {kv.key: kv.value for kv in status.values}
    raise KeyError(f"no diagnostic status {name!r}")
