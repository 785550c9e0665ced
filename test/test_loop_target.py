"""The simulated target's loop (core/loop/target_loop.py) without ROS: joining a running loop (on
actions, timer-driven on beliefs, or alone after join_timeout), waiting for subscribers, stepping
on new actions only, gaps, the window, re-sync to a restarted planner, re-sending, timer mode,
the report, and the sampling itself against the model's matrices. Time is passed in by hand."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.core.errors import OptionError
from pomdp_planner.core.io.sensors import load_model_file
from pomdp_planner.core.loop import JOIN_DELAY, ActionSample, Level, Liveness, StallLimits, TargetLoop
from pomdp_planner.core.model import POMDP

MODEL = load_model_file(str(Path(__file__).resolve().parents[1] / "config" / "models" / "tracking_s3_info.yaml"))
LIVE = Liveness(epoch_window=50, resend_period=1.0, stall=StallLimits(2.0, 10.0))
T0 = 100.0


def make(**kw) -> TargetLoop:
    loop = TargetLoop(MODEL, [MODEL.O], ["observation"], LIVE, now=T0, seed=3, **kw)
    out = loop.start(T0)
    assert out.true_states == [(0, loop.state)]
    return loop


def act(epoch, priority=2):
    return ActionSample(epoch, priority)


def joined(loop, epoch=1, now=T0):
    """Join on the action of ``epoch`` (so the loop was at ``epoch - 1``) and step it."""
    out = loop.action(act(epoch), now)
    assert out.readings == [] and out.join_at == pytest.approx(now + JOIN_DELAY)
    return loop.join_due(now + JOIN_DELAY)


def test_a_restarted_target_joins_at_the_newest_action_received_within_the_join_delay():
    loop = make()
    loop.action(act(400, 1), T0)       # the planner's transient-local history, as a burst
    loop.action(act(431, 3), T0 + 0.05)
    loop.action(act(420, 2), T0 + 0.1)
    assert loop.join_due(T0 + JOIN_DELAY / 2).readings == [] and not loop.joined
    out = loop.join_due(T0 + JOIN_DELAY)
    assert loop.joined and loop.joined_at == "epoch 430"
    assert [(r.epoch, r.priority) for r in out.readings] == [(431, 3)]  # the newest action is stepped
    assert [e for e, _ in out.true_states] == [430, 431]
    assert "joined the loop at epoch 430 (the newest epoch of the loop it received); next step: epoch 431" \
        in out.logs[0].text
    assert loop.health.counts["steps"] == 1


def test_no_step_before_the_subscribers_are_there():
    loop = make(outputs_ready=False)
    loop.action(act(1), T0)
    assert loop.join_due(T0 + 1.0).readings == [] and not loop.joined  # the evidence has settled, no subscribers
    out = loop.outputs_matched(T0 + 2.0)
    assert [r.epoch for r in out.readings] == [1] and "observation subscribers matched; stepping" in out.logs[0].text


def test_stepping_on_actions_steps_the_next_epoch_only():
    loop = make()
    joined(loop, 1)
    assert [r.epoch for r in loop.action(act(2), T0 + 1).readings] == [2]
    for e in (2, 1):  # a repeat and a stale action
        assert loop.action(act(e), T0 + 1).readings == []
    assert loop.health.counts["stale_actions"] == 2
    out = loop.action(act(6, 3), T0 + 1)  # beyond epoch 3, the one it steps next: no planner of the loop sent it
    assert out.readings == [] and loop.epoch == 2
    assert loop.health.counts["unexplained_epochs"] == 1
    assert "action of epoch 6 is beyond epoch 3, the one the simulator steps next: dropped" in out.logs[0].text
    assert loop.action(act(40, 3), T0 + 1.1).readings == [] and loop.health.counts["unexplained_epochs"] == 2
    assert [(r.epoch, r.priority) for r in loop.action(act(3, 1), T0 + 1.2).readings] == [(3, 1)]
    assert loop.health.counts["steps"] == 3


def test_one_action_beyond_the_window_is_dropped_and_never_moves_the_target():
    loop = make()
    joined(loop, 1)
    out = loop.action(act(1 + 900), T0 + 1)
    assert out.readings == [] and loop.health.counts["out_of_window"] == 1
    assert "action of epoch 901 is beyond the epoch window (50) of epoch 1" in out.logs[0].text
    loop.watchdog(T0 + 1000.0)
    assert loop.epoch == 1 and loop.health.counts["resyncs"] == 0


def test_a_stalled_target_resyncs_to_a_restarted_planners_numbering():
    loop = make()
    joined(loop, 100)
    for e, t in ((1, 1.0), (2, 1.5)):  # a planner restarted from epoch 1 (stale for the target)
        assert loop.action(act(e), T0 + t).readings == []
    out = loop.action(act(3, 1), T0 + 3.0)  # stall_warn_after since the first stale one, three of them
    assert [(r.epoch, r.priority) for r in out.readings] == [(3, 1)] and loop.epoch == 3
    assert loop.health.counts["resyncs"] == 1 and "re-synced from epoch 100 to epoch 3" in out.logs[0].text


def test_the_last_readings_are_re_sent_every_period_until_a_new_action_comes():
    loop = make()
    (r1,) = joined(loop, 1).readings  # at T0 + JOIN_DELAY
    t = T0 + JOIN_DELAY
    assert loop.watchdog(t + 0.99).readings == []
    out = loop.watchdog(t + 1.0)
    assert out.readings == [r1] and out.true_states == [] and loop.health.counts["resent_observations"] == 1
    loop.action(act(1), t + 1.2)  # a repeat does not answer it
    assert loop.watchdog(t + 2.0).readings == [r1]
    loop.action(act(2), t + 2.1)
    assert loop.watchdog(t + 3.0).readings == []


def test_timer_mode_joins_on_the_belief_epoch_and_actions_only_set_the_priority():
    loop = make(step_period=0.1, default_priority=2)
    assert loop.tick(T0 + 0.1).readings == []  # no step before it knows the loop's epoch
    loop.belief_epoch(70, T0 + 0.1)
    loop.action(act(65, 3), T0 + 0.15)
    out = loop.tick(T0 + 0.1 + JOIN_DELAY)
    assert loop.joined_at == "epoch 70" and [(r.epoch, r.priority) for r in out.readings] == [(71, 3)]
    loop.action(act(72, 1), T0 + 0.4)
    assert loop.action(act(66, 2), T0 + 0.4).readings == []  # older: ignored, and never a step
    assert [(r.epoch, r.priority) for r in loop.tick(T0 + 0.5).readings] == [(72, 1)]
    assert loop.watchdog(T0 + 100.0).readings == []  # the clock re-sends nothing
    r = loop.report(T0 + 2.5)
    assert r.level == Level.WARN and r.message == ("epoch 72; action: no new action for 2.1 s (last: epoch 72); "
                                                   "1 received meanwhile, none new (repeats, stale or out of window); "
                                                   "stepping with priority 1")


def test_timer_mode_never_takes_the_priority_of_an_action_beyond_the_next_step():
    loop = make(step_period=0.1, default_priority=2)
    loop.belief_epoch(70, T0)
    loop.tick(T0 + JOIN_DELAY)  # steps 71
    for e in (71 + 900 - 40, 80, 73):  # inside the window (50) or beyond it, all beyond epoch 72
        loop.action(act(e, 3), T0 + 0.3)
    assert loop.health.counts["unexplained_epochs"] == 2 and loop.health.counts["out_of_window"] == 1
    assert [(r.epoch, r.priority) for r in loop.tick(T0 + 0.4).readings] == [(72, 2)]
    loop.action(act(73, 1), T0 + 0.45)  # the planner's answer to the belief of 72
    loop.action(act(73, 3), T0 + 0.46)  # the same epoch again: not newer, ignored
    assert [(r.epoch, r.priority) for r in loop.tick(T0 + 0.5).readings] == [(73, 1)]


def test_timer_mode_with_nothing_received_numbers_on_its_own_after_join_timeout():
    loop = make(step_period=0.1, join_timeout=5.0)
    assert loop.tick(T0 + 4.9).readings == []
    out = loop.tick(T0 + 5.0)
    assert loop.joined_at == "epoch 0" and [(r.epoch, r.priority) for r in out.readings] == [(1, 1)]
    assert "nothing received within join_timeout (5 s): numbering on its own" in out.logs[0].text


def test_report_and_bad_actions():
    loop = make()
    r = loop.report(T0 + 1)
    assert (r.level, r.message) == (Level.OK, "epoch 0 (not joined yet)") and r.values["joined_at"] == "not yet"
    loop.rejected_action("action: expected 2 integers [epoch,action_priority], got 1", T0 + 1)
    r = loop.report(T0 + 1.5)
    assert r.level == Level.WARN and "since the last report: 1 malformed actions; last: ignored action" in r.message
    assert loop.report(T0 + 10.0).level == Level.ERROR


def test_start_parameters_are_checked():
    with pytest.raises(OptionError, match=r"initial_state: must be an integer in -1..2, got 3"):
        TargetLoop(MODEL, [MODEL.O], ["o"], LIVE, now=T0, initial_state=3)
    with pytest.raises(OptionError, match=r"default_priority: must be an integer in 1..3, got 4"):
        TargetLoop(MODEL, [MODEL.O], ["o"], LIVE, now=T0, default_priority=4)


def test_steps_sample_the_models_transitions_and_observations():
    """Empirical frequencies of (a, s) -> s' and (a, s') -> z over many steps under random
    priorities match P and O within five standard errors (a well-mixing model, so that every row
    is visited often)."""
    mixing = POMDP(P=[[[0.5, 0.3, 0.2], [0.2, 0.5, 0.3], [0.3, 0.2, 0.5]], [[0.1, 0.6, 0.3], [0.4, 0.2, 0.4],
                                                                         [0.6, 0.3, 0.1]]],
                   O=[[[0.7, 0.3], [0.4, 0.6], [0.1, 0.9]], [[0.5, 0.5], [0.8, 0.2], [0.25, 0.75]]],
                   r=np.zeros((3, 2)), gamma=0.9)
    loop = TargetLoop(mixing, [mixing.O], ["o"], LIVE, now=T0, seed=11, initial_state=0, step_period=0.1,
                      join_timeout=0.0)
    rng = np.random.default_rng(5)
    counts = {"P": Counter(), "O": Counter()}
    for _ in range(12_000):
        prev, p = loop.state, int(rng.integers(1, mixing.A + 1))
        loop.action(act(loop.epoch + 1, p), T0)  # timer-driven: sets the priority of the next tick
        (r,) = loop.tick(T0).readings
        assert r.priority == p
        counts["P"][p - 1, prev, loop.state] += 1
        counts["O"][p - 1, loop.state, r.observations[0]] += 1
    for name, M in (("P", mixing.P), ("O", mixing.O)):
        for a in range(mixing.A):
            for i in range(M.shape[1]):
                n = sum(counts[name][a, i, j] for j in range(M.shape[2]))
                assert n > 1000
                for j in range(M.shape[2]):
                    f, p = counts[name][a, i, j] / n, M[a, i, j]
                    assert abs(f - p) <= 5 * np.sqrt(p * (1 - p) / n), (name, a, i, j, f, p)
