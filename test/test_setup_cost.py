"""Set-up cost: the planner's set-up (assumption check, bound LP, planner tables) is estimated before
it runs, refused with the figures when it cannot fit or would take too long, and announced when
it is long (core/gate.py, core/structure.py, core/bounds.py, core/search.py; the CLI prints).

* Memory estimates against ``tracemalloc`` peaks of the real computations (upper estimates,
  not far above).
* ``plan`` / ``simulate`` on a generator model S = 400, A = 40 (its tables alone need over 2 GiB):
  refused in one line with the figure when less memory is available, before any check.
* A model whose assumption check is expected to take tens of minutes (perimeter, S = 100: above
  the exact test's size, the counterexample search runs per matrix): refused with the expected
  time unless the limit is lifted; then announced on stderr before the check starts.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from test_simulate_streaming import traced_peak  # tracemalloc peak of a call (after a warm-up call)

from pomdp_planner.cli import main
from pomdp_planner.core import gate, search_kernel
from pomdp_planner.core.bounds import estimate_solve_bounds, solve_bounds
from pomdp_planner.core.domains.comparison import comparison_model
from pomdp_planner.core.domains.perimeter import PRESETS, perimeter_model
from pomdp_planner.core.io.cassandra import export_pomdp
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import POMDP, ModelError
from pomdp_planner.core.search import Planner, planner_table_bytes
from pomdp_planner.core.structure import check_assumptions, check_copositivity, estimate_check, seconds_text

ROOT = Path(__file__).resolve().parents[1]
S8 = str(ROOT / "config/models/tracking_s8_info.yaml")
GRID10 = str(ROOT / "config/models/grid_10x10.yaml")
GIB = 2**30


def random_model(S: int, A: int, Z: int, seed: int = 0) -> POMDP:
    rng = np.random.default_rng(seed)
    return POMDP(P=rng.dirichlet(np.ones(S), size=(A, S)), O=rng.dirichlet(np.ones(Z), size=(A, S)),
                 r=rng.normal(size=(S, A)), gamma=0.9, uncertainty="renyi2", w=[0.1] * A)


def perimeter(S: int) -> POMDP:
    return perimeter_model(**(PRESETS["perimeter_s8"] | {"S": S}), name=f"perimeter_s{S}")


# ------------------------------------------------------------------ estimates vs measured memory
@pytest.mark.parametrize("S,A,Z", [(3, 3, 3), (8, 3, 8), (40, 12, 30), (64, 16, 64), (20, 2, 50)])
def test_planner_table_estimate_is_an_upper_estimate_of_the_real_peak(S, A, Z):
    model = random_model(S, A, Z)
    peak = traced_peak(lambda: Planner(model))
    est = planner_table_bytes(S, A, Z)
    assert peak <= est <= 1.5 * peak + 16 * 2**10
    assert est >= 8 * A * (A + 1) * Z * S  # the fused leaf table alone (core/search.py module docstring)


@pytest.mark.parametrize("model", [perimeter(16), perimeter(32), comparison_model(64, 16), random_model(6, 3, 4),
                                   load_model(S8)], ids=lambda m: m.name)
def test_check_estimate_bounds_the_check_memory_and_counts_the_matrices_it_builds(model):
    est = estimate_check(model)
    assert traced_peak(lambda: check_assumptions(model)) <= est.bytes
    rep = check_copositivity(model)
    built = int(np.count_nonzero(~np.isnan(rep.min_entry)))
    if est.pairs <= 32:  # every undecided (j, a) sampled: the count is exact
        assert est.dirty == built
    assert est.seconds <= est.seconds_max


@pytest.mark.parametrize("model", [comparison_model(64, 16), perimeter(32), random_model(24, 4, 5)],
                         ids=lambda m: m.name)
def test_lp_estimate_bounds_the_lp_memory(model):
    _, est = estimate_solve_bounds(model)
    assert traced_peak(lambda: solve_bounds(model, "tight")) <= est


def test_available_memory_is_read():
    mem = gate.available_memory()
    assert mem is None or mem > 0


# ------------------------------------------------------------------ refusals and notices
@pytest.fixture(scope="module")
def big_generator(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("models") / "gen_s400_a40.yaml"
    path.write_text("name: gen_s400_a40\ndiscount: 0.95\ngenerator: {domain: tracking, S: 400, A: 40, q: 0.8}\n"
                    "reward_generator: {kind: tracking_comparison}\nuncertainty: {function: renyi2, weights: 0.5}\n")
    return str(path)


@pytest.fixture(scope="module")
def slow_check_model(tmp_path_factory) -> str:
    path = tmp_path_factory.mktemp("models") / "perimeter_s100.POMDP"  # reads faster than YAML
    path.write_text(export_pomdp(perimeter(100)))
    return str(path)


def no_check(monkeypatch: pytest.MonkeyPatch) -> None:
    """The assumption check must not run (a refusal comes before it); if it starts, stop with a marker."""
    def stop(*args, **kwargs):
        raise ModelError("CHECK STARTED")
    monkeypatch.setattr(gate, "check_assumptions", stop)


@pytest.mark.parametrize("argv", [["plan", "--time-budget", "1"], ["plan", "--exhaustive", "--depth", "1"],
                                  ["simulate", "--policy", "bnb", "--steps", "1"]])
def test_a_setup_beyond_the_available_memory_is_refused_with_the_figure(big_generator, argv, capsys, monkeypatch):
    monkeypatch.setattr(gate, "available_memory", lambda: 64 * 2**20)
    no_check(monkeypatch)
    code = main([argv[0], big_generator, *argv[1:]])
    out, err = capsys.readouterr()
    assert code == 2 and out == ""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err and "CHECK STARTED" not in err
    head = "pomdp-planner: error: model: the planner's set-up for S=400, A=40, Z=400 needs about "
    assert lines[0].startswith(head) and lines[0].endswith("more than the 64 MiB of memory available")
    figure, unit = lines[0][len(head):].split()[:2]
    S, A, Z = 400, 40, 400
    if search_kernel.available():  # the kernel's planner: O transposed, the Renyi leaf table (MiB)
        held = 8 * A * S * 2 * Z / 2**20
    else:  # the numpy engine's: P transposed, O transposed twice, the Renyi leaf table
        held = 8 * A * S * (S + 3 * Z) / 2**20
    fused = 8 * A * (A + 1) * Z * S / 2**20  # the fused leaf table, not built at this size
    assert unit == "MiB" and held <= float(figure) < fused
    if "--exhaustive" in argv:  # no assumption check: the tables are the figure
        assert float(figure) <= 2 * held
    assert "planner tables" in lines[0]


@pytest.mark.parametrize("fused", [True, False])
def test_the_fused_leaf_table_is_built_only_when_small_or_asked_for(fused):
    """Beyond FUSED_TABLE_MAX_BYTES the planner keeps no A (A + 1) Z S table; the estimate says so."""
    S, A, Z = 64, 16, 64
    model = random_model(S, A, Z)
    auto = Planner(model)
    assert auto.fused and planner_table_bytes(S, A, Z) >= 8 * A * (A + 1) * Z * S  # 8.9 MB: under the limit
    peak = traced_peak(lambda: Planner(model, fused=fused))
    est = planner_table_bytes(S, A, Z, fused=fused)
    assert peak <= est <= 1.5 * peak + 16 * 2**10
    assert (est >= 8 * A * (A + 1) * Z * S) == fused


def test_a_setup_expected_to_take_too_long_is_refused_with_the_expected_time(slow_check_model, capsys,
                                                                            monkeypatch):
    no_check(monkeypatch)
    est = gate.estimate_setup(load_model(slow_check_model))
    assert est.seconds > gate.MAX_SETUP_SECONDS  # the premise: S = 100 > EXACT_MAX_STATES, search per matrix
    code = main(["plan", slow_check_model, "--time-budget", "0.1"])
    _, err = capsys.readouterr()
    assert code == 2 and len(err.strip().splitlines()) == 1 and "CHECK STARTED" not in err
    assert f"is expected to take {seconds_text(est.seconds)} (assumption check about" in err
    assert "more than the limit of 10 min (MAX_SETUP_SECONDS); --no-limit lifts the limit" in err
    code = main(["simulate", slow_check_model, "--policy", "bnb", "--steps", "1"])
    _, err = capsys.readouterr()
    assert code == 2 and "MAX_SETUP_SECONDS); the option no_limit=1 lifts the limit" in err


@pytest.mark.parametrize("argv", [["plan", "--time-budget", "0.1", "--no-limit"],
                                  ["simulate", "--policy", "bnb", "--option", "no_limit=1", "--steps", "1"]])
def test_a_long_setup_is_announced_before_it_starts(slow_check_model, argv, capsys, monkeypatch):
    no_check(monkeypatch)
    est = gate.estimate_setup(load_model(slow_check_model))
    code = main([argv[0], slow_check_model, *argv[1:]])
    _, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 2 and lines[1].endswith("CHECK STARTED")  # the notice came first
    assert lines[0].startswith(f"pomdp-planner {argv[0]}: set-up for S=100, A=3, Z=100 is running, expected about "
                               f"{seconds_text(est.seconds)} before the first decision (assumption check about ")
    assert lines[0].endswith("no time budget includes it")


def test_check_announces_a_long_check(slow_check_model, capsys, monkeypatch):
    import pomdp_planner.cli.check as check_cli

    monkeypatch.setattr(check_cli, "check_assumptions", lambda *a, **k: (_ for _ in ()).throw(ModelError("STOP")))
    code = main(["check", slow_check_model])
    _, err = capsys.readouterr()
    lines = err.strip().splitlines()
    est = estimate_check(load_model(slow_check_model))
    assert code == 2 and lines[1].endswith("STOP")
    assert lines[0] == f"pomdp-planner check: checking Assumption 1 for S=100, A=3, Z=100: expected {est.describe()}"


def test_a_short_setup_says_nothing(capsys):
    assert main(["plan", S8, "--depth", "2"]) == 0
    assert main(["check", S8]) == 0
    assert capsys.readouterr().err == ""


# ------------------------------------------------------------------ what the estimate counts
def test_no_lp_is_counted_when_assumption_1_is_known_to_fail():
    """A negative 2x2 minor found in one pass proves (A1) fails: no LP will be solved, none is counted
    (it was counted before, refusing grid models that set up in seconds); forced pruning solves it."""
    for model in (random_model(24, 4, 5), load_model(GRID10)):
        gate._reports.clear()
        est = gate.estimate_setup(model)
        assert est.lp_seconds == 0.0 and est.lp_bytes == 0 and est.no_lp.startswith("(A1) fails: the ")
        assert f"no bound LP ({est.no_lp})" in est.parts()
        setup = gate.build_planner(model)
        assert setup.mode == "exhaustive" and "bound LP" not in setup.seconds and not setup.report.holds
        assert gate.estimate_setup(model, forced=True).lp_seconds > 0.0
        cached = gate.estimate_setup(model)  # from the cached report now: no check, no LP
        assert cached.check is None and cached.lp_seconds == 0.0 and cached.no_lp.startswith("Assumption 1 fails")
    holds = load_model(S8)
    gate._reports.clear()
    est = gate.estimate_setup(holds)
    assert est.no_lp == "" and est.lp_seconds > 0.0


def test_sparse_check_estimate_bounds_its_memory_and_counts_frames():
    model = load_model(ROOT / "config/models/grid_40x40.yaml")
    assert model.sparse
    est = estimate_check(model)
    assert traced_peak(lambda: check_assumptions(model)) <= est.bytes < 2**28
    rep = check_copositivity(model)
    assert est.dirty == int(np.count_nonzero(
        np.asarray(model.O_csr[0][1:].multiply(model.O_csr[1][:-1]).toarray()) > 0)) + int(np.count_nonzero(
        np.asarray(model.O_csr[1][1:].multiply(model.O_csr[2][:-1]).toarray()) > 0))
    assert rep.codes.size <= est.dirty  # the candidates (beta > 0) bound the matrices built
    setup = gate.estimate_setup(model)
    nnz = model.P_csr.nnz + model.O_csr.nnz
    assert setup.dense_bytes == 0 and setup.sparse_search  # the kernel searches the non-zeros
    assert setup.table_bytes < 30 * nnz + 2**20 < 8 * 3 * 1600 * 1600
    assert "planner tables" in setup.parts() and "the non-zeros of P and O" in setup.parts()


def test_the_kernel_searches_a_sparse_model_of_any_size_without_dense_matrices():
    from pomdp_planner.core.domains.grid import grid_model

    model = grid_model(100, 100)  # dense P and O would take 2.24 GiB
    setup = gate.build_planner(model, use_bounds=False)
    assert setup.planner.kernel == "c"
    assert "P" not in vars(model) and "O" not in vars(model)  # no dense view was built
    res = setup.planner.search(np.full(model.S, 1 / model.S), 1, use_bounds=False)
    assert res.nodes_expanded == (1 + 3 * model.Z,) and np.all(np.isfinite(res.q_values))


def test_without_the_kernel_a_sparse_model_too_large_for_the_dense_search_is_refused_before_the_check(monkeypatch):
    no_check(monkeypatch)
    from pomdp_planner.core.domains.grid import grid_model

    monkeypatch.setattr(search_kernel, "searches", lambda model: False)
    model = grid_model(100, 100)
    est = gate.estimate_setup(model)
    assert est.dense_bytes == 8 * 3 * 10_000 * (10_000 + 10_001) and not est.sparse_search
    with pytest.raises(gate.SetupCostError, match=r"^model: the search takes the dense P and O of this sparse model "
                       r"\(S=10000, A=3, Z=10001\): 2.24 GiB for the larger, more than the limit of 128 MiB "
                       r"\(MAX_DENSE_BYTES\)$"):
        gate.build_planner(model)


def test_the_planner_loop_takes_the_set_up_limit_of_its_node():
    from pomdp_planner.core.loop import Liveness, PlannerLoop
    from pomdp_planner.core.loop.planner_loop import SETUP_HINT, setup_limit

    assert setup_limit(0.0) is None and setup_limit(30.0) == 30.0
    params = {"time_budget": 0.1, "max_depth": 2, "use_bounds": True, "bound_variant": "tight",
              "bound_constant": "mlr", "deadline_slack": 0.02}
    model = comparison_model(64, 16)
    gate._reports.clear()
    with pytest.raises(gate.SetupCostError, match=r"more than the limit of 0.1 s \(MAX_SETUP_SECONDS\); "
                       + re.escape(SETUP_HINT) + "$"):
        PlannerLoop(model, params, Liveness(), now=0.0, max_setup_seconds=1e-6)
    loop = PlannerLoop(model, params, Liveness(), now=0.0, max_setup_seconds=None)
    assert loop.setup.mode == "prune"
