"""The decoded inputs of the loops: one sample of a topic each, as the adapters' decoders return it.

Priorities are the paper's tracking priorities ``1..A``, as on the wire (the decoders have checked
the range); a loop converts one to a 0-based action once, where it uses it. Epochs are
``0..10^18 - 1`` (the decoders' bound); whether an epoch is plausible is the loop's rule.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class ActionSample:
    """``[epoch, priority]``: the action that moves the system from epoch ``epoch - 1`` to ``epoch``."""

    epoch: int
    priority: int


@dataclass(frozen=True)
class ObservationSample:
    """``[epoch, priority, observation]``: a reading taken after the transition of ``epoch`` under ``priority``."""

    epoch: int
    priority: int
    observation: int


@dataclass(frozen=True)
class LikelihoodSample:
    """Soft evidence ``[epoch, priority, l(0..S-1)]``: a reading taken after the transition of
    ``epoch`` under ``priority``, given as its likelihood in every state (``l(s) = P(reading | s)``
    up to a positive factor; checked by the core's ``check_likelihood`` where it is applied)."""

    epoch: int
    priority: int
    likelihood: tuple[float, ...]


@dataclass(frozen=True, eq=False)
class BeliefSample:
    """The belief after the observations of ``epoch`` (``0``: the prior), checked on the simplex."""

    epoch: int
    belief: np.ndarray
