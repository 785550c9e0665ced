"""A budgeted multi-target problem: K independent single-target POMDPs, one effort budget per epoch.

Target ``k`` is a model of this package (any file, the same or different for different
targets). Every epoch the sensor manager gives every target one priority ``a_k`` (0-based
action, priority ``a_k + 1``); priority ``a`` of target ``k`` costs the effort ``e_k(a) >= 0``,
and the joint action must satisfy ``sum_k e_k(a_k) <= B``. The targets are independent: each
one's state moves and is observed under its own action only, so the joint belief is the
product of the per-target beliefs at every epoch, and the joint reward is
``sum_k rho_k(b_k, a_k)`` (Eq. 3 per target), discounted with one common ``gamma``.

Efforts and the budget are **exact rationals** (:class:`fractions.Fraction`): integers, or
decimals read digit for digit (``0.5`` is ``1/2``, never ``0.5000000000000001``). The
multiple-choice knapsack (:mod:`.knapsack`) works on integers: all efforts and the budget are
multiplied by the least common multiple of their denominators (:attr:`MultiTargetProblem.scale`),
so ``sum_k e_k(a_k) <= B`` is decided exactly, never up to rounding. The scaled budget (or, if smaller, the
scaled largest joint effort) may be at most :data:`MAX_CAPACITY_UNITS` units.

Default efforts (:func:`default_efforts`): ``e(priority p) = A - p``, i.e. ``e(a) = A - 1 - a``
for the 0-based action: the lowest priority (``A``, "not tracked") costs nothing and every step
up in priority costs one unit, so priority 1 costs ``A - 1``. With these defaults the joint
action "every target at the lowest priority" is always within any budget ``B >= 0``.

All targets must share one discount (``0 <= gamma <= 1``; 1 is valid for the finite lookahead):
a single Lagrange price per epoch prices every target's effort at the same epoch alike, which
is a stationary price per target only when the targets discount alike (docs/THEORY.md,
"Several targets"). :func:`make_problem` refuses models with different discounts unless
``discount`` is given, which then replaces every model's discount (the gate solves each target's
bounds for that discount).
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from fractions import Fraction

import numpy as np

from ..checks import check_number
from ..errors import OptionError, kind_of, short_repr
from ..model import POMDP

#: Most targets of one problem (the knapsack and the planner are linear in K; the cap keeps a
#: typo in a list of targets from starting a search over millions of them).
MAX_TARGETS = 4096
#: Largest denominator of an effort or of the budget (``0.001`` is fine, ``1/3`` written as a
#: float is not: its decimal digits would make a huge denominator).
MAX_DENOMINATOR = 10**6
#: Largest scaled budget ``B * scale`` (integer units of the knapsack's table).
MAX_CAPACITY_UNITS = 10**6


def as_rational(value: object, field: str) -> Fraction:
    """``value`` as an exact non-negative :class:`~fractions.Fraction`: an integer, a float or a
    decimal string read digit for digit (``0.1`` is ``1/10``), or a fraction string ``"1/3"``."""
    if isinstance(value, Fraction):
        q = value
    elif isinstance(value, str):
        try:
            q = Fraction(value.strip())
        except (ValueError, ZeroDivisionError):
            raise OptionError(f"{field}: must be a number, got {short_repr(value)}") from None
    elif isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Real):
        raise OptionError(f"{field}: must be a number, got {kind_of(value)}")
    elif isinstance(value, numbers.Integral):
        q = Fraction(int(value))
    else:
        x = check_number(value, field)
        q = Fraction(repr(float(x)))  # the shortest decimal that round-trips: 0.1 -> 1/10
    if q < 0:
        raise OptionError(f"{field}: must be >= 0, got {short_repr(value)}")
    if q.denominator > MAX_DENOMINATOR:
        raise OptionError(f"{field}: {short_repr(value)} needs a denominator above {MAX_DENOMINATOR} "
                         "(give efforts as integers or short decimals)")
    return q


def default_efforts(model: POMDP) -> tuple[Fraction, ...]:
    """``e(a) = A - 1 - a`` (priority ``p`` costs ``A - p``): the module docstring's default."""
    return tuple(Fraction(model.A - 1 - a) for a in range(model.A))


def parse_efforts(value: object, model: POMDP, field: str) -> tuple[Fraction, ...]:
    """One target's efforts: ``None`` (the default), or one non-negative number per priority
    ``1..A`` (list order = priority order: the first entry is priority 1)."""
    if value is None:
        return default_efforts(model)
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        raise OptionError(f"{field}: must be a list of {model.A} numbers (one per priority 1..{model.A}), "
                         f"got {kind_of(value)}")
    if len(value) != model.A:
        raise OptionError(f"{field}: expected {model.A} efforts (one per priority 1..{model.A}), got {len(value)}")
    return tuple(as_rational(x, f"{field}[{i}]") for i, x in enumerate(value))


@dataclass(frozen=True, eq=False)
class MultiTargetProblem:
    """K targets, their efforts and the per-epoch budget (module docstring); build with :func:`make_problem`.

    ``models[k]`` is target ``k``'s model (all with the discount :attr:`gamma`), ``efforts[k][a]``
    the effort of its 0-based action ``a``, ``budget`` the budget ``B``. Derived exactly:
    ``scale`` (the least common multiple of all denominators), ``units[k]`` (``efforts[k] * scale``
    as an int array) and ``capacity`` (``B * scale``, an int).
    """

    models: tuple[POMDP, ...]
    efforts: tuple[tuple[Fraction, ...], ...]
    budget: Fraction
    names: tuple[str, ...]

    def __post_init__(self) -> None:
        dens = [q.denominator for row in self.efforts for q in row] + [self.budget.denominator]
        scale = math.lcm(*dens)
        units = tuple(np.array([int(q * scale) for q in row], dtype=np.int64) for row in self.efforts)
        for u in units:
            u.setflags(write=False)
        capacity = int(self.budget * scale)  # exact: budget * scale is an integer
        object.__setattr__(self, "scale", scale)
        object.__setattr__(self, "units", units)
        object.__setattr__(self, "capacity", capacity)

    scale: int = field(init=False, default=1)
    units: tuple[np.ndarray, ...] = field(init=False, default=())
    capacity: int = field(init=False, default=0)

    @property
    def num_targets(self) -> int:
        """Number of targets ``K``."""
        return len(self.models)

    K = num_targets

    @property
    def gamma(self) -> float:
        """The common discount of all targets."""
        return self.models[0].gamma

    @property
    def knapsack_capacity(self) -> int:
        """The capacity the knapsack needs: ``min(B, sum_k max_a e_k(a))`` in units (a budget above
        the largest joint effort admits every joint action, whatever its size)."""
        return min(self.capacity, int(sum(int(u.max()) for u in self.units)))

    @property
    def least_effort(self) -> Fraction:
        """``sum_k min_a e_k(a)``: the smallest effort of any joint action."""
        return sum((min(row) for row in self.efforts), Fraction(0))

    @property
    def most_effort(self) -> Fraction:
        """``sum_k max_a e_k(a)``: the largest effort of any joint action."""
        return sum((max(row) for row in self.efforts), Fraction(0))

    @property
    def budget_binds(self) -> bool:
        """Some joint action exceeds the budget (``B < sum_k max_a e_k(a)``); otherwise every joint
        action is within it and the targets decouple (the planner's price is then 0)."""
        return self.budget < self.most_effort

    def effort_of(self, actions: Sequence[int]) -> Fraction:
        """``sum_k e_k(a_k)`` of a joint action (0-based), exactly."""
        return sum((self.efforts[k][int(a)] for k, a in enumerate(actions)), Fraction(0))

    def within_budget(self, actions: Sequence[int]) -> bool:
        """``sum_k e_k(a_k) <= B``, decided exactly."""
        return len(actions) == self.K and self.effort_of(actions) <= self.budget

    def check_actions(self, actions: Sequence[int], field: str = "actions") -> tuple[int, ...]:
        """A joint action (0-based) as a tuple after checking its length, ranges and the budget."""
        if len(actions) != self.K:
            raise OptionError(f"{field}: {len(actions)} actions for {self.K} targets")
        out = []
        for k, a in enumerate(actions):
            if isinstance(a, (bool, np.bool_)) or not isinstance(a, (int, np.integer)) \
                    or not 0 <= a < self.models[k].A:
                raise OptionError(f"{field}[{k}]: {short_repr(a)} is not an action 0..{self.models[k].A - 1}")
            out.append(int(a))
        used = self.effort_of(out)
        if used > self.budget:
            raise OptionError(f"{field}: effort {format_effort(used)} exceeds the budget {format_effort(self.budget)}")
        return tuple(out)

    def describe(self) -> str:
        """One line: the targets, the efforts and the budget."""
        parts = [f"{n}(e={','.join(format_effort(q) for q in row)})" for n, row in zip(self.names, self.efforts,
                                                                                         strict=True)]
        return f"{self.K} targets: {' '.join(parts)}; budget {format_effort(self.budget)} per epoch, " \
               f"gamma={self.gamma:g}"


def format_effort(q: Fraction) -> str:
    """An effort for people: ``2``, ``0.5``, or ``1/3`` when it has no short decimal."""
    if q.denominator == 1:
        return str(q.numerator)
    x = float(q)
    text = f"{x:.6g}"
    return text if Fraction(text) == q else f"{q.numerator}/{q.denominator}"


def make_problem(models: Sequence[POMDP], budget: object, efforts: Sequence[object] | None = None,
                 discount: float | None = None, names: Sequence[str] | None = None, *,
                 fields: Mapping[str, str] | None = None) -> MultiTargetProblem:
    """Check and build a :class:`MultiTargetProblem`; errors are one-line
    :class:`~pomdp_planner.core.errors.OptionError` s naming the field (``targets``, ``efforts[k]``,
    ``budget``, ``discount``, or what ``fields`` calls them where the user gave them: the command
    line's ``--budget``, the sensor manager's ``effort_budget``).

    ``efforts``: ``None`` (every target the default), or one entry per target, each ``None`` (that
    target's default) or ``A_k`` numbers in priority order. ``discount``: ``None`` (the models'
    common discount; refused if they differ) or a number in ``[0, 1]`` that replaces every model's.
    """
    f = {"targets": "targets", "efforts": "efforts", "budget": "budget", "discount": "discount", **(fields or {})}
    models = list(models)
    if not models:
        raise OptionError(f"{f['targets']}: at least one target model is needed")
    if len(models) > MAX_TARGETS:
        raise OptionError(f"{f['targets']}: {len(models)} targets, more than the limit of {MAX_TARGETS} (MAX_TARGETS)")
    names = tuple(m.name for m in models) if names is None else tuple(str(n) for n in names)
    if len(names) != len(models):
        raise OptionError(f"{f['targets']}: {len(names)} names for {len(models)} targets")
    if discount is None:
        gammas = sorted({m.gamma for m in models})
        if len(gammas) > 1:
            shown = ", ".join(f"{m.name} {m.gamma:g}" for m in {m.gamma: m for m in models}.values())
            raise OptionError(f"{f['discount']}: the targets' models have different discounts ({shown}); one price "
                              "per epoch needs one discount: give the joint discount explicitly")
    else:
        gamma = check_number(discount, f["discount"], 0.0, 1.0)
        cache: dict[int, POMDP] = {}
        models = [m if m.gamma == gamma else cache.setdefault(id(m), replace(m, gamma=gamma)) for m in models]
    if efforts is None:
        efforts = [None] * len(models)
    elif isinstance(efforts, (str, bytes)) or not isinstance(efforts, Sequence):
        raise OptionError(f"{f['efforts']}: must be a list with one entry per target, got {kind_of(efforts)}")
    if len(efforts) != len(models):
        raise OptionError(f"{f['efforts']}: {len(efforts)} entries for {len(models)} targets")
    rows = tuple(parse_efforts(e, m, f"{f['efforts']}[{k}]")
                 for k, (e, m) in enumerate(zip(efforts, models, strict=True)))
    B = as_rational(budget, f["budget"])
    problem = MultiTargetProblem(tuple(models), rows, B, names)
    if B < problem.least_effort:
        raise OptionError(f"{f['budget']}: {format_effort(B)} is below the least effort of any joint action "
                          f"({format_effort(problem.least_effort)} = the sum of every target's smallest effort)")
    if problem.knapsack_capacity > MAX_CAPACITY_UNITS:
        raise OptionError(f"{f['budget']}: {format_effort(B)} is {problem.capacity} units of 1/{problem.scale} "
                          f"(the efforts' common denominator), more than the limit of {MAX_CAPACITY_UNITS} "
                          "(MAX_CAPACITY_UNITS)")
    return problem
