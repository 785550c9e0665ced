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
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .belief import check_belief, start_belief, uniform_belief
from .filter import EpochFilter
from .model import POMDP
from .policies import Policy, as_callable, make_policy
from .uncertainty import SHANNON


# ------------------------------------------------------------------------- simulation
@dataclass(frozen=True, eq=False)
class SimulationTrace:
    """Everything that happened in one closed-loop run of ``steps`` steps (0-based indices).

    ``states[t]`` = ``s_t`` (true state when acting), ``next_states[t]`` = ``s_{t+1}``,
    ``actions[t]`` = ``a_t``, ``observations[t]`` = ``z_{t+1}``, ``beliefs[t]`` = ``b_t``
    (shape ``(steps + 1, S)``, ``beliefs[0]`` the initial belief), ``entropies[t]`` = Shannon
    entropy (nats) of ``b_{t+1}``, ``rewards[t]`` = ``rho(b_t, a_t)``, ``state_rewards[t]`` =
    ``r(s_t, a_t)``, ``recovered[t]`` = the observation was impossible under ``b_t`` (see the
    module docstring).
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

    def to_dict(self, state_names: tuple[str, ...] | None = None,
                observation_names: tuple[str, ...] | None = None) -> dict:
        """JSON-ready record; actions as tracking priorities ``1..A`` (key ``priority``).

        Per step: ``state`` = ``s_t``, ``next_state`` = ``s_{t+1}``, ``observation`` = ``z_{t+1}``,
        ``belief`` = the updated belief ``b_{t+1}`` and ``entropy`` its Shannon entropy (nats),
        ``reward`` = ``rho(b_t, a_t)``, ``state_reward`` = ``r(s_t, a_t)``; indices 0-based.
        """
        rows = []
        for t in range(self.steps):
            row = {
                "step": t,
                "state": int(self.states[t]),
                "next_state": int(self.next_states[t]),
                "priority": int(self.actions[t]) + 1,
                "observation": int(self.observations[t]),
                "belief": self.beliefs[t + 1].tolist(),
                "entropy": float(self.entropies[t]),
                "reward": float(self.rewards[t]),
                "state_reward": float(self.state_rewards[t]),
                "recovered": bool(self.recovered[t]),
            }
            if state_names is not None:
                row["state_name"] = state_names[self.states[t]]
                row["next_state_name"] = state_names[self.next_states[t]]
            if observation_names is not None:
                row["observation_name"] = observation_names[self.observations[t]]
            rows.append(row)
        return {
            "model": self.model_name,
            "policy": self.policy,
            "seed": self.seed,
            "gamma": self.gamma,
            "initial_belief": self.beliefs[0].tolist(),
            "steps": rows,
            "summary": self.summary(),
        }


def _sample(rng: np.random.Generator, p: np.ndarray) -> int:
    """Inverse-CDF sample from ``p`` (rows sum to 1 only within the model's tolerance)."""
    c = np.cumsum(p)
    return int(min(np.searchsorted(c, rng.random() * c[-1], side="right"), p.size - 1))


def simulate(model: POMDP, policy: Policy | str, steps: int, seed: int | None = None,
             initial_state: int | None = None, initial_belief: np.ndarray | None = None) -> SimulationTrace:
    """Run ``policy`` in closed loop for ``steps`` steps (see the module docstring).

    ``policy``: a callable ``belief -> action`` (0-based), an object with ``.act(belief)``, or
    the name of a policy of :data:`~.policies.POLICIES` (built with ``options {"seed": seed + 1}``).
    ``initial_belief``: default the model's ``start`` (metadata), else uniform.
    ``initial_state``: default sampled from the initial belief. Same seed, same run.
    """
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)) or steps < 0:
        raise ValueError(f"steps: must be a non-negative integer, got {steps!r}")
    rng = np.random.default_rng(seed)
    if isinstance(policy, str):
        policy_name = policy
    else:
        policy_name = getattr(policy, "name", None) or getattr(policy, "__name__", None) or type(policy).__name__
    if isinstance(policy, str):
        policy = make_policy(policy, model, seed=None if seed is None else seed + 1)
    act = as_callable(policy)
    if initial_belief is None:
        b = start_belief(model)
        b = uniform_belief(model) if b is None else b
    else:
        b = check_belief(model, initial_belief, field="initial_belief")
    if initial_state is None:
        s = _sample(rng, b)
    else:
        if isinstance(initial_state, bool) or not isinstance(initial_state, (int, np.integer)) \
                or not 0 <= initial_state < model.S:
            raise ValueError(f"initial_state: index {initial_state!r} out of range 0..{model.S - 1}")
        s = int(initial_state)

    S = model.S
    epoch_filter = EpochFilter(model)
    states = np.empty(steps, dtype=int)
    next_states = np.empty(steps, dtype=int)
    actions = np.empty(steps, dtype=int)
    observations = np.empty(steps, dtype=int)
    beliefs = np.empty((steps + 1, S))
    rewards = np.empty(steps)
    state_rewards = np.empty(steps)
    recovered = np.zeros(steps, dtype=bool)
    beliefs[0] = b
    for t in range(steps):
        a = act(b.copy())
        if isinstance(a, bool) or not isinstance(a, (int, np.integer)) or not 0 <= a < model.A:
            raise ValueError(f"policy returned {a!r} at step {t}: expected a 0-based action in 0..{model.A - 1}")
        a = int(a)
        rewards[t] = model.rho(b)[a]
        state_rewards[t] = model.r[s, a]
        s_next = _sample(rng, model.P[a, s])
        z = _sample(rng, model.O[a, s_next])
        epoch = epoch_filter.step(b, a, {0: z})
        b = epoch.belief
        recovered[t] = bool(epoch.restarted)
        states[t], next_states[t], actions[t], observations[t] = s, s_next, a, z
        beliefs[t + 1] = b
        s = s_next
    entropies = SHANNON.value(beliefs[1:])
    return SimulationTrace(
        model_name=model.name, gamma=model.gamma, seed=seed, policy=str(policy_name), states=states,
        next_states=next_states, actions=actions, observations=observations, beliefs=beliefs,
        entropies=np.asarray(entropies, dtype=float).reshape(steps), rewards=rewards,
        state_rewards=state_rewards, recovered=recovered,
    )
