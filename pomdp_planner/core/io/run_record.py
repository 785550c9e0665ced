"""Run records: one CSV row per decision of a closed-loop run, for pictures and later analysis.

The format (version 1). Line 1 is a comment naming the format and the run::

    # pomdp_planner run record 1; model=perimeter_s8; S=8; A=3; time_budget=0.05

(``time_budget`` in seconds, ``none`` when the run had none). Line 2 is the header, then one
row per decision, in increasing ``epoch``:

========== ==================================================================================
column     value
========== ==================================================================================
epoch      the decision's epoch: an integer >= 0, increasing from row to row (gaps allowed)
true_state the hidden state at that epoch, 0-based, where known (a simulation); else empty
b0..bS-1   the belief the decision was made from (``S`` columns, on the simplex within 1e-6)
action     the chosen action as a tracking priority ``1..A``
lower      the root's lower-bound priority ``1..A`` (Theorem 2); empty without bounds
upper      the root's upper-bound priority ``1..A``; empty without bounds (both or neither)
guaranteed ``1`` if ``lower``/``upper`` are guaranteed (the assumption gate's verdict,
           ``core/gate.py``; then ``lower <= upper``), ``0`` if they are shown without a guarantee
           (a diagnostic, e.g. pruning forced on a model failing Assumption 1); empty without bounds
depth      the depth searched (Table II convention); empty for a policy that does not search
certified  ``1`` if the root bounds agree and are guaranteed (Proposition 1), else ``0``; ``1``
           only with ``guaranteed`` ``1`` and ``lower == upper``
latency    seconds the decision took; empty where not measured
========== ==================================================================================

:class:`RunRecordWriter` writes and flushes one row at a time, so a long run (or a node) can
stream its record and a reader sees every finished decision. Into a file (:func:`open_run_record`)
a row is written whole or not at all: a write that fails part-way (a full disk) is cut back to the
end of the previous row, so the file always ends on a complete line. :func:`read_run_record` checks
every line and refuses a malformed file with one line naming the line and the column
(:class:`RunRecordError`, an :class:`~..errors.OptionError`: a bad argument file). Only a last
line without its line end (a row still being written, or one cut by a crash) is not refused: it is
left out, and the record says which line (:attr:`RunRecord.cut_line`), for one warning.
"""

from __future__ import annotations

import csv
import io
import math
import os
import warnings
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import TextIO

import numpy as np

from ..errors import InputWarning, OptionError, short_repr

FORMAT = "pomdp_planner run record"
VERSION = 1
#: Columns before and after the ``S`` belief columns.
HEAD_COLUMNS = ("epoch", "true_state")
TAIL_COLUMNS = ("action", "lower", "upper", "guaranteed", "depth", "certified", "latency")
#: A belief row may miss the simplex by this much (the package's belief rule, ``core/belief.py``).
BELIEF_ATOL = 1e-6


class RunRecordError(OptionError):
    """A malformed run record: the message names the file, the line and the column."""


def columns(S: int) -> tuple[str, ...]:
    """The header of a record with ``S`` states."""
    return (*HEAD_COLUMNS, *(f"b{i}" for i in range(S)), *TAIL_COLUMNS)


def _blank(x: object) -> str:
    return "" if x is None else str(x)


def _float_text(x: float) -> str:
    return repr(float(x))  # shortest text that reads back to the same float


class RunRecordWriter:
    """Writes a run record to ``stream`` row by row (module docstring), flushing after each row.

    ``model_name``, ``S``, ``A`` and ``time_budget`` (seconds or ``None``) go to the first line.
    :meth:`write` checks each row as the reader would, so a record the writer produced is always
    readable. ``stream`` is a text stream, or an unbuffered binary file (``io.RawIOBase``, as
    :func:`open_run_record` opens it): then each line goes out whole or not at all (a write that
    fails part-way is cut back to the previous line and raised as a :class:`RunRecordError`
    starting with ``where``)."""

    def __init__(self, stream: TextIO | io.RawIOBase, model_name: str, S: int, A: int,
                 time_budget: float | None = None, *, where: str = "run record: cannot write"):
        if any(ch in str(model_name) for ch in ";\n\r"):
            raise RunRecordError(f"run record: the model name {short_repr(model_name)} contains ';' or a line break")
        self.stream, self.S, self.A = stream, int(S), int(A)
        self.where = where
        self._last_epoch: int | None = None
        self._size = 0  # bytes of whole lines in a binary file
        budget = "none" if time_budget is None else _float_text(time_budget)
        self._put(f"# {FORMAT} {VERSION}; model={model_name}; S={self.S}; A={self.A}; time_budget={budget}\n"
                  + ",".join(columns(self.S)) + "\n")

    def write(self, epoch: int, belief: Sequence[float] | np.ndarray, priority: int, *, true_state: int | None = None,
              bounds: tuple[int, int] | None = None, guaranteed: bool = False, depth: int | None = None,
              certified: bool = False, latency: float | None = None) -> None:
        """One decision: ``priority`` and ``bounds`` (lower, upper) as priorities ``1..A``, ``true_state``
        0-based; ``None`` where unknown. ``guaranteed``: the gate guarantees ``bounds`` (default: they
        are written as not guaranteed)."""
        label = None if bounds is None else int(bool(guaranteed))
        row = [str(int(epoch)), _blank(true_state), *(_float_text(p) for p in np.asarray(belief, dtype=float)),
               str(int(priority)), _blank(None if bounds is None else int(bounds[0])),
               _blank(None if bounds is None else int(bounds[1])), _blank(label),
               _blank(None if depth is None else int(depth)), "1" if certified else "0",
               "" if latency is None else _float_text(latency)]
        epoch_checked = _check_row(row, self.S, self.A, self._last_epoch, f"run record, epoch {int(epoch)}", None)
        self._put(",".join(row) + "\n")  # numbers and blanks only: no cell needs CSV quoting
        self._last_epoch = epoch_checked

    def _put(self, text: str) -> None:
        """Write whole lines ``text`` and flush; into a binary file whole or not at all (class docstring)."""
        if not isinstance(self.stream, io.RawIOBase):
            self.stream.write(text)
            self.stream.flush()
            return
        data = memoryview(text.encode("utf-8"))
        try:
            while data:
                data = data[self.stream.write(data):]
        except OSError as exc:
            try:  # cutting a file back needs no space
                self.stream.truncate(self._size)
                self.stream.seek(self._size)
            except OSError:
                pass
            raise RunRecordError(f"{self.where}: {exc.strerror or type(exc).__name__}") from None
        self._size += len(data.obj)

    def close(self) -> None:
        """Close the stream."""
        self.stream.close()


def open_run_record(path: str | os.PathLike, field: str, model_name: str, S: int, A: int,
                    time_budget: float | None = None) -> RunRecordWriter:
    """A :class:`RunRecordWriter` streaming into the file ``path`` (created or overwritten; whole
    rows only; :meth:`RunRecordWriter.close` ends it); a file that cannot be written, then or
    later, is a :class:`RunRecordError` ``FIELD: cannot write PATH: REASON`` (``field``: the option
    or parameter that gave the path)."""
    where = f"{field}: cannot write {path}"
    try:
        stream = open(path, "wb", buffering=0)
    except OSError as exc:
        raise RunRecordError(f"{where}: {exc.strerror or type(exc).__name__}") from None
    try:
        return RunRecordWriter(stream, model_name, S, A, time_budget, where=where)
    except RunRecordError as exc:
        stream.close()
        raise (exc if str(exc).startswith(where) else RunRecordError(f"{where}: {exc}")) from None


@dataclass(frozen=True, eq=False)
class RunRecord:
    """A run record read back: ``beliefs`` ``(T, S)``; ``true_state`` ``(T,)`` with -1 where unknown;
    ``action``, ``lower``, ``upper`` priorities ``1..A`` (bounds 0 where absent); ``guaranteed`` (bool:
    the bounds are guaranteed; ``False`` where absent or not guaranteed); ``depth`` (-1 where absent),
    ``certified`` (bool), ``latency`` (seconds, NaN where absent); ``cut_line``: a last line left
    out because it was cut off (module docstring)."""

    model: str
    S: int
    A: int
    time_budget: float | None
    epoch: np.ndarray
    true_state: np.ndarray
    beliefs: np.ndarray
    action: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    guaranteed: np.ndarray
    depth: np.ndarray
    certified: np.ndarray
    latency: np.ndarray
    #: The number of a last line left out because it lacks its line end (a row cut off), else ``None``.
    cut_line: int | None = None

    @property
    def has_bounds(self) -> np.ndarray:
        return self.lower > 0

    @property
    def unguaranteed_bounds(self) -> np.ndarray:
        """Rows whose bounds are shown without a guarantee (a diagnostic)."""
        return self.has_bounds & ~self.guaranteed


def _fail(where: str, line: int | None, column: str | None, problem: str) -> RunRecordError:
    at = where + (f":{line}" if line is not None else "") + (f": column {column}" if column else "")
    return RunRecordError(f"{at}: {problem}")


def _int(text: str, lo: int, hi: int | None, where: str, line: int | None, column: str, blank_ok: bool) -> int | None:
    t = text.strip()
    if t == "" and blank_ok:
        return None
    if not (t.isascii() and t.isdigit() and len(t) <= 18) or int(t) < lo or (hi is not None and int(t) > hi):
        want = f"an integer in {lo}..{hi}" if hi is not None else f"an integer >= {lo}"
        raise _fail(where, line, column, f"expected {want}" + (" or empty" if blank_ok else "")
                    + f", got {short_repr(text)}")
    return int(t)


def _float(text: str, where: str, line: int | None, column: str, blank_ok: bool) -> float | None:
    t = text.strip()
    if t == "" and blank_ok:
        return None
    try:
        value = float(t) if t.isascii() else math.nan
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise _fail(where, line, column, "expected a finite number" + (" or empty" if blank_ok else "")
                    + f", got {short_repr(text)}")
    return value


def _check_row(row: Sequence[str], S: int, A: int, last_epoch: int | None, where: str, line: int | None) -> int:
    """Check one row (the reader's and the writer's rule); returns its epoch."""
    names = columns(S)
    if len(row) != len(names):
        raise _fail(where, line, None, f"expected {len(names)} columns ({S} belief columns), got {len(row)}")
    cell = dict(zip(names, row, strict=True))
    epoch = _int(cell["epoch"], 0, None, where, line, "epoch", False)
    if last_epoch is not None and epoch <= last_epoch:
        raise _fail(where, line, "epoch", f"{epoch} does not increase (previous row: {last_epoch})")
    _int(cell["true_state"], 0, S - 1, where, line, "true_state", True)
    b = np.array([_float(cell[f"b{i}"], where, line, f"b{i}", False) for i in range(S)])
    for i, p in enumerate(b):
        if not -BELIEF_ATOL <= p <= 1 + BELIEF_ATOL:
            raise _fail(where, line, f"b{i}", f"a probability must be in [0, 1], got {p!r}")
    if abs(b.sum() - 1.0) > BELIEF_ATOL:
        raise _fail(where, line, f"b0..b{S - 1}", f"the belief sums to {b.sum()!r}, not 1")
    _int(cell["action"], 1, A, where, line, "action", False)
    lo = _int(cell["lower"], 1, A, where, line, "lower", True)
    up = _int(cell["upper"], 1, A, where, line, "upper", True)
    if (lo is None) != (up is None):
        raise _fail(where, line, "upper" if up is None else "lower", "lower and upper are both given or both empty")
    guaranteed = _int(cell["guaranteed"], 0, 1, where, line, "guaranteed", True)
    if (guaranteed is None) != (lo is None):
        raise _fail(where, line, "guaranteed", "given exactly where lower and upper are: 1 guaranteed bounds, "
                    "0 bounds without a guarantee")
    if guaranteed == 1 and lo > up:
        raise _fail(where, line, "upper", f"guaranteed bounds never cross, got lower {lo} above upper {up}")
    _int(cell["depth"], 0, None, where, line, "depth", True)
    if _int(cell["certified"], 0, 1, where, line, "certified", False) == 1 and not (guaranteed == 1 and lo == up):
        raise _fail(where, line, "certified", "1 needs guaranteed bounds that agree (guaranteed 1, lower == upper)")
    lat = _float(cell["latency"], where, line, "latency", True)
    if lat is not None and lat < 0:
        raise _fail(where, line, "latency", f"must be >= 0 seconds, got {lat!r}")
    return epoch


def _parse_first_line(text: str, where: str) -> tuple[str, int, int, float | None]:
    head = f"# {FORMAT} {VERSION};"
    if not text.startswith(head):
        raise _fail(where, 1, None, f"not a run record: line 1 must start with {head!r}, got {short_repr(text)}")
    fields: dict[str, str] = {}
    for part in text[len(head):].split(";"):
        key, sep, value = part.strip().partition("=")
        if not sep:
            raise _fail(where, 1, None, f"expected key=value, got {short_repr(part.strip())}")
        fields[key] = value.strip()
    missing = [k for k in ("model", "S", "A", "time_budget") if k not in fields]
    if missing:
        raise _fail(where, 1, None, f"missing {', '.join(missing)}")
    S = _int(fields["S"], 1, 10**6, where, 1, "S", False)
    A = _int(fields["A"], 1, 10**6, where, 1, "A", False)
    budget = None if fields["time_budget"] == "none" else _float(fields["time_budget"], where, 1, "time_budget", False)
    if budget is not None and budget <= 0:
        raise _fail(where, 1, "time_budget", f"must be > 0 seconds or none, got {budget!r}")
    return fields["model"], S, A, budget


def read_run_record(path: str | os.PathLike, text: str | None = None) -> RunRecord:
    """Read and check a run record (module docstring); any problem is one :class:`RunRecordError`
    line ``FILE:LINE: column NAME: problem``. A last row without its line end is left out with one
    :class:`~..errors.InputWarning` ``FILE:LINE: ...`` (and :attr:`RunRecord.cut_line`). ``text``:
    the record's text, read instead of the file (a record kept in a bag, :mod:`.run_bag`; ``path``
    names it in messages)."""
    where = str(path)
    cut: list[int] = []

    def whole_lines(fh: TextIO, first: int) -> Iterator[str]:
        """The lines of ``fh`` that end with a line end; the number of a last one that does not goes to ``cut``."""
        for k, text in enumerate(fh, start=first):
            if text.endswith("\n"):
                yield text
            else:  # only the last line can lack its end
                cut.append(k)

    try:
        with io.StringIO(text, newline="") if text is not None else open(path, encoding="utf-8", newline="") as fh:
            first = fh.readline()
            if not first.endswith("\n") and first:
                raise _fail(where, 1, None, "the first line is cut off (no line end)")
            model, S, A, budget = _parse_first_line(first.rstrip("\r\n"), where)
            reader = csv.reader(whole_lines(fh, 2))
            try:
                header = next(reader)
            except StopIteration:
                raise _fail(where, 2, None, "no header line" + (" (it is cut off)" if cut else "")) from None
            if tuple(header) != columns(S):
                bad = next((i for i, (h, c) in enumerate(zip(header, columns(S), strict=False)) if h != c),
                           min(len(header), len(columns(S))))
                want = columns(S)[bad] if bad < len(columns(S)) else "(end of line)"
                got = header[bad] if bad < len(header) else "(end of line)"
                raise _fail(where, 2, None, f"header column {bad + 1}: expected {want!r}, got {short_repr(got)}")
            rows, last = [], None
            for k, row in enumerate(reader):
                line = k + 3
                last = _check_row(row, S, A, last, where, line)
                rows.append(row)
    except UnicodeDecodeError as exc:
        raise RunRecordError(f"{where}: not UTF-8 text ({exc.reason})") from None
    except csv.Error as exc:
        raise RunRecordError(f"{where}: not a CSV file ({exc})") from None
    except OSError as exc:
        raise RunRecordError(f"{where}: cannot read: {exc.strerror or type(exc).__name__}") from None
    cut_line = cut[0] if cut else None
    if not rows:
        raise _fail(where, 3, None, "no rows: the record has a header but no decision"
                    + (f" (line {cut_line} is a row cut off)" if cut_line else ""))
    if cut_line is not None:
        warnings.warn(InputWarning(f"{where}:{cut_line}: the last row is cut off (no line end: still being written, "
                                   f"or the writer stopped part-way); read the {len(rows)} rows before it"),
                      stacklevel=2)
    names = columns(S)
    cols = {name: [r[i] for r in rows] for i, name in enumerate(names)}

    def ints(name: str, blank: int) -> np.ndarray:
        return np.array([blank if v.strip() == "" else int(v) for v in cols[name]], dtype=np.int64)

    return RunRecord(
        model=model, S=S, A=A, time_budget=budget, epoch=ints("epoch", -1), true_state=ints("true_state", -1),
        beliefs=np.array([[float(cols[f"b{i}"][t]) for i in range(S)] for t in range(len(rows))]),
        action=ints("action", 0), lower=ints("lower", 0), upper=ints("upper", 0),
        guaranteed=ints("guaranteed", 0).astype(bool), depth=ints("depth", -1),
        certified=ints("certified", 0).astype(bool),
        latency=np.array([math.nan if v.strip() == "" else float(v) for v in cols["latency"]]),
        cut_line=cut_line,
    )
