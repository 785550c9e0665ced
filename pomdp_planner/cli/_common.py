"""Small helpers shared by the CLI subcommands (argument conventions and output).

Every subcommand module uses the same conventions, so that the commands look alike:

* ``add_model_argument(parser)`` adds the positional ``MODEL`` (a YAML model file or a
  Cassandra ``.POMDP`` file); ``load_model_arg(args)`` loads it (errors are
  :class:`~pomdp_planner.core.model.ModelError`, which ``cli.main`` turns into exit code 2).
* ``add_json_argument(parser)`` adds ``--json``; ``emit_json(data)`` prints ``data`` as JSON,
  converting numpy scalars/arrays on the way (``to_jsonable``).
* ``add_belief_argument(parser)`` / ``parse_belief(text, model)``: a belief given on the
  command line as ``uniform`` or comma-separated probabilities ``0.2,0.3,0.5``.
* ``format_table(headers, rows)`` renders a plain-text table (right-aligned numbers).

Actions are always shown to users as tracking priorities ``1..A`` (``priority_of``).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Iterable, Sequence
from typing import Any, TextIO

import numpy as np

from ..core.belief import check_belief, uniform_belief
from ..core.io.model_yaml import load_model
from ..core.model import POMDP, ModelError


def add_model_argument(parser: argparse.ArgumentParser) -> None:
    """Add the positional ``MODEL`` argument (YAML model file or Cassandra ``.POMDP``)."""
    parser.add_argument("model", metavar="MODEL", help="model file: YAML (see README) or Cassandra .POMDP")


def add_json_argument(parser: argparse.ArgumentParser) -> None:
    """Add ``--json`` (machine-readable output on stdout instead of text)."""
    parser.add_argument("--json", action="store_true", help="print machine-readable JSON instead of text")


def load_model_arg(args: argparse.Namespace) -> POMDP:
    """Load the model named by ``args.model`` (raises ``ModelError`` with the file name)."""
    return load_model(args.model)


def add_belief_argument(parser: argparse.ArgumentParser, default: str = "uniform",
                        help_text: str = "belief: 'uniform' or comma-separated probabilities, e.g. 0.2,0.3,0.5"
                        ) -> None:
    """Add ``--belief`` (parse it with :func:`parse_belief` once the model is loaded)."""
    parser.add_argument("--belief", default=default, metavar="B", help=help_text)


def parse_belief(text: str, model: POMDP, field: str = "--belief") -> np.ndarray:
    """Parse ``uniform`` or ``p1,p2,...,pS`` into a belief of ``model``.

    Only the text is handled here; the belief itself is checked by the core's one rule,
    :func:`~pomdp_planner.core.belief.check_belief` (length S, finite, on the simplex within
    1e-6). Errors name ``field``: ``ModelError`` for the text, ``BeliefError`` from the core
    (``cli.main`` turns both into exit code 2).
    """
    text = text.strip()
    if text.lower() == "uniform":
        return uniform_belief(model)
    try:
        values = [float(x) for x in text.replace(" ", "").split(",") if x != ""]
    except ValueError:
        raise ModelError(f"{field}: expected 'uniform' or comma-separated numbers, got {text!r}") from None
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
