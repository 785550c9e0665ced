"""A 2-D target search: a target moving on an ``rows x cols`` grid, watched by one sensor.

The sensor-management problem of the paper (Sec. II) on a grid instead of a line: the action is
the *priority* the sensor gives the target, and the priority sets how well the sensor sees it.

* **States** ``s = 0..S-1``: the free cells (not obstacles) in row-major order; with no obstacles
  state ``s`` is the cell ``(s // cols, s % cols)``. :func:`grid_cells` gives the cell of every
  state, from the model's ``metadata["grid"]`` (``{"rows", "cols", "obstacles"}``, the field a
  consumer such as an occupancy-grid view reads).
* **Transitions** (the same for every action: watching the target does not move it): with
  probability ``1 - move`` the target stays; otherwise it tries one of the four directions
  (``move / 4`` each) and stays where that direction is blocked (the border or an obstacle). At
  most five non-zeros per row.
* **Observations** ``z = 0..S``: ``z < S`` reports the cell of state ``z``, ``z = S`` is "not
  detected". Under priority ``a + 1`` a target inside the sensor's field of view
  (``fov[a]``: the Chebyshev distance from the cell ``sensor``, default the whole grid) is detected
  with probability ``detection[a]``; a detection reports the true cell with probability
  ``accuracy``, otherwise one of its free 4-neighbours (uniformly; a cell without free neighbours
  reports itself). So ``Z = S + 1`` and at most six non-zeros per row.
* **Reward** (``effort_reward``): ``r(s, a) = -cost[a]``, the price of the sensor's time at
  priority ``a + 1``; the belief reward of Eq. 3 subtracts ``w_a f(b)`` (the model's
  ``uncertainty``: Renyi quadratic or Shannon entropy of where the target is).

**Assumption 1 does not hold for grid models.** It needs the states totally ordered so that the
transition and observation kernels are TP2 along that order (A1); a grid has no such order. In
row-major numbering a step down (``+cols``) and a step left (``-1``) already give a negative 2x2
minor of ``P``: with rows ``s < s + 1`` and columns ``s < s + cols``,
``P[s, s] P[s+1, s+cols] - P[s, s+cols] P[s+1, s] = -P[s, s+cols] P[s+1, s] < 0`` for a cell ``s``
with a free neighbour below and a free right neighbour ``s + 1`` (any grid with two rows and two
columns). ``pomdp-planner check`` reports (A1) failing; the assumption gate (``core/gate.py``)
then plans by exhaustive search (every action, no bound pruning) and certifies nothing.

Sizes are checked before anything is allocated: the matrices are built sparse
(:class:`~pomdp_planner.core.sparse.SparseStack`) and the model stores them sparse when that is
smaller (:func:`~pomdp_planner.core.sparse.choose_storage`): a 100 x 100 grid with three
priorities stores about 2 MiB.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..checks import is_integer
from ..errors import ModelError
from ..model import POMDP, as_count, as_number, check_model_size, per_action_vector
from ..sparse import SparseStack

#: Largest number of cells of a grid (rows x cols): a million cells.
MAX_GRID_CELLS = 10**6
#: Default probability that the target moves in one step.
DEFAULT_MOVE = 0.2
#: Default probability that a detection reports the true cell.
DEFAULT_ACCURACY = 0.8


def default_detection(A: int) -> np.ndarray:
    """Detection probabilities from 0.9 (priority 1) down to 0.3 (priority A), evenly spaced."""
    return np.linspace(0.9, 0.3, A) if A > 1 else np.array([0.9])


def _probability(value: object, field: str, low_open: bool = False) -> float:
    x = as_number(value, field)
    if not (0.0 < x <= 1.0 if low_open else 0.0 <= x <= 1.0):
        raise ModelError(f"{field}: must be a probability in {'(0, 1]' if low_open else '[0, 1]'}, got {x:g}")
    return x


def _cell(value: object, field: str, rows: int, cols: int) -> tuple[int, int]:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise ModelError(f"{field}: expected a cell [row, col], got {value!r:.60}")
    if not all(is_integer(v) for v in value):
        raise ModelError(f"{field}: a cell is two integers [row, col], got {value!r:.60}")
    r, c = (int(v) for v in value)
    if not (0 <= r < rows and 0 <= c < cols):
        raise ModelError(f"{field}: cell [{r}, {c}] is outside the {rows} x {cols} grid (rows and columns 0-based)")
    return r, c


class GridLayout:
    """The cells of a grid and which are free: ``index[r, c]`` is the state of cell ``(r, c)``
    (-1 for an obstacle), ``cells[s]`` the cell ``(row, col)`` of state ``s``."""

    def __init__(self, rows: int, cols: int, obstacles: Sequence[Sequence[int]] = ()):
        self.rows = as_count(rows, "generator.rows")
        self.cols = as_count(cols, "generator.cols")
        if self.rows * self.cols > MAX_GRID_CELLS:
            raise ModelError(f"generator: a {self.rows} x {self.cols} grid has {self.rows * self.cols:,} cells, "
                             f"more than {MAX_GRID_CELLS:,} (MAX_GRID_CELLS)")
        if not isinstance(obstacles, (list, tuple)):
            raise ModelError(f"generator.obstacles: expected a list of cells [row, col], got {obstacles!r:.60}")
        if len(obstacles) > self.rows * self.cols:
            raise ModelError(f"generator.obstacles: {len(obstacles)} cells given for a grid of "
                             f"{self.rows * self.cols}")
        free = np.ones((self.rows, self.cols), dtype=bool)
        for k, cell in enumerate(obstacles):
            r, c = _cell(cell, f"generator.obstacles[{k}]", self.rows, self.cols)
            free[r, c] = False
        if not free.any():
            raise ModelError("generator.obstacles: every cell is an obstacle (the target needs a free cell)")
        self.free = free
        self.index = np.full((self.rows, self.cols), -1, dtype=np.int64)
        self.index[free] = np.arange(int(free.sum()))
        self.cells = np.argwhere(free)  # (S, 2), row-major

    @property
    def S(self) -> int:  # noqa: N802 - the paper's name
        return int(self.cells.shape[0])

    def obstacles(self) -> list[list[int]]:
        """The obstacle cells ``[row, col]``, row-major."""
        return np.argwhere(~self.free).tolist()

    def neighbours(self) -> np.ndarray:
        """``(S, 4)``: the state reached by a step up, down, left, right from each state (-1 where
        that step is blocked)."""
        r, c = self.cells[:, 0], self.cells[:, 1]
        out = np.full((self.S, 4), -1, dtype=np.int64)
        for d, (dr, dc) in enumerate(((-1, 0), (1, 0), (0, -1), (0, 1))):
            rr, cc = r + dr, c + dc
            inside = (rr >= 0) & (rr < self.rows) & (cc >= 0) & (cc < self.cols)
            out[inside, d] = self.index[rr[inside], cc[inside]]
        return out

    def metadata(self) -> dict:
        """``{"rows", "cols", "obstacles"}``: the model's ``metadata["grid"]``."""
        return {"rows": self.rows, "cols": self.cols, "obstacles": self.obstacles()}


def grid_cells(metadata: dict) -> np.ndarray:
    """The cell ``(row, col)`` of every state of a grid model, ``(S, 2)``, from its
    ``metadata["grid"]`` (states are the free cells in row-major order)."""
    grid = metadata["grid"]
    return GridLayout(grid["rows"], grid["cols"], grid.get("obstacles", ())).cells


def grid_transitions(layout: GridLayout, A: int, move: float = DEFAULT_MOVE) -> SparseStack:
    """``P`` (module docstring), one CSR matrix per action (the same matrix for every action)."""
    move = _probability(move, "generator.move")
    S = layout.S
    nb = layout.neighbours()
    blocked = (nb < 0).sum(axis=1)
    rows = [np.arange(S)]
    cols = [np.arange(S)]
    vals = [(1.0 - move) + move * blocked / 4.0]
    for d in range(4):
        ok = nb[:, d] >= 0
        rows.append(np.flatnonzero(ok))
        cols.append(nb[ok, d])
        vals.append(np.full(int(ok.sum()), move / 4.0))
    r, c, v = (np.concatenate(x) for x in (rows, cols, vals))
    keep = v > 0
    one = SparseStack.from_coo(1, S, S, np.zeros(int(keep.sum()), int), r[keep], c[keep], v[keep])
    return SparseStack([one[0]] * A, (A, S, S))


def grid_observations(layout: GridLayout, A: int, detection: Sequence[float] | None = None,
                      accuracy: float = DEFAULT_ACCURACY, sensor: Sequence[int] | None = None,
                      fov: Sequence[float] | float | None = None) -> SparseStack:
    """``O`` (module docstring), ``S x (S + 1)`` per action."""
    S = layout.S
    det = default_detection(A) if detection is None else per_action_vector("generator.detection", detection, A,
                                                                            "probability")
    for a, p in enumerate(det):
        _probability(p, f"generator.detection[{a}]")
    accuracy = _probability(accuracy, "generator.accuracy")
    if fov is None:
        seen = np.ones((A, S), dtype=bool)
    else:
        radius = per_action_vector("generator.fov", fov, A, "radius")
        if np.any(radius < 0):
            raise ModelError(f"generator.fov[{int(np.argmax(radius < 0))}]: a radius must be >= 0")
        if sensor is None:
            raise ModelError("generator.sensor: missing (the cell the field of view is centred on, [row, col])")
        sr, sc = _cell(sensor, "generator.sensor", layout.rows, layout.cols)
        dist = np.maximum(np.abs(layout.cells[:, 0] - sr), np.abs(layout.cells[:, 1] - sc))
        seen = dist[None, :] <= radius[:, None]
    nb = layout.neighbours()
    free_nb = (nb >= 0).sum(axis=1)
    # where a detection is reported: the cell itself, or a free neighbour
    rep_r = [np.arange(S)]
    rep_c = [np.arange(S)]
    rep_v = [np.where(free_nb > 0, accuracy, 1.0)]
    for d in range(4):
        ok = nb[:, d] >= 0
        rep_r.append(np.flatnonzero(ok))
        rep_c.append(nb[ok, d])
        rep_v.append((1.0 - accuracy) / free_nb[ok])
    rr, rc, rv = (np.concatenate(x) for x in (rep_r, rep_c, rep_v))
    mats = []
    for a in range(A):
        p = np.where(seen[a], det[a], 0.0)
        v = np.concatenate([p[rr] * rv, 1.0 - p])
        i = np.concatenate([rr, np.arange(S)])
        j = np.concatenate([rc, np.full(S, S)])
        keep = v > 0
        mats.append(SparseStack.from_coo(1, S, S + 1, np.zeros(int(keep.sum()), int), i[keep], j[keep], v[keep])[0])
    return SparseStack(mats, (A, S, S + 1))


def effort_reward(S: int, A: int, cost: Sequence[float] | float | None = None) -> np.ndarray:
    """``r(s, a) = -cost[a]`` (S x A); default ``cost[a] = 0.1 (A - 1 - a) / max(A - 1, 1)``: priority
    1 costs 0.1, priority A nothing."""
    c = 0.1 * (A - 1 - np.arange(A)) / max(A - 1, 1) if cost is None else per_action_vector(
        "reward_generator.cost", cost, A, "cost")
    return np.broadcast_to(-c[None, :], (S, A)).copy()


def check_grid_size(layout: GridLayout, A: int, field: str = "generator") -> None:
    """The grid model's matrices (at most 5 and 6 non-zeros per row) within ``MAX_MODEL_BYTES``."""
    S = layout.S
    check_model_size(S, A, S + 1, field, nnz=A * 11 * S)


def grid_model(rows: int, cols: int, A: int = 3, *, move: float = DEFAULT_MOVE,
               detection: Sequence[float] | None = None, accuracy: float = DEFAULT_ACCURACY,
               obstacles: Sequence[Sequence[int]] = (), sensor: Sequence[int] | None = None,
               fov: Sequence[float] | float | None = None, cost: Sequence[float] | float | None = None,
               gamma: float = 0.95, uncertainty: str = "renyi2", w: Sequence[float] | float | None = 1.0,
               epsilon: float | None = None, name: str | None = None, storage: str = "auto") -> POMDP:
    """A complete grid target-search POMDP (module docstring)."""
    A = as_count(A, "generator.A")
    layout = GridLayout(rows, cols, obstacles)
    check_grid_size(layout, A)
    P = grid_transitions(layout, A, move)
    O = grid_observations(layout, A, detection, accuracy, sensor, fov)
    gen = {"domain": "grid", "rows": layout.rows, "cols": layout.cols, "A": A, "move": move,
           "detection": None if detection is None else list(map(float, np.broadcast_to(detection, (A,)))),
           "accuracy": accuracy, "obstacles": layout.obstacles(),
           "sensor": None if sensor is None else list(sensor),
           "fov": None if fov is None else list(map(float, np.broadcast_to(fov, (A,))))}
    return POMDP(P=P, O=O, r=effort_reward(layout.S, A, cost), gamma=gamma, uncertainty=uncertainty,
                 w=np.broadcast_to(w, (A,)) if w is not None else None, epsilon=epsilon,
                 name=name or f"grid_{layout.rows}x{layout.cols}",
                 metadata={"grid": layout.metadata(), "generator": gen}, storage=storage)
