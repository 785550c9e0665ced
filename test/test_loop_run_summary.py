"""The demo's per-row facts and summary (core/loop/run_summary.py) against a direct computation
from the model's matrices: Shannon entropy, the reward with the true state, the greedy priority,
the counts over the decisions with a plan_info and the open bound widths."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.io.paths import shipped_model_path
from pomdp_planner.core.loop import PlanInfo
from pomdp_planner.core.loop.recorder_loop import RecordRow
from pomdp_planner.core.loop.run_summary import RunSummary

MODEL = load_model(shipped_model_path("perimeter_s3"))  # Renyi-2 uncertainty, three priorities


def plan_info(epoch: int, priority: int, bounds: tuple[int, int] | None, miss: bool) -> PlanInfo:
    lo, hi = bounds if bounds is not None else (math.nan, math.nan)
    return PlanInfo(epoch=epoch, action_priority=priority, depth=2, nodes_expanded=5, pruned_percent=0.0,
                    certified=bounds is not None and lo == hi, time_used=0.001, latency=0.002, deadline_hit=False,
                    deadline_miss=miss, bound_lower=float(lo), bound_upper=float(hi))


rows = st.lists(st.tuples(
    st.lists(st.floats(0.01, 1.0), min_size=3, max_size=3),  # belief weights
    st.one_of(st.none(), st.integers(0, 2)),                   # true state
    st.integers(1, 3),                                         # priority chosen
    st.one_of(st.none(), st.sampled_from([(1, 1), (1, 2), (2, 3), (1, 3), (3, 3)])),  # root bounds
    st.booleans(), st.booleans()), min_size=1, max_size=12)   # has plan_info, deadline miss


@settings(max_examples=60, deadline=None)
@given(rows)
def test_facts_and_sums_match_a_direct_computation(spec):
    m, summary = MODEL, RunSummary(MODEL)
    rewards, entropies, not_greedy, decisions, misses, certified, widths = [], [], 0, 0, 0, 0, set()
    for t, (weights, s, p, bounds, has_info, miss) in enumerate(spec):
        b = np.array(weights) / sum(weights)
        info = plan_info(t + 1, p, bounds, miss) if has_info else None
        facts = summary.add(RecordRow(t, b, p, s, info))
        f = -math.log(float(np.sum(b * b)))  # Renyi quadratic entropy, written out
        rho = [float(b @ m.r[:, a]) - m.w[a] * f for a in range(m.A)]
        greedy = 1 + max(range(m.A), key=lambda a: (rho[a], -a))  # ties: the greatest priority
        assert facts.greedy == greedy and facts.priority == p and facts.epoch == t and facts.info is info
        assert facts.mode == int(np.argmax(b)) and facts.p_mode == b.max()
        h = -sum(x * math.log(x) for x in b)
        assert math.isclose(facts.entropy, h, rel_tol=1e-12)
        entropies.append(h)
        if s is not None:
            rewards.append(m.r[s, p - 1] - m.w[p - 1] * f)
        not_greedy += greedy != p
        if info is not None:
            decisions += 1
            misses += miss
            certified += info.certified
            if bounds is not None and bounds[1] > bounds[0]:
                widths.add(bounds[1] - bounds[0] + 1)
    assert summary.shown == len(spec) and summary.not_greedy == not_greedy
    assert (summary.decisions, summary.misses, summary.certified) == (decisions, misses, certified)
    assert summary.open_widths == widths
    assert math.isclose(summary.mean_entropy, sum(entropies) / len(entropies), rel_tol=1e-12)
    if rewards:
        assert math.isclose(summary.mean_reward, sum(rewards) / len(rewards), rel_tol=1e-9, abs_tol=1e-12)
    else:
        assert summary.mean_reward is None
