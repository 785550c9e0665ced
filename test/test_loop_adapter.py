"""The measurement adapter's loop (core/loop/adapter_loop.py) without ROS: binning, which action a
reading answers, every kind of bad reading counted and dropped, joining, the window, re-sync,
re-send, the report, a burst from a fast sensor, and the beliefs a scripted measurement stream
gives against the same stream typed as ``[epoch, priority, z]``. Time is passed in by hand."""

from __future__ import annotations

import math
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.core.errors import OptionError
from pomdp_planner.core.io.sensors import load_model_file
from pomdp_planner.core.loop import (
    JOIN_DELAY,
    ActionSample,
    AdapterLoop,
    FilterLoop,
    Level,
    LikelihoodSample,
    Liveness,
    ObservationBins,
    ObservationSample,
    StallLimits,
    point_value,
)

REPO = Path(__file__).resolve().parents[1]
MODEL = load_model_file(str(REPO / "config" / "models" / "tracking_s3_info.yaml"))  # S = A = Z = 3
LIVE = Liveness(epoch_window=50, resend_period=1.0, stall=StallLimits(2.0, 10.0))
T0 = 1000.0
EDGES = [0.5, 1.5]


def make(**kw) -> AdapterLoop:
    kw.setdefault("bin_edges", None if kw.get("input_type") == "likelihood" else EDGES)
    loop = AdapterLoop(MODEL, LIVE, now=T0, **kw)
    out = loop.start(T0)
    assert "waiting for the first action" in out.logs[0].text
    return loop


def joined(epoch=1, priority=2, **kw) -> AdapterLoop:
    """An adapter that has joined at action ``[epoch, priority]`` heard at ``T0``."""
    loop = make(**kw)
    out = loop.action(ActionSample(epoch, priority), T0)
    assert out.join_at == pytest.approx(T0 + JOIN_DELAY)
    loop.join_due(T0 + JOIN_DELAY)
    assert loop.joined and loop.pending.epoch == epoch
    return loop


def forwarded(out) -> list:
    return [(s.epoch, s.priority, s.observation) for s in out.samples]


# ----------------------------------------------------------------- binning
def bin_by_hand(edges, x):
    z = 0
    for e in edges:
        if x >= e:
            z += 1
    return z


@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-1e6, 1e6), min_size=1, max_size=7, unique=True),
       st.one_of(st.floats(-2e6, 2e6), st.sampled_from([-math.inf, math.inf])), st.booleans())
def test_a_scalar_goes_to_the_number_of_edges_at_or_below_it(edges, x, on_edge):
    edges = sorted(edges)
    if on_edge:
        x = edges[len(edges) // 2]
    bins = ObservationBins(edges, len(edges) + 1)
    assert bins.index(x) == bin_by_hand(edges, x)


def test_bin_edges_by_hand():
    bins = ObservationBins([0.5, 1.5], 3)
    assert [bins.index(x) for x in (-math.inf, -3.0, 0.4999, 0.5, 1.0, 1.5, 7.0, math.inf)] == [0, 0, 0, 1, 1, 2, 2, 2]


@pytest.mark.parametrize("kw, message", [
    (dict(bin_edges=[0.5]), r"bin_edges: 1 edges for an observation model with Z = 3 observations \(give Z - 1 = 2"),
    (dict(bin_edges=[0.5, 1.5, 2.5]), "bin_edges: 3 edges"),
    (dict(bin_edges=[1.5, 0.5]), r"bin_edges: edges must increase strictly, but bin_edges\[1\] = 0.5 <= "),
    (dict(bin_edges=[0.5, 0.5]), "must increase strictly"),
    (dict(bin_edges=[0.5, math.nan]), r"bin_edges\[1\]: must be a number"),
    (dict(bin_edges=None), "bin_edges: needed for input_type float64: Z - 1 = 2"),
    (dict(input_type="likelihood", bin_edges=[0.5, 1.5]), "bin_edges: not used with input_type likelihood"),
    (dict(input_type="sonar"), "input_type: expected one of float64, range, point, likelihood, got 'sonar'"),
    (dict(point_field="w"), "point_field: expected one of x, y, z, norm, got 'w'"),
    (dict(max_age=-1.0), "max_age: must be a number >= 0"),
    (dict(settle_time=math.inf), "settle_time: must be a number >= 0"),
])
def test_bad_settings_are_one_line_naming_the_parameter(kw, message):
    kw.setdefault("bin_edges", EDGES)
    with pytest.raises(OptionError, match=message) as info:
        AdapterLoop(MODEL, LIVE, now=T0, **kw)
    assert "\n" not in str(info.value)


def test_edges_are_checked_against_the_sensors_own_number_of_observations():
    AdapterLoop(MODEL, LIVE, now=T0, bin_edges=[0.0], num_observations=2)
    with pytest.raises(OptionError, match="Z = 2"):
        AdapterLoop(MODEL, LIVE, now=T0, bin_edges=EDGES, num_observations=2)
    AdapterLoop(MODEL, LIVE, now=T0, bin_edges=None, num_observations=1)  # one observation: no edges


def test_point_value_is_a_coordinate_or_the_norm():
    assert point_value(3.0, 4.0, 12.0, "norm") == 13.0
    assert [point_value(1.0, 2.0, 3.0, f) for f in "xyz"] == [1.0, 2.0, 3.0]
    assert math.isnan(point_value(math.nan, math.inf, 0.0, "norm"))
    assert point_value(math.nan, 2.0, 0.0, "y") == 2.0


# ----------------------------------------------------------------- numbering
def test_readings_before_the_first_action_are_counted_and_dropped():
    loop = make()
    out = loop.measurement(1.0, T0 + 0.1)
    assert out.samples == [] and loop.health.counts["before_first_action"] == 1
    assert "dropped until the first action" in out.logs[0].text
    assert loop.measurement(1.0, T0 + 0.2).logs == []  # said once
    assert loop.health.counts["before_first_action"] == 2 and loop.health.counts["forwarded"] == 0


def test_the_newest_action_is_answered_by_one_reading_the_rest_are_surplus():
    loop = make()
    for t in (1, 3, 2):  # the planner's history arrives as a burst: the newest wins
        loop.action(ActionSample(t, t), T0)
    assert loop.measurement(2.0, T0 + 0.1).samples == []  # still joining
    out = loop.measurement(2.0, T0 + JOIN_DELAY)  # the join delay has passed: joined at epoch 3, answered
    assert loop.joined_at == "epoch 3" and forwarded(out) == [(3, 3, 2)]
    assert loop.measurement(0.0, T0 + 0.3).samples == [] and loop.health.counts["surplus_readings"] == 1
    loop.action(ActionSample(4, 1), T0 + 0.4)
    assert forwarded(loop.measurement(0.7, T0 + 0.41)) == [(4, 1, 1)]
    assert loop.health.counts["forwarded"] == 2 and loop.health.counts["before_first_action"] == 1


def test_settle_time_and_stamps_decide_whether_a_reading_was_taken_under_the_action():
    loop = joined(settle_time=0.05)  # action 1 heard at T0
    t = T0 + JOIN_DELAY  # joined (accepted) at this time
    assert loop.measurement(1.0, t + 0.01).samples == []  # unstamped, within the settle time
    assert loop.measurement(1.0, t + 0.2, stamp=t + 0.04).samples == []  # arrives late, stamped early
    assert loop.health.counts["early_readings"] == 2
    assert forwarded(loop.measurement(1.0, t + 0.2, stamp=t + 0.05)) == [(1, 2, 1)]


def test_an_action_superseded_before_any_reading_is_counted():
    loop = joined()
    loop.action(ActionSample(2, 1), T0 + 1)
    assert loop.health.counts["unanswered_actions"] == 1
    assert forwarded(loop.measurement(2.0, T0 + 1.1)) == [(2, 1, 2)]


def test_likelihood_input_is_forwarded_as_soft_evidence():
    loop = joined(input_type="likelihood")
    out = loop.measurement([0.1, 0.2, 0.7], T0 + 1)
    assert out.samples == [LikelihoodSample(1, 2, (0.1, 0.2, 0.7))]
    assert loop.report(T0 + 1).values["last.observation"] == "likelihood"


# ----------------------------------------------------------------- bad readings
def test_every_kind_of_bad_reading_is_counted_once_and_dropped():
    loop = joined(max_age=0.5)
    now = T0 + 10
    bad = [
        ("nan_readings", dict(value=math.nan)),
        ("nan_readings", dict(value=math.nan, stamp=now)),                     # NaN first, whatever the stamp
        ("stale_readings", dict(value=1.0, stamp=now - 0.6)),
        ("future_readings", dict(value=1.0, stamp=now + 0.6)),
        ("out_of_limits_readings", dict(value=5.0, stamp=now, limits=(0.1, 4.0))),
        ("out_of_limits_readings", dict(value=0.05, stamp=now, limits=(0.1, 4.0))),
    ]
    for counter, kw in bad:
        before = dict(loop.health.counts)
        out = loop.measurement(kw.pop("value"), now, **kw)
        assert out.samples == [], counter
        grew = {k for k in loop.health.counts if loop.health.counts[k] != before[k]}
        assert grew == {"readings", counter}, (counter, grew)
    assert loop.pending.answered is False  # nothing answered the action
    # stamped readings must come in order: an older or equal stamp is out of order
    assert forwarded(loop.measurement(1.0, now, stamp=now - 0.1)) == [(1, 2, 1)]
    loop.action(ActionSample(2, 2), now)
    for stamp in (now - 0.2, now - 0.1):
        assert loop.measurement(1.0, now + 0.01, stamp=stamp).samples == []
    assert loop.health.counts["out_of_order_readings"] == 2
    assert forwarded(loop.measurement(1.0, now + 0.01, stamp=now + 0.005)) == [(2, 2, 1)]
    c = loop.health.counts
    assert c["readings"] == 10 and c["forwarded"] == 2
    dropped = sum(c[k] for k in ("nan_readings", "stale_readings", "future_readings", "out_of_limits_readings",
                                 "out_of_order_readings"))
    assert dropped == 8


def test_ranges_at_infinity_are_readings_and_unset_limits_are_ignored():
    loop = joined()
    assert forwarded(loop.measurement(math.inf, T0 + 1, limits=(0.1, 4.0))) == [(1, 2, 2)]  # nothing within range
    loop.action(ActionSample(2, 2), T0 + 1)
    assert forwarded(loop.measurement(-math.inf, T0 + 1.1, limits=(0.1, 4.0))) == [(2, 2, 0)]  # too close
    loop.action(ActionSample(3, 2), T0 + 2)
    assert forwarded(loop.measurement(9.0, T0 + 2.1, limits=(0.0, 0.0))) == [(3, 2, 2)]  # limits left unset
    assert loop.health.counts["out_of_limits_readings"] == 0


def test_zero_stamps_and_max_age_zero_skip_the_stamp_rules():
    loop = joined(max_age=0.0)
    # very old (a clock out of step): no age check, and the settle rule takes the arrival time
    assert forwarded(loop.measurement(1.0, T0 + 1, stamp=T0 - 1e6)) == [(1, 2, 1)]
    loop.action(ActionSample(2, 2), T0 + 2)
    assert forwarded(loop.measurement(1.0, T0 + 2.1, stamp=0.0)) == [(2, 2, 1)]  # an unset header stamp
    assert loop.newest_stamp == T0 - 1e6


@pytest.mark.parametrize("values, counter", [
    ([0.2, math.nan, 0.1], "nan_readings"), ([0.2, -0.1, 0.1], "malformed_messages"),
    ([0.0, 0.0, 0.0], "malformed_messages"), ([1.0, 1.0], "malformed_messages"),
    ([1.0, math.inf, 1.0], "malformed_messages"),
])
def test_bad_likelihoods_are_counted_and_dropped(values, counter):
    loop = joined(input_type="likelihood")
    assert loop.measurement(values, T0 + 1).samples == []
    assert loop.health.counts[counter] == 1 and not loop.pending.answered


def test_a_sensor_message_that_cannot_be_decoded_is_counted():
    loop = joined(input_type="likelihood")
    loop.rejected_measurement("likelihood: expected 3 values (one per state), got 4", T0 + 1)
    assert loop.health.counts["malformed_messages"] == 1 and loop.health.counts["readings"] == 1
    r = loop.report(T0 + 1)
    assert r.level == Level.WARN and "1 malformed messages" in r.message and "expected 3 values" in r.message


# ----------------------------------------------------------------- window, re-sync, re-send
def test_a_forged_action_far_ahead_is_dropped_and_does_not_stall_the_adapter():
    loop = joined()
    loop.action(ActionSample(10**15, 1), T0 + 1)
    assert loop.health.counts["out_of_window"] == 1 and loop.pending.epoch == 1
    assert forwarded(loop.measurement(1.0, T0 + 1.1)) == [(1, 2, 1)]
    loop.action(ActionSample(2, 3), T0 + 1.2)
    assert forwarded(loop.measurement(1.0, T0 + 1.3)) == [(2, 3, 1)]
    assert loop.health.counts["resyncs"] == 0


def test_a_planner_persisting_on_another_numbering_is_re_synced_to():
    loop = joined(epoch=500)
    loop.measurement(1.0, T0 + 0.5)
    for k, t in enumerate((T0 + 1.0, T0 + 2.0, T0 + 3.1)):  # a restarted planner counting from 1
        loop.action(ActionSample(1 + k, 1), t)
    assert loop.health.counts["resyncs"] == 1 and loop.pending.epoch == 3
    assert forwarded(loop.measurement(0.0, T0 + 3.2)) == [(3, 1, 0)]
    assert loop.health.counts["unanswered_actions"] == 0


def test_a_repeated_action_is_stale_and_the_last_observation_is_re_sent_until_answered():
    loop = joined()
    assert forwarded(loop.measurement(1.0, T0 + 0.3)) == [(1, 2, 1)]
    loop.action(ActionSample(1, 2), T0 + 0.5)  # the planner re-sends: its belief has not come yet
    assert loop.health.counts["stale_actions"] == 1
    assert loop.watchdog(T0 + 1.0).samples == []
    assert forwarded(loop.watchdog(T0 + 1.31)) == [(1, 2, 1)]
    assert loop.health.counts["resent_observations"] == 1
    loop.action(ActionSample(2, 2), T0 + 1.5)
    assert loop.watchdog(T0 + 5.0).samples == []  # action 2 answered nothing yet: nothing to re-send


def test_the_report_names_the_state_the_counts_and_the_stall_of_each_input():
    loop = make()
    r = loop.report(T0 + 3)
    assert r.message.startswith("waiting for the first action") and r.level == Level.WARN
    assert "measurement: no reading since start" in r.message and "action: no action since start" in r.message
    loop = joined()
    loop.measurement(1.0, T0 + 0.3)
    r = loop.report(T0 + 0.4)
    assert r.level == Level.OK and r.message == "epoch 1 answered"
    assert r.values["last.observation"] == 1 and r.values["param.bin_edges"] == "0.5, 1.5"
    assert r.values["input.measurement.last_new_epoch"] == 1 and r.values["forwarded"] == 1
    loop.measurement(math.nan, T0 + 0.5)
    r = loop.report(T0 + 0.6)
    assert r.level == Level.WARN and "1 nan readings" in r.message
    assert loop.report(T0 + 0.7).level == Level.OK  # WARN only while problems keep coming


# ----------------------------------------------------------------- a fast sensor
def test_a_burst_keeps_the_state_and_the_memory_bounded():
    """10^5 readings at 1 kHz (by the clock passed in) with an action every 50 ms: one reading
    answers each action, the rest are surplus; nothing the loop holds grows."""
    loop = joined()
    n, next_epoch = 100_000, 2
    tracemalloc.start()
    try:
        for i in range(n):
            now = T0 + 1 + i * 1e-3
            if i % 50 == 0:
                loop.action(ActionSample(2 + i // 50, 1 + i % 3), now)
            for s in loop.measurement(0.1 * (i % 30), now, stamp=now).samples:
                assert s.epoch == next_epoch
                next_epoch += 1
            if i == 1000:
                base = tracemalloc.get_traced_memory()[0]
        grown = tracemalloc.get_traced_memory()[0] - base
    finally:
        tracemalloc.stop()
    c = loop.health.counts
    assert next_epoch == 2 + n // 50
    assert c["readings"] == n and c["forwarded"] == n // 50 and c["surplus_readings"] == n - n // 50
    assert loop.health.logs == [] and loop._out.samples == []
    assert grown < 16 * 1024, f"memory grew by {grown} bytes over {n} readings"


# ----------------------------------------------------------------- the filter fed both ways
def script(seed=7, epochs=40):
    """A planner's actions and a sensor's scalar readings: per epoch, a few readings before the
    action is heard (surplus), the action, bad readings, then good ones."""
    rng = np.random.default_rng(seed)
    for t in range(1, epochs + 1):
        yield "action", t, int(rng.integers(1, 4)), None
        yield "reading", t, math.nan, None
        yield "reading", t, float(rng.uniform(-1.0, 3.0)), None
        yield "reading", t, float(rng.uniform(-1.0, 3.0)), None


def run_through_adapter(loop, filt, events, t0):
    beliefs, now = [], t0
    for kind, epoch, a, _ in events:
        now += 0.01
        if kind == "action":
            out = loop.action(ActionSample(epoch, a), now)
            if out.join_at is not None:
                now = out.join_at
                out = loop.join_due(now)
            continue
        for s in loop.measurement(a, now).samples:
            beliefs += filt.observation(0, s, now).beliefs
    return beliefs


def test_a_scripted_measurement_stream_gives_the_beliefs_of_the_same_observations_typed_by_hand():
    prior = np.full(3, 1 / 3)
    events = list(script())
    adapter = make()
    via_adapter = FilterLoop(MODEL, [MODEL.O], prior, ["observation"], LIVE, now=T0)
    via_adapter.start(T0)
    beliefs = run_through_adapter(adapter, via_adapter, events, T0)
    # by hand: the action of each epoch, the first non-NaN reading after it, binned by explicit comparison
    typed, action = [], None
    for kind, epoch, a, _ in events:
        if kind == "action":
            action = (epoch, a)
        elif not math.isnan(a) and action is not None:
            typed.append(ObservationSample(action[0], action[1], bin_by_hand(EDGES, a)))
            action = None
    raw = FilterLoop(MODEL, [MODEL.O], prior, ["observation"], LIVE, now=T0)
    raw.start(T0)
    expected = [b for obs in typed for b in raw.observation(0, obs, T0).beliefs]
    assert [b.epoch for b in beliefs] == list(range(1, 41)) == [b.epoch for b in expected]
    for got, want in zip(beliefs, expected, strict=True):
        assert np.array_equal(got.belief, want.belief)
    assert adapter.health.counts["nan_readings"] == 40 and adapter.health.counts["surplus_readings"] == 40


def test_soft_evidence_through_the_adapter_matches_the_hard_observation_it_encodes():
    """A sensor that reports the column ``O[a][:, z]`` of the model's own observation gives the
    beliefs of the hard observation ``z`` (to rounding)."""
    prior = np.full(3, 1 / 3)
    rng = np.random.default_rng(3)
    adapter = make(input_type="likelihood")
    soft = FilterLoop(MODEL, [], prior, [], LIVE, now=T0, likelihood_topics=["likelihood"])
    hard = FilterLoop(MODEL, [MODEL.O], prior, ["observation"], LIVE, now=T0)
    soft.start(T0)
    hard.start(T0)
    now = T0
    for t in range(1, 31):
        p, z = int(rng.integers(1, 4)), int(rng.integers(0, 3))
        now += 0.3
        out = adapter.action(ActionSample(t, p), now)
        if out.join_at is not None:
            now = out.join_at
            adapter.join_due(now)
        (sample,) = adapter.measurement(list(MODEL.O[p - 1][:, z]), now + 0.01).samples
        (got,) = soft.observation(0, sample, now).beliefs
        (want,) = hard.observation(0, ObservationSample(t, p, z), now).beliefs
        assert got.epoch == want.epoch == t
        np.testing.assert_allclose(got.belief, want.belief, rtol=1e-12, atol=1e-15)


def test_actions_slower_than_the_sensor_are_one_warning():
    """Rule "Pace": a reading every 0.1 s answering an action every 0.1 s is no warning; once the
    actions come every 0.3 s (decisions longer than the sensor period) the unused readings in
    between are one warning naming both periods, and no second one."""
    loop = joined(1, 2, max_age=0.0)
    now, epoch, lines = T0 + 1.0, 1, []

    def pace(out):
        return [line.text for line in out.logs if "a decision takes longer than the sensor period" in line.text]

    for _ in range(15):
        now += 0.1
        lines += pace(loop.measurement(1.0, now))  # answers the pending action
        epoch += 1
        lines += pace(loop.action(ActionSample(epoch, 2), now + 0.01))
    assert lines == [] and loop.health.counts["surplus_readings"] == 0
    for k in range(1, 61):
        now += 0.1
        lines += pace(loop.measurement(1.0, now))
        if k % 3 == 0:
            epoch += 1
            lines += pace(loop.action(ActionSample(epoch, 2), now + 0.01))
    assert loop.health.counts["surplus_readings"] == 40
    assert len(lines) == 1, lines
    # warned as the median of the last 20 action intervals (0.1 s, then 0.3 s) passed 1.5 x 0.1 s
    assert lines[0].startswith("actions come every 0.2 s, measurement readings every 0.1 s (median, mean)")
    assert "keep the planner's time_budget below the sensor period" in lines[0]
