"""The ``pomdp-planner`` command line (also ``python -m pomdp_planner``).

Each subcommand is a module ``pomdp_planner.cli.<name>`` (listed in :data:`SUBCOMMANDS`)
exposing ``register(subparsers)``, which adds its parser and sets ``func`` (called with the
parsed arguments, returning an exit code). Pure core only: nothing here imports rclpy.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from ..core.belief import BeliefError
from ..core.model import ModelError
from . import bench, bounds, check, export, plan, simulate

#: Subcommand modules, in the order ``--help`` lists them.
SUBCOMMANDS = (check, bounds, export, simulate, plan, bench)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="pomdp-planner",
        description="Information-acquisition POMDPs with myopic policy bounds (Lauri et al.). "
        "Actions are shown as tracking priorities 1..A (1 = greatest priority).",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for module in SUBCOMMANDS:
        module.register(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ModelError, BeliefError) as exc:  # bad input: the message names the field
        print(f"pomdp-planner: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
