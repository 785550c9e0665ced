"""Run records (core/io/run_record.py), ``simulate --record`` and ``pomdp-planner plot``.

* A record written row by row reads back to the same values (hypothesis), and a reader sees each
  row as soon as it is written (streaming, as a node would).
* Every kind of malformed record is refused with one line naming the file, the line and the column.
* A row is written whole or not at all: a write the kernel cuts short (a file size limit, as a full
  disk) leaves the file ending on the previous whole row, and the error is one line; ``simulate
  --record`` then ends with that line (exit code 2). A last row without its line end (cut off)
  is left out with one warning naming its line, at every cut point, also where the cut text would
  pass as a row; ``plot`` draws the rows before it.
* ``simulate --record``: one row per step, the belief the decision was made from (checked against
  the JSON steps of the same run), the priority, the planner's root bounds, depth and search time.
* ``plot``: the PNG has the asked size (read from its IHDR chunk); a malformed record and a missing
  matplotlib each give one line and exit code 2.
"""

from __future__ import annotations

import builtins
import io
import json
import os
import struct
import subprocess
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pomdp_planner.cli import main
from pomdp_planner.core.errors import InputWarning
from pomdp_planner.core.io.run_record import RunRecordError, RunRecordWriter, columns, read_run_record

ROOT = Path(__file__).resolve().parents[1]
S8 = str(ROOT / "config/models/perimeter_s8.yaml")
S3 = str(ROOT / "config/models/tracking_s3_info.yaml")


def png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n", "not a PNG file"
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def small_record(path: Path, S: int = 3, A: int = 3, rows: int = 4, budget: float | None = 0.05) -> None:
    with open(path, "w", encoding="utf-8") as fh:
        w = RunRecordWriter(fh, "m", S, A, budget)
        rng = np.random.default_rng(0)
        for t in range(rows):
            w.write(2 * t, rng.dirichlet(np.ones(S)), 1 + t % A, true_state=t % S, bounds=(1, 1) if t == 0 else (1, A),
                    guaranteed=True, depth=2, certified=t == 0, latency=0.01 * (t + 1))


# ------------------------------------------------------------------ writer and reader
@settings(max_examples=40, deadline=None)
@given(st.integers(1, 6), st.integers(1, 4), st.integers(1, 12), st.integers(0, 10**6), st.booleans())
def test_a_record_reads_back_to_what_was_written(S, A, T, seed, with_budget):
    rng = np.random.default_rng(seed)
    stream = io.StringIO()
    w = RunRecordWriter(stream, "model x", S, A, 0.25 if with_budget else None)
    rows = []
    epoch = 0
    for _ in range(T):
        epoch += int(rng.integers(1, 4))
        b = rng.dirichlet(np.ones(S))
        guaranteed = bool(rng.uniform() < 0.5)
        pair = [int(x) for x in rng.integers(1, A + 1, 2)]
        bounds = None if rng.uniform() < 0.3 else tuple(sorted(pair) if guaranteed else pair)  # only these may cross
        row = dict(epoch=epoch, belief=b, priority=int(rng.integers(1, A + 1)),
                   true_state=None if rng.uniform() < 0.3 else int(rng.integers(S)), bounds=bounds,
                   guaranteed=bounds is not None and guaranteed,
                   depth=None if rng.uniform() < 0.3 else int(rng.integers(0, 9)),
                   certified=bounds is not None and guaranteed and bounds[0] == bounds[1],
                   latency=None if rng.uniform() < 0.3 else float(rng.uniform(0, 2)))
        w.write(row["epoch"], b, row["priority"], true_state=row["true_state"], bounds=row["bounds"],
                guaranteed=guaranteed, depth=row["depth"], certified=row["certified"], latency=row["latency"])
        rows.append(row)
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "run.csv"
        path.write_text(stream.getvalue())
        rec = read_run_record(path)
    assert (rec.model, rec.S, rec.A, rec.time_budget) == ("model x", S, A, 0.25 if with_budget else None)
    for t, row in enumerate(rows):
        assert rec.epoch[t] == row["epoch"] and rec.action[t] == row["priority"]
        assert np.array_equal(rec.beliefs[t], row["belief"])  # floats written exactly (repr)
        assert rec.true_state[t] == (-1 if row["true_state"] is None else row["true_state"])
        assert (rec.lower[t], rec.upper[t]) == ((0, 0) if row["bounds"] is None else row["bounds"])
        assert rec.guaranteed[t] == row["guaranteed"]
        assert rec.unguaranteed_bounds[t] == (row["bounds"] is not None and not row["guaranteed"])
        assert rec.depth[t] == (-1 if row["depth"] is None else row["depth"])
        assert rec.certified[t] == row["certified"]
        assert (np.isnan(rec.latency[t]) if row["latency"] is None else rec.latency[t] == row["latency"])


def test_rows_are_readable_while_the_record_is_being_written(tmp_path):
    path = tmp_path / "live.csv"
    with open(path, "w", encoding="utf-8") as fh:
        w = RunRecordWriter(fh, "live", 2, 2)
        for t in range(3):
            w.write(t, [0.5, 0.5], 1)
            assert len(read_run_record(path).epoch) == t + 1  # flushed: a reader sees the row at once


def test_the_writer_refuses_what_the_reader_would_refuse():
    w = RunRecordWriter(io.StringIO(), "m", 2, 3)
    w.write(5, [0.5, 0.5], 1)
    with pytest.raises(RunRecordError, match=r"^run record, epoch 5: column epoch: 5 does not increase"):
        w.write(5, [0.5, 0.5], 1)
    with pytest.raises(RunRecordError, match=r"column action: expected an integer in 1\.\.3"):
        w.write(6, [0.5, 0.5], 4)
    with pytest.raises(RunRecordError, match="model name"):
        RunRecordWriter(io.StringIO(), "a;b", 2, 3)
    with pytest.raises(RunRecordError, match=r"column certified: 1 needs guaranteed bounds that agree"):
        w.write(6, [0.5, 0.5], 2, bounds=(2, 2), certified=True)  # bounds not labelled guaranteed
    w.write(6, [0.5, 0.5], 2, bounds=(2, 2))
    assert w.stream.getvalue().splitlines()[-1].split(",")[columns(2).index("guaranteed")] == "0"


GOOD_HEAD = "# pomdp_planner run record 1; model=m; S=2; A=3; time_budget=0.05\n" + ",".join(columns(2)) + "\n"
GOOD_ROW = "0,1,0.25,0.75,2,1,3,1,2,0,0.01"

MALFORMED = [  # (text, line, column or None, fragment of the problem)
    ("epoch,true_state\n", 1, None, "not a run record"),
    ("# pomdp_planner run record 1; model=m; S=2; A=3\n", 1, None, "missing time_budget"),
    ("# pomdp_planner run record 1; model=m; S=two; A=3; time_budget=none\n", 1, "S", "expected an integer"),
    ("# pomdp_planner run record 1; model=m; S=2; A=3; time_budget=-1\n", 1, "time_budget", "must be > 0"),
    (GOOD_HEAD.replace(",b1,", ",belief1,"), 2, None, "header column 4: expected 'b1'"),
    (GOOD_HEAD, 3, None, "no rows"),
    (GOOD_HEAD + "0,1,0.25,0.75,2,1,3,2,0\n", 3, None, "expected 11 columns"),
    (GOOD_HEAD + GOOD_ROW.replace("0,1,", "x,1,", 1) + "\n", 3, "epoch", "expected an integer >= 0"),
    (GOOD_HEAD + GOOD_ROW + "\n" + GOOD_ROW + "\n", 4, "epoch", "0 does not increase"),
    (GOOD_HEAD + GOOD_ROW.replace("0,1,", "0,2,", 1) + "\n", 3, "true_state", "expected an integer in 0..1"),
    (GOOD_HEAD + GOOD_ROW.replace("0.25,", "nan,") + "\n", 3, "b0", "expected a finite number"),
    (GOOD_HEAD + GOOD_ROW.replace("0.25,0.75", "1.5,-0.5") + "\n", 3, "b0", "must be in [0, 1]"),
    (GOOD_HEAD + GOOD_ROW.replace("0.25,0.75", "0.25,0.7") + "\n", 3, "b0..b1", "the belief sums to"),
    (GOOD_HEAD + GOOD_ROW.replace("0.75,2,", "0.75,0,") + "\n", 3, "action", "expected an integer in 1..3"),
    (GOOD_HEAD + GOOD_ROW.replace(",1,3,1,", ",1,,1,") + "\n", 3, "upper", "both given or both empty"),
    (GOOD_HEAD + GOOD_ROW.replace(",1,3,1,", ",1,3,,") + "\n", 3, "guaranteed", "given exactly where lower"),
    (GOOD_HEAD + GOOD_ROW.replace(",1,3,1,", ",,,0,") + "\n", 3, "guaranteed", "given exactly where lower"),
    (GOOD_HEAD + GOOD_ROW.replace(",1,3,1,", ",1,3,2,") + "\n", 3, "guaranteed", "expected an integer in 0..1"),
    (GOOD_HEAD + GOOD_ROW.replace(",1,3,1,", ",3,1,1,") + "\n", 3, "upper", "guaranteed bounds never cross"),
    (GOOD_HEAD + GOOD_ROW.replace(",3,1,2,0,", ",3,1,2,2,") + "\n", 3, "certified", "expected an integer in 0..1"),
    (GOOD_HEAD + GOOD_ROW.replace(",3,1,2,0,", ",3,1,2,1,") + "\n", 3, "certified", "needs guaranteed bounds"),
    (GOOD_HEAD + GOOD_ROW.replace(",1,3,1,2,0,", ",2,2,0,2,1,") + "\n", 3, "certified", "needs guaranteed bounds"),
    (GOOD_HEAD + GOOD_ROW.replace("0.01", "-0.01") + "\n", 3, "latency", "must be >= 0 seconds"),
]


@pytest.mark.parametrize("text,line,column,problem", MALFORMED, ids=[m[3] for m in MALFORMED])
def test_a_malformed_record_is_refused_naming_the_line_and_column(tmp_path, text, line, column, problem):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(RunRecordError) as info:
        read_run_record(path)
    msg = str(info.value)
    assert "\n" not in msg
    assert msg.startswith(f"{path}:{line}: " + (f"column {column}: " if column else "")), msg
    assert problem in msg, msg


def test_a_binary_file_is_refused_in_one_line(tmp_path):
    path = tmp_path / "bin.csv"
    path.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(RunRecordError, match="not UTF-8"):
        read_run_record(path)


# ------------------------------------------------------------------ whole rows
#: A child process whose files may not grow beyond LIMIT bytes (the kernel writes up to the limit,
#: then fails the write with EFBIG, as a full disk fails it with ENOSPC), running ``CODE``.
LIMITED = """
import resource, signal, sys
{imports}
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
resource.setrlimit(resource.RLIMIT_FSIZE, ({limit}, {limit}))
{code}
"""


def _limited(tmp_path: Path, limit: int, imports: str, code: str, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", LIMITED.format(imports=imports, limit=limit, code=code), *args],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path,
                          env={**os.environ, "PYTHONDONTWRITEBYTECODE": "1"})


ROW_BELIEF = [0.2, 0.3, 0.5]


def test_a_failed_write_leaves_the_file_ending_on_its_last_whole_row(tmp_path):
    """The limit falls inside the third row: the kernel writes part of it, then refuses; the file is
    cut back to the end of the second row and the error names the field, the file and the reason."""
    path = tmp_path / "run.csv"
    w = RunRecordWriter(io.StringIO(), "m", 3, 3)
    head = len(w.stream.getvalue())
    w.write(0, ROW_BELIEF, 1, latency=0.0123456789)
    row = len(w.stream.getvalue()) - head
    for cut in (1, row // 2, row - 1):
        limit = head + 2 * row + cut
        proc = _limited(tmp_path, limit, "from pomdp_planner.core.io.run_record import RunRecordError, open_run_record",
                        f"""
w = open_run_record(sys.argv[1], "--record", "m", 3, 3)
try:
    for t in range(100):
        w.write(t, {ROW_BELIEF}, 1, latency=0.0123456789)
        print("wrote", t, flush=True)
except RunRecordError as exc:
    print(exc)
w.close()
""", str(path))
        assert proc.returncode == 0, proc.stderr
        *wrote, error = proc.stdout.splitlines()
        assert wrote == ["wrote 0", "wrote 1"]
        assert error == f"--record: cannot write {path}: File too large"
        data = path.read_bytes()
        assert len(data) == head + 2 * row and data.endswith(b"\n")
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            assert list(read_run_record(path).epoch) == [0, 1]


def test_simulate_record_on_a_full_file_system_is_one_line_and_a_readable_record(tmp_path):
    path = tmp_path / "run.csv"
    proc = _limited(tmp_path, 3000, "from pomdp_planner.cli import main",
                    "sys.exit(main(sys.argv[1:]))",
                    "simulate", S8, "--steps", "200", "--record", str(path))
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and err == [f"pomdp-planner: error: --record: cannot write {path}: File too large"], \
        proc.stderr[-2000:]
    assert path.stat().st_size <= 3000 and path.read_bytes().endswith(b"\n")
    rec = read_run_record(path)
    assert list(rec.epoch) == list(range(len(rec.epoch))) and rec.cut_line is None


def _cut_record(tmp_path: Path, keep: int) -> tuple[Path, int]:
    """A record of 4 rows whose last row keeps only its first ``keep`` characters (no line end); its line number."""
    path = tmp_path / f"cut{keep}.csv"
    small_record(path)
    text = path.read_text()
    body, last = text[:-1].rsplit("\n", 1)
    path.write_text(body + "\n" + last[:keep])
    return path, text.count("\n")


def test_a_cut_last_row_is_left_out_with_one_warning_naming_its_line(tmp_path):
    full = tmp_path / "full.csv"
    small_record(full)
    whole = read_run_record(full)
    last = full.read_text().splitlines()[-1]
    for keep in range(1, len(last) + 1):  # every cut point, the whole row without its line end too
        path, line = _cut_record(tmp_path, keep)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            rec = read_run_record(path)
        assert [str(w.message) for w in caught if issubclass(w.category, InputWarning)] == [
            f"{path}:{line}: the last row is cut off (no line end: still being written, or the writer stopped "
            "part-way); read the 3 rows before it"]
        assert rec.cut_line == line and list(rec.epoch) == list(whole.epoch[:3])
        np.testing.assert_array_equal(rec.beliefs, whole.beliefs[:3])
        np.testing.assert_array_equal(rec.latency, whole.latency[:3])


def test_a_record_whose_only_row_is_cut_has_no_rows(tmp_path):
    path = tmp_path / "run.csv"
    path.write_text(GOOD_HEAD + GOOD_ROW[:9])
    with pytest.raises(RunRecordError, match=r":3: no rows: .*\(line 3 is a row cut off\)$"):
        read_run_record(path)


@pytest.mark.parametrize("text,line,problem", [
    (GOOD_HEAD + GOOD_ROW[:9] + "\n" + GOOD_ROW.replace("0,", "1,", 1) + "\n", 3, "expected 11 columns"),
    (GOOD_HEAD + GOOD_ROW + "\n" + GOOD_ROW.replace("0,1,", "1,1,", 1).replace("0.25", "0.2") + "\n", 4,
     "the belief sums to"),
    (GOOD_HEAD + GOOD_ROW + "\n" + "1,1,0.25,0.7\n" + GOOD_ROW.replace("0,", "2,", 1)[:5], 4,
     "expected 11 columns"),
])
def test_a_row_cut_anywhere_but_at_the_end_is_refused(tmp_path, text, line, problem):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(RunRecordError) as info:
        read_run_record(path)
    assert str(info.value).startswith(f"{path}:{line}: ") and problem in str(info.value)


# ------------------------------------------------------------------ simulate --record
def test_simulate_records_every_decision_with_its_belief(tmp_path, capsys):
    rec_path = tmp_path / "run.csv"
    argv = ["simulate", S8, "--policy", "bnb", "--option", "depth=2", "--steps", "12", "--seed", "4"]
    assert main([*argv, "--record", str(rec_path), "--json"]) == 0
    steps = json.loads(capsys.readouterr().out)
    rec = read_run_record(rec_path)
    assert (rec.model, rec.S, rec.A, rec.time_budget) == ("perimeter_s8", 8, 3, None)
    assert list(rec.epoch) == list(range(12))
    beliefs = [steps["initial_belief"]] + [s["belief"] for s in steps["steps"][:-1]]  # b_t: before step t's update
    np.testing.assert_array_equal(rec.beliefs, np.array(beliefs))
    assert list(rec.action) == [s["priority"] for s in steps["steps"]]
    assert list(rec.true_state) == [s["state"] for s in steps["steps"]]
    assert np.all(rec.depth == 2) and np.all(rec.has_bounds) and np.all(rec.latency > 0)
    assert np.all((rec.lower <= rec.action) & (rec.action <= rec.upper))  # B&B keeps its action in the bounds
    assert np.all(rec.guaranteed) and np.all(rec.certified == (rec.lower == rec.upper))  # the gate proved them


def test_simulate_record_of_a_policy_without_bounds(tmp_path):
    rec_path = tmp_path / "run.csv"
    assert main(["simulate", S3, "--policy", "myopic", "--steps", "3", "--record", str(rec_path)]) == 0
    rec = read_run_record(rec_path)
    assert not rec.has_bounds.any() and np.all(rec.depth == -1) and np.all(np.isnan(rec.latency))


def test_simulate_refuses_an_unusable_record_path_before_running(tmp_path, capsys):
    code = main(["simulate", S3, "--steps", "3", "--record", str(tmp_path)])
    out, err = capsys.readouterr()
    assert code == 2 and out == "" and "--record:" in err and "is a directory" in err


# ------------------------------------------------------------------ plot
@pytest.mark.parametrize("extra,size", [([], (1000, 700)),
                                        (["--width", "6", "--height", "4", "--dpi", "50"], (300, 200))])
def test_plot_writes_a_png_of_the_asked_size(tmp_path, capsys, extra, size):
    rec_path, png = tmp_path / "run.csv", tmp_path / "run.png"
    assert main(["simulate", S8, "--policy", "bnb", "--option", "time_budget=0.02", "--steps", "8",
                 "--record", str(rec_path)]) == 0
    capsys.readouterr()
    assert main(["plot", str(rec_path), "-o", str(png), *extra]) == 0
    assert png_size(png) == size
    assert capsys.readouterr().out.strip() == f"wrote {png} (8 decisions of perimeter_s8)"


def test_plot_draws_a_record_without_latency_or_bounds(tmp_path):
    rec_path, png = tmp_path / "run.csv", tmp_path / "run.png"
    assert main(["simulate", S3, "--policy", "random", "--steps", "5", "--record", str(rec_path)]) == 0
    assert main(["plot", str(rec_path), "-o", str(png)]) == 0
    assert png_size(png) == (1000, 700)


def test_plot_refuses_a_malformed_record_in_one_line(tmp_path, capsys):
    bad, png = tmp_path / "bad.csv", tmp_path / "run.png"
    small_record(bad)
    lines = bad.read_text().splitlines()
    cells = lines[4].split(",")  # line 5 of the file: the third decision
    cells[columns(3).index("depth")] = "deep"
    lines[4] = ",".join(cells)
    bad.write_text("\n".join(lines) + "\n")
    with pytest.raises(RunRecordError) as info:
        read_run_record(bad)
    code = main(["plot", str(bad), "-o", str(png)])
    out, err = capsys.readouterr()
    assert code == 2 and out == "" and not png.exists()
    assert err.strip().splitlines() == [f"pomdp-planner: error: {info.value}"]
    assert f"{bad}:5: column depth: expected an integer >= 0 or empty, got 'deep'" in err


def test_plot_draws_the_whole_rows_of_a_record_with_a_cut_last_row(tmp_path, capsys):
    path, line = _cut_record(tmp_path, 12)
    png = tmp_path / "run.png"
    assert main(["plot", str(path), "-o", str(png)]) == 0
    out, err = capsys.readouterr()
    assert err.strip().splitlines() == [f"pomdp-planner: warning: {path}:{line}: the last row is cut off (no line "
                                        "end: still being written, or the writer stopped part-way); read the 3 rows "
                                        "before it"]
    assert out.strip() == f"wrote {png} (3 decisions of m)" and png_size(png) == (1000, 700)


def test_plot_without_matplotlib_says_how_to_install_it(tmp_path, capsys, monkeypatch):
    rec_path, png = tmp_path / "run.csv", tmp_path / "run.png"
    small_record(rec_path)
    real_import = builtins.__import__

    def no_matplotlib(name, *args, **kwargs):
        if name == "matplotlib" or name.startswith("matplotlib."):
            raise ImportError(f"No module named {name!r}")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_matplotlib)
    code = main(["plot", str(rec_path), "-o", str(png)])
    _, err = capsys.readouterr()
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert "matplotlib is not installed" in err and "pip install" in err and "[plot]" in err


def test_plot_refuses_an_unknown_picture_format(tmp_path, capsys):
    rec_path = tmp_path / "run.csv"
    small_record(rec_path)
    assert main(["plot", str(rec_path), "-o", str(tmp_path / "run.gif")]) == 2
    assert "--output: the suffix must be one of .png, .svg, .pdf" in capsys.readouterr().err
