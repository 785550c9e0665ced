"""What the belief visualiser shows (docs/ros.md, "Visualisation"), without ROS: the newest belief
as one bar per state (its height the state's probability), the true state of that epoch where a
simulator publishes it, a line with the newest decision (its action, root bounds and certificate),
and, for a grid model, the belief over the grid as occupancy values.

:class:`VisualLoop` takes decoded inputs with the time (``now``) and keeps only what it shows; its
health follows the rules "Stall levels", "One writer", "Bounded samples" and "Report" as every
loop's. :meth:`VisualLoop.scene` gives a :class:`Scene`, which the node encodes as
``visualization_msgs/MarkerArray`` and ``nav_msgs/OccupancyGrid``.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from ..model import POMDP
from .health import InputWatch, Level, LoopHealth, Report, StallLimits
from .samples import BeliefSample

#: True states kept by epoch (the newest), to pair with a belief that comes after its true state.
TRUE_STATES_KEPT = 256
#: Counters of the visualiser (all problems but ``beliefs``, ``plan_infos`` and ``true_states``).
COUNTERS = ("beliefs", "plan_infos", "true_states", "malformed_messages", "out_of_range_true_states")
PROBLEMS = ("malformed_messages", "out_of_range_true_states")
#: The colour of a bar of probability 0 and of the most probable state (RGBA, 0..1), and the true state's.
LOW_RGBA = (0.25, 0.45, 0.95, 0.9)
HIGH_RGBA = (0.95, 0.25, 0.15, 0.9)
TRUE_RGBA = (0.1, 0.85, 0.2, 1.0)


class GridError(ValueError):
    """A grid shape that does not fit the model."""


def grid_shape(model: POMDP, given: Sequence[int] | None = None) -> tuple[int, int] | None:
    """``(rows, cols)`` of a grid model, state ``s`` being the cell ``(s // cols, s % cols)``
    (row-major): the model's ``grid: {rows, cols}`` metadata, else its ``generator``'s ``rows`` and
    ``cols`` when its domain is ``grid``, else ``given`` (``[rows, cols]``; empty or ``None``: the
    model is not a grid). ``rows * cols`` minus the grid's obstacles must be the number of states
    (:class:`GridError`; the states are the free cells in row-major order, :func:`grid_cells`)."""
    meta = model.metadata or {}
    source, shape = "grid_shape", None
    grid = meta.get("grid")
    gen = meta.get("generator")
    if isinstance(grid, Mapping) and {"rows", "cols"} <= set(grid):
        source, shape = "the model's grid", (grid["rows"], grid["cols"])
    elif isinstance(gen, Mapping) and gen.get("domain") == "grid" and {"rows", "cols"} <= set(gen):
        source, shape = "the model's generator", (gen["rows"], gen["cols"])
    elif given:
        shape = tuple(given)
    if shape is None:
        return None
    if len(shape) != 2 or not all(isinstance(n, int | np.integer) and not isinstance(n, bool) and n >= 1
                                  for n in shape):
        raise GridError(f"{source}: must be [rows, cols], two positive integers, got {list(shape)}")
    rows, cols = int(shape[0]), int(shape[1])
    blocked = len(_obstacles(model)) if source == "the model's grid" else 0
    if rows * cols - blocked != model.S:
        free = f"{rows * cols - blocked} free cells" if blocked else f"{rows * cols} cells"
        raise GridError(f"{source}: [{rows}, {cols}] has {free}, the model {model.S} states")
    return rows, cols


def _obstacles(model: POMDP) -> list:
    grid = (model.metadata or {}).get("grid")
    return list(grid.get("obstacles") or ()) if isinstance(grid, Mapping) else []


def grid_cells(model: POMDP, shape: tuple[int, int]) -> np.ndarray:
    """``(S, 2)``: the ``(row, col)`` of every state on the grid ``shape`` (:func:`grid_shape`): the
    free cells in row-major order, the model's grid obstacles left out."""
    rows, cols = shape
    blocked = {(int(r), int(c)) for r, c in _obstacles(model)}
    cells = [(r, c) for r in range(rows) for c in range(cols) if (r, c) not in blocked]
    return np.array(cells, dtype=np.int64).reshape(-1, 2)


@dataclass(frozen=True)
class Bar:
    """The bar of one state: its cell's centre ``(x, y)`` in the frame (m), its probability, its
    height and colour (RGBA)."""

    state: int
    x: float
    y: float
    probability: float
    height: float
    rgba: tuple[float, float, float, float]


@dataclass(frozen=True)
class Scene:
    """What the visualiser publishes for the newest belief (module docstring)."""

    epoch: int
    bars: tuple[Bar, ...]
    true_state: int | None
    text: str
    #: The text's position (above the bars, m).
    text_xyz: tuple[float, float, float]
    #: Grid models: ``(rows, cols)`` and one occupancy value per cell, row-major (0..100; -1 on an
    #: obstacle).
    grid: tuple[int, int] | None = None
    occupancy: tuple[int, ...] = ()


def occupancy(belief: np.ndarray) -> tuple[int, ...]:
    """Occupancy values 0..100 of a belief over grid cells: ``round(100 b(s) / max b)``, so the most
    probable cell is 100 and a cell of probability 0 is 0 (the probabilities themselves are the
    bars' and the belief topic's)."""
    b = np.asarray(belief, dtype=float)
    top = float(b.max())
    if top <= 0.0:
        return (0,) * b.size
    return tuple(int(v) for v in np.rint(100.0 * b / top).astype(int))


def decision_text(info: Mapping[str, float] | None, model: POMDP) -> str:
    """The line for the newest decision (``plan_info``'s fields): its epoch, action, root bounds and
    certificate; ``None``: no decision yet."""
    if info is None:
        return "no decision yet"
    p = int(info["action_priority"])
    names = model.action_names
    name = f" ({names[p - 1]})" if names and 1 <= p <= len(names) else ""
    lo, hi = int(info["bound_lower"]), int(info["bound_upper"])
    bounds = f"bounds [{lo}, {hi}]" if lo >= 1 and hi >= 1 else "no bounds"
    return (f"epoch {int(info['epoch'])}: priority {p}{name}, {bounds}, "
            f"{'certified' if info['certified'] >= 0.5 else 'not certified'}, depth {int(info['depth'])}")


class VisualLoop:
    """The visualiser's inputs and what they show (module docstring). ``grid``: ``(rows, cols)`` of
    a grid model (:func:`grid_shape`), ``None`` for bars in a row; ``spacing``: the distance between
    neighbouring bars (m), ``bar_height``: the height of a bar of probability 1 (m)."""

    def __init__(self, model: POMDP, grid: tuple[int, int] | None, *, now: float, spacing: float = 1.0,
                 bar_height: float = 1.0, stall: StallLimits | None = None):
        self.model, self.grid = model, grid
        self.cells = None if grid is None else grid_cells(model, grid)
        self.spacing, self.bar_height = spacing, bar_height
        self.health = LoopHealth(COUNTERS, PROBLEMS, [InputWatch("belief", "belief", started=now)],
                                 stall or StallLimits(), streams=("plan_info", "true_state"))
        self.newest: BeliefSample | None = None
        self.info: dict[str, float] | None = None
        self.true_states: OrderedDict[int, int] = OrderedDict()
        self.changed = False

    # ----------------------------------------------------------- inputs
    def belief(self, sample: BeliefSample, now: float) -> None:
        """A belief: shown from now on (the newest received; a restarted filter's too)."""
        new = self.newest is None or sample.epoch != self.newest.epoch
        self.health.watch("belief").arrived(now, new, sample.epoch)
        self.health.count("beliefs")
        self.newest = sample
        self.changed = True

    def true_state(self, epoch: int, state: int, now: float) -> None:
        """The simulator's true state of ``epoch`` (kept for the belief of that epoch)."""
        if not 0 <= state < self.model.S:
            self.health.warn("out_of_range_true_states", f"true_state: state {state} out of range "
                             f"0..{self.model.S - 1} (epoch {epoch})", now)
            return
        self.health.count("true_states")
        self.true_states[epoch] = state
        self.true_states.move_to_end(epoch)
        while len(self.true_states) > TRUE_STATES_KEPT:
            self.true_states.popitem(last=False)
        self.changed = self.changed or (self.newest is not None and self.newest.epoch == epoch)

    def plan_info(self, info: Mapping[str, float], now: float) -> None:
        """A decision's record: its line replaces the previous one."""
        self.health.count("plan_infos")
        self.info = dict(info)
        self.changed = True

    def rejected(self, topic: str, problem: str, now: float) -> None:
        """A sample of ``topic`` that does not decode: counted, warned, dropped."""
        self.health.reject(self.health.watch(topic), "malformed_messages", problem, now)

    # ----------------------------------------------------------- output
    def position(self, state: int) -> tuple[float, float]:
        """The centre of ``state``'s cell (m): ``(col + 1/2, row + 1/2) * spacing`` on a grid (row
        ``r`` at ``y = (r + 1/2) * spacing``, as an OccupancyGrid's row ``r``), else
        ``((s + 1/2) * spacing, 0)``."""
        if self.grid is None:
            return (state + 0.5) * self.spacing, 0.0
        r, c = self.cells[state]
        return (c + 0.5) * self.spacing, (r + 0.5) * self.spacing

    def scene(self) -> Scene | None:
        """What to publish for the newest belief (``None``: none yet); clears :attr:`changed`."""
        self.changed = False
        if self.newest is None:
            return None
        b = np.asarray(self.newest.belief, dtype=float)
        top = float(b.max()) or 1.0
        bars = []
        for s, p in enumerate(b):
            w = float(p) / top
            rgba = tuple(lo + w * (hi - lo) for lo, hi in zip(LOW_RGBA, HIGH_RGBA, strict=True))
            x, y = self.position(s)
            bars.append(Bar(s, x, y, float(p), float(p) * self.bar_height, rgba))
        true = self.true_states.get(self.newest.epoch)
        if self.grid is None:
            centre = (self.model.S * self.spacing / 2, 0.0)
        else:
            centre = (self.grid[1] * self.spacing / 2, self.grid[0] * self.spacing / 2)
        text = f"belief of epoch {self.newest.epoch}; {decision_text(self.info, self.model)}"
        return Scene(epoch=self.newest.epoch, bars=tuple(bars), true_state=true, text=text,
                     text_xyz=(centre[0], centre[1] - self.spacing, self.bar_height + 0.3 * self.spacing),
                     grid=self.grid, occupancy=self.occupancy(b) if self.grid is not None else ())

    def occupancy(self, belief: np.ndarray) -> tuple[int, ...]:
        """One value per cell of the grid, row-major: :func:`occupancy` of the belief on the free
        cells, -1 (unknown) on an obstacle."""
        rows, cols = self.grid
        out = np.full(rows * cols, -1, dtype=np.int64)
        out[self.cells[:, 0] * cols + self.cells[:, 1]] = occupancy(belief)
        return tuple(int(v) for v in out)

    def report(self, now: float) -> Report:
        """The diagnostics (rule "Report"): the newest belief's epoch and the counts."""
        epoch = "none" if self.newest is None else self.newest.epoch
        values = {"epoch": epoch, "grid": "none" if self.grid is None else f"{self.grid[0]}x{self.grid[1]}"}
        head = [f"showing the belief of epoch {epoch}"] if self.newest is not None else []
        return self.health.report(now, values, head=head, level=Level.OK, idle="waiting for the first belief")
