"""The belief filter's loop (core/loop/filter_loop.py) without ROS: readings in epoch order with
their carried action, duplicates and conflicts, incomplete epochs and lost runs on time-outs,
the window, joining a running loop, re-syncing to a restarted simulator, re-sending, stall
levels and the report. Time is passed in by hand; expected beliefs come from Bayes' rule written
out here (prediction then one update per reading), not from the filter."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.core.io.sensors import load_model_file
from pomdp_planner.core.loop import ActionSample, FilterLoop, Level, Liveness, ObservationSample, StallLimits
from pomdp_planner.core.model import POMDP

MODEL = load_model_file(str(Path(__file__).resolve().parents[1] / "config" / "models" / "tracking_s3_info.yaml"))
LIVE = Liveness(epoch_window=50, resend_period=1.0, stall=StallLimits(2.0, 10.0))
T0 = 100.0
UNIFORM = np.full(3, 1 / 3)


def bayes(b, priority, *readings):
    """b' ∝ (b P[a]) * prod_k O_k[a, :, z_k] for readings (O_k, z_k)."""
    a = priority - 1
    post = np.asarray(b) @ MODEL.P[a]
    for O, z in readings:
        post = post * O[a, :, z]
    return post / post.sum()


def make(sensors=None, topics=("observation",), **kw) -> FilterLoop:
    sensors = [MODEL.O] * len(topics) if sensors is None else sensors
    loop = FilterLoop(MODEL, sensors, UNIFORM, topics, LIVE, now=T0, **kw)
    out = loop.start(T0)
    assert [b.epoch for b in out.beliefs] == [0] and "prior published as epoch 0" in out.logs[0].text
    return loop


def feed(loop, epoch, priority, z, now=T0, sensor=0):
    return loop.observation(sensor, ObservationSample(epoch, priority, z), now)


def test_readings_in_any_order_are_applied_in_epoch_order_with_their_carried_action():
    loop = make(epoch_timeout=5.0)
    seq = {1: (2, 0), 2: (1, 2), 3: (3, 1), 4: (1, 1), 5: (2, 2)}
    published = []
    for t in (3, 5, 1, 1, 4, 2):
        published += feed(loop, t, *seq[t]).beliefs
    assert [b.epoch for b in published] == [1, 2, 3, 4, 5]
    assert loop.health.counts["duplicates"] == 1 and loop.health.counts["readings"] == 6
    b = UNIFORM
    for out in published:
        p, z = seq[out.epoch]
        b = bayes(b, p, (MODEL.O, z))
        np.testing.assert_allclose(out.belief, b, rtol=1e-12, atol=1e-15)
        assert out.entropy == pytest.approx(-sum(p * np.log(p) for p in b if p > 0))


def test_a_conflicting_reading_is_dropped_with_a_warning():
    loop = make(epoch_timeout=5.0)
    feed(loop, 3, 1, 0)
    out = feed(loop, 3, 2, 0)  # the same epoch under another action
    assert loop.health.counts["conflicts"] == 1 and "conflicts with an earlier one" in out.logs[0].text
    assert loop.buffer.pending_epochs == 1


def test_an_incomplete_epoch_is_applied_at_its_time_out_with_the_readings_it_has():
    O2 = np.array([[[0.9, 0.1], [0.5, 0.5], [0.2, 0.8]]] * 3)
    loop = make([MODEL.O, O2], ("cam", "radar"), epoch_timeout=0.3)
    out = feed(loop, 1, 2, 1, sensor=1)
    assert out.beliefs == [] and out.release_at == pytest.approx(T0 + 0.3)
    assert loop.release(T0 + 0.29).beliefs == []
    out = loop.release(T0 + 0.31)
    (b,) = out.beliefs
    np.testing.assert_allclose(b.belief, bayes(UNIFORM, 2, (O2, 1)), rtol=1e-12)
    assert "no reading from ['cam']" in out.logs[0].text and out.release_at is None
    assert loop.health.counts["incomplete_epochs"] == 1
    # both sensors: one prediction, then one update per reading
    feed(loop, 2, 3, 0, T0 + 1, sensor=0)
    (b2,) = feed(loop, 2, 3, 1, T0 + 1, sensor=1).beliefs
    np.testing.assert_allclose(b2.belief, bayes(b.belief, 3, (MODEL.O, 0), (O2, 1)), rtol=1e-12)


def test_a_run_of_lost_epochs_is_one_warning_and_one_belief_predicted_with_the_commanded_action():
    loop = make(epoch_timeout=0.5)
    (b1,) = feed(loop, 1, 1, 0).beliefs
    loop.action(ActionSample(2, 3), T0)  # the planner commanded priority 3 for epoch 2; 3: unknown
    out = feed(loop, 4, 2, 1, T0 + 0.1)
    assert out.beliefs == [] and out.release_at is None  # one reading ahead: no epoch lost on its word
    out = feed(loop, 5, 2, 0, T0 + 0.2)
    assert out.beliefs == [] and out.release_at == pytest.approx(T0 + 0.6)
    out = loop.release(T0 + 0.6)
    assert [b.epoch for b in out.beliefs] == [3, 4, 5]
    predicted_2_held_3 = b1.belief @ MODEL.P[2]
    np.testing.assert_allclose(out.beliefs[0].belief, predicted_2_held_3, rtol=1e-12)
    b4 = bayes(predicted_2_held_3, 2, (MODEL.O, 1))
    np.testing.assert_allclose(out.beliefs[1].belief, b4, rtol=1e-12)
    np.testing.assert_allclose(out.beliefs[2].belief, bayes(b4, 2, (MODEL.O, 0)), rtol=1e-12)
    assert [x.text for x in out.logs] == [
        "epochs 2..3 lost (2, no reading): predicted with the commanded action for 1, held for 1"]
    assert loop.health.counts["gaps"] == 2


def test_one_reading_ahead_declares_nothing_lost_and_costs_at_most_its_own_epoch():
    loop = make(epoch_timeout=0.5)
    for t in range(1, 11):
        feed(loop, t, 2, t % 3)
    feed(loop, 13, 1, 0, T0 + 0.1)  # a stray's guess of a later epoch, within the reach
    for k in range(1, 5):
        assert loop.release(T0 + k).beliefs == []
        assert [b.epoch for b in loop.watchdog(T0 + k).beliefs] in ([], [10])  # at most the re-sent belief
    assert loop.epoch == 10 and loop.health.counts["gaps"] == 0
    assert [b.epoch for b in feed(loop, 11, 2, 1, T0 + 5).beliefs] == [11]
    assert [b.epoch for b in feed(loop, 12, 2, 1, T0 + 5).beliefs] == [12, 13]  # the guess: its own epoch only
    assert feed(loop, 13, 2, 2, T0 + 5).beliefs == [] and loop.health.counts["duplicates"] == 1
    assert [b.epoch for b in feed(loop, 14, 2, 2, T0 + 5).beliefs] == [14]


def test_one_reading_far_ahead_is_unexplained_and_a_jump_needs_two_and_a_quiet_line():
    loop = make(epoch_timeout=0.5, max_pending=10)
    for t in range(1, 11):
        feed(loop, t, 2, t % 3)
    b10 = loop.belief
    out = feed(loop, 40, 1, 0, T0 + 0.1)  # 30 ahead: beyond the reach (10), inside the window (50)
    assert out.beliefs == [] and loop.buffer.pending_epochs == 0
    assert loop.health.counts["unexplained_epochs"] == 1 and "more than 10 epochs ahead" in out.logs[0].text
    # a stream far ahead while the line advances (a replay beside the real readings): never followed
    for t in range(11, 21):
        feed(loop, t + 30, 1, 0, T0 + 0.1 + t / 100)
        feed(loop, t, 2, 0, T0 + 0.1 + t / 100)
    assert loop.epoch == 20 and loop.health.counts["gaps"] == 0
    for k in range(1, 4):  # one reading far ahead, however long the line then stays quiet
        feed(loop, 60, 2, 1, T0 + k)
        loop.watchdog(T0 + k)
    assert loop.epoch == 20
    # the readings go on far ahead and nothing has been applied for epoch_timeout: a long loss
    out = feed(loop, 61, 2, 0, T0 + 4)
    assert [b.epoch for b in out.beliefs] == [61] and loop.epoch == 61
    np.testing.assert_allclose(out.beliefs[0].belief, bayes(loop_belief_at_20(b10), 2, (MODEL.O, 0)), rtol=1e-12)
    assert loop.health.counts["gaps"] == 40 and "epochs 21..60 lost (40" in out.logs[0].text


def test_two_consecutive_readings_far_ahead_are_followed_only_once_the_line_is_quiet():
    loop = make(epoch_timeout=0.5, max_pending=10)
    feed(loop, 1, 2, 0, T0)
    feed(loop, 30, 2, 0, T0 + 0.1)
    assert feed(loop, 31, 2, 0, T0 + 0.2).beliefs == [] and loop.epoch == 1  # the line advanced 0.2 s ago
    out = loop.watchdog(T0 + 0.5)
    assert [b.epoch for b in out.beliefs][-1:] == [31] and loop.epoch == 31


def loop_belief_at_20(b10):
    b = b10
    for _ in range(11, 21):
        b = bayes(b, 2, (MODEL.O, 0))
    return b


def test_a_reading_beyond_the_window_is_dropped_never_buffered_never_walked():
    loop = make()
    for t in range(1, 11):
        feed(loop, t, 2, t % 3)
    out = feed(loop, 10 + 50_000, 2, 0)  # one forged reading far ahead
    assert out.beliefs == [] and loop.buffer.pending_epochs == 0 and out.release_at is None
    assert loop.health.counts["out_of_window"] == 1 and "beyond the epoch window (50) of epoch 10" in out.logs[0].text
    for k in range(3):  # however long it then stalls: one reading is no evidence
        loop.watchdog(T0 + 100.0 * (k + 1))
    assert loop.epoch == 10 and loop.health.counts["resyncs"] == 0


def test_a_fresh_filter_joins_a_running_loop_on_two_consecutive_readings_beyond_its_window():
    loop = make()
    out = feed(loop, 7000, 2, 1)
    assert out.beliefs == [] and loop.epoch == 0  # one reading (perhaps forged) is not enough
    out = feed(loop, 7001, 3, 0)
    assert [b.epoch for b in out.beliefs] == [7001]
    np.testing.assert_allclose(out.beliefs[0].belief, bayes(UNIFORM, 3, (MODEL.O, 0)), rtol=1e-12)
    assert "joined a running loop at epoch 7001" in out.logs[0].text
    assert loop.started_from == "prior at epoch 7000 (joined a running loop)"
    assert loop.health.counts["resyncs"] == 0  # a join is not a re-sync


def test_actions_out_of_the_window_or_ahead_warn_only_once_the_filter_has_joined():
    loop = make()
    assert loop.action(ActionSample(9000, 1), T0).logs == []  # the planner's history before the join
    feed(loop, 1, 1, 0)
    out = loop.action(ActionSample(9000, 1), T0)
    assert loop.health.counts["out_of_window"] == 1 and "action: epoch 9000 is beyond" in out.logs[0].text
    out = loop.action(ActionSample(5, 1), T0)  # ahead of the epoch the filter applies next (2)
    assert loop.health.counts["unexplained_epochs"] == 1 and "beyond epoch 2, the one the filter" in out.logs[0].text
    assert loop.action(ActionSample(2, 1), T0).logs == []


def test_a_stalled_filter_resyncs_to_a_simulator_counting_on_a_numbering_of_its_own():
    loop = make()
    for t in range(1, 31):
        feed(loop, t, 2, t % 3)
    b30 = loop.belief
    # a restarted simulator counts from 1 again: stale for the filter, but consecutive
    for t in (1, 2):
        assert feed(loop, t, 2, 1, T0 + 1).beliefs == []
    assert feed(loop, 3, 2, 1, T0 + 2.9).beliefs == []  # the evidence is not stall_warn_after old yet
    out = loop.watchdog(T0 + 3.0)
    assert [b.epoch for b in out.beliefs] == [30, 3] and loop.epoch == 3  # the re-sent 30, then the re-sync
    np.testing.assert_allclose(out.beliefs[1].belief, bayes(b30, 2, (MODEL.O, 1)), rtol=1e-12)  # belief kept
    assert loop.health.counts["resyncs"] == 1 and "re-synced from epoch 30 to epoch 3" in out.logs[0].text
    assert [b.epoch for b in feed(loop, 4, 2, 0, T0 + 3.1).beliefs] == [4]


def test_a_stray_repeating_one_stale_reading_never_resyncs_the_filter():
    loop = make()
    for t in range(1, 31):
        feed(loop, t, 2, 0)
    for k in range(20):
        feed(loop, 5, 2, 0, T0 + k)
    loop.watchdog(T0 + 30.0)
    assert loop.epoch == 30 and loop.health.counts["resyncs"] == 0 and loop.health.counts["duplicates"] == 20


def test_the_last_belief_is_re_sent_every_period_until_a_reading_answers_it():
    loop = make()
    (b1,) = feed(loop, 1, 2, 0).beliefs
    assert loop.watchdog(T0 + 0.99).beliefs == []
    (again,) = loop.watchdog(T0 + 1.0).beliefs
    assert again is b1 and loop.health.counts["resent_beliefs"] == 1
    assert loop.watchdog(T0 + 1.5).beliefs == [] and loop.watchdog(T0 + 2.0).beliefs == [b1]
    feed(loop, 1, 2, 0, T0 + 2.1)  # a repeat does not answer it
    assert loop.watchdog(T0 + 3.0).beliefs == [b1]
    feed(loop, 2, 2, 0, T0 + 3.1)  # the next epoch does (and is published: a new period)
    assert loop.watchdog(T0 + 4.0).beliefs == [] and loop.watchdog(T0 + 4.1).beliefs[0].epoch == 2


def test_report_names_the_silent_input_and_warns_while_problems_come():
    loop = make([MODEL.O, MODEL.O], ("cam", "radar"))
    r = loop.report(T0 + 1.0)
    assert (r.level, r.message) == (Level.OK, "epoch 0")
    assert r.values["started_from"] == "prior at epoch 0" and r.values["pending_epochs"] == 0
    loop.rejected_observation(0, "observation: observation 7 out of range 0..2", T0 + 1, out_of_range=True)
    loop.rejected_action("action: expected 2 integers", T0 + 1)
    r = loop.report(T0 + 2.0)
    assert r.level == Level.WARN and r.message.startswith("epoch 0; cam: no reading since start (2.0 s)")
    assert "since the last report: 1 out of range observations, 1 malformed messages; last: ignored action" \
        in r.message
    assert r.values["input.cam.received"] == 1 and r.values["input.action.received"] == 1
    r = loop.report(T0 + 10.0)
    assert r.level == Level.ERROR and "radar: no reading since start (10.0 s)" in r.message
    assert "since the last report" not in r.message


def test_impossible_and_contradicting_readings_are_counted_and_warned():
    """S = 2, static, perfect sensor: reading 1 is impossible under [1, 0] (restart from the uniform
    prior pushed through the transition: [0, 1]); reading 2 is impossible from every state."""
    model = POMDP(P=[[[1, 0], [0, 1]]], O=[[[1, 0, 0], [0, 1, 0]]], r=np.zeros((2, 1)), gamma=0.9)
    loop = FilterLoop(model, [model.O], np.array([1.0, 0.0]), ["observation"], LIVE, now=T0)
    (b,) = loop.observation(0, ObservationSample(1, 1, 1), T0).beliefs
    np.testing.assert_array_equal(b.belief, [0.0, 1.0])
    out = loop.observation(0, ObservationSample(2, 1, 2), T0)
    np.testing.assert_array_equal(out.beliefs[0].belief, [0.0, 1.0])
    assert loop.health.counts["impossible_observations"] == 1 and loop.health.counts["contradicting_observations"] == 1
    assert "contradicts the model; reading dropped" in out.logs[0].text


def test_topics_must_name_every_sensor():
    with pytest.raises(ValueError, match="topics"):
        FilterLoop(MODEL, [MODEL.O], UNIFORM, ["a", "b"], LIVE, now=T0)
