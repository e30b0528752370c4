"""The node's parameters on the ROS side: `declare` declares the table of parameters.py with
rclpy (descriptions, ranges, read-only flags) and reads the values rclpy parsed, refusing an
unknown or mistyped one in one line; `validate` answers a run-time change."""
from __future__ import annotations

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.exceptions import (
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterUninitializedException,
)
from rclpy.node import Node

from ..scene.errors import UserError
from . import parameters, qos
from .parameters import ARM_GAIN_PARAMETERS, NODE_NAME, PARAMETERS


def declare(node: Node) -> dict:
    """Declare PARAMETERS on ``node``; their values (rclpy checks types and ranges: UserError)."""
    for name, spec in PARAMETERS.items():
        descriptor = ParameterDescriptor(description=spec.description,
                                         read_only=not spec.dynamic,
                                         dynamic_typing=name in ARM_GAIN_PARAMETERS)
        if spec.range and isinstance(spec.default, int):
            descriptor.integer_range = [IntegerRange(
                from_value=spec.range[0], to_value=spec.range[1], step=1)]
        elif spec.range:
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=spec.range[0], to_value=spec.range[1], step=0.0)]
        try:
            node.declare_parameter(name, spec.default, descriptor)
        except InvalidParameterTypeException:
            raise UserError(name, f"expected {parameters.expected_kind(name)}") from None
        except InvalidParameterValueException:
            override = node._parameter_overrides.get(name)
            value = override.value if override is not None else spec.default
            raise UserError(name, f"{value} is outside {parameters.bounds(name)}") from None
    # A parameter given for this node that it does not declare is a mistake (a typo such
    # as real_time_facter would otherwise be silently ignored). QoS overrides: qos.py's.
    unknown = sorted(name for name in set(node._parameter_overrides) - set(node._parameters)
                     if not name.startswith(qos.QOS_OVERRIDES))
    if unknown:
        raise UserError(unknown[0], f"unknown parameter of {NODE_NAME} (known: "
                                    f"{', '.join(PARAMETERS)})")
    values = {}
    for name in PARAMETERS:
        try:
            values[name] = node.get_parameter(name).value
        except ParameterUninitializedException:   # -p NAME:=[]: rclpy cannot type it
            raise UserError(name, f"expected {parameters.expected_kind(name)}, got an "
                                  f"empty list") from None
    return values


def validate(changes) -> SetParametersResult:
    """A run-time change of dynamic parameters: refused, with the reason, unless every value
    is valid."""
    for change in changes:
        problem = parameters.value_problem(change.name, change.value)
        if problem is not None:
            return SetParametersResult(successful=False, reason=f"{change.name} {problem}")
    return SetParametersResult(successful=True)
