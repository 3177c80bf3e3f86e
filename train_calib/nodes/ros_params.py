"""A node's parameters in ROS: the ParameterDescriptor of a ParamSpec, its value as a ROS parameter, an
override coerced to the declared type, and the check of ``--params-file`` before ``rclpy.init``."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.parameter import Parameter

from ..params import ParamSpec

_INT64_MAX = 2**63 - 1


def descriptor_for(spec: ParamSpec) -> ParameterDescriptor:
    """The ROS parameter descriptor of a ParamSet field: description, range, choices, read-only."""
    d = ParameterDescriptor(description=spec.doc, read_only=bool(spec.read_only))
    if spec.kind is float and (spec.low is not None or spec.high is not None):
        d.floating_point_range = [
            FloatingPointRange(
                from_value=-math.inf if spec.low is None else float(spec.low),
                to_value=math.inf if spec.high is None else float(spec.high),
                step=0.0,
            )
        ]
    elif spec.kind is int and (spec.low is not None or spec.high is not None):
        d.integer_range = [
            IntegerRange(
                from_value=-_INT64_MAX if spec.low is None else math.ceil(spec.low),
                to_value=_INT64_MAX if spec.high is None else math.floor(spec.high),
                step=0,
            )
        ]
    constraints = []
    if spec.low_open and spec.low is not None:
        constraints.append(f"must be greater than {spec.low:g}")
    if spec.choices:
        constraints.append("one of: " + ", ".join(spec.choices))
    if spec.kind is tuple and (spec.low is not None or spec.high is not None):
        constraints.append("every element " + spec.doc.rsplit("range ", 1)[-1])
    d.additional_constraints = "; ".join(constraints)
    return d


def ros_value(spec: ParamSpec, value: Any) -> Any:
    """A ParamSet value as rclpy declares it (a tuple parameter as a list of floats)."""
    if spec.kind is tuple:
        return [float(v) for v in value]
    return value


def coerced_override(spec: ParamSpec, override: Parameter) -> Parameter:
    """An INTEGER (array) override of a double (array) parameter, as a double: `30` in a params file."""
    if spec.kind is float and override.type_ == Parameter.Type.INTEGER:
        return Parameter(override.name, Parameter.Type.DOUBLE, float(override.value))
    if spec.kind is tuple and override.type_ == Parameter.Type.INTEGER_ARRAY:
        return Parameter(override.name, Parameter.Type.DOUBLE_ARRAY, [float(v) for v in override.value])
    return override


def check_params_files(argv: Sequence[str]) -> None:
    """ConfigError (one line: file and problem) for a ``--params-file`` that cannot be read or is not a mapping."""
    from ..yamlcheck import load_yaml_mapping

    for i, arg in enumerate(argv):
        if arg == "--params-file" and i + 1 < len(argv):
            load_yaml_mapping(argv[i + 1], "params file")
