"""The assumption gate: the one place that decides whether a planner may prune with the bounds.

The myopic bounds of Theorem 2 bracket the optimal action only when the model satisfies
Assumption 1 (Sec. III; Lemma 1, Corollary 1) and the LP for ``g``/``h`` is feasible (for
Shannon entropy, only where the guarantee covers the posteriors, see
:func:`~.bounds.covered_domain`). Every entry point (``pomdp-planner plan``, the ``simulate``
policies, the benchmarks and experiments, the planner node) builds its planner with
:func:`build_planner`, which decides, in this order:

1. ``use_bounds=False``: exhaustive search, nothing checked ("bounds disabled").
2. Assumption 1 (:func:`assumption_report`, cached per model content): if it fails or is
   unproven, ``on_assumption_failure="exhaustive"`` falls back to exhaustive search with the
   reason, ``"refuse"`` gives no planner at all (``mode="refuse"``).
3. A discount of 1 (a finite-horizon model): Theorem 2 needs ``gamma < 1``, so there are no
   bounds -> exhaustive search with that reason (also with the override below).
4. The LP (:func:`~.bounds.solve_bounds`, with the chosen ``variant`` and ``constant``):
   infeasible -> exhaustive search with the LP's message.
5. Shannon bounds whose guarantee covers no domain (``covers`` starts with ``"none"``) ->
   exhaustive search with the reason.
6. Otherwise prune, ``guaranteed=True``: pruning keeps the optimal action and agreeing root
   bounds certify it (Proposition 1).

:func:`bounds_verdict` applies the same rule (steps 2-5) to an LP solution already in hand, for
the commands that show the bounds themselves (``pomdp-planner bounds``): its
:class:`BoundsVerdict` says whether they are guaranteed and, if not, why.

``prune_without_guarantee=True`` is the explicit override: where 2 or 5 would stop pruning, the
planner prunes anyway with ``guaranteed=False``, and every output says that no guarantee holds
(a discount of 1 or an infeasible LP gives no bounds to prune with, so 3 and 4 still fall back). A planner built
without the guarantee never reports a decision as certified and, in the anytime search, does
not stop early when the root bounds agree (:class:`~.search.Planner`).

The decision covers every action-only price of the model: ``setup.planner.priced(c)`` (rewards
``r[s, a] - c[a]``, the multi-target planner's ``lambda e(a)``) keeps the same bounds and the same
``guaranteed`` flag, because such a price changes neither Assumption 1 nor the LP
(docs/THEORY.md, "Several targets", Theorem P).

``check_assumptions`` can take seconds on large models (about 1 s at S = 256, A = 64; minutes
where (A2) needs the expensive tests on many matrices), so its report is cached by the content
of ``P`` and ``O`` (the only inputs of Assumption 1): a second gate call for the same model, or
an equal copy of it (a model unpickled in a worker process), does not recompute it (the same
object is not even hashed again).

Set-up cost (:func:`estimate_setup`): before anything expensive, :func:`build_planner` predicts
the time and peak memory of its set-up (the assumption check, :func:`~.structure.estimate_check`;
the LP, :func:`~.bounds.estimate_solve_bounds`; the planner's tables,
:func:`~.search.planner_table_bytes`) and refuses (:class:`SetupCostError`, one line with the
figures) a set-up whose peak memory exceeds the memory available to the process
(:func:`available_memory`; a failing allocation would otherwise end it with a ``MemoryError``
or the kernel's OOM killer) or whose expected time exceeds ``max_setup_seconds`` (default
:data:`MAX_SETUP_SECONDS`; ``None`` lifts it); a set-up expected
to take more than :data:`SETUP_NOTICE_SECONDS` is announced through ``progress`` before it starts
(:func:`setup_notice`). Time budgets of the search never include the set-up.
"""

from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any
from weakref import WeakKeyDictionary

from . import search_kernel
from .bounds import (
    DEFAULT_CONSTANT,
    BoundsSolution,
    check_constant,
    check_variant,
    estimate_solve_bounds,
    solve_bounds,
)
from .checks import check_choice
from .errors import OptionError
from .model import MAX_DENSE_BYTES, POMDP, format_bytes, infinite_horizon_refusal, matrix_digest
from .myopic import MyopicBounds
from .search import DEFAULT_CHUNK_BYTES, DEFAULT_MEMORY_BUDGET, Planner, planner_table_bytes, uses_fused_table
from .structure import (
    AssumptionReport,
    CheckEstimate,
    check_assumptions,
    estimate_check,
    quick_tp2_refutation,
    seconds_text,
)

#: What :func:`build_planner` does when Assumption 1 fails or is unproven.
ON_ASSUMPTION_FAILURE = ("exhaustive", "refuse")
#: The decisions of the gate: prune with the bounds, search exhaustively, or give no planner.
MODES = ("prune", "exhaustive", "refuse")
#: How many assumption reports :func:`assumption_report` keeps (least recently used dropped).
REPORT_CACHE_SIZE = 32

_reports: OrderedDict[bytes, AssumptionReport] = OrderedDict()
#: The digest of each live model object, so that one object is hashed once (hashing ``P`` and
#: ``O`` takes about half a second at S = 256, A = 64; the models are immutable).
_keys: WeakKeyDictionary[POMDP, bytes] = WeakKeyDictionary()


def model_key(model: POMDP) -> bytes:
    """Digest of what Assumption 1 depends on: the shapes and values of ``P`` and ``O``."""
    key = _keys.get(model)
    if key is None:
        key = _keys[model] = matrix_digest(model)
    return key


def assumption_report(model: POMDP) -> AssumptionReport:
    """``check_assumptions(model)`` with its defaults, computed once per model content (LRU cache)."""
    key = model_key(model)
    report = _reports.get(key)
    if report is None:
        report = check_assumptions(model)
        _reports[key] = report
        while len(_reports) > REPORT_CACHE_SIZE:
            _reports.popitem(last=False)
    else:
        _reports.move_to_end(key)
    return report if report.model_name == model.name else replace(report, model_name=model.name)


#: A set-up expected to take longer than this many seconds is announced (:func:`setup_notice`).
SETUP_NOTICE_SECONDS = 2.0
#: :func:`build_planner` refuses a set-up expected to take longer than this many seconds, unless
#: the caller lifts the limit (``max_setup_seconds=None``: ``--no-limit``, ``no_limit=1``).
MAX_SETUP_SECONDS = 600.0
#: Seconds per byte of the planner's tables (filling them: a few passes over memory).
COST_TABLE_BYTE = 2e-9
#: Seconds per byte of the dense ``P`` and ``O`` a sparse model builds for the search.
COST_DENSE_BYTE = 3e-9


def available_memory() -> int | None:
    """Bytes this process may still allocate: the kernel's ``MemAvailable`` (``/proc/meminfo``), or
    less when a cgroup (v2) limit leaves less; ``None`` where neither can be read (no check then)."""
    found: list[int] = []
    try:
        with open("/proc/meminfo") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    found.append(int(line.split()[1]) * 1024)
                    break
    except (OSError, ValueError, IndexError):
        pass
    try:
        with open("/sys/fs/cgroup/memory.max") as fh:
            limit = fh.read().strip()
        with open("/sys/fs/cgroup/memory.current") as fh:
            used = int(fh.read().strip())
        if limit != "max":
            found.append(max(int(limit) - used, 0))
    except (OSError, ValueError):
        pass
    return min(found) if found else None


class SetupCostError(OptionError):
    """A planner set-up that would exceed the available memory or the set-up time limit (the message
    gives the figures): a request the planner refuses, an :class:`~.errors.OptionError` (exit code 2)."""


@dataclass(frozen=True)
class SetupEstimate:
    """The predicted cost of :func:`build_planner` for one model (module docstring).

    ``check`` is ``None`` when no assumption check runs (bounds disabled, or its report is
    already cached); ``lp_seconds``/``lp_bytes`` are zero when no LP will be solved: bounds disabled,
    a discount of 1, or Assumption 1 known to fail (``no_lp`` says why: the cached report, or a
    negative 2x2 minor found in one pass, :func:`~.structure.quick_tp2_refutation`; the check may
    still fail on (A2) or (A3), and the LP counted is then not solved). ``dense_bytes``: the dense
    ``P`` and ``O`` the search builds for a sparse model when the compiled kernel cannot search it
    (``sparse_search``: it can, through the non-zeros, and builds no dense matrix). ``seconds`` is the expected total,
    ``seconds_max`` the most it may take (:class:`~.structure.CheckEstimate`), ``bytes`` the peak of
    the temporaries and tables (they do not coexist: the check's and the LP's are freed before the
    tables are built).
    """

    S: int
    A: int
    Z: int
    check: CheckEstimate | None
    lp_seconds: float
    lp_bytes: int
    table_bytes: int
    no_lp: str = ""
    dense_bytes: int = 0
    sparse_search: bool = False

    @property
    def table_seconds(self) -> float:
        return COST_TABLE_BYTE * self.table_bytes + COST_DENSE_BYTE * self.dense_bytes

    @property
    def seconds(self) -> float:
        return (self.check.seconds if self.check else 0.0) + self.lp_seconds + self.table_seconds

    @property
    def seconds_max(self) -> float:
        return (self.check.seconds_max if self.check else 0.0) + self.lp_seconds + self.table_seconds

    @property
    def bytes(self) -> int:
        return max(self.check.bytes if self.check else 0, self.lp_bytes, self.table_bytes + self.dense_bytes)

    def parts(self) -> str:
        """The stages with their figures, e.g. ``"assumption check about 2 s, 195 MiB; ..."``."""
        out = []
        if self.check is not None:
            out.append(f"assumption check {self.check.describe()}, {format_bytes(self.check.bytes)}")
        if self.lp_bytes:
            out.append(f"bound LP about {seconds_text(self.lp_seconds)}, {format_bytes(self.lp_bytes)}")
        elif self.no_lp:
            out.append(f"no bound LP ({self.no_lp})")
        if self.dense_bytes:
            out.append(f"dense P and O for the search {format_bytes(self.dense_bytes)}")
        growth = ("the non-zeros of P and O" if self.sparse_search
                  else "A^2 S Z" if uses_fused_table(self.S, self.A, self.Z) else "A S (S + Z)")
        out.append(f"planner tables {format_bytes(self.table_bytes)} (they grow like {growth})")
        return "; ".join(out)


_estimates: OrderedDict[tuple, SetupEstimate] = OrderedDict()


def estimate_setup(model: POMDP, *, use_bounds: bool = True, variant: str = "tight",
                   report: AssumptionReport | None = None, forced: bool = False) -> SetupEstimate:
    """Predict the time and memory of ``build_planner(model, use_bounds=..., variant=...)`` before it
    runs (module docstring; a few tenths of a second at S = 256, A = 64). ``report``: the
    Assumption 1 report the call will be given (then no check runs). ``forced``: the LP is solved
    even where Assumption 1 fails (``prune_without_guarantee``). Cached for the last few models, so
    an entry point may ask before the gate asks again."""
    rep = report if report is not None else (_reports.get(model_key(model)) if use_bounds else None)
    key = (model_key(model), use_bounds, variant, rep is not None, forced)
    est = _estimates.get(key)
    if est is None:
        check = estimate_check(model) if use_bounds and rep is None else None
        no_lp = ""
        if use_bounds and not forced:
            if rep is not None and not rep.holds:
                no_lp = assumption_failure(rep)
            elif rep is None:
                no_lp = quick_tp2_refutation(model)
        solves_lp = use_bounds and not infinite_horizon_refusal(model, "the bound LP") and not no_lp
        lp_seconds, lp_bytes = estimate_solve_bounds(model, variant) if solves_lp else (0.0, 0)
        on_csr = model.sparse and search_kernel.searches(model)  # else the dense P and O (Planner)
        nnz = model.P_csr.nnz + model.O_csr.nnz if on_csr else None
        est = SetupEstimate(model.S, model.A, model.Z, check, lp_seconds, lp_bytes,
                            planner_table_bytes(model.S, model.A, model.Z, nnz=nnz), no_lp,
                            8 * model.A * model.S * (model.S + model.Z) if model.sparse and not on_csr else 0,
                            on_csr)
        _estimates[key] = est
        while len(_estimates) > 4:
            _estimates.popitem(last=False)
    return est


def check_setup_cost(est: SetupEstimate, max_seconds: float | None = MAX_SETUP_SECONDS, time_hint: str = "",
                     memory: int | None = None) -> None:
    """Refuse (:class:`SetupCostError`, one line) a set-up whose peak memory exceeds ``memory``
    bytes (default :func:`available_memory`, read when called) or whose expected time exceeds
    ``max_seconds`` (``None``: no time limit); ``time_hint`` (how the caller's user lifts the time
    limit) ends that message."""
    sizes = f"S={est.S}, A={est.A}, Z={est.Z}"
    if est.dense_bytes:
        stack = 8 * est.A * est.S * max(est.S, est.Z)
        if stack > MAX_DENSE_BYTES:
            raise SetupCostError(f"model: the search takes the dense P and O of this sparse model (S={est.S}, "
                                 f"A={est.A}, Z={est.Z}): {format_bytes(stack)} for the larger, more than the limit "
                                 f"of {format_bytes(MAX_DENSE_BYTES)} (MAX_DENSE_BYTES)")
    memory = available_memory() if memory is None else memory
    if memory is not None and est.bytes > memory:
        raise SetupCostError(f"model: the planner's set-up for {sizes} needs about {format_bytes(est.bytes)} "
                             f"({est.parts()}), more than the {format_bytes(memory)} of memory available")
    if max_seconds is not None and est.seconds > max_seconds:
        raise SetupCostError(f"model: the planner's set-up for {sizes} is expected to take "
                             f"{seconds_text(est.seconds)} ({est.parts()}), more than the limit of "
                             f"{seconds_text(max_seconds)} (MAX_SETUP_SECONDS)"
                             + (f"; {time_hint}" if time_hint else ""))


def setup_notice(est: SetupEstimate) -> str | None:
    """One line announcing a long set-up (expected over :data:`SETUP_NOTICE_SECONDS`), else ``None``."""
    if est.seconds <= SETUP_NOTICE_SECONDS:
        return None
    return (f"set-up for S={est.S}, A={est.A}, Z={est.Z} is running, expected about "
            f"{seconds_text(est.seconds)} before the first decision ({est.parts()}); no time budget includes it")


def check_notice(est: CheckEstimate, model: POMDP) -> str | None:
    """One line announcing a long assumption check (``pomdp-planner check``; expected over
    :data:`SETUP_NOTICE_SECONDS`), else ``None``."""
    if est.seconds <= SETUP_NOTICE_SECONDS:
        return None
    return f"checking Assumption 1 for S={model.S}, A={model.A}, Z={model.Z}: expected {est.describe()}"


def assumption_failure(report: AssumptionReport) -> str:
    """One line saying how Assumption 1 fails, e.g. ``"Assumption 1 fails (A1 fails, A2 unknown)"``."""
    bad = [k for k, v in report.status.items() if v != "holds"]
    verdict = "fails" if any(report.status[k] == "fails" for k in bad) else "is not proven"
    return f"Assumption 1 {verdict} ({', '.join(f'{k} {report.status[k]}' for k in bad)}; see 'pomdp-planner check')"


#: A set-up stage that takes longer than this many seconds is reported through ``progress`` as it ends.
STAGE_REPORT_SECONDS = 1.0
#: The stages of :func:`build_planner`, in order (keys of :attr:`PlannerSetup.seconds`).
STAGES = ("estimate", "assumption check", "bound LP", "planner tables")


class SetupStages:
    """The wall-clock seconds of each stage of one set-up (:data:`STAGES`); a stage that took longer
    than :data:`STAGE_REPORT_SECONDS` is reported through ``progress`` as it ends (``"set-up:
    assumption check took 1.3 s"``), so that a long set-up shows where it is."""

    #: The wall clock the stages are timed with.
    clock: Callable[[], float] = staticmethod(time.perf_counter)

    def __init__(self, progress: Callable[[str], None] | None = None):
        self.seconds: dict[str, float] = {}
        self._progress = progress

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        t0 = self.clock()
        yield
        took = self.seconds[name] = self.clock() - t0
        if took > STAGE_REPORT_SECONDS and self._progress is not None:
            self._progress(f"set-up: {name} took {seconds_text(took)}")


def _assumption_loss(report: AssumptionReport) -> str:
    """Why the guarantee is lost when Assumption 1 fails or is unproven (step 2)."""
    return f"{assumption_failure(report)}: the myopic bounds are not valid for this model"


_THEOREM_2 = "the bound LP (Theorem 2)"


def _lp_name(variant: str, constant: str) -> str:
    return f"the bound LP ({variant}, constant {constant})"


def _valid_reason(lp: str, covers: str) -> str:
    """The reason of a guaranteed decision (step 5)."""
    domain = "the simplex" if covers == "simplex" else covers
    return f"Assumption 1 holds and {lp} is feasible; the guarantee covers {domain}"


@dataclass(frozen=True)
class BoundsVerdict:
    """Whether an LP solution gives guaranteed bounds for its model (:func:`bounds_verdict`).

    ``guaranteed``: Assumption 1 holds, the LP is feasible and (Shannon) the guarantee covers a
    domain, so the lower and upper bound policies bracket an optimal action (Theorem 2) and
    agreeing bounds certify it (Proposition 1). ``reason`` is one line for people: the gate's
    reason, the same words :func:`build_planner` would give. ``report``: the Assumption 1 report.
    """

    guaranteed: bool
    reason: str
    report: AssumptionReport

    def describe(self) -> str:
        """One line, the verdict first: ``"guaranteed: ..."`` or ``"NOT GUARANTEED: ..."``."""
        return f"{'guaranteed' if self.guaranteed else 'NOT GUARANTEED'}: {self.reason}"

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: ``guaranteed``, ``reason`` and the (A1)-(A3) status."""
        return {"guaranteed": bool(self.guaranteed), "reason": self.reason,
                "assumptions_hold": bool(self.report.holds), "assumptions": dict(self.report.status)}


def bounds_verdict(model: POMDP, sol: BoundsSolution, report: AssumptionReport | None = None) -> BoundsVerdict:
    """The gate's rule (module docstring, steps 2-4) for the LP solution ``sol`` of ``model``.

    ``report``: an Assumption 1 report already computed for ``model`` (else :func:`assumption_report`,
    cached). Checked in the gate's order: Assumption 1, the discount, the LP's feasibility, the Shannon
    domain.
    """
    rep = assumption_report(model) if report is None else report
    lp = _lp_name(sol.variant, sol.constant)
    if not rep.holds:
        return BoundsVerdict(False, _assumption_loss(rep), rep)
    horizon = infinite_horizon_refusal(model, _THEOREM_2)
    if horizon:
        return BoundsVerdict(False, horizon, rep)
    if not sol.feasible or sol.myopic is None:
        return BoundsVerdict(False, f"{lp} is infeasible: {sol.message}", rep)
    if sol.covers.startswith("none"):
        return BoundsVerdict(False, sol.covers.removeprefix("none: "), rep)
    return BoundsVerdict(True, _valid_reason(lp, sol.covers), rep)


@dataclass(frozen=True, eq=False)
class PlannerSetup:
    """What :func:`build_planner` decided (module docstring).

    ``planner`` is ``None`` when refused. ``mode`` is one of :data:`MODES`. ``guaranteed``: the
    bounds are proven valid for this model, so pruning keeps the optimal action and agreeing
    root bounds certify it; ``False`` for exhaustive search (nothing pruned, nothing certified),
    for a refusal and for pruning forced by ``prune_without_guarantee``. ``reason`` is one line
    for people. ``report`` is the Assumption 1 report (``None`` if bounds were disabled),
    ``bounds`` the LP solution (``None`` if the LP was not solved). ``variant`` and ``constant``
    are the bound variant and the belief-independent constant the LP was solved with
    (:data:`~.bounds.BOUND_CONSTANTS`; both ``None`` when no LP was solved). ``seconds``: the
    wall-clock seconds of each stage that ran (:class:`SetupStages`).
    """

    planner: Planner | None
    mode: str
    guaranteed: bool
    reason: str
    report: AssumptionReport | None
    bounds: BoundsSolution | None
    variant: str | None
    forced: bool = False
    constant: str | None = None
    seconds: Mapping[str, float] = field(default_factory=dict)

    @property
    def pruning(self) -> bool:
        """The planner prunes with the bounds (with or without the guarantee)."""
        return self.mode == "prune"

    @property
    def myopic(self) -> MyopicBounds | None:
        """The bound policies the planner prunes with (``None`` unless :attr:`pruning`)."""
        return self.bounds.myopic if self.pruning and self.bounds is not None else None

    def describe(self) -> str:
        """One line for a command line: the mode and the reason."""
        if self.mode == "prune":
            head = "valid bounds" if self.guaranteed else "bounds used WITHOUT GUARANTEE"
        else:
            head = {"exhaustive": "exhaustive search", "refuse": "refused"}[self.mode]
        return f"{head}: {self.reason}"

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary (the report and LP solution as short dictionaries). Without the guarantee,
        ``bounds.covers`` starts with ``none`` (the LP's own domain is no guarantee then)."""
        sol = self.bounds
        covers = None if sol is None else sol.covers
        if covers is not None and not self.guaranteed and not covers.startswith("none"):
            covers = f"none: not guaranteed ({self.reason})"
        return {
            "mode": self.mode, "guaranteed": bool(self.guaranteed), "forced": bool(self.forced),
            "reason": self.reason, "variant": self.variant, "constant": self.constant,
            "assumptions_hold": None if self.report is None else bool(self.report.holds),
            "assumptions": None if self.report is None else dict(self.report.status),
            "bounds": None if sol is None else {"variant": sol.variant, "constant": sol.constant,
                                                "feasible": bool(sol.feasible), "covers": covers,
                                                "message": sol.message, "why": sol.constants.get("why")},
        }


def build_planner(model: POMDP, *, use_bounds: bool = True, variant: str = "tight", constant: str = DEFAULT_CONSTANT,
                  on_assumption_failure: str = "exhaustive", prune_without_guarantee: bool = False,
                  chunk_bytes: int = DEFAULT_CHUNK_BYTES, memory_budget: int = DEFAULT_MEMORY_BUDGET,
                  report: AssumptionReport | None = None, override_name: str = "prune_without_guarantee",
                  max_setup_seconds: float | None = MAX_SETUP_SECONDS, setup_hint: str = "",
                  progress: Callable[[str], None] | None = None) -> PlannerSetup:
    """Check Assumption 1, solve the bounds and build the planner (module docstring).

    ``variant`` (:data:`~.bounds.BOUND_VARIANTS`) and ``constant`` (:data:`~.bounds.BOUND_CONSTANTS`:
    ``"mlr"``, the default, exact for the MLR monotonicity Corollary 1 needs, or ``"fosd"``, the
    stronger first-order dominance constant ``C_S``) choose the LP's bounds; both are checked first
    (an ``OptionError`` naming the field and the choices), also when ``use_bounds`` is off; the
    result records both (``variant``, ``constant``, in :meth:`PlannerSetup.to_dict` and in the
    reason). ``report``: an Assumption 1 report already computed for ``model``
    (else :func:`assumption_report`). ``override_name`` is how the caller's user spells the
    override (``--prune-without-guarantee``, ``prune_without_guarantee=1``), quoted in the reason.
    ``chunk_bytes`` and ``memory_budget`` (bytes, checked before every search) go to the
    :class:`~.search.Planner`.

    Set-up cost (module docstring): the set-up is refused first (:class:`SetupCostError`) when its
    estimate exceeds the available memory or ``max_setup_seconds`` (then ``setup_hint``, how to
    lift that limit, ends the message), and announced through ``progress`` (one line) when it
    is expected to be long; a stage that takes longer than :data:`STAGE_REPORT_SECONDS` is
    reported through ``progress`` as it ends, and :attr:`PlannerSetup.seconds` holds the time of
    every stage that ran.
    """
    check_variant(variant)
    check_constant(constant)
    check_choice(on_assumption_failure, ON_ASSUMPTION_FAILURE, "on_assumption_failure")

    stages = SetupStages(progress)
    with stages.stage("estimate"):
        est = estimate_setup(model, use_bounds=use_bounds, variant=variant, report=report,
                             forced=prune_without_guarantee)
        check_setup_cost(est, max_setup_seconds, setup_hint)
    notice = setup_notice(est)
    if notice is not None and progress is not None:
        progress(notice)
    setup = _decide(model, use_bounds, variant, constant, on_assumption_failure, prune_without_guarantee, report,
                    override_name, stages,
                    lambda bounds, guaranteed: Planner(model, bounds, chunk_bytes=chunk_bytes, guaranteed=guaranteed,
                                                       memory_budget=memory_budget))
    return replace(setup, seconds=dict(stages.seconds))


def _decide(model: POMDP, use_bounds: bool, variant: str, constant: str, on_assumption_failure: str,
            prune_without_guarantee: bool, report: AssumptionReport | None, override_name: str, stages: SetupStages,
            build: Callable[[MyopicBounds | None, bool], Planner]) -> PlannerSetup:
    """The gate's decisions 1-6 (module docstring), each stage timed by ``stages``."""

    def planner(bounds: MyopicBounds | None, guaranteed: bool) -> Planner:
        with stages.stage("planner tables"):
            return build(bounds, guaranteed)

    def exhaustive(reason: str, rep: AssumptionReport | None = None, sol: BoundsSolution | None = None
                   ) -> PlannerSetup:
        solved = sol is not None
        return PlannerSetup(planner(None, False), "exhaustive", False, reason, rep, sol,
                            variant if solved else None, constant=constant if solved else None)

    if not use_bounds:
        return exhaustive("bounds disabled by the user")
    with stages.stage("assumption check"):
        rep = assumption_report(model) if report is None else report
    unguaranteed = ""  # why the guarantee is lost, if it is
    if not rep.holds:
        unguaranteed = _assumption_loss(rep)
        if not prune_without_guarantee and on_assumption_failure == "refuse":
            return PlannerSetup(None, "refuse", False, unguaranteed, rep, None, None)
    horizon = infinite_horizon_refusal(model, _THEOREM_2)
    if horizon:  # no bounds to prune with, forced or not
        return exhaustive(horizon + (f"; also, {unguaranteed}" if unguaranteed else ""), rep)
    if unguaranteed and not prune_without_guarantee:
        return exhaustive(unguaranteed, rep)
    with stages.stage("bound LP"):
        sol = solve_bounds(model, variant, constant=constant)
    lp = _lp_name(variant, constant)
    if not sol.feasible or sol.myopic is None:
        return exhaustive(f"{lp} is infeasible: {sol.message}", rep, sol)
    if sol.covers.startswith("none") and not unguaranteed:
        unguaranteed = sol.covers.removeprefix("none: ")
        if not prune_without_guarantee:
            return exhaustive(f"{unguaranteed} ({lp} is feasible but not used)", rep, sol)
    if unguaranteed:
        reason = (f"forced by {override_name} although {unguaranteed}; pruning with {lp}: no guarantee holds, "
                  "the bounds may exclude the optimal action, and they certify nothing")
        return PlannerSetup(planner(sol.myopic, False), "prune", False, reason, rep, sol, variant, forced=True,
                            constant=constant)
    return PlannerSetup(planner(sol.myopic, True), "prune", True, _valid_reason(lp, sol.covers), rep, sol, variant,
                        constant=constant)
