"""The experiments' cache holds data, never code.

Whoever can write into ``bench all``'s output folder can put any file into its cache. Such a
file is never unpickled or executed: a pickle that would create a marker file when loaded is
ignored (the marker never appears), and so are corrupted, tampered, foreign or stale JSON files,
each with one line on stderr and no traceback; the section is reported missing, a peer chunk is
run again. Valid files round-trip every value the experiments produce exactly (NaN and
infinities included).

matplotlib is needed for the report's plots (as in test_experiments_smoke.py).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import pickle
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

if os.environ.get("POMDP_PLANNER_REQUIRE_INSTALLED") == "1":
    import matplotlib  # noqa: F401 - must be installed under `make test`
else:
    pytest.importorskip("matplotlib")

from pomdp_planner.bench.experiments import datafile, peers
from pomdp_planner.bench.experiments.datafile import CacheError, decode, encode, load_entry, write_entry
from pomdp_planner.bench.experiments.peer_policies import ProbeConfig
from pomdp_planner.bench.experiments.peers import PeerChunk, PeerPlan, PeerResult, compare_peers
from pomdp_planner.bench.experiments.pruning import PruningCell
from pomdp_planner.bench.experiments.runner import CACHE_DIR, QUICK, run_all, section_signature
from pomdp_planner.cli import main
from pomdp_planner.core.io.model_yaml import load_model
from pomdp_planner.core.model import model_digest

MODELS = Path(__file__).resolve().parents[1] / "config" / "models"
S3 = load_model(MODELS / "tracking_s3_info.yaml")


class _Marker:
    """Unpickling this object creates the file ``path`` (what a malicious pickle could do)."""

    def __init__(self, path: Path) -> None:
        self.path = str(path)

    def __reduce__(self):
        return (open, (self.path, "w"))


def _malicious(path: Path, marker: Path) -> None:
    path.write_bytes(pickle.dumps({"data": _Marker(marker)}))


def _same(a, b) -> bool:
    """Equal values, NaN equal to NaN, -0.0 told from 0.0, tuples told from lists, dtypes compared."""
    if type(a) is not type(b):
        return False
    if isinstance(a, float):
        return (math.isnan(a) and math.isnan(b)) or (a == b and math.copysign(1, a) == math.copysign(1, b))
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and a.shape == b.shape and np.array_equal(a, b, equal_nan=a.dtype.kind == "f")
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, dict):
        return list(a) == list(b) and all(_same(a[k], b[k]) for k in a)
    if dataclasses.is_dataclass(a):
        return all(_same(getattr(a, f.name), getattr(b, f.name)) for f in dataclasses.fields(a))
    return a == b


# ------------------------------------------------------------------ values round-trip exactly
_floats = st.floats(allow_nan=True, allow_infinity=True)
_keys = st.one_of(st.text(max_size=6), st.floats(allow_nan=False), st.integers(), st.none())
_arrays = st.one_of(
    st.lists(_floats, max_size=6).map(lambda x: np.array(x, dtype=float)),
    st.lists(st.integers(-2**62, 2**62), min_size=1, max_size=6).map(lambda x: np.array(x).reshape(1, -1)),
    st.lists(st.booleans(), max_size=4).map(np.array), st.just(np.zeros((0, 3))))
_leaves = st.one_of(st.none(), st.booleans(), st.integers(), _floats, st.text(max_size=8), _arrays)
_values = st.recursive(_leaves, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.lists(inner, max_size=4).map(tuple),
    st.dictionaries(_keys, inner, max_size=4)), max_leaves=20)


@given(_values)
def test_every_value_round_trips_through_a_file(tmp_path_factory, value) -> None:
    path = tmp_path_factory.mktemp("v") / "x.json"
    write_entry(path, {"plan": 1}, value)
    assert _same(load_entry(path, [{"plan": 1}]), value)
    json.loads(path.read_text())  # a JSON document (with NaN / Infinity where floats are not finite)


def test_result_rows_round_trip_and_other_objects_are_refused() -> None:
    cell = PruningCell(S=4, A=8, feasible=True, pct=(12.5, 50.0, 100.0), mean_width=float("nan"),
                       extra={"cell_time": 0.25})
    row = PeerResult("m", "bnb", 0.01, 2, 5, 1.5, (1.0, 2.0), 0.5, 0.1, 0.2, 0.1, 0.2, 1.5, 2, None,
                     regret=-0.0, regret_ci=(-math.inf, math.inf), returns=[1.0, 2.0])
    back = decode(json.loads(json.dumps(encode({"cells": [cell], "rows": [row]}))))
    assert _same(back, {"cells": [cell], "rows": [row]})
    for bad in (object(), {1, 2}, np.array(["text"]), S3, _Marker("x")):
        with pytest.raises(CacheError):
            encode(bad)


@pytest.mark.parametrize("doc", [
    {"__dataclass__": "POMDP", "fields": {}},  # not an allowed class
    {"__dataclass__": "PruningCell", "fields": {"S": 1}},  # required fields missing
    {"__dataclass__": "PruningCell", "fields": {"S": 1, "A": 1, "feasible": True, "evil": 1}},
    {"__ndarray__": [1, 2], "dtype": "object", "shape": [2]},
    {"__ndarray__": [1, 2], "dtype": "float64", "shape": [3]},
    {"__reduce__": ["os.system", "touch x"]},
    {"__tuple__": 5}, {"__dict__": [[[1], 2]]},
])
def test_unknown_tags_classes_and_dtypes_are_refused(doc) -> None:
    with pytest.raises(CacheError):
        decode(doc)


# ------------------------------------------------------------------ files that are not used
def _rewrite(path: Path, change, source: Path | None = None) -> None:
    doc = json.loads((source or path).read_text())
    change(doc)
    path.write_text(json.dumps(doc))


def test_bad_files_are_ignored_with_one_line_each(tmp_path, capsys) -> None:
    good = tmp_path / "good.json"
    write_entry(good, {"plan": 1}, {"x": [1.0, float("nan")]})
    cases = {
        "truncated": lambda p: p.write_text(good.read_text()[:-7]),
        "binary": lambda p: p.write_bytes(b"\x80\x04\x95\xff\x00garbage"),
        "pickle": lambda p: _malicious(p, tmp_path / "MARKER"),
        "other version": lambda p: _rewrite(p, lambda d: d.update(version=0), good),
        "other plan": lambda p: _rewrite(p, lambda d: d.update(signature={"plan": 2}), good),
        "tampered": lambda p: _rewrite(p, lambda d: d["payload"].update(x=[2.0]), good),
        "non-standard constant": lambda p: p.write_text(good.read_text().replace("NaN", "nan")),
        "duplicate key": lambda p: p.write_text(good.read_text().replace('{"format"', '{"version":1,"format"')),
        "nested": lambda p: p.write_text("[" * 100_000 + "]" * 100_000),
    }
    for name, make in cases.items():
        path = tmp_path / f"{name}.json"
        make(path)
        assert datafile.read_entry(path, [{"plan": 1}], then="recomputed") is None, name
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "ignoring cache file" in err and "recomputed" in err, (name, err)
        assert "Traceback" not in err
    assert not (tmp_path / "MARKER").exists()
    assert datafile.read_entry(tmp_path / "absent.json", [{"plan": 1}]) is None
    assert capsys.readouterr().err == ""  # a missing file is not worth a line


def test_report_only_never_loads_a_planted_pickle_and_skips_broken_sections(tmp_path, capsys) -> None:
    out = tmp_path / "out"
    run_all(out, quick=True, progress=False, sections=("fig3",))
    cache = out / CACHE_DIR
    assert (cache / "fig3.json").is_file() and not list(cache.glob("*.pickle"))
    marker = tmp_path / "MARKER"
    _malicious(cache / "fig1.pickle", marker)  # the old format's name ...
    _malicious(cache / "fig1.json", marker)  # ... and the new one's
    (cache / "table2.json").write_text('{"format": "pomdp_planner.experiments-cache", "version": 1, ')  # cut short
    capsys.readouterr()
    assert main(["bench", "all", "--output", str(out), "--report-only", "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert not marker.exists()
    text = (out / "RESULTS.md").read_text()
    assert "## Fig. 3" in text and "## Fig. 1" not in text and "## Table II" not in text  # reported missing
    lines = err.strip().splitlines()
    assert len(lines) == 3 and all(line.startswith("pomdp-planner: ignoring") for line in lines), err
    assert any("fig1.json" in line for line in lines) and any("table2.json" in line for line in lines)
    assert any("*.pickle" in line and "never loaded" in line for line in lines)
    assert "Traceback" not in err


def test_a_valid_json_that_does_not_fit_the_report_is_ignored(tmp_path, capsys) -> None:
    """Well-formed, right version, signature and checksum, but not what the section's report
    reads: validation (the section renders from it alone) rejects it, no traceback."""
    out = tmp_path / "out"
    run_all(out, quick=True, progress=False, sections=("fig3",))
    path = out / CACHE_DIR / "fig3.json"
    entry = load_entry(path, [section_signature(QUICK, "fig3")])
    entry["data"] = {"image": 5}
    write_entry(path, section_signature(QUICK, "fig3"), entry)
    capsys.readouterr()
    data = run_all(out, quick=True, progress=False, sections=())
    err = capsys.readouterr().err
    assert "fig3" not in data and "## Fig. 3" not in (out / "RESULTS.md").read_text()
    assert err.count("ignoring cache file") == 1 and "invalid data" in err and "Traceback" not in err


def test_a_cached_section_from_another_plan_is_ignored(tmp_path, capsys) -> None:
    out = tmp_path / "out"
    run_all(out, quick=True, progress=False, sections=("fig3",))
    path = out / CACHE_DIR / "fig3.json"
    entry = load_entry(path, [section_signature(QUICK, "fig3")])
    cfg = {**entry["config"], "fig1_grid": 7}  # a plan this program does not run
    write_entry(path, section_signature(cfg, "fig3"), {**entry, "config": cfg})
    capsys.readouterr()
    assert "fig3" not in run_all(out, quick=True, progress=False, sections=())
    assert "another plan" in capsys.readouterr().err


# ------------------------------------------------------------------ the peers' chunks
def _plan(**kw) -> PeerPlan:
    base = dict(budgets=(0.01,), planners=("greedy", "random"), episodes_cheap=4, episodes_by_budget={0.01: 2},
                steps=5, max_depth=2, seed=5, chunk=2, probes=ProbeConfig(episodes=0))
    return PeerPlan(**{**base, **kw})


def test_planted_or_broken_chunks_are_recomputed_never_loaded(tmp_path, monkeypatch, capsys) -> None:
    plan = _plan()
    first = {(r.planner, tuple(r.returns)) for r in compare_peers({"s3": S3}, plan, cache_dir=tmp_path)}
    marker = tmp_path / "MARKER"
    victim, broken, forged = PeerChunk("s3", "greedy", None, 0, 2), PeerChunk("s3", "random", None, 2, 4), \
        PeerChunk("s3", "greedy", None, 2, 4)
    _malicious(tmp_path / victim.filename, marker)
    (tmp_path / broken.filename).write_text((tmp_path / broken.filename).read_text()[:50])
    # a consistent file (checksum right) whose records are not this chunk's episodes
    records = load_entry(tmp_path / forged.filename, [plan.signature(forged)])
    write_entry(tmp_path / forged.filename, plan.signature(forged), [{**r, "episode": 9} for r in records])
    ran = []
    real = peers.run_chunk
    monkeypatch.setattr(peers, "run_chunk", lambda c, m, p: ran.append(c) or real(c, m, p))
    capsys.readouterr()
    again = {(r.planner, tuple(r.returns)) for r in compare_peers({"s3": S3}, plan, cache_dir=tmp_path)}
    err = capsys.readouterr().err
    assert not marker.exists()
    assert sorted(ran, key=str) == sorted([victim, broken, forged], key=str)
    assert again == first
    assert err.count("ignoring cache file") == 3 and "Traceback" not in err


# ------------------------------------------------------------------ cache keys by model content
def test_model_digest_is_a_content_hash() -> None:
    copy = load_model(MODELS / "tracking_s3_info.yaml")
    assert copy is not S3 and model_digest(copy) == model_digest(S3)
    r = S3.r.copy()
    r[0, 0] += 1e-12
    for other in (dataclasses.replace(S3, r=r), dataclasses.replace(S3, gamma=0.9),
                  dataclasses.replace(S3, w=S3.w * 2), dataclasses.replace(S3, uncertainty="shannon"),
                  dataclasses.replace(S3, metadata={**S3.metadata, "start": [1.0, 0.0, 0.0]})):
        assert model_digest(other) != model_digest(S3)
