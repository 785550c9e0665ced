"""Parameter declarations shared by the nodes: descriptors (types and ranges, enforced by rclpy at
declare and at set time), the model file parameter, optional array parameters."""

from __future__ import annotations

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.node import Node
from rclpy.parameter import Parameter

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
    node.declare_parameter(name, ptype, descriptor(description, read_only=True, type_=ros_type))


def optional_array(node: Node, name: str) -> list | None:
    """Value of a statically typed array parameter declared without a default (None if unset)."""
    if not node.has_parameter(name):
        return None
    value = node.get_parameter_or(name, None)
    value = None if value is None else value.value
    return None if value is None else list(value)


def declare_model_file(node: Node) -> str:
    """Declare the read-only ``model_file`` parameter (every node has it) and return its value."""
    node.declare_parameter("model_file", DEFAULT_MODEL, descriptor(
        "Model file: absolute, relative to the current directory, the package share dir or the source tree, "
        "or a shipped model's name", read_only=True))
    return node.get_parameter("model_file").value
