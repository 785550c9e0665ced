"""Message layouts of the node topics (std_msgs only) and their strict decoders.

Pairing of actions and observations is by design, not by timing: every message carries the
decision epoch it belongs to, and every observation carries the action it was taken under.

* **action** (``std_msgs/Int64MultiArray``), data ``[epoch, action_priority]``, one dimension
  labelled ``"epoch,action_priority"`` (size 2). ``epoch = t`` means "the action that moves the
  system from epoch ``t-1`` to epoch ``t``"; the planner computes it from the belief of epoch
  ``t-1``. ``action_priority`` is the paper's tracking priority 1..A.
* **observation** (``std_msgs/Int64MultiArray``), data ``[epoch, action_priority,
  observation]``, one dimension labelled ``"epoch,action_priority,observation"`` (size 3). The
  observation is 0-based (``0..Z-1``) and was generated after the transition of epoch ``t``
  under ``action_priority`` (the action the simulator actually applied).
* **likelihood** (``std_msgs/Float64MultiArray``), soft evidence: the likelihood of one reading in
  every state, ``l(0..S-1)`` (finite, non-negative, not all 0; any positive scale), three
  dimensions: ``("state", S, S)``, ``("epoch=<t>", 1, 1)`` and ``("action_priority=<p>", 1, 1)``:
  the reading of epoch ``t`` taken under priority ``p``, as the measurement adapter publishes it
  and the filter's ``likelihood_topics`` take it (the labels carry the integers, as the belief's
  epoch). A sensor's own likelihood message, the adapter's input, needs no labels: ``S`` values
  with no layout or one dimension ``("state", S)``.
* **true_state** (``std_msgs/Int64MultiArray``), data ``[epoch, state]``, label ``"epoch,state"``
  (0-based state after the transition of epoch ``t``; epoch 0 is the initial state).
* **belief** (``std_msgs/Float64MultiArray``), data ``b(0..S-1)`` (a point of the simplex), two
  dimensions: ``("state", S, S)`` and ``("epoch=<t>", 1, 1)``. The array is ``S x 1``, the
  single column is labelled by the epoch the belief is valid for (after the observations of
  epoch ``t``; ``t = 0`` is the prior). The data stay a plain probability vector for generic
  tools; the epoch rides in the layout so that belief and epoch arrive in one message.

* **allocation** (``std_msgs/Int64MultiArray``), the sensor manager's joint record, one per
  decision: data ``[decision, epoch_1, action_priority_1, ..., epoch_K, action_priority_K]``, the
  action in force of every target after that decision (``0, 0``: none yet), one dimension labelled
  ``"decision,<target_1>.epoch,<target_1>.action_priority,..."`` with the targets' namespaces.

* **plan_info** (``std_msgs/Float64MultiArray``), one record per decision, published right after
  the action: data ``[epoch, action_priority, depth, nodes_expanded, pruned_percent, certified,
  time_used, latency, deadline_hit, deadline_miss, bound_lower, bound_upper]`` with one dimension
  labelled with these names (comma separated). ``nodes_expanded`` sums all completed depths,
  ``pruned_percent`` is that of the deepest one, ``time_used`` is the search time and ``latency``
  belief-in to action-out (s); ``deadline_hit`` (1/0): the budget limited the depth;
  ``deadline_miss`` (1/0): the planner's rule, ``latency > time_budget + deadline_slack`` with the
  parameters in force. ``bound_lower``, ``bound_upper``: the myopic policy bounds at the belief
  (Theorem 2), as priorities: the optimal priority lies in ``[bound_lower, bound_upper]``, and
  ``certified`` is 1 exactly when they agree (Proposition 1); ``NaN`` when the decision used no
  guaranteed bounds (``use_bounds`` false, or the model fails the assumptions). The record is
  ``core.loop.PlanInfo``.

A sample larger than its layout allows (:func:`wire_bounds`: the model's ``S`` values for a
belief, 2 or 3 integers for an action, an observation or a true state, labels of at most
:data:`MAX_LABEL_CHARS` characters; ``plan_info``: its fields and their names) is dropped before
it is copied or decoded
(``nodes/inputs.py``, ``nodes/take.py``; :func:`oversized`). Decoders raise :class:`MessageError` with a message that
names the field and the problem. They bound what they accept before converting anything: epochs
are ``0..MAX_EPOCH`` (so that ``epoch + 1`` always fits the ``int64`` of the next message, and an
epoch label is at most 18 digits), and the length is checked before the data are copied. They
return the loops' sample types (``core/loop/samples.py``); whether an epoch is *plausible* is the
loops' business (the epoch window and the rule "Explained epochs", ``core/loop``).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from std_msgs.msg import Float64MultiArray, Int64MultiArray, MultiArrayDimension, MultiArrayLayout

from ..core.belief import BeliefError, check_belief, check_likelihood
from ..core.loop.samples import ActionSample, BeliefSample, LikelihoodSample, ObservationSample

ACTION_LABEL = "epoch,action_priority"
OBSERVATION_LABEL = "epoch,action_priority,observation"
TRUE_STATE_LABEL = "epoch,state"
BELIEF_STATE_LABEL = "state"
PLAN_INFO_FIELDS = ("epoch", "action_priority", "depth", "nodes_expanded", "pruned_percent", "certified",
                    "time_used", "latency", "deadline_hit", "deadline_miss", "bound_lower", "bound_upper")
PLAN_INFO_LABEL = ",".join(PLAN_INFO_FIELDS)
#: Largest epoch a message may carry (10^18 - 1 < 2^63 - 1, the int64 range, with room for + 1).
MAX_EPOCH = 10**18 - 1
_EPOCH_LABEL_RE = re.compile(r"^epoch=(\d{1,18})$")
_PRIORITY_LABEL_RE = re.compile(r"^action_priority=(\d{1,18})$")
#: Longest dimension label a sample may carry (ours: at most 33 characters).
MAX_LABEL_CHARS = 64


def max_wire_bytes(values: int, dims: int, value_bytes: int = 8, label_chars: int = MAX_LABEL_CHARS) -> int:
    """The most bytes a serialized ``*MultiArray`` sample with ``values`` numbers of ``value_bytes``
    each and ``dims`` dimensions (labels of at most ``label_chars``) takes in CDR: the
    encapsulation, each dimension (label length, label, padding, size, stride), the data offset,
    the data's length and alignment, the data."""
    per_dim = 4 + label_chars + 1 + 3 + 4 + 4
    return 4 + 4 + dims * per_dim + 4 + 4 + 4 + value_bytes * values


@dataclass(frozen=True)
class WireBound:
    """The most bytes a sample of a topic takes (:func:`max_wire_bytes`) and what it holds, as the
    line for a larger sample says it (:func:`oversized`)."""

    max_bytes: int
    layout: str


def wire_bounds(num_states: int) -> dict[str, WireBound]:
    """The size bound of each sample of the loop's topics: ``belief`` (``S`` doubles, two
    dimensions), ``likelihood`` (``S`` doubles, three), ``action``, ``observation`` and
    ``true_state`` (2, 3 and 2 integers, one dimension), ``plan_info`` (its fields, one dimension
    labelled with their names)."""
    S = num_states
    return {"belief": WireBound(max_wire_bytes(S, 2), f"a belief of {S} states"),
            "likelihood": WireBound(max_wire_bytes(S, 3), f"a likelihood of {S} states"),
            "action": WireBound(max_wire_bytes(2, 1), f"[{ACTION_LABEL.replace(',', ', ')}]"),
            "observation": WireBound(max_wire_bytes(3, 1), f"[{OBSERVATION_LABEL.replace(',', ', ')}]"),
            "true_state": WireBound(max_wire_bytes(2, 1), f"[{TRUE_STATE_LABEL.replace(',', ', ')}]"),
            "plan_info": WireBound(max_wire_bytes(len(PLAN_INFO_FIELDS), 1, label_chars=len(PLAN_INFO_LABEL)),
                                   f"[{PLAN_INFO_LABEL.replace(',', ', ')}]")}


def oversized(what: str, size: int, bound: WireBound) -> str:
    """The one line for a sample of ``size`` bytes over ``bound``."""
    return (f"{what}: a sample of {size} bytes, more than the {bound.max_bytes} that {bound.layout} takes: "
            "dropped unread")


class MessageError(ValueError):
    """A message on a node topic does not follow the documented layout."""


class OutOfRangeError(MessageError):
    """A well-formed message whose action priority or observation is out of range."""


def _short(text: str, limit: int = 60) -> str:
    """``text`` cut to ``limit`` characters: error messages never embed an unbounded field."""
    return text if len(text) <= limit else text[:limit] + f"... ({len(text)} characters)"


def _record(label: str, values: Sequence[int]) -> Int64MultiArray:
    msg = Int64MultiArray()
    msg.layout = MultiArrayLayout(
        dim=[MultiArrayDimension(label=label, size=len(values), stride=len(values))], data_offset=0
    )
    msg.data = [int(v) for v in values]
    return msg


def _decode_record(msg: Int64MultiArray, label: str, what: str) -> list[int]:
    names = label.split(",")
    if len(msg.data) != len(names):
        raise MessageError(f"{what}: expected {len(names)} integers [{label}], got {len(msg.data)}")
    data = [int(v) for v in msg.data]
    dims = list(msg.layout.dim)
    # The label is the protocol: accept it, or no layout at all (hand-typed messages).
    if dims and (len(dims) != 1 or dims[0].label != label):
        got = _short(",".join(d.label for d in dims[:4]))
        raise MessageError(f"{what}: layout label {got!r} is not {label!r}")
    if not 0 <= data[0] <= MAX_EPOCH:
        raise MessageError(f"{what}: epoch must be in 0..{MAX_EPOCH}, got {data[0]}")
    return data


def encode_action(epoch: int, priority: int) -> Int64MultiArray:
    return _record(ACTION_LABEL, (epoch, priority))


def decode_action(msg: Int64MultiArray, num_actions: int) -> ActionSample:
    epoch, priority = _decode_record(msg, ACTION_LABEL, "action")
    if not 1 <= priority <= num_actions:
        raise OutOfRangeError(f"action: action_priority {priority} out of range 1..{num_actions}")
    return ActionSample(epoch, priority)


def encode_observation(epoch: int, priority: int, observation: int) -> Int64MultiArray:
    return _record(OBSERVATION_LABEL, (epoch, priority, observation))


def decode_observation(msg: Int64MultiArray, num_actions: int, num_observations: int) -> ObservationSample:
    epoch, priority, z = _decode_record(msg, OBSERVATION_LABEL, "observation")
    if not 1 <= priority <= num_actions:
        raise OutOfRangeError(f"observation: action_priority {priority} out of range 1..{num_actions}")
    if not 0 <= z < num_observations:
        raise OutOfRangeError(f"observation: observation {z} out of range 0..{num_observations - 1}")
    return ObservationSample(epoch, priority, z)


def allocation_label(targets: Sequence[str]) -> str:
    """The label of the sensor manager's ``allocation`` record for ``targets`` (module docstring)."""
    return ",".join(["decision", *(f"{t}.{f}" for t in targets for f in ("epoch", "action_priority"))])


def encode_allocation(decision: int, actions: Sequence[ActionSample | None], targets: Sequence[str]) -> Int64MultiArray:
    values = [decision]
    for a in actions:
        values += [0, 0] if a is None else [a.epoch, a.priority]
    return _record(allocation_label(targets), values)


def decode_allocation(msg: Int64MultiArray, targets: Sequence[str]) -> tuple[int, list[ActionSample | None]]:
    """``(decision, the action in force of every target or None)`` of an ``allocation`` record."""
    data = _decode_record(msg, allocation_label(targets), "allocation")
    pairs = zip(data[1::2], data[2::2], strict=True)
    return data[0], [None if p == 0 else ActionSample(t, p) for t, p in pairs]


def encode_true_state(epoch: int, state: int) -> Int64MultiArray:
    return _record(TRUE_STATE_LABEL, (epoch, state))


def decode_true_state(msg: Int64MultiArray) -> tuple[int, int]:
    epoch, state = _decode_record(msg, TRUE_STATE_LABEL, "true_state")
    return epoch, state


def encode_belief(epoch: int, belief: np.ndarray) -> Float64MultiArray:
    b = np.asarray(belief, dtype=float)
    msg = Float64MultiArray()
    msg.layout = MultiArrayLayout(
        dim=[
            MultiArrayDimension(label=BELIEF_STATE_LABEL, size=b.size, stride=b.size),
            MultiArrayDimension(label=f"epoch={int(epoch)}", size=1, stride=1),
        ],
        data_offset=0,
    )
    msg.data = [float(x) for x in b]
    return msg


def decode_belief(msg: Float64MultiArray, num_states: int) -> BeliefSample:
    """Decode a belief message (layout, epoch label, length) and check the belief with the core's
    ``check_belief`` (finite, on the simplex); its error becomes a :class:`MessageError`."""
    dims = list(msg.layout.dim)
    if len(dims) != 2 or dims[0].label != BELIEF_STATE_LABEL:
        raise MessageError(
            f"belief: layout must be [('{BELIEF_STATE_LABEL}', S), ('epoch=<t>', 1)], got "
            f"{_short(str([(d.label, d.size) for d in dims[:4]]))}"
        )
    m = _EPOCH_LABEL_RE.match(dims[1].label)
    if m is None:
        raise MessageError(f"belief: second dimension label {_short(dims[1].label)!r} is not 'epoch=<t>' "
                           f"(t: 0..{MAX_EPOCH})")
    if msg.layout.data_offset != 0:
        raise MessageError(f"belief: data_offset must be 0, got {msg.layout.data_offset}")
    if len(msg.data) != num_states or dims[0].size != num_states:
        raise MessageError(
            f"belief: expected {num_states} probabilities, got {len(msg.data)} (layout size {dims[0].size})"
        )
    try:
        b = check_belief(num_states, np.array(msg.data, dtype=float))
    except BeliefError as exc:
        raise MessageError(str(exc)) from None
    return BeliefSample(int(m.group(1)), b)


def encode_likelihood(epoch: int, priority: int, likelihood: Sequence[float]) -> Float64MultiArray:
    """Soft evidence of epoch ``epoch`` under ``priority`` (module docstring, **likelihood**)."""
    msg = Float64MultiArray()
    n = len(likelihood)
    msg.layout = MultiArrayLayout(
        dim=[MultiArrayDimension(label=BELIEF_STATE_LABEL, size=n, stride=n),
             MultiArrayDimension(label=f"epoch={int(epoch)}", size=1, stride=1),
             MultiArrayDimension(label=f"action_priority={int(priority)}", size=1, stride=1)],
        data_offset=0,
    )
    msg.data = [float(x) for x in likelihood]
    return msg


def decode_likelihood(msg: Float64MultiArray, num_actions: int, num_states: int) -> LikelihoodSample:
    """Decode soft evidence (layout, labels, length) and check the values with the core's
    ``check_likelihood``; a priority out of range is an :class:`OutOfRangeError`."""
    dims = list(msg.layout.dim)
    labels = [d.label for d in dims[:4]]
    m_epoch = _EPOCH_LABEL_RE.match(labels[1]) if len(dims) == 3 else None
    m_prio = _PRIORITY_LABEL_RE.match(labels[2]) if len(dims) == 3 else None
    if len(dims) != 3 or labels[0] != BELIEF_STATE_LABEL or m_epoch is None or m_prio is None:
        raise MessageError(f"likelihood: layout must be [('{BELIEF_STATE_LABEL}', S), ('epoch=<t>', 1), "
                           f"('action_priority=<p>', 1)], got {_short(str(labels))}")
    if msg.layout.data_offset != 0:
        raise MessageError(f"likelihood: data_offset must be 0, got {msg.layout.data_offset}")
    if len(msg.data) != num_states:
        raise MessageError(f"likelihood: expected {num_states} values (one per state), got {len(msg.data)}")
    priority = int(m_prio.group(1))
    if not 1 <= priority <= num_actions:
        raise OutOfRangeError(f"likelihood: action_priority {priority} out of range 1..{num_actions}")
    try:
        lik = check_likelihood(num_states, np.array(msg.data, dtype=float))
    except BeliefError as exc:
        raise MessageError(str(exc)) from None
    return LikelihoodSample(int(m_epoch.group(1)), priority, tuple(float(x) for x in lik))


def sensor_likelihood_values(msg: Float64MultiArray, num_states: int) -> list[float]:
    """The values of a sensor's likelihood message (the adapter's input): the layout (none, or one
    dimension ``("state", S)``) and the length are checked here; the values are the core's
    business (the adapter loop counts NaN and checks the rest)."""
    dims = list(msg.layout.dim)
    if dims and (len(dims) != 1 or dims[0].label != BELIEF_STATE_LABEL):
        raise MessageError(f"likelihood: layout must be empty or [('{BELIEF_STATE_LABEL}', S)], got "
                           f"{_short(str([d.label for d in dims[:4]]))}")
    if len(msg.data) != num_states:
        raise MessageError(f"likelihood: expected {num_states} values (one per state), got {len(msg.data)}")
    return [float(x) for x in msg.data]


def encode_plan_info(**fields: float) -> Float64MultiArray:
    msg = Float64MultiArray()
    n = len(PLAN_INFO_FIELDS)
    msg.layout = MultiArrayLayout(dim=[MultiArrayDimension(label=PLAN_INFO_LABEL, size=n, stride=n)], data_offset=0)
    msg.data = [float(fields[k]) for k in PLAN_INFO_FIELDS]
    return msg


def decode_plan_info(msg: Float64MultiArray) -> dict[str, float]:
    data = list(msg.data)
    if len(data) != len(PLAN_INFO_FIELDS):
        raise MessageError(f"plan_info: expected {len(PLAN_INFO_FIELDS)} numbers [{PLAN_INFO_LABEL}], got {len(data)}")
    return dict(zip(PLAN_INFO_FIELDS, data, strict=True))
