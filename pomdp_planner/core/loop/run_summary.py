"""What a recorded run shows per decision and in sum, without ROS: the demo's table and summary
(``nodes/demo.py`` formats them) over the rows of the run recorder's rule
(:class:`~.recorder_loop.RecorderLoop`).

Per row (:class:`RowFacts`): the belief's mode and its probability, its Shannon entropy (nats),
the reward ``r(s_t, a_t) - w_a f(b_t)`` where the true state is known (the paper's Eq. 3 with the
true state for the expectation, the model's uncertainty function ``f``), and the greedy priority
``argmax_a rho(b_t, a)`` at the same belief (the core's ``myopic`` policy; ties: the greatest
priority). In sum (:class:`RunSummary`): the mean reward and entropy, on how many rows the action
differs from greedy's, and over the rows with a ``plan_info``, the decisions, deadline misses
(each decision's own flag: the planner's rule) and certified decisions, and the widths of the
root bound intervals that left more than one priority open.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..model import POMDP
from ..policies import MyopicPolicy
from ..uncertainty import SHANNON
from .planner_loop import PlanInfo
from .recorder_loop import RecordRow


@dataclass(frozen=True)
class RowFacts:
    """One row of the table: the decision made from ``belief`` at ``epoch`` (priorities ``1..A``)."""

    epoch: int
    true_state: int | None
    mode: int
    p_mode: float
    entropy: float
    priority: int
    bounds: tuple[int, int] | None
    greedy: int
    info: PlanInfo | None


@dataclass
class RunSummary:
    """The rows added so far (:meth:`add`) and their sums (module docstring)."""

    model: POMDP
    rewards: list[float] = field(default_factory=list)
    entropies: list[float] = field(default_factory=list)
    not_greedy: int = 0
    decisions: int = 0
    misses: int = 0
    certified: int = 0
    open_widths: set[int] = field(default_factory=set)

    def __post_init__(self):
        self._greedy = MyopicPolicy(self.model)

    @property
    def shown(self) -> int:
        """Rows added."""
        return len(self.entropies)

    def add(self, row: RecordRow) -> RowFacts:
        """Count ``row`` and return what the table shows of it."""
        m, b, a, s = self.model, row.belief, row.priority - 1, row.true_state
        mode = int(b.argmax())
        entropy = float(SHANNON.value(b))
        if s is not None:
            self.rewards.append(float(m.r[s, a] - m.w[a] * m.uncertainty.value(b)))
        self.entropies.append(entropy)
        if row.bounds is not None and row.bounds[1] > row.bounds[0]:
            self.open_widths.add(row.bounds[1] - row.bounds[0] + 1)
        if row.info is not None:
            self.decisions += 1
            self.misses += row.info.deadline_miss
            self.certified += row.info.certified
        greedy = self._greedy.act(b)
        self.not_greedy += greedy != a
        return RowFacts(row.epoch, s, mode, float(b[mode]), entropy, row.priority, row.bounds, greedy + 1, row.info)

    @property
    def mean_reward(self) -> float | None:
        """Over the rows with a true state (``None``: none)."""
        return sum(self.rewards) / len(self.rewards) if self.rewards else None

    @property
    def mean_entropy(self) -> float | None:
        return sum(self.entropies) / len(self.entropies) if self.entropies else None
