"""Parameter declarations shared by the nodes: descriptors (types and ranges, enforced by rclpy at
declare and at set time), the model file parameter, optional array parameters, the liveness
parameters of every node, and integers accepted for floating-point parameters."""

from __future__ import annotations

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.node import Node
from rclpy.parameter import Parameter

from ..core.loop import Liveness, StallLimits
from ..core.loop.epochs import DEFAULT_EPOCH_WINDOW, DEFAULT_RESEND_PERIOD
from ..core.loop.health import DEFAULT_STALL_ERROR, DEFAULT_STALL_WARN
from .runtime import NodeConfigError

#: ``model_file`` when none is given (found by ``core.io.paths.resolve_path``).
DEFAULT_MODEL = "config/models/tracking_s3_info.yaml"

# Ranges of the planner's search parameters, stated once: in their descriptors, which rclpy
# enforces at declare time (a bad parameter file) and at set time (a rejected ``ros2 param set``
# with the reason), so no node callback checks them again; the core's ``Planner.plan`` is the
# last guard (``time_budget >= 0``, ``max_depth >= 1``). The core exports no limits of its own:
# these are what a node accepts per decision, not limits of the search.
#: ``time_budget`` (s): at least a millisecond, at most a minute per decision.
TIME_BUDGET_RANGE = (0.001, 60.0)
#: ``max_depth``: the tree grows as ``(A Z)^depth``, so the budget stops any real model far earlier.
MAX_DEPTH_RANGE = (1, 50)


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
    """Declare a read-only, statically typed array parameter without a default (``kind``: string/double)."""
    ptype, ros_type = {
        "string": (Parameter.Type.STRING_ARRAY, ParameterType.PARAMETER_STRING_ARRAY),
        "double": (Parameter.Type.DOUBLE_ARRAY, ParameterType.PARAMETER_DOUBLE_ARRAY),
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


def declare_model_file(node: Node) -> None:
    """Declare the read-only ``model_file`` parameter (every node has it)."""
    node.declare_parameter("model_file", DEFAULT_MODEL, descriptor(
        "Model file: absolute, relative to the current directory, the package share dir or the source tree, "
        "or a shipped model's name", read_only=True))


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
