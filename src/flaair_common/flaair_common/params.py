"""Declare a node's ROS parameters from a schema: descriptor, unit, range, default from config/.

Each node lists its parameters once (name, type, unit, range, description); default values
come from its file in config/, so no number is written twice. rclpy enforces the ranges
and types both at start (overrides from --ros-args or --params-file) and at run time.
"""

from __future__ import annotations

from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.node import Node

from flaair_model.config import ConfigError, node_parameters, shared_parameter_names
from flaair_model.schema import ParameterError, ParamSpec

_TYPES = {
    float: ParameterType.PARAMETER_DOUBLE,
    int: ParameterType.PARAMETER_INTEGER,
    bool: ParameterType.PARAMETER_BOOL,
    str: ParameterType.PARAMETER_STRING,
    list: ParameterType.PARAMETER_DOUBLE_ARRAY,
}


def descriptor(spec: ParamSpec) -> ParameterDescriptor:
    """The rcl_interfaces descriptor rclpy uses to validate and to describe `spec`."""
    constraints = ""
    if spec.choices:
        constraints = "one of: " + ", ".join(spec.choices)
    out = ParameterDescriptor(
        name=spec.name,
        type=_TYPES[spec.type],
        description=spec.description,
        additional_constraints=constraints,
        read_only=spec.read_only,
    )
    if spec.min_value is not None or spec.max_value is not None:
        if spec.type is float:
            out.floating_point_range = [
                FloatingPointRange(
                    from_value=float(spec.min_value if spec.min_value is not None else -1e300),
                    to_value=float(spec.max_value if spec.max_value is not None else 1e300),
                    step=0.0,
                )
            ]
        elif spec.type is int:
            out.integer_range = [
                IntegerRange(
                    from_value=int(spec.min_value if spec.min_value is not None else -(2**62)),
                    to_value=int(spec.max_value if spec.max_value is not None else 2**62),
                    step=1,
                )
            ]
    return out


def declare_parameters(node: Node, specs: list[ParamSpec], config_file: str) -> dict[str, Any]:
    """Declare every parameter of `specs` on `node`, defaults from config/`config_file`.

    Returns the parameter values after overrides. Raises ParameterError naming the parameter
    when a value is of the wrong type, out of range, or not one of the allowed choices.
    """
    try:
        defaults = node_parameters(
            config_file, getattr(node, "default_name", node.get_name()), renamed=node.get_name()
        )
    except ConfigError as exc:
        raise ParameterError(str(exc)) from exc
    values: dict[str, Any] = {}
    for spec in specs:
        if spec.name not in defaults:
            raise ParameterError(f"config/{config_file}: no default for parameter '{spec.name}'")
        default = defaults[spec.name]
        if spec.type is float and isinstance(default, int) and not isinstance(default, bool):
            default = float(default)
        if spec.type is list:
            default = [float(v) for v in default]
        try:
            parameter = node.declare_parameter(spec.name, default, descriptor(spec))
        except Exception as exc:  # rclpy raises several exception types here
            raise ParameterError(f"parameter '{spec.name}' refused: {exc}") from exc
        value = parameter.value
        if spec.type is list:
            value = [float(v) for v in value]
        if spec.choices and value not in spec.choices:
            raise ParameterError(
                f"parameter '{spec.name}' = {value!r} is not one of {', '.join(spec.choices)}"
            )
        values[spec.name] = value
    overrides = getattr(node, "_parameter_overrides", {}) or {}
    # Shared `/**` values reach every node given the whole file as --params-file; not an error.
    unknown = sorted(
        name
        for name in set(overrides)
        - {s.name for s in specs}
        - shared_parameter_names(config_file)
        - {"use_sim_time"}
        if not name.startswith("qos_overrides.")
    )  # rclpy's own, per topic
    if unknown:
        known = ", ".join(s.name for s in specs)
        raise ParameterError(f"unknown parameter(s) {', '.join(unknown)}; this node takes: {known}")
    return values
