"""Smoke test of `pomdp-planner bench all --quick`: the whole pipeline at toy sizes.

Runs every experiment once into a temporary directory (about a minute on 2 cores) and checks
what a reader of docs/RESULTS.md relies on: all files are produced, every table is complete,
numbers are in their valid ranges (percentages in [0, 100], min <= avg <= max, confidence
intervals contain their means, lower <= upper), the theory holds where we can check it
(no belief with the optimum outside [lower, upper]) and the PNGs are real images.

matplotlib is a test dependency (``make test`` installs the ``experiments`` extra); without it
the test is skipped, unless ``POMDP_PLANNER_REQUIRE_INSTALLED=1`` (set by ``make test``), where
it fails instead.
"""

from __future__ import annotations

import os
import re

import numpy as np
import pytest

if os.environ.get("POMDP_PLANNER_REQUIRE_INSTALLED") == "1":
    import matplotlib  # noqa: F401 - must be installed under `make test`
else:
    pytest.importorskip("matplotlib")

from pomdp_planner.bench.experiments.peer_policies import mcts_available
from pomdp_planner.bench.experiments.pouct import pouct_available
from pomdp_planner.bench.experiments.report import render_report
from pomdp_planner.bench.experiments.runner import CACHE_DIR, QUICK, SECTIONS, run_all
from pomdp_planner.cli import main


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("results")
    data = run_all(out, quick=True, progress=False)
    return out, data


def test_files_are_produced(quick_run):
    out, _ = quick_run
    text = (out / "RESULTS.md").read_text()
    for heading in ("## Fig. 1", "## Fig. 3", "## Table II", "## A non-trivial Sec. VI-B model", "## Table III",
                    "## Looseness", "## Against peers", "## When to use what"):
        assert heading in text
    assert "quick" in text.lower()  # a quick report says so
    images = sorted(p.name for p in (out / "img").glob("*.png"))
    assert images == ["fig1_policy_bounds_s3.png", "fig3_rewards_s2.png", "fig4_looseness.png",
                      "peers_return_regret.png"]
    for name in images:
        assert f"img/{name}" in text


def test_pngs_are_valid_images(quick_run):
    import matplotlib.image as mpimg

    out, _ = quick_run
    for png in (out / "img").glob("*.png"):
        raw = png.read_bytes()
        assert raw[:8] == b"\x89PNG\r\n\x1a\n"
        assert len(raw) < 300_000
        img = mpimg.imread(png)
        assert img.ndim == 3 and img.shape[0] > 100 and img.shape[1] > 100
        assert np.ptp(img[..., :3]) > 0.5  # not a blank canvas


def test_markdown_tables_are_complete(quick_run):
    out, _ = quick_run
    for line in (out / "RESULTS.md").read_text().splitlines():
        if line.startswith("|") and not line.startswith("|---"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            assert all(cells[1:]), f"empty cell in table row: {line}"
            assert "nan" not in line.lower(), line


def test_bound_figures_respect_the_theory(quick_run):
    _, data = quick_run
    for key in ("fig1", "fig3"):
        d = data[key]
        assert d["violations"] == 0
        assert 0.0 <= d["agree_fraction"] <= 1.0
    assert data["fig3"]["lower_increasing"] and data["fig3"]["upper_decreasing"]
    f1 = data["fig1"]
    assert f1["agree_and_correct"] == f1["agree_decided"]


def test_table2_percentages(quick_run):
    _, data = quick_run
    for r in data["table2"]["models"]:
        assert r["bounds_feasible"]
        for p in r["pruning"]:
            assert 0.0 <= p["percent_pruned_min"] <= p["percent_pruned_mean"] <= p["percent_pruned_max"] <= 100.0
            assert p["beliefs"] >= 1


def test_table3_cells_valid(quick_run):
    _, data = quick_run
    for variant, v in data["table3"].items():
        cells = v["cells"]
        assert {(c.S, c.A) for c in cells} == {(S, A) for S in QUICK.table3_states for A in QUICK.table3_actions}
        for c in cells:
            assert c.feasible, (variant, c.S, c.A, c.message)
            lo, avg, hi = c.pct
            assert 0.0 <= lo <= avg <= hi <= 100.0
            clo, cavg, chi = c.pct_count
            assert 0.0 <= clo <= cavg <= chi <= 100.0
            assert cavg == pytest.approx(avg - 100.0 / c.A)
            assert c.crossed == 0  # lower <= upper everywhere
            assert c.lp_time >= 0.0
            if c.upper_minus_opt is not None:
                assert c.opt_outside == 0  # optimal action inside [lower, upper]
                assert c.upper_minus_opt >= 0.0 and c.opt_minus_lower >= 0.0


def test_model_check_rows(quick_run):
    _, data = quick_run
    for r in data["model_check"]["rows"]:
        assert sum(r["exact_counts"]) == 500
        if r["natural"]:
            assert r["single_action"] == r["A"]
        else:
            assert r["single_action"] is None
            assert sum(1 for k in r["exact_counts"] if k > 0) >= 2


def test_peer_results_valid(quick_run):
    _, data = quick_run
    peers = data["peers"]
    results = peers["results"]
    expected = {"bnb", "exhaustive", "greedy", "lower-bound", "upper-bound", "random", "optimal"}
    if pouct_available():
        expected.add("pouct")
    if mcts_available():
        expected.add("mcts")
    for m in peers["models"]:  # every planner on every model, every budgeted one at every budget
        rows = [r for r in results if r.model == m]
        assert {r.planner for r in rows} == expected
        for p in ("bnb", "exhaustive", "pouct", "mcts"):
            if p in expected:
                assert sorted(r.budget for r in rows if r.planner == p) == sorted(QUICK.peers_budgets)
    assert set(peers["models"]) | set(peers["missing"]) == set(QUICK.peers_models)
    assert {"tracking_s3_info", "tracking_s8_info"} <= set(peers["models"])
    for r in results:
        assert all(np.isfinite(x) for x in (r.mean, *r.ci))
        assert r.ci[0] <= r.mean <= r.ci[1]
        assert len(r.returns) == r.episodes >= 2
        assert r.mean == pytest.approx(np.mean(r.returns))
        assert 0.0 <= r.time_median <= r.time_p99 and 0.0 <= r.wall_median <= r.wall_p99
        if r.planner in ("bnb", "exhaustive"):
            assert 1.0 <= r.mean_depth <= QUICK.peers_max_depth
        if r.planner in ("pouct", "mcts"):  # depth of a sampled tree, with the simulations per decision
            assert r.mean_depth >= 1.0 and r.mean_sims >= 1
        if r.certified_fraction is not None:
            assert 0.0 <= r.certified_fraction <= 1.0
        # regret columns: present (and finite) exactly on the models with an optimal reference
        has_ref = any(x.planner == "optimal" for x in results if x.model == r.model)
        assert (r.regret is not None) == has_ref
        if has_ref:
            assert all(np.isfinite(x) for x in (r.regret, *r.regret_ci))
            assert r.regret_ci[0] <= r.regret <= r.regret_ci[1]
    assert all(r.regret == 0.0 for r in results if r.planner == "optimal")
    # on S = 3 every B&B decision is certified by the bounds (root bounds agree on the reached beliefs)
    s3 = {(r.planner, r.budget): r for r in results if r.model == "tracking_s3_info"}
    for b in QUICK.peers_budgets:
        assert s3[("bnb", b)].certified_fraction == 1.0
    assert any(r.probes for r in results if r.planner == "bnb")  # B&B vs exhaustive probes were taken


def test_sanity_checks_pass_and_are_reported(quick_run):
    out, data = quick_run
    sanity = data["peers"]["sanity"]
    assert "tracking_s3_info" in sanity["models"]
    checked = {(r.planner, r.budget) for r in sanity["results"] if r.label == r.planner}
    planners = {r.planner for r in data["peers"]["results"]}
    for p in planners:  # every planner of the comparison was checked, the budgeted ones at every budget
        budgets = QUICK.peers_budgets if p in ("bnb", "exhaustive", "pouct", "mcts") else (None,)
        assert all((p, b) in checked for b in budgets), p
    for r in sanity["results"]:
        assert r.checked >= 3 + 1  # vertices and centre at least
        if r.required:
            assert r.passed, (r.label, r.budget, r.correct, r.checked)
    text = (out / "RESULTS.md").read_text()
    assert "### Table S: sanity check" in text and "**FAIL**" not in text
    assert ("POUCT was skipped" in text) != pouct_available()


def test_when_to_use_what_cites_a_table_in_every_bullet(quick_run):
    out, _ = quick_run
    text = (out / "RESULTS.md").read_text()
    section = text[text.index("## When to use what"):]
    bullets = [line for line in section.splitlines() if line.lstrip().startswith("- ")]
    assert bullets
    for line in bullets:
        assert re.search(r"Table (P\d+|S|X|III)", line), line
        assert re.search(r"\d", line), line
    assert "optimises a different objective" not in text  # the old, unsupported claim about POUCT is gone


def test_the_cache_reproduces_the_report_exactly(quick_run, capsys):
    """Every section is cached as JSON (no pickle) and re-rendering from the cache alone gives the
    same report, character for character (the generation time aside, which is the report's own)."""
    out, data = quick_run
    cache = out / CACHE_DIR
    assert sorted(p.name for p in cache.glob("*.json")) == sorted(f"{s}.json" for s in SECTIONS)
    assert not list(cache.rglob("*.pickle")) and list((cache / "peers-chunks").glob("*.json"))
    again = run_all(out, quick=True, progress=False, sections=())
    assert "ignoring" not in capsys.readouterr().err
    assert render_report({**again, "started": data["started"]}) == render_report(data)


def test_cli_bench_all_quick_report_only(quick_run, capsys):
    """`pomdp-planner bench all --report-only` re-renders from the cache without running anything."""
    out, _ = quick_run
    (out / "RESULTS.md").unlink()
    assert main(["bench", "all", "--output", str(out), "--report-only", "--no-progress"]) == 0
    assert "## Table III" in (out / "RESULTS.md").read_text()
    assert "wrote" in capsys.readouterr().out


def test_markdown_numbers_in_range(quick_run):
    """Every '(min, avg, max)' triple printed in RESULTS.md is ordered and within [0, 100]."""
    out, _ = quick_run
    triples = re.findall(r"\((\d+\.?\d*), (\d+\.?\d*), (\d+\.?\d*)\)", (out / "RESULTS.md").read_text())
    assert triples
    for t in triples:
        lo, avg, hi = map(float, t)
        assert 0.0 <= lo <= avg <= hi <= 100.0
