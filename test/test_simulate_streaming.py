"""``simulate`` streams its steps: constant memory for any ``--steps``.

The core's :class:`~pomdp_planner.core.simulate.Simulation` yields the steps one at a time and
the command line prints each as it comes, keeping only running sums. Checked here:

* the streamed steps are the steps of :func:`~pomdp_planner.core.simulate.simulate` (same seed),
  and the running summary equals the summary computed from the stored arrays (vectorised dot
  products and means: a second computation);
* ``tracemalloc`` peaks (numpy reports its buffers to it) of a run of 10x the steps are no larger
  than those of the short run, for the core iterator and for ``main(["simulate", ...])`` in both
  output modes; the stored trace of the same long run does grow (so the measurement can tell);
* the streamed JSON is one valid object equal to the trace's ``to_dict``;
* ``simulate ... | head`` stops a run of 10^8 steps at once and quietly (no traceback, no
  "Exception ignored"), which a run that first computes every step could not do.
"""

from __future__ import annotations

import io
import json
import subprocess
import sys
import tracemalloc
from collections.abc import Callable
from contextlib import redirect_stdout
from pathlib import Path

import numpy as np
import pytest

from pomdp_planner.cli import main
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import POMDP
from pomdp_planner.core.simulate import RunningSummary, Simulation, simulate

ROOT = Path(__file__).resolve().parents[1]
S2 = str(ROOT / "config/models/tracking_s2_info.yaml")
S3 = str(ROOT / "config/models/tracking_s3_info.yaml")
SHORT, LONG = 500, 5000


class Sink(io.TextIOBase):
    """A stdout that keeps nothing (counts the characters written)."""

    def __init__(self) -> None:
        self.chars = 0

    def writable(self) -> bool:
        return True

    def write(self, s: str) -> int:
        self.chars += len(s)
        return len(s)


def traced_peak(fn: Callable[[], object]) -> int:
    fn()  # warm-up: caches, lazy imports
    tracemalloc.start()
    try:
        fn()
        return tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


@pytest.fixture(scope="module")
def s2() -> POMDP:
    return load_model(S2)


@pytest.mark.parametrize("policy", ["myopic", "random"])
def test_streamed_steps_are_the_trace(policy: str) -> None:
    model = load_model(S3)
    trace = simulate(model, policy, 80, seed=7)
    run = Simulation(model, policy, 80, seed=7)
    summary = RunningSummary(model.gamma)
    np.testing.assert_array_equal(run.initial_belief, trace.beliefs[0])
    count = 0
    for st in run:
        summary.add(st)
        t = st.t
        assert (st.state, st.next_state, st.action, st.observation) == (
            trace.states[t], trace.next_states[t], trace.actions[t], trace.observations[t])
        np.testing.assert_array_equal(st.belief, trace.beliefs[t + 1])
        assert st.reward == trace.rewards[t] and st.state_reward == trace.state_rewards[t]
        assert st.entropy == pytest.approx(trace.entropies[t], abs=1e-15)
        count += 1
    assert count == 80
    expected = trace.summary()
    got = summary.summary()
    assert set(got) == set(expected)
    for key, value in expected.items():
        assert got[key] == pytest.approx(value, rel=1e-12, abs=1e-12), key
    with pytest.raises(RuntimeError, match="once"):
        iter(run)


def test_running_summary_counts_recoveries_and_empty_runs() -> None:
    m = POMDP(P=np.eye(2)[None], O=np.eye(2)[None], r=np.zeros((2, 1)), gamma=0.5)
    summary = RunningSummary(m.gamma)
    for st in Simulation(m, lambda b: 0, 3, seed=0, initial_state=1, initial_belief=[1.0, 0.0]):
        summary.add(st)
    assert summary.summary()["recovered_steps"] == 1
    empty = RunningSummary(0.9).summary()
    assert empty["steps"] == 0 and np.isnan(empty["mean_reward"]) and empty["discounted_return"] == 0.0


def test_core_iterator_memory_does_not_grow_with_the_steps(s2: POMDP) -> None:
    def stream(n: int) -> Callable[[], object]:
        def go() -> None:
            summary = RunningSummary(s2.gamma)
            for st in Simulation(s2, "myopic", n, seed=1):
                summary.add(st)
        return go

    short, long = traced_peak(stream(SHORT)), traced_peak(stream(LONG))
    assert long <= short + 16 * 2**10, (short, long)
    stored = traced_peak(lambda: simulate(s2, "myopic", LONG, seed=1))
    assert stored > long + 100 * 2**10  # the stored trace grows: the measurement can tell


@pytest.mark.parametrize("json_output", [False, True])
def test_cli_memory_does_not_grow_with_the_steps(json_output: bool) -> None:
    def cli(n: int) -> Callable[[], object]:
        def go() -> None:
            sink = Sink()
            argv = ["simulate", S2, "--steps", str(n), "--seed", "3"] + (["--json"] if json_output else [])
            with redirect_stdout(sink):
                assert main(argv) == 0
            assert sink.chars > 60 * n
        return go

    short, long = traced_peak(cli(SHORT)), traced_peak(cli(LONG))
    assert long <= short + 64 * 2**10, (short, long)


def test_streamed_json_is_the_trace(capsys: pytest.CaptureFixture[str]) -> None:
    model = load_model(S3)
    for steps in (0, 1, 9):
        assert main(["simulate", S3, "--steps", str(steps), "--seed", "5", "--policy", "random", "--json"]) == 0
        data = json.loads(capsys.readouterr().out)
        expected = simulate(model, "random", steps, seed=5).to_dict(model.state_names, model.observation_names)
        assert data["steps"] == expected["steps"]
        assert data["initial_belief"] == expected["initial_belief"]
        for key, value in expected["summary"].items():
            assert data["summary"][key] == (None if value != value else pytest.approx(value, rel=1e-12, abs=1e-12))
        assert data["policy"] == "random" and data["seed"] == 5 and data["model"] == model.name


def test_text_rows_line_up_with_the_header(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", S3, "--steps", "12", "--seed", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("step"))
    rule = lines[header + 1]
    rows = lines[header + 2:header + 14]
    assert [int(r.split()[0]) for r in rows] == list(range(12))
    assert all(len(r) == len(rule) for r in rows)  # fixed widths although the rows were never measured


def test_head_stops_a_huge_run_quietly() -> None:
    proc = subprocess.Popen([sys.executable, "-m", "pomdp_planner", "simulate", S2, "--steps", str(10**8), "--json"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = [proc.stdout.readline() for _ in range(8)]
        proc.stdout.close()  # what `| head` does
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert first[0] == "{\n" and '"steps": [' in "".join(first)
    assert proc.returncode == 0, err
    assert "Traceback" not in err and "Exception ignored" not in err
