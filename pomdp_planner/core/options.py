"""What a user may ask of the planners: the range of every search and policy parameter, stated once.

The command line (``--depth``, ``--max-depth``, ``--time-budget``, ``--seed``, ``--option``), the
``simulate`` policies (:mod:`.policies`, :mod:`.belief_mcts`) and the planner node's parameter
descriptors (``max_depth``, ``time_budget``) all take their limits from here, and check values
with the functions below (errors are :class:`~.errors.OptionError` naming the field). The
planners' own guards are wider (``depth >= 1``, ``time_budget >= 0``): these are what a user may
ask per decision, not limits of the search.
"""

from __future__ import annotations

from typing import Any

from .checks import check_int, check_number

#: The search depths a user may ask for (Table II convention; ``--depth``/``--max-depth`` of the
#: CLI, the ``simulate`` options, the planner node's ``max_depth``), inclusive. The tree grows as
#: ``(A Z)^depth``, so the time budget stops any real model far earlier.
MAX_DEPTH_RANGE = (1, 50)
#: The time budgets a user may ask for, seconds per decision (``--time-budget``, the ``simulate``
#: option, the planner node's ``time_budget``), inclusive: a millisecond to a minute.
TIME_BUDGET_RANGE = (0.001, 60.0)
#: Seeds a user may give (``--seed``, the ``seed`` option): integers in this range, inclusive
#: (numpy takes any non-negative integer; the cap keeps a seed an int64 for JSON readers).
SEED_RANGE = (0, 2**63 - 1)
#: Steps of one closed-loop simulation (``simulate --steps``): streamed in constant memory, so the
#: cap only keeps a mistyped count from running for years (10^12 steps of a 10 microsecond policy
#: are about four months).
STEPS_RANGE = (0, 10**12)
#: Simulations per decision of the MCTS policy (``--option simulations=N``): at most about 25-50 s
#: of search at the 20-50 thousand simulations/s measured on the tracking models.
SIMULATIONS_RANGE = (1, 10**6)
#: Greedy rollout steps per MCTS simulation (``--option rollout_depth=N``).
ROLLOUT_DEPTH_RANGE = (0, 1000)


def check_depth(depth: Any, field: str = "depth", allowed: tuple[int, int | None] = (1, None)) -> int:
    """``depth`` as an int after checking it is an integer in ``allowed`` (inclusive; ``None``: no
    upper limit). The planner's own guard is ``>= 1``; user-facing edges pass :data:`MAX_DEPTH_RANGE`."""
    return check_int(depth, field, allowed[0], allowed[1])


def check_time_budget(seconds: Any, field: str = "time_budget",
                      allowed: tuple[float, float | None] = (0.0, None)) -> float:
    """``seconds`` as a float after checking it is a finite number in ``allowed`` (inclusive). The
    planner's own guard is ``>= 0`` (0: depth 1 only); user-facing edges pass :data:`TIME_BUDGET_RANGE`."""
    return check_number(seconds, field, allowed[0], allowed[1], what="a number of seconds")


def check_seed(seed: Any, field: str = "seed") -> int:
    """``seed`` as an int after checking it is an integer in :data:`SEED_RANGE`."""
    return check_int(seed, field, *SEED_RANGE)
