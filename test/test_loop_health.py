"""A loop's health (core/loop/health.py) without ROS: stall levels of an input, the worst of
several, throttled warnings, and the report rule of every node: WARN while problems keep coming
(since the previous report), OK again once they stop. Time is passed in by hand."""

from __future__ import annotations

import pytest

from pomdp_planner.core.loop import Level, LoopHealth, StallLimits
from pomdp_planner.core.loop.health import COMMON_COUNTERS, InputWatch, LogThrottle, worst

T0 = 100.0
LIMITS = StallLimits(2.0, 10.0)


def test_input_watch_levels_and_messages():
    w = InputWatch("action", "action", started=T0)
    assert w.status(LIMITS, T0) == (Level.OK, "")
    assert w.status(LIMITS, T0 + 1.99)[0] == Level.OK
    assert w.status(LIMITS, T0 + 2.0) == (Level.WARN, "action: no action since start (2.0 s)")
    w.arrived(T0 + 2.0, True, 41)
    assert w.status(LIMITS, T0 + 2.0)[0] == Level.OK
    for _ in range(3):  # duplicates are not progress
        w.arrived(T0 + 3.0, False, 41)
    level, text = w.status(LIMITS, T0 + 12.0)
    assert level == Level.ERROR
    assert text == "action: no new action for 10.0 s (last: epoch 41); 3 received meanwhile, none new " \
                   "(repeats, stale or out of window)"
    assert w.values(T0 + 12.0) == {"input.action.last_new_epoch": 41, "input.action.seconds_since_new": 10.0,
                                   "input.action.received": 4, "input.action.received_since_new": 3}


def test_optional_input_is_quiet_until_it_has_advanced_once():
    w = InputWatch("action", "action", started=T0, required=False)
    assert w.status(StallLimits(), T0 + 100.0)[0] == Level.OK
    w.arrived(T0 + 100.0, True, 3)
    assert w.status(StallLimits(), T0 + 200.0)[0] == Level.ERROR


def test_worst_limits_and_log_throttle():
    assert worst([(Level.OK, ""), (Level.WARN, "a"), (Level.ERROR, "b"), (Level.ERROR, "c")]) == (Level.ERROR, "b; c")
    assert worst([]) == (Level.OK, "")
    with pytest.raises(ValueError, match="warn_after"):
        StallLimits(5.0, 1.0)
    log = LogThrottle(10.0)
    assert log.ready(T0) == (True, 0)
    assert log.ready(T0 + 1) == (False, 0)
    assert log.ready(T0 + 9.99) == (False, 0)
    assert log.ready(T0 + 10.0) == (True, 2)


def _health(watches=()):
    return LoopHealth(("steps", "bad", "odd"), ("bad", "odd"), list(watches), LIMITS)


def test_warnings_are_counted_always_and_logged_once_per_interval_per_counter():
    h = _health()
    for k in range(5):
        h.warn("bad", f"bad {k}", T0 + k)
    h.warn("odd", "odd 0", T0 + 5)
    h.warn("bad", "bad 11", T0 + 11)
    h.warn(None, "a note", T0 + 12)
    h.warn("bad", "quiet", T0 + 30, log=False)
    assert h.counts == {"steps": 0, "bad": 7, "odd": 1, **dict.fromkeys(COMMON_COUNTERS, 0)}
    assert [(x.level, x.text) for x in h.drain_logs()] == [
        ("warning", "bad 0"), ("warning", "odd 0"), ("warning", "bad 11 (and 4 similar since the last such line)"),
        ("warning", "a note")]
    assert h.last_warning == "quiet" and h.drain_logs() == []


def test_report_warns_while_problems_keep_coming_and_is_ok_once_they_stop():
    h = _health()
    r = h.report(T0, {"epoch": 3}, head=["epoch 3"])
    assert (r.level, r.message) == (Level.OK, "epoch 3")
    h.count("steps", 10)  # not a problem
    h.warn("bad", "the first", T0)
    h.warn("bad", "the second", T0)
    h.warn("odd", "the third", T0)
    r = h.report(T0 + 1, {"epoch": 4}, head=["epoch 4"])
    assert r.level == Level.WARN
    assert r.message == "epoch 4; since the last report: 2 bad, 1 odd; last: the third"
    assert r.values == {"epoch": 4, "steps": 10, "bad": 2, "odd": 1, **dict.fromkeys(COMMON_COUNTERS, 0)}
    r = h.report(T0 + 2, {}, head=["epoch 4"])  # nothing new since: OK again, counts kept
    assert (r.level, r.message, r.values["bad"]) == (Level.OK, "epoch 4", 2)
    h.warn("odd", "again", T0 + 2)
    r = h.report(T0 + 3, {}, idle="idle")
    assert (r.level, r.message) == (Level.WARN, "since the last report: 1 odd; last: again")
    assert h.report(T0 + 4, {}, idle="idle").message == "idle"


def test_report_level_is_the_highest_of_own_stall_and_problems():
    w1, w2 = InputWatch("cam", "reading", started=T0), InputWatch("radar", "reading", started=T0)
    h = _health([w1, w2])
    w1.arrived(T0 + 9.0, True, 5)
    r = h.report(T0 + 10.0, {}, head=["epoch 5"], stall_note="; still stepping")
    assert r.level == Level.ERROR and r.message == "epoch 5; radar: no reading since start (10.0 s); still stepping"
    assert r.values["input.cam.last_new_epoch"] == 5 and r.values["input.radar.last_new_epoch"] == "none"
    w2.arrived(T0 + 10.0, True, 5)
    assert h.report(T0 + 10.0, {}, level=Level.WARN).level == Level.WARN  # the loop's own level
    h.reject(w1, "bad", "cam: ignored garbage", T0 + 10.0)
    assert w1.received == 2 and w1.idle == 1 and h.counts["bad"] == 1


def test_problems_must_be_counters():
    with pytest.raises(ValueError, match="problems"):
        LoopHealth(("a",), ("b",), [], LIMITS)


def test_a_change_of_level_is_one_line_each_way():
    """``HealthChanges``: OK -> WARN -> ERROR -> WARN -> OK is four lines, a report at the same
    level none (however often it comes), and back to OK says for how long it was not."""
    from pomdp_planner.core.loop.health import HealthChanges

    h = HealthChanges()
    assert h.update(Level.OK, "", 0.0) is None
    line = h.update(Level.WARN, "belief: no new belief for 2.0 s", 1.0)
    assert (line.level, line.text) == ("warning", "health WARN: belief: no new belief for 2.0 s")
    assert h.update(Level.WARN, "belief: no new belief for 3.0 s", 2.0) is None
    line = h.update(Level.ERROR, "belief: no new belief for 10.0 s", 9.0)
    assert (line.level, line.text) == ("error", "health ERROR: belief: no new belief for 10.0 s")
    assert h.update(Level.ERROR, "still", 10.0) is None
    assert h.update(Level.WARN, "", 11.0).text == "health WARN"
    line = h.update(Level.OK, "", 13.5)
    assert (line.level, line.text) == ("info", "health OK again after 12.5 s (was WARN)")
    assert h.update(Level.OK, "", 14.0) is None
    assert h.update(Level.ERROR, "x", 20.0).level == "error"
    assert h.update(Level.OK, "", 21.0).text == "health OK again after 1.0 s (was ERROR)"


def test_every_node_logs_its_level_changes_through_its_diagnostics():
    """The nodes' diagnostics (``nodes/diagnostics.array``, which every node's report goes through)
    log a change of level once to the node's console."""
    import pytest

    pytest.importorskip("rclpy")
    from diagnostic_msgs.msg import DiagnosticStatus

    from pomdp_planner.nodes.diagnostics import array, status

    class Logger:
        def __init__(self):
            self.lines = []

        def info(self, text):
            self.lines.append(("info", text))

        def warning(self, text):
            self.lines.append(("warning", text))

        def error(self, text):
            self.lines.append(("error", text))

    class Clock:
        def now(self):
            from rclpy.time import Time
            return Time(seconds=5)

    class FakeNode:
        def __init__(self):
            self.logger = Logger()

        def get_logger(self):
            return self.logger

        def get_clock(self):
            return Clock()

    node = FakeNode()
    for level, message in [(Level.OK, ""), (Level.OK, ""), (Level.WARN, "gaps: 2"), (Level.WARN, "gaps: 3"),
                           (Level.OK, ""), (Level.OK, ""), (DiagnosticStatus.ERROR, "belief: stalled")]:
        array(node, status("planner: planning", "m", level, message, {}))
    assert [lv for lv, _ in node.logger.lines] == ["warning", "info", "error"]
    assert node.logger.lines[0][1] == "health WARN: gaps: 2"
    assert node.logger.lines[1][1].startswith("health OK again after ")
    assert node.logger.lines[2][1] == "health ERROR: belief: stalled"
