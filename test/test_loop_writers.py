"""One writer per stream (core/loop/writers.py) and the node's ROS time (core/loop/clock.py)
without ROS, and how a loop's health applies them: the established writer, foreign samples while
it is alive, a replaced writer after silence (its restart, an expected writer) or after it left
the graph, never a writer of another name that merely falls silent while in the graph (a flood's
crowding out), a stray that spoke first replaced at once by the expected writer (its numbering
forgotten), the graph's names in the report, unattributed samples, bounded memory; use_sim_time
refused at run time and a /clock that does not advance. Time is passed in by hand."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.core.loop import Level, LoopHealth, StallLimits
from pomdp_planner.core.loop.clock import ClockWatch
from pomdp_planner.core.loop.health import InputWatch
from pomdp_planner.core.loop.writers import EXPECTED_WRITERS, MAX_WRITERS, WriterWatch, expected_writers

T0 = 100.0
PLANNER, PROBE, RESTARTED = "aa" * 8, "bb" * 8, "cc" * 8


def test_the_first_writer_is_followed_and_a_second_one_is_foreign_while_the_first_writes():
    w = WriterWatch("action", alive_after=2.0)
    w.graph({PLANNER: "/planner", PROBE: "/probe"})
    assert w.admit(PLANNER, T0) == ("admitted", "")
    verdict, text = w.admit(PROBE, T0 + 0.1)
    assert verdict == "foreign"
    assert text == ("action: samples of a second writer, /probe [bbbbbbbbbbbbbbbb], dropped while "
                    "/planner [aaaaaaaaaaaaaaaa] writes (one writer per stream)")
    assert w.admit(PROBE, T0 + 0.2) == ("foreign", "")  # logged once per writer
    for k in range(1, 20):  # the planner keeps writing: the probe never takes over
        assert w.admit(PLANNER, T0 + k)[0] == "admitted"
        assert w.admit(PROBE, T0 + k + 0.5)[0] == "foreign"
    assert w.foreign == 21 and w.changes == 0 and w.established == PLANNER
    assert w.status() == "action has 2 writers: /planner [aaaaaaaaaaaaaaaa] (followed), /probe [bbbbbbbbbbbbbbbb]"
    assert w.values() == {"input.action.writer": "/planner [aaaaaaaaaaaaaaaa]", "input.action.writers": 2,
                          "input.action.expected_writers": "any", "input.action.wrong_type_publishers": 0,
                          "input.action.foreign_samples": 21, "input.action.writer_changes": 0}


def test_a_restarted_writer_takes_over_once_the_old_one_is_silent_for_alive_after():
    w = WriterWatch("belief", alive_after=2.0)
    w.graph({PLANNER: "/belief_filter"})
    w.admit(PLANNER, T0)  # its last sample: then kill -9 (it stays in the graph until its lease ends)
    w.graph({PLANNER: "/belief_filter", RESTARTED: "/belief_filter"})
    assert w.admit(RESTARTED, T0 + 1.5)[0] == "foreign"  # a restart within alive_after: waits
    assert not w.takeover_due(T0 + 1.99) and w.takeover_due(T0 + 2.0)
    verdict, text = w.admit(RESTARTED, T0 + 2.0)  # the node hands the waiting sample in again
    assert verdict == "replaced" and w.established == RESTARTED and w.changes == 1
    assert text == ("belief: writer changed from /belief_filter [aaaaaaaaaaaaaaaa] (silent for 2.0 s) to "
                    "/belief_filter [cccccccccccccccc] (a restart?)")
    assert not w.takeover_due(T0 + 2.0)
    assert w.admit(PLANNER, T0 + 2.1)[0] == "foreign"  # the old one, should it come back, is now foreign


def test_a_silent_writer_still_in_the_graph_is_never_replaced_by_another_name():
    """A flood crowds the established writer's samples out: the reader hears nothing of it for as
    long as the flood lasts, but the graph still lists it. Expected or not, known or not: the
    flooder never takes over, and the established writer is followed again as soon as it is heard."""
    for expected in (None, expected_writers("observation"), frozenset()):
        w = WriterWatch("observation", alive_after=2.0, expected=expected)
        w.graph({PLANNER: "/target_simulator", PROBE: "/flood"})
        w.admit(PLANNER, T0)
        for k in range(1, 3001):  # 30 s of a 100 Hz flood, the simulator unheard
            assert w.admit(PROBE, T0 + 0.01 * k)[0] == "foreign"
            assert not w.takeover_due(T0 + 0.01 * k)
        assert w.admit(PLANNER, T0 + 30.5) == ("admitted", "") and w.changes == 0 and w.established == PLANNER


def test_a_stray_that_spoke_first_is_dropped_once_the_expected_writer_appears():
    w = WriterWatch("belief", alive_after=2.0, expected=expected_writers("belief"))
    w.graph({PROBE: "/rosbag2_player"})
    assert w.admit(PROBE, T0) == ("admitted", "")  # the first writer heard, while the loop starts
    assert w.admit(PROBE, T0 + 0.1) == ("admitted", "")
    w.graph({PROBE: "/rosbag2_player", PLANNER: "/robot1/belief_filter"})  # any namespace
    verdict, text = w.admit(PLANNER, T0 + 0.2)
    assert verdict == "replaced" and w.forget and w.established == PLANNER
    assert text == ("belief: writer changed from /rosbag2_player [bbbbbbbbbbbbbbbb] (not an expected writer of this "
                    "input) to /robot1/belief_filter [aaaaaaaaaaaaaaaa] (expected: belief_filter)")
    for k in range(1, 100):  # the stray goes on: foreign, also when the filter is silent (in the graph)
        assert w.admit(PROBE, T0 + 0.2 + 0.1 * k)[0] == "foreign"
    assert w.established == PLANNER and w.changes == 1


def test_expected_names_match_the_whole_name_or_its_last_part_and_the_user_adds_names():
    assert expected_writers("measurement") == frozenset() and "planner" in EXPECTED_WRITERS["action"]
    w = WriterWatch("measurement", alive_after=2.0, expected=expected_writers("measurement", ["sonar", " /a/b "]))
    w.graph({PLANNER: "/robot/sonar", PROBE: "/sonar_stray", RESTARTED: "/a/b"})
    assert w.is_expected(PLANNER) and w.is_expected(RESTARTED) and not w.is_expected(PROBE)
    assert not w.is_expected("dd" * 8)  # not named by the graph yet: not expected


def test_after_silence_a_restart_or_an_expected_writer_takes_over_a_stray_anyone():
    w = WriterWatch("action", alive_after=2.0, expected=expected_writers("action"))
    w.graph({PLANNER: "/planner", PROBE: "/probe", RESTARTED: "/sensor_manager"})
    w.admit(PLANNER, T0)
    assert w.admit(PROBE, T0 + 5.0)[0] == "foreign"  # not expected: never, silence or not
    verdict, text = w.admit(RESTARTED, T0 + 5.1)  # another expected writer, after the planner's silence
    assert verdict == "replaced" and not w.forget and "(silent for 5.1 s)" in text
    s = WriterWatch("action", alive_after=2.0, expected=expected_writers("action"))
    s.graph({PROBE: "/probe", "dd" * 8: "/other_stray"})
    s.admit(PROBE, T0)  # a stray followed (no expected writer yet); silent: another stray may follow
    assert s.admit("dd" * 8, T0 + 1.0)[0] == "foreign" and s.admit("dd" * 8, T0 + 2.5)[0] == "replaced"


def test_a_writer_that_left_the_graph_is_replaced_at_once():
    w = WriterWatch("action", alive_after=2.0)
    w.graph({PLANNER: "/planner"})
    w.admit(PLANNER, T0)
    w.graph({RESTARTED: "/planner"})  # a clean exit removes it from the graph
    verdict, text = w.admit(RESTARTED, T0 + 0.1)
    assert verdict == "replaced" and "(it left the graph)" in text


def test_unattributed_samples_are_admitted_and_names_can_be_missing():
    w = WriterWatch("observation", alive_after=2.0)
    assert w.admit(None, T0) == ("admitted", "") and w.unattributed == 1 and w.established is None
    assert w.values()["input.observation.writer"] == "none" and w.values()["input.observation.writers"] == "unknown"
    w.admit(PLANNER, T0)
    assert not w.known(PLANNER) and w.label(PLANNER) == "(node not in the graph) [aaaaaaaaaaaaaaaa]"
    assert w.status() == ""  # the graph has not been looked at: nothing to say
    with pytest.raises(ValueError, match="alive_after"):
        WriterWatch("x", alive_after=0)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.integers(0, 10**6), min_size=1, max_size=300))
def test_memory_is_bounded_and_the_established_writer_is_never_forgotten(ids):
    w = WriterWatch("action", alive_after=1e9)
    w.admit("first", T0)
    for k, i in enumerate(ids):
        assert w.admit(f"w{i}", T0 + k)[0] == "foreign"
        w.graph({"first": "/planner", f"w{i}": f"/n{i}"})
    assert len(w._writers) <= MAX_WRITERS and w.established == "first"
    assert len(w._names) <= 4 * MAX_WRITERS + 2


def test_health_drops_foreign_samples_counts_them_and_reports_writers_and_changes():
    watch = InputWatch("action", "action", started=T0)
    h = LoopHealth(("steps",), (), [watch], StallLimits(2.0, 10.0))
    h.writers["action"].graph({PLANNER: "/planner", PROBE: "/probe"})
    assert h.admit("action", PLANNER, T0)
    watch.arrived(T0, True, 5)
    assert not h.admit("action", PROBE, T0 + 0.1)
    assert h.counts["foreign_samples"] == 1 and watch.received == 2 and watch.idle == 1
    assert "samples of a second writer, /probe" in h.drain_logs()[0].text
    r = h.report(T0 + 0.5, {}, head=["epoch 5"])
    assert r.level == Level.WARN
    assert r.message == ("epoch 5; action has 2 writers: /planner [aaaaaaaaaaaaaaaa] (followed), /probe "
                         "[bbbbbbbbbbbbbbbb]; since the last report: 1 foreign samples; last: action: samples of a "
                         "second writer, /probe [bbbbbbbbbbbbbbbb], dropped while /planner [aaaaaaaaaaaaaaaa] writes "
                         "(one writer per stream)")
    assert r.values["input.action.writer"] == "/planner [aaaaaaaaaaaaaaaa]" and r.values["foreign_samples"] == 1
    h.writers["action"].graph({PLANNER: "/planner"})
    assert h.report(T0 + 1.0, {}, head=["epoch 5"]).level == Level.OK  # one writer again, nothing new
    h.writers["action"].graph({RESTARTED: "/planner"})
    assert h.admit("action", RESTARTED, T0 + 1.1) and h.counts["writer_changes"] == 1
    assert "writer changed from /planner [aaaaaaaaaaaaaaaa] (it left the graph)" in h.drain_logs()[0].text


def test_a_stream_without_a_stall_watch_has_writers_too_and_oversized_samples_are_counted():
    h = LoopHealth(("steps",), (), [], StallLimits(2.0, 10.0), streams=("belief",))
    assert h.admit("belief", PLANNER, T0) and not h.admit("belief", PROBE, T0)
    h.oversized("belief", "belief: 80000020 bytes, more than the 200 a belief of 3 states takes; dropped unread",
                T0)
    assert h.counts["oversized_samples"] == 1
    assert "80000020 bytes" in h.report(T0 + 1, {}).message


def test_use_sim_time_is_refused_at_run_time_with_a_reason_and_counted():
    h = LoopHealth(("steps",), (), [], StallLimits(2.0, 10.0))
    h.set_clock(False, T0)
    reason = h.refuse_sim_time(True, T0)
    assert reason == ("use_sim_time: set at start-up only (it is false; asked for True at run time): restart the "
                      "node with -p use_sim_time:=<true|false>")
    assert h.counts["use_sim_time_refused"] == 1 and reason in h.drain_logs()[0].text
    r = h.report(T0 + 1, {})
    assert r.level == Level.WARN and r.values["use_sim_time"] is False and "1 use sim time refused" in r.message


def test_sim_time_without_clock_progress_is_error_saying_so():
    h = LoopHealth(("steps",), (), [], StallLimits(2.0, 10.0))
    h.set_clock(True, T0)
    assert "use_sim_time is true" in h.drain_logs()[0].text
    h.clock.tick(0, T0 + 1.0)  # no /clock yet: ROS time is 0
    assert h.report(T0 + 1.0, {}).level == Level.OK
    h.clock.tick(0, T0 + 2.0)
    r = h.report(T0 + 2.0, {})
    assert r.level == Level.ERROR and r.message == ("use_sim_time is true and /clock has never advanced for 2.0 s "
                                                    "(no /clock publisher?): what runs on ROS time waits for it")
    for k, t in enumerate((3.0, 4.0, 5.0)):  # /clock advances
        h.clock.tick(10**9 * (k + 1), T0 + t)
        assert h.report(T0 + t, {}).level == Level.OK
    h.clock.tick(3 * 10**9, T0 + 7.5)  # paused
    r = h.report(T0 + 7.5, {})
    assert r.level == Level.ERROR and "/clock has not advanced for 2.5 s: what runs" in r.message
    assert r.values["clock.ros_time_ns"] == 3 * 10**9 and r.values["clock.seconds_since_advance"] == 2.5


def test_on_the_system_clock_nothing_is_watched():
    c = ClockWatch(False, 2.0, T0)
    c.tick(12345, T0)
    assert c.status(T0 + 100) == "" and c.values(T0) == {"use_sim_time": False}


def test_a_publisher_of_another_type_is_one_warning_once_and_in_the_report_while_it_is_there():
    h = LoopHealth(["x"], [], [InputWatch("measurement", "reading", started=T0)], StallLimits())
    h.writers["measurement"].type_name = "sensor_msgs/msg/Range"
    h.graph("measurement", {PLANNER: "/sonar"}, {PROBE: ("/laser", "sensor_msgs/msg/LaserScan")}, T0)
    assert [ln.text for ln in h.drain_logs()] == [
        "measurement: /laser [bbbbbbbbbbbbbbbb] publishes sensor_msgs/msg/LaserScan, not the sensor_msgs/msg/Range "
        "this node reads: its samples never reach it"]
    h.graph("measurement", {PLANNER: "/sonar"}, {PROBE: ("/laser", "sensor_msgs/msg/LaserScan")}, T0 + 1)
    assert h.drain_logs() == []  # said once
    r = h.report(T0 + 1, {})
    assert r.level == Level.WARN and r.values["input.measurement.wrong_type_publishers"] == 1
    assert "measurement: /laser publishes sensor_msgs/msg/LaserScan, not sensor_msgs/msg/Range" in r.message
    h.graph("measurement", {PLANNER: "/sonar"}, {}, T0 + 1.5)  # it left
    assert h.report(T0 + 1.5, {}).level == Level.OK
