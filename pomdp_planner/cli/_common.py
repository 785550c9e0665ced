"""Small helpers shared by the CLI subcommands (argument conventions and output).

Every subcommand module uses the same conventions, so that the commands look alike:

* ``add_model_argument(parser)`` adds the positional ``MODEL`` (a YAML model file or a
  Cassandra ``.POMDP`` file, or a shipped model's name); ``load_model_arg(args)`` finds it as the
  nodes do (``core.io.paths.resolve_path``) and loads it (errors are
  :class:`~pomdp_planner.core.errors.ModelError`, which ``cli.main`` turns into exit code 2).
* ``add_json_argument(parser)`` adds ``--json``; ``emit_json(data)`` prints ``data`` as JSON,
  converting numpy scalars/arrays on the way (``to_jsonable``).
* ``add_belief_argument(parser)`` / ``parse_belief(text, model)``: a belief given on the
  command line as ``uniform`` or comma-separated probabilities ``0.2,0.3,0.5``.
* ``format_table(headers, rows)`` renders a plain-text table (right-aligned numbers).
* Every parser is a :class:`Parser`: a bad argument is one line on stderr naming the option
  (``pomdp-planner plan: error: argument --depth: ...``) and exit code 2, never the usage text
  and never a traceback. Numbers are parsed by :func:`int_in` / :func:`float_in` (ranges checked
  while parsing, NaN and infinity refused) and seeds by :func:`seed_arg`.

Actions are always shown to users as tracking priorities ``1..A`` (``priority_of``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable, Iterable, Sequence
from typing import Any, TextIO

import numpy as np

from ..core.belief import check_belief, uniform_belief
from ..core.checks import option_value
from ..core.errors import OptionError
from ..core.io.sensors import load_model_file
from ..core.model import POMDP, short_repr
from ..core.one_line import Parser, one_line  # noqa: F401 (the subcommands' names)
from ..core.options import SEED_RANGE, check_seed


def int_in(lo: int | None, hi: int | None) -> Callable[[str], int]:
    """An argparse ``type``: an integer (ASCII digits, optional sign: ``core.checks.option_value``) in
    ``lo..hi`` (``None``: open)."""
    want = (f"an integer in {lo}..{hi}" if lo is not None and hi is not None else
            f"an integer >= {lo}" if lo is not None else f"an integer <= {hi}")

    def parse(text: str) -> int:
        value = option_value(text)
        if not isinstance(value, int) or (lo is not None and value < lo) or (hi is not None and value > hi):
            raise argparse.ArgumentTypeError(f"must be {want}, got {short_repr(text)}")
        return value

    parse.__name__ = "integer"
    return parse


def float_in(lo: float, hi: float, unit: str = "") -> Callable[[str], float]:
    """An argparse ``type``: a finite number (plain ASCII: ``core.checks.option_value``) in ``lo..hi``
    (NaN and infinity refused)."""
    span = "..".join(f"{x:.0f}" if float(x).is_integer() else f"{x:g}" for x in (lo, hi))

    def parse(text: str) -> float:
        value = option_value(text)
        if isinstance(value, str) or not (math.isfinite(value) and lo <= value <= hi):
            raise argparse.ArgumentTypeError(f"must be a number{unit} in {span}, got {short_repr(text)}")
        return float(value)

    parse.__name__ = "number"
    return parse


def seed_arg(text: str) -> int:
    """An argparse ``type`` for seeds: an integer in :data:`~pomdp_planner.core.policies.SEED_RANGE`."""
    try:
        return check_seed(int_in(*SEED_RANGE)(text), "seed")
    except (argparse.ArgumentTypeError, OptionError):
        raise argparse.ArgumentTypeError(f"must be an integer in {SEED_RANGE[0]}..{SEED_RANGE[1]}, "
                                         f"got {short_repr(text)}") from None


def add_seed_argument(parser: argparse.ArgumentParser, help_text: str) -> None:
    """Add ``--seed K`` (:func:`seed_arg`, default 0)."""
    parser.add_argument("--seed", type=seed_arg, default=0, metavar="K", help=help_text)


def add_model_argument(parser: argparse.ArgumentParser) -> None:
    """Add the positional ``MODEL`` argument (YAML model file or Cassandra ``.POMDP``)."""
    parser.add_argument("model", metavar="MODEL",
                        help="model file: YAML (see README) or Cassandra .POMDP, absolute, relative to the current "
                             "directory or to the installed share/pomdp_planner, or a shipped model's name "
                             "(e.g. tracking_s3_info)")


def add_json_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--json`` (machine-readable output on stdout instead of text)."""
    parser.add_argument("--json", action="store_true", help="print machine-readable JSON instead of text")


def load_model_arg(args: argparse.Namespace) -> POMDP:
    """Load the model named by ``args.model`` with the nodes' own function
    (:func:`~pomdp_planner.core.io.sensors.load_model_file`, through
    :func:`~pomdp_planner.core.io.paths.resolve_path`: absolute, relative to the current directory,
    under the installed share directory, or a bare shipped name such as ``tracking_s3_info``);
    raises ``ModelError`` naming ``MODEL`` and where it looked, or the file and its field."""
    return load_model_file(args.model, "MODEL")


def add_belief_argument(parser: argparse.ArgumentParser, default: str = "uniform",
                        help_text: str = "belief: 'uniform' or comma-separated probabilities, e.g. 0.2,0.3,0.5"
                        ) -> None:
    """Add ``--belief`` (parse it with :func:`parse_belief` once the model is loaded)."""
    parser.add_argument("--belief", default=default, metavar="B", help=help_text)


def parse_belief(text: str, model: POMDP, field: str = "--belief") -> np.ndarray:
    """Parse ``uniform`` or ``p1,p2,...,pS`` into a belief of ``model``.

    Only the text is handled here; the belief itself is checked by the core's one rule,
    :func:`~pomdp_planner.core.belief.check_belief` (length S, finite, on the simplex within
    1e-6). Errors name ``field``: ``OptionError`` for the text, ``BeliefError`` from the core
    (``cli.main`` turns both into exit code 2).
    """
    text = text.strip()
    if text.lower() == "uniform":
        return uniform_belief(model)
    values = [option_value(x) for x in text.replace(" ", "").split(",")]
    if any(isinstance(v, str) for v in values):  # an empty item ("0.5,,0.5", a trailing comma), "0_5", ...
        raise OptionError(f"{field}: expected 'uniform' or comma-separated numbers, got {short_repr(text)}")
    return check_belief(model, np.asarray(values, dtype=float), field=field)


def to_jsonable(x: Any) -> Any:
    """Convert numpy arrays/scalars (recursively, inside dicts/lists/tuples) to plain Python.

    Non-finite floats become ``None`` (JSON has no NaN/Infinity).
    """
    if isinstance(x, dict):
        return {str(k): to_jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [to_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return to_jsonable(x.tolist())
    if isinstance(x, (bool, np.bool_)):
        return bool(x)
    if isinstance(x, (int, np.integer)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return x if math.isfinite(x) else None
    return x


def emit_json(data: Any, stream: TextIO | None = None) -> None:
    """Print ``data`` as indented JSON (numpy converted with :func:`to_jsonable`)."""
    stream = sys.stdout if stream is None else stream
    json.dump(to_jsonable(data), stream, indent=2, allow_nan=False)
    stream.write("\n")


def emit_json_stream(head: dict, key: str, items: Iterable[Any], tail: Callable[[], dict],
                     stream: TextIO | None = None) -> None:
    """Print one JSON object ``{**head, key: [*items], **tail()}`` while ``items`` is being produced.

    Each item is written (one line) as soon as it comes and then dropped, so the memory does not
    grow with the number of items (``simulate --json`` with any ``--steps``); ``tail`` is called
    after the last item (summaries of the run). The output is the same JSON as :func:`emit_json`
    would give for the whole object, laid out differently.
    """
    out = sys.stdout if stream is None else stream

    def dump(value: Any) -> str:
        return json.dumps(to_jsonable(value), allow_nan=False)

    out.write("{\n" + "".join(f"  {json.dumps(str(k))}: {dump(v)},\n" for k, v in head.items()))
    out.write(f"  {json.dumps(key)}: [")
    sep = "\n    "
    for item in items:
        out.write(sep + dump(item))
        sep = ",\n    "
    out.write("]" if sep == "\n    " else "\n  ]")
    out.write("".join(f",\n  {json.dumps(str(k))}: {dump(v)}" for k, v in tail().items()) + "\n}\n")


def format_number(x: Any, digits: int = 4) -> str:
    """Floats with ``digits`` decimals; integers and strings unchanged; NaN as ``-``."""
    if isinstance(x, (bool, np.bool_)):
        return str(bool(x))
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    if isinstance(x, (float, np.floating)):
        return "-" if math.isnan(x) else f"{float(x):.{digits}f}"
    return str(x)


def format_table(headers: Sequence[str], rows: Iterable[Sequence[Any]], digits: int = 4) -> str:
    """A plain-text table: a header line, a rule, one line per row.

    Numbers are formatted with :func:`format_number` and right-aligned; other cells are
    left-aligned. Returns the text without a trailing newline.
    """
    cells = [[format_number(v, digits) for v in row] for row in rows]
    widths = [len(h) for h in headers]
    for row in cells:
        if len(row) != len(headers):
            raise ValueError(f"format_table: row has {len(row)} cells, expected {len(headers)}")
        widths = [max(w, len(c)) for w, c in zip(widths, row, strict=True)]
    right = [all(_is_number_text(row[i]) for row in cells) if cells else False for i in range(len(headers))]

    def line(values: Sequence[str]) -> str:
        padded = (v.rjust(w) if r else v.ljust(w) for v, w, r in zip(values, widths, right, strict=True))
        return "  ".join(padded).rstrip()

    out = [line(list(headers)), "  ".join("-" * w for w in widths)]
    out.extend(line(row) for row in cells)
    return "\n".join(out)


def _is_number_text(s: str) -> bool:
    if s == "-":
        return True
    try:
        float(s)
    except ValueError:
        return False
    return True
