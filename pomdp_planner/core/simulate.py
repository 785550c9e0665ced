"""Closed-loop simulation of a policy on a POMDP (the true state is hidden from the policy).

One step ``t`` of :func:`simulate` (paper Sec. II, Eqs. 1-3):

1. the policy sees only the belief ``b_t`` and picks an action ``a_t`` (0-based);
2. rewards: ``rho(b_t, a_t)`` (Eq. 3, the belief reward a planner maximises) and the state
   reward ``r(s_t, a_t)`` of the hidden true state;
3. the true state moves, ``s_{t+1} ~ P[a_t, s_t, :]``, and an observation is drawn,
   ``z_{t+1} ~ O[a_t, s_{t+1}, :]``;
4. the belief is updated, ``b_{t+1} = tau(b_t, a_t, z_{t+1})`` (Eqs. 1-2), by the epoch filter
   of ``core/filter.py`` that the belief filter node uses too.

The discounted return is ``sum_t gamma^t rho(b_t, a_t)``. Observations are sampled from the
model, so an impossible observation can only happen when the initial belief excludes the
true initial state (both can be given independently). Then the filter restarts from the
uniform prior pushed through ``P[a_t]`` (``core/filter.py``: ``b ∝ (u @ P[a_t]) * O[a_t, :, z]``)
and the step is flagged ``recovered``.

Policies are callables ``belief -> 0-based action`` or objects with ``.act(belief)``; a name
is looked up in the one policy table :data:`~.policies.POLICIES` (``core/policies.py``).

:class:`Simulation` yields the steps one by one and keeps none of them (constant memory for any
number of steps; ``pomdp-planner simulate`` streams its output from it, with a
:class:`RunningSummary`); :func:`simulate` collects them into a :class:`SimulationTrace`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from .belief import check_belief, start_belief, uniform_belief
from .checks import check_int, is_integer
from .filter import EpochFilter
from .model import POMDP, short_repr
from .options import STEPS_RANGE, check_seed
from .policies import Policy, as_callable, make_policy
from .sparse import sample_inverse_cdf
from .uncertainty import SHANNON


# ------------------------------------------------------------------------- simulation
@dataclass(frozen=True, eq=False)
class SimulationStep:
    """One step ``t`` of a closed-loop run (0-based indices): ``state`` = ``s_t``, ``next_state``
    = ``s_{t+1}``, ``action`` = ``a_t``, ``observation`` = ``z_{t+1}``, ``belief`` = ``b_{t+1}``
    and ``entropy`` its Shannon entropy (nats), ``reward`` = ``rho(b_t, a_t)``, ``state_reward``
    = ``r(s_t, a_t)``, ``recovered``: the observation was impossible under ``b_t``."""

    t: int
    state: int
    next_state: int
    action: int
    observation: int
    belief: np.ndarray
    entropy: float
    reward: float
    state_reward: float
    recovered: bool

    def to_dict(self, state_names: tuple[str, ...] | None = None,
                observation_names: tuple[str, ...] | None = None) -> dict:
        """JSON-ready row; the action as a tracking priority ``1..A`` (key ``priority``)."""
        row = {
            "step": int(self.t),
            "state": int(self.state),
            "next_state": int(self.next_state),
            "priority": int(self.action) + 1,
            "observation": int(self.observation),
            "belief": self.belief.tolist(),
            "entropy": float(self.entropy),
            "reward": float(self.reward),
            "state_reward": float(self.state_reward),
            "recovered": bool(self.recovered),
        }
        if state_names is not None:
            row["state_name"] = state_names[self.state]
            row["next_state_name"] = state_names[self.next_state]
        if observation_names is not None:
            row["observation_name"] = observation_names[self.observation]
        return row


class RunningSummary:
    """The summary of a run from running sums (constant memory, any number of steps): the same
    figures as :meth:`SimulationTrace.summary`, which computes them from the stored arrays."""

    def __init__(self, gamma: float):
        self.gamma = float(gamma)
        self.steps = self.recovered = 0
        self._discount = 1.0
        self._reward = self._state_reward = self._entropy = 0.0
        self._return = self._state_return = 0.0

    def add(self, step: SimulationStep) -> None:
        self.steps += 1
        self.recovered += bool(step.recovered)
        self._reward += step.reward
        self._state_reward += step.state_reward
        self._entropy += step.entropy
        self._return += self._discount * step.reward
        self._state_return += self._discount * step.state_reward
        self._discount *= self.gamma

    def summary(self) -> dict:
        n = self.steps
        return {
            "steps": n,
            "mean_reward": self._reward / n if n else float("nan"),
            "mean_state_reward": self._state_reward / n if n else float("nan"),
            "discounted_return": self._return,
            "discounted_state_return": self._state_return,
            "mean_entropy": self._entropy / n if n else float("nan"),
            "recovered_steps": self.recovered,
        }


@dataclass(frozen=True, eq=False)
class SimulationTrace:
    """Everything that happened in one closed-loop run of ``steps`` steps (0-based indices).

    ``states[t]`` = ``s_t`` (true state when acting), ``next_states[t]`` = ``s_{t+1}``,
    ``actions[t]`` = ``a_t``, ``observations[t]`` = ``z_{t+1}``, ``beliefs[t]`` = ``b_t``
    (shape ``(steps + 1, S)``, ``beliefs[0]`` the initial belief), ``entropies[t]`` = Shannon
    entropy (nats) of ``b_{t+1}``, ``rewards[t]`` = ``rho(b_t, a_t)``, ``state_rewards[t]`` =
    ``r(s_t, a_t)``, ``recovered[t]`` = the observation was impossible under ``b_t`` (see the
    module docstring). It holds every step: for long runs iterate a :class:`Simulation` instead.
    """

    model_name: str
    gamma: float
    seed: int | None
    policy: str
    states: np.ndarray
    next_states: np.ndarray
    actions: np.ndarray
    observations: np.ndarray
    beliefs: np.ndarray
    entropies: np.ndarray
    rewards: np.ndarray
    state_rewards: np.ndarray
    recovered: np.ndarray

    @property
    def steps(self) -> int:
        return int(self.actions.size)

    @property
    def discounts(self) -> np.ndarray:
        return self.gamma ** np.arange(self.steps)

    @property
    def discounted_return(self) -> float:
        """``sum_t gamma^t rho(b_t, a_t)``."""
        return float(self.discounts @ self.rewards)

    @property
    def discounted_state_return(self) -> float:
        """``sum_t gamma^t r(s_t, a_t)``."""
        return float(self.discounts @ self.state_rewards)

    @property
    def mean_reward(self) -> float:
        return float(self.rewards.mean()) if self.steps else float("nan")

    @property
    def mean_state_reward(self) -> float:
        return float(self.state_rewards.mean()) if self.steps else float("nan")

    def summary(self) -> dict:
        return {
            "steps": self.steps,
            "mean_reward": self.mean_reward,
            "mean_state_reward": self.mean_state_reward,
            "discounted_return": self.discounted_return,
            "discounted_state_return": self.discounted_state_return,
            "mean_entropy": float(self.entropies.mean()) if self.steps else float("nan"),
            "recovered_steps": int(self.recovered.sum()),
        }

    def step(self, t: int) -> SimulationStep:
        """Step ``t`` as a :class:`SimulationStep`."""
        return SimulationStep(t, int(self.states[t]), int(self.next_states[t]), int(self.actions[t]),
                              int(self.observations[t]), self.beliefs[t + 1], float(self.entropies[t]),
                              float(self.rewards[t]), float(self.state_rewards[t]), bool(self.recovered[t]))

    def to_dict(self, state_names: tuple[str, ...] | None = None,
                observation_names: tuple[str, ...] | None = None) -> dict:
        """JSON-ready record; actions as tracking priorities ``1..A`` (key ``priority``).

        Per step (:meth:`SimulationStep.to_dict`): ``state`` = ``s_t``, ``next_state`` =
        ``s_{t+1}``, ``observation`` = ``z_{t+1}``, ``belief`` = the updated belief ``b_{t+1}``
        and ``entropy`` its Shannon entropy (nats), ``reward`` = ``rho(b_t, a_t)``,
        ``state_reward`` = ``r(s_t, a_t)``; indices 0-based.
        """
        return {
            "model": self.model_name,
            "policy": self.policy,
            "seed": self.seed,
            "gamma": self.gamma,
            "initial_belief": self.beliefs[0].tolist(),
            "steps": [self.step(t).to_dict(state_names, observation_names) for t in range(self.steps)],
            "summary": self.summary(),
        }


def _sample(rng: np.random.Generator, p: np.ndarray) -> int:
    """Inverse-CDF sample from ``p`` (rows sum to 1 only within the model's tolerance)."""
    c = np.cumsum(p)
    return int(min(np.searchsorted(c, rng.random() * c[-1], side="right"), p.size - 1))


def check_steps(steps: object, field: str = "steps") -> int:
    """``steps`` as an int after checking it is an integer in :data:`~.options.STEPS_RANGE`
    (``OptionError`` naming ``field``)."""
    return check_int(steps, field, *STEPS_RANGE)


class Simulation:
    """A closed-loop run, one step at a time: iterating it yields ``steps`` :class:`SimulationStep`
    records, simulated as they are asked for; nothing of a step is kept after it is yielded, so a
    run of any length needs constant memory (the command line prints each step as it comes and
    keeps a :class:`RunningSummary`). Arguments as :func:`simulate`, which collects the steps into a
    :class:`SimulationTrace`; the same seed gives the same steps either way. Everything is checked
    when it is built; it may be iterated once.
    """

    def __init__(self, model: POMDP, policy: Policy | str, steps: int, seed: int | None = None,
                 initial_state: int | None = None, initial_belief: np.ndarray | None = None):
        self.model = model
        self.steps = check_steps(steps)
        self.seed = None if seed is None else check_seed(seed)
        self._rng = np.random.default_rng(seed)
        if isinstance(policy, str):
            self.policy_name = policy
            policy = make_policy(policy, model, seed=None if seed is None else seed + 1)
        else:
            self.policy_name = str(getattr(policy, "name", None) or getattr(policy, "__name__", None)
                                   or type(policy).__name__)
        self.policy = policy
        self._act = as_callable(policy)
        if initial_belief is None:
            b = start_belief(model)
            b = uniform_belief(model) if b is None else b
        else:
            b = check_belief(model, initial_belief, field="initial_belief")
        self.initial_belief = b
        if initial_state is None:
            self.initial_state = _sample(self._rng, b)
        else:
            self.initial_state = check_int(initial_state, "initial_state", 0, model.S - 1)
        self._started = False

    def __iter__(self) -> Iterator[SimulationStep]:
        if self._started:
            raise RuntimeError("a Simulation can be iterated once")
        self._started = True
        return self._run()

    def _run(self) -> Iterator[SimulationStep]:
        model, rng, act = self.model, self._rng, self._act
        epoch_filter = EpochFilter(model)
        P, O = (model.P_csr, model.O_csr) if model.sparse else (model.P, model.O)
        b, s = self.initial_belief, self.initial_state
        for t in range(self.steps):
            a = act(b.copy())
            if not is_integer(a) or not 0 <= a < model.A:
                raise ValueError(f"policy returned {short_repr(a)} at step {t}: expected a 0-based action in "
                                 f"0..{model.A - 1}")
            a = int(a)
            reward = float(model.rho(b)[a])
            state_reward = float(model.r[s, a])
            s_next = sample_inverse_cdf(rng, P, a, s)
            z = sample_inverse_cdf(rng, O, a, s_next)
            epoch = epoch_filter.step(b, a, {0: z})
            b = epoch.belief
            yield SimulationStep(t, s, s_next, a, z, b, float(SHANNON.value(b)), reward, state_reward,
                                 bool(epoch.restarted))
            s = s_next


def simulate(model: POMDP, policy: Policy | str, steps: int, seed: int | None = None,
             initial_state: int | None = None, initial_belief: np.ndarray | None = None) -> SimulationTrace:
    """Run ``policy`` in closed loop for ``steps`` steps (see the module docstring).

    ``policy``: a callable ``belief -> action`` (0-based), an object with ``.act(belief)``, or
    the name of a policy of :data:`~.policies.POLICIES` (built with ``options {"seed": seed + 1}``).
    ``initial_belief``: default the model's ``start`` (metadata), else uniform.
    ``initial_state``: default sampled from the initial belief. Same seed, same run. The trace
    holds every step (``O(steps)`` memory); :class:`Simulation` streams them.
    """
    run = Simulation(model, policy, steps, seed, initial_state, initial_belief)
    n, S = run.steps, model.S
    states = np.empty(n, dtype=int)
    next_states = np.empty(n, dtype=int)
    actions = np.empty(n, dtype=int)
    observations = np.empty(n, dtype=int)
    beliefs = np.empty((n + 1, S))
    entropies = np.empty(n)
    rewards = np.empty(n)
    state_rewards = np.empty(n)
    recovered = np.zeros(n, dtype=bool)
    beliefs[0] = run.initial_belief
    for st in run:
        t = st.t
        states[t], next_states[t], actions[t], observations[t] = st.state, st.next_state, st.action, st.observation
        beliefs[t + 1], entropies[t], rewards[t], state_rewards[t] = st.belief, st.entropy, st.reward, st.state_reward
        recovered[t] = st.recovered
    return SimulationTrace(
        model_name=model.name, gamma=model.gamma, seed=seed, policy=run.policy_name, states=states,
        next_states=next_states, actions=actions, observations=observations, beliefs=beliefs,
        entropies=entropies, rewards=rewards, state_rewards=state_rewards, recovered=recovered,
    )
