"""What a managed node reports while it has no loop (rule "Inactive"; ROS: the
lifecycle states of ``rclpy.lifecycle``), and which transition requests it carries out.

A managed node builds its loop when it is configured and releases it when it is cleaned up; in
``inactive`` and ``active`` its loop reports (``report(now)`` of the loop). In every other state
it still publishes diagnostics, saying the state: :func:`state_report`. A configure that failed
leaves the node unconfigured with its one-line reason, reported as ERROR until a configure
succeeds; every other state without a loop is OK (a deliberate state, not a fault).

A request to change the state (``lifecycle_msgs/srv/ChangeState``: a transition by label, or by
id when the label is empty) is carried out only when it names a transition that exists from the
current state (:func:`transition_request`); any other request (an id or a label that does not
exist from there, an id and a label naming different transitions, a request that lost a race to
another client's) is answered ``success: false`` with one log line, and the node stays where it is.
"""

from __future__ import annotations

from collections.abc import Sequence

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


def transition_request(transition_id: int, label: str, state: str,
                       available: Sequence[tuple[int, str]]) -> tuple[str | None, str]:
    """The transition to carry out for a request naming ``transition_id`` and ``label`` while the
    node is in ``state`` with the transitions ``available`` from it (``(id, label)`` pairs), as
    ``(label, "")``; or ``(None, reason)``: the one-line reason the request is refused (module
    docstring). The label wins over the id (rclpy's rule); an id besides it must be ``0`` (none)
    or the same transition's."""
    names = ", ".join(f"{lab} ({tid})" for tid, lab in available) or "none"
    if label:
        match = [(tid, lab) for tid, lab in available if lab == label]
        asked = f"transition {label!r}" + (f" (id {transition_id})" if transition_id else "")
        if match and transition_id not in (0, match[0][0]):
            return None, f"change_state: {asked}: the id and the label name different transitions; refused, " \
                         f"still {state} (available: {names})"
    else:
        match = [(tid, lab) for tid, lab in available if tid == transition_id]
        asked = f"transition id {transition_id}"
    if not match:
        return None, f"change_state: no {asked} from the state {state}; refused, still {state} (available: {names})"
    return match[0][1], ""
