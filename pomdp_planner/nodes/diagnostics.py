"""``diagnostic_msgs/DiagnosticStatus`` records as the nodes publish them on ``/diagnostics``:
status name ``"<node name>: <task>"``, ``hardware_id`` the model name, values as ``KeyValue`` strings;
the loops' report levels (``core.loop.Level``) as ``DiagnosticStatus`` levels."""

from __future__ import annotations

import time

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue

from ..core.loop import Level, Log
from ..core.loop.health import HealthChanges
from ..core.loop.parameter_names import unknown_text

LEVELS = {Level.OK: DiagnosticStatus.OK, Level.WARN: DiagnosticStatus.WARN, Level.ERROR: DiagnosticStatus.ERROR}
_LEVEL_OF = {v: k for k, v in LEVELS.items()}


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
    found by ``params.check_given_parameters``; ``none`` if there are none). A change of ``node``'s
    level is logged once (:func:`log_health_change`)."""
    log_health_change(node, st)
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


def log_health_change(node, st: DiagnosticStatus) -> None:
    """Log a change of ``node``'s diagnostics level to its console once (the core's
    :class:`~pomdp_planner.core.loop.health.HealthChanges`: OK -> WARN/ERROR and back)."""
    changes = node.__dict__.setdefault("_health_changes", HealthChanges())
    line = changes.update(_LEVEL_OF.get(bytes(st.level), Level.ERROR), st.message, time.monotonic())
    if line is None:
        return
    log_line(node.get_logger(), line)


def log_line(logger, line: Log) -> None:
    """``line`` (a core :class:`~pomdp_planner.core.loop.Log`) to ``logger`` at its level (one call
    site per severity: rclpy refuses two severities at one site)."""
    if line.level == "debug":
        logger.debug(line.text)
    elif line.level == "info":
        logger.info(line.text)
    elif line.level == "warning":
        logger.warning(line.text)
    else:
        logger.error(line.text)
