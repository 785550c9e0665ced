"""``diagnostic_msgs/DiagnosticStatus`` records as the nodes publish them on ``/diagnostics``:
status name ``"<node name>: <task>"``, ``hardware_id`` the model name, values as ``KeyValue`` strings."""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue


def status(name: str, hardware_id: str, level: bytes, message: str, values: dict) -> DiagnosticStatus:
    return DiagnosticStatus(
        level=level, name=name, message=message, hardware_id=hardware_id,
        values=[KeyValue(key=str(k), value=_fmt(v)) for k, v in values.items()],
    )


def _fmt(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)
