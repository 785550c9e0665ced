"""``diagnostic_msgs/DiagnosticStatus`` records as the nodes publish them on ``/diagnostics``:
status name ``"<node name>: <task>"``, ``hardware_id`` the model name, values as ``KeyValue`` strings;
the loops' report levels (``core.loop.Level``) as ``DiagnosticStatus`` levels."""

from __future__ import annotations

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from ..core.loop import Level
from ..core.loop.parameter_names import unknown_text

LEVELS = {Level.OK: DiagnosticStatus.OK, Level.WARN: DiagnosticStatus.WARN, Level.ERROR: DiagnosticStatus.ERROR}


def status(name: str, hardware_id: str, level: bytes | Level, message: str, values: dict) -> DiagnosticStatus:
    if isinstance(level, Level):
        level = LEVELS[level]
    return DiagnosticStatus(
        level=level, name=name, message=message, hardware_id=hardware_id,
        values=[KeyValue(key=str(k), value=_fmt(v)) for k, v in values.items()],
    )


def array(node, st: DiagnosticStatus) -> DiagnosticArray:
    """A ``DiagnosticArray`` with ``node``'s clock stamp holding the one status ``st``, to which the
    parameters given to ``node`` that it does not declare are added (``unknown_parameters``, as
    found by ``params.check_given_parameters``; ``none`` if there are none)."""
    unknown = getattr(node, "unknown_parameters", None)
    if unknown is not None:
        st.values.append(KeyValue(key="unknown_parameters", value=unknown_text(unknown)))
    msg = DiagnosticArray()
    msg.header.stamp = node.get_clock().now().to_msg()
    msg.status = [st]
    return msg


def _fmt(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return f"{v:.6g}"
    return str(v)
