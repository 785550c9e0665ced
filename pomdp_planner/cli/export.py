"""``pomdp-planner export MODEL --format pomdp|yaml [-o FILE]``: write a model in another format.

``pomdp`` is Cassandra's ``.POMDP`` (the uncertainty term in its ``# pomdp_planner:`` comment, which
other readers ignore); ``yaml`` is our explicit model file (matrices written out: nested lists, text
blocks or the sparse form).
"""

from __future__ import annotations

import argparse
import sys
import warnings

from ..core.io.cassandra import export_pomdp
from ..core.io.model_yaml import dump_model
from ..core.io.outputs import check_output_file, is_stdout, write_text_file
from ._common import add_json_argument, add_model_argument, emit_json, load_model_arg


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("export", help="write a model as Cassandra .POMDP or explicit YAML",
                              description=__doc__.split("\n\n")[0].replace("``", ""))
    add_model_argument(p)
    p.add_argument("--format", choices=("pomdp", "yaml"), default="pomdp",
                   help="pomdp: Cassandra .POMDP (the uncertainty term in a comment); yaml: explicit model file")
    p.add_argument("-o", "--output", metavar="FILE",
                   help="write to FILE (a regular file, checked before any work) instead of stdout; '-' is stdout")
    add_json_argument(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    if args.output is not None:  # before any work: a directory, a FIFO, a missing folder, a file not writable
        check_output_file(args.output, "-o/--output")
        if is_stdout(args.output):
            args.output = None
    model = load_model_arg(args)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if args.format == "pomdp":
            text = export_pomdp(model)
        else:
            text = dump_model(model)
    messages = [str(w.message) for w in caught]
    for m in messages:
        print(f"pomdp-planner: warning: {m}", file=sys.stderr)
    if args.output is not None:
        write_text_file(args.output, text, "-o/--output")
    if args.json:
        emit_json({"model": model.name, "format": args.format, "output": args.output, "warnings": messages,
                   "text": None if args.output is not None else text})
    elif args.output is None:
        sys.stdout.write(text)
    return 0
