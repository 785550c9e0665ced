"""What a managed node reports while it has no loop (rule "Inactive"; ROS: the
lifecycle states of ``rclpy.lifecycle``).

A managed node builds its loop when it is configured and releases it when it is cleaned up; in
``inactive`` and ``active`` its loop reports (``report(now)`` of the loop). In every other state
it still publishes diagnostics, saying the state: :func:`state_report`. A configure that failed
leaves the node unconfigured with its one-line reason, reported as ERROR until a configure
succeeds; every other state without a loop is OK (a deliberate state, not a fault).
"""

from __future__ import annotations

from .health import Level, Report

#: The states in which a managed node has a loop (it reports through the loop's report).
LOOP_STATES = ("inactive", "active", "activating", "deactivating")


def state_report(state: str, *, configure_error: str = "", busy_for: float | None = None) -> Report:
    """The report of a managed node in ``state`` (a lifecycle state label) without a loop.

    ``configure_error``: the reason the last configure failed (``""``: none, or it has succeeded
    since). ``busy_for``: seconds the transition under way (e.g. ``configuring``) has taken."""
    values: dict[str, object] = {}
    if configure_error:
        values["configure_error"] = configure_error
    if state == "unconfigured" and configure_error:
        return Report(Level.ERROR, f"unconfigured: configure failed: {configure_error}", values)
    if state == "unconfigured":
        return Report(Level.OK, "unconfigured: waiting for configure", values)
    if state == "finalized":
        return Report(Level.OK, "finalized: shut down", values)
    if busy_for is not None:
        return Report(Level.OK, f"{state} for {busy_for:.1f} s", values)
    return Report(Level.OK, state, values)
