"""Parameter declarations shared by the nodes: descriptors (types and ranges, enforced by rclpy at
declare and at set time), the model file parameter, optional array parameters, the liveness
parameters of every node, integers accepted for floating-point parameters, and the start-up rules
of :class:`ParameterNode` (every node's base): a parameter refused at start-up is one line
(:class:`NodeConfigError`), a parameter given to a node that it does not declare is reported
(:func:`check_given_parameters`)."""

from __future__ import annotations

import contextvars
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from ..core.errors import short_repr
from ..core.loop import Liveness, StallLimits
from ..core.loop.epochs import DEFAULT_EPOCH_WINDOW, DEFAULT_RESEND_PERIOD
from ..core.loop.health import DEFAULT_STALL_ERROR, DEFAULT_STALL_WARN
from ..core.loop.parameter_names import BY_NAME, find_unknown, given_scopes, unknown_text

#: ``model_file`` when none is given (found by ``core.io.paths.resolve_path``).
DEFAULT_MODEL = "config/models/tracking_s3_info.yaml"


class NodeConfigError(ValueError):
    """A node parameter makes the node unable to start (message names the parameter); ``node``:
    the name of the node it belongs to, when known."""

    def __init__(self, message: str, node: str | None = None):
        super().__init__(message)
        self.node = node


def descriptor(description: str, *, read_only: bool = False, float_range: tuple[float, float] | None = None,
               int_range: tuple[int, int] | None = None, type_: int | None = None,
               constraints: str = "") -> ParameterDescriptor:
    d = ParameterDescriptor(description=description, read_only=read_only, additional_constraints=constraints)
    if type_ is not None:
        d.type = type_
    if float_range is not None:
        d.floating_point_range = [FloatingPointRange(from_value=float(float_range[0]),
                                                     to_value=float(float_range[1]), step=0.0)]
    if int_range is not None:
        d.integer_range = [IntegerRange(from_value=int(int_range[0]), to_value=int(int_range[1]), step=1)]
    return d


def declare_optional_array(node: Node, name: str, kind: str, description: str) -> None:
    """Declare a read-only, statically typed array parameter without a default (``kind``: string/double/integer)."""
    ptype, ros_type = {
        "string": (Parameter.Type.STRING_ARRAY, ParameterType.PARAMETER_STRING_ARRAY),
        "double": (Parameter.Type.DOUBLE_ARRAY, ParameterType.PARAMETER_DOUBLE_ARRAY),
        "integer": (Parameter.Type.INTEGER_ARRAY, ParameterType.PARAMETER_INTEGER_ARRAY),
    }[kind]
    _convert_override(node, name, ros_type)
    node.declare_parameter(name, ptype, descriptor(description, read_only=True, type_=ros_type))


def optional_array(node: Node, name: str) -> list | None:
    """Value of a statically typed array parameter declared without a default (None if unset)."""
    if not node.has_parameter(name):
        return None
    value = node.get_parameter_or(name, None)
    value = None if value is None else value.value
    return None if value is None else list(value)


def declare_model_file(node: Node) -> str:
    """Declare the read-only ``model_file`` parameter (every node has it); its value now (a managed
    node reads it again at configure)."""
    return node.declare_parameter("model_file", DEFAULT_MODEL, descriptor(
        "Model file: absolute, relative to the current directory, the package share dir or the source tree, "
        "or a shipped model's name", read_only=True)).value


# rclpy types a parameter by its default: a double parameter refuses the integer ``5`` (from a
# parameter file, ``-p time_budget:=5`` or ``ros2 param set /planner time_budget 5``) with "Wrong
# parameter type". ``ParameterDescriptor.dynamic_typing`` would accept it, but also any other type
# (a string), and a FloatingPointRange only applies to doubles. So the nodes keep static types and
# convert an integer given for a double (an integer array for a double array) to the double type
# before rclpy checks it: the override as the parameter is declared (:func:`declare_double`,
# :func:`declare_optional_array`), and run-time sets in a pre-set callback
# (:func:`accept_integers_for_doubles`, Jazzy's ``add_pre_set_parameters_callback``).
_AS_DOUBLE = {Parameter.Type.INTEGER: (Parameter.Type.DOUBLE, float),
              Parameter.Type.INTEGER_ARRAY: (Parameter.Type.DOUBLE_ARRAY, lambda v: [float(x) for x in v])}
_DOUBLE_TYPES = {ParameterType.PARAMETER_DOUBLE: Parameter.Type.DOUBLE,
                 ParameterType.PARAMETER_DOUBLE_ARRAY: Parameter.Type.DOUBLE_ARRAY}


def _as_double(param: Parameter, declared: int) -> Parameter:
    """``param`` converted to the double type ``declared`` if it is the integer form of it."""
    conv = _AS_DOUBLE.get(param.type_)
    if conv is None or _DOUBLE_TYPES.get(declared) != conv[0]:
        return param
    return Parameter(param.name, conv[0], conv[1](param.value))


def _convert_override(node: Node, name: str, declared: int) -> None:
    overrides = getattr(node, "_parameter_overrides", None)  # rclpy's dict of -p / parameter-file values
    if overrides is not None and name in overrides:
        overrides[name] = _as_double(overrides[name], declared)


def declare_double(node: Node, name: str, default: float, desc: ParameterDescriptor) -> None:
    """Declare a double parameter that also takes an integer override (comment above)."""
    _convert_override(node, name, ParameterType.PARAMETER_DOUBLE)
    node.declare_parameter(name, float(default), desc)


def accept_integers_for_doubles(node: Node) -> None:
    """Convert integers set at run time for ``node``'s double parameters (comment above)."""
    def pre_set(params: list[Parameter]) -> list[Parameter]:
        return [_as_double(p, node.describe_parameter(p.name).type) if node.has_parameter(p.name) else p
                for p in params]

    node.add_pre_set_parameters_callback(pre_set)


def declare_liveness(node: Node) -> None:
    """Declare ``epoch_window``, ``resend_period``, ``stall_warn_after`` and ``stall_error_after``
    (read-only; :func:`liveness` reads them)."""
    d = descriptor
    node.declare_parameter("epoch_window", DEFAULT_EPOCH_WINDOW, d(
        "Farthest epoch jump acted on; beyond it an input is dropped and counted (a restarted peer or a forged "
        "message; a peer that persists is re-synced to)", read_only=True, int_range=(1, 1_000_000)))
    declare_double(node, "resend_period", DEFAULT_RESEND_PERIOD, d(
        "Re-publish the last output when the input it expects next has not come within this many seconds "
        "(0 = never)", read_only=True, float_range=(0.0, 3600.0)))
    declare_double(node, "stall_warn_after", DEFAULT_STALL_WARN, d(
        "Seconds without a new input before diagnostics say WARN (and a re-sync may happen)", read_only=True,
        float_range=(0.01, 86400.0)))
    declare_double(node, "stall_error_after", DEFAULT_STALL_ERROR, d(
        "Seconds without a new input before diagnostics say ERROR", read_only=True, float_range=(0.01, 86400.0)))


def liveness(node: Node) -> Liveness:
    """The liveness parameters of ``node`` (:func:`declare_liveness`); a warn limit above the error
    limit is a :class:`NodeConfigError`."""
    value = node.get_parameter
    try:
        stall = StallLimits(value("stall_warn_after").value, value("stall_error_after").value)
    except ValueError as exc:
        raise NodeConfigError(f"stall_warn_after, stall_error_after: {exc}") from None
    return Liveness(value("epoch_window").value, value("resend_period").value, stall)


# ----------------------------------------------------------------- start-up rules of every node

_KINDS = {
    ParameterType.PARAMETER_BOOL: "true or false",
    ParameterType.PARAMETER_INTEGER: "an integer",
    ParameterType.PARAMETER_DOUBLE: "a number",
    ParameterType.PARAMETER_STRING: "a string",
    ParameterType.PARAMETER_BYTE_ARRAY: "a list of bytes",
    ParameterType.PARAMETER_BOOL_ARRAY: "a list of true/false values",
    ParameterType.PARAMETER_INTEGER_ARRAY: "a list of integers",
    ParameterType.PARAMETER_DOUBLE_ARRAY: "a list of numbers",
    ParameterType.PARAMETER_STRING_ARRAY: "a list of strings",
}


#: The note a managed node adds to a parameter it reads at configure (read-only for a plain node;
#: ``loop_node.ManagedLoopNode``). It says when a value may be set, not which values are allowed.
CONFIGURE_TIME = "read at configure: settable only while the node is unconfigured"


def allowed_values(desc: ParameterDescriptor) -> str:
    """What ``desc`` allows, in words: its type, its range, its other constraints (not :data:`CONFIGURE_TIME`)."""
    text = _KINDS.get(desc.type, "a value")
    for r in desc.integer_range:
        text += f" in {r.from_value}..{r.to_value}"
    for r in desc.floating_point_range:
        text += f" in {r.from_value:g}..{r.to_value:g}"
    constraints = "; ".join(c for c in desc.additional_constraints.split("; ") if c and c != CONFIGURE_TIME)
    if constraints:
        text += f" ({constraints})"
    return text


def _out_of_range(value, desc: ParameterDescriptor) -> bool:
    ranges = (*desc.integer_range, *desc.floating_point_range)
    return isinstance(value, (int, float)) and any(not r.from_value <= value <= r.to_value for r in ranges)


def refusal(name: str, value, desc: ParameterDescriptor, reason: str = "") -> str:
    """The one-line message for a parameter value refused at start-up: the parameter, the value and
    what is allowed (in the core's style, ``<field>: must be <allowed>, got <value>``); a value
    that passes the descriptor but was refused by a callback gives that callback's ``reason``."""
    got = short_repr(value)
    if reason and not _out_of_range(value, desc) and Parameter.Type.from_parameter_value(value).value == desc.type:
        return reason if reason.startswith(f"{name}:") else f"{name}: {reason}, got {got}"
    return f"{name}: must be {allowed_values(desc)}, got {got}"


_START_DEFERRED: contextvars.ContextVar[bool] = contextvars.ContextVar("start_deferred", default=False)


@contextmanager
def deferred_start() -> Iterator[None]:
    """Nodes built inside leave their :meth:`ParameterNode.start` to the caller."""
    token = _START_DEFERRED.set(True)
    try:
        yield
    finally:
        _START_DEFERRED.reset(token)


class ParameterNode(Node):
    """Base of the package's nodes: start-up parameter errors as :class:`NodeConfigError`.

    A value that rclpy refuses while a parameter is declared (out of the descriptor's range, the
    wrong type; from a parameter file, ``-p`` or ``parameter_overrides``) raises
    :class:`NodeConfigError` with :func:`refusal`'s one line instead of rclpy's exceptions.
    The node keeps what it was given (``cli_args``, ``parameter_overrides``) so that
    :func:`check_given_parameters` can tell a parameter given to it by name from one given to
    every node, and declares ``strict_parameters`` (read-only): refuse to start on an undeclared
    parameter instead of warning. A node whose start can wait for that check (a managed node's
    autostart) does it in :meth:`start`; built under :func:`deferred_start` (``runtime.run_nodes``)
    it leaves that to the caller.
    """

    def __init__(self, node_name: str, *, cli_args: Sequence[str] | None = None,
                 parameter_overrides: Sequence[Parameter] | None = None, use_global_arguments: bool = True,
                 **kwargs):
        self.given_cli_args = list(cli_args or ())
        self.given_overrides = frozenset(p.name for p in parameter_overrides or ())
        self.uses_global_arguments = use_global_arguments
        #: undeclared parameters given to this node -> the closest declared name ('' if none)
        self.unknown_parameters: dict[str, str] = {}
        #: built under :func:`deferred_start`: the caller calls :meth:`start`
        self.start_deferred = _START_DEFERRED.get()
        super().__init__(node_name, cli_args=cli_args, parameter_overrides=parameter_overrides,
                         use_global_arguments=use_global_arguments, **kwargs)
        self.declare_parameter("strict_parameters", False, descriptor(
            "Refuse to start when a parameter given to this node is not one it declares (default: warn)",
            read_only=True))

    def start(self) -> None:
        """What the node does once the parameters given to it are checked (nothing here)."""

    def declare_parameters(self, namespace, parameters, ignore_override=False):
        """rclpy's ``declare_parameters``, one parameter at a time (rclpy declares them one by one
        too), with a refused value raised as :class:`NodeConfigError`."""
        declared = []
        for entry in parameters:
            try:
                declared += super().declare_parameters(namespace, [entry], ignore_override)
            except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
                name = f"{namespace}.{entry[0]}" if namespace else entry[0]
                default = entry[1] if len(entry) > 1 else None
                desc = entry[2] if len(entry) > 2 else ParameterDescriptor(
                    type=Parameter.Type.from_parameter_value(default).value)
                given = self._parameter_overrides.get(name)
                value = default if given is None or ignore_override else given.value
                reason = str(exc).split("Reason: ", 1)[-1].rsplit(": ", 1)[0]
                raise NodeConfigError(refusal(name, value, desc, reason), node=self.get_name()) from None
        return declared


def _given(node: Node, args: Sequence[str]) -> dict[str, int]:
    """What ``node`` was given (rclpy's overrides) and how (:func:`given_scopes`; a parameter not
    found in the arguments counts as given by name)."""
    fqn = node.get_fully_qualified_name()
    scopes = given_scopes(args, fqn, own=False) if getattr(node, "uses_global_arguments", True) else {}
    for name, scope in given_scopes(getattr(node, "given_cli_args", ()), fqn, own=True).items():
        scopes[name] = min(scope, scopes.get(name, scope))
    scopes.update(dict.fromkeys(getattr(node, "given_overrides", ()), BY_NAME))
    return {name: scopes.get(name, BY_NAME) for name in node._parameter_overrides}  # rclpy's dict


def check_given_parameters(nodes: Sequence[Node], args: Sequence[str] = ()) -> None:
    """Report the parameters given to ``nodes`` (one process, started with the command line
    ``args``) that they do not declare (the rule: :func:`find_unknown`): a WARN naming each and the
    closest declared name, kept in ``node.unknown_parameters`` (the diagnostics show it); a node
    whose ``strict_parameters`` is true raises :class:`NodeConfigError` instead. Parameters rclpy
    itself reads are declared by rclpy (``use_sim_time``, ``start_type_description_service``) or
    skipped (:data:`RCLPY_PARAMETER_PREFIXES`)."""
    found = find_unknown([_given(n, args) for n in nodes], [list(n.list_parameters([], 0).names) for n in nodes])
    for node, unknown in zip(nodes, found, strict=True):
        if unknown and node.has_parameter("strict_parameters") and node.get_parameter("strict_parameters").value:
            what = "not a parameter" if len(unknown) == 1 else "not parameters"
            raise NodeConfigError(f"{unknown_text(unknown)}: {what} of this node; refused because "
                                  "strict_parameters is true", node=node.get_name())
    for node, unknown in zip(nodes, found, strict=True):
        node.unknown_parameters = unknown
        for name, near in unknown.items():
            hint = f"did you mean {near}?" if near else f"`ros2 param list {node.get_fully_qualified_name()}` " \
                                                       "lists the parameters"
            node.get_logger().warning(f"parameter {name} is not a parameter of this node and is ignored; {hint}")
