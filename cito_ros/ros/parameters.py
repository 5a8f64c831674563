"""The planner's settings as ROS 2 parameters, declared with descriptors.

Every field of cito_ros.settings.Settings is a parameter named by its dotted path, declared with
its type, its description and its range (from the field's metadata), and read-only except the
few a running node can take up (RUNTIME). Values come from the params file
(config/planner.yaml) and `-p` overrides; a parameter the schema does not have is an error, as is
one the file leaves unset. The solver option sections (solver.ipopt, solver.least_squares,
solver.ilqr) are passed to their solvers as they are, so their entries are declared from the file
with the types it gives them.
"""
from __future__ import annotations

import dataclasses
import sys
import typing
from typing import Any, Iterator

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter

from cito_ros.settings import Settings
from cito_ros.settings.typed_config import optional_type

#: Parameters a running node takes up on its next plan (the others are read-only).
RUNTIME = ("solver.time_limit_s", "node.default_contact_model", "tracking.reference_offsets")
#: Every rclpy node's own parameters.
ROS_PARAMETERS = ("use_sim_time", "start_type_description_service")
OPTION_SECTIONS = ("solver.ipopt", "solver.least_squares", "solver.ilqr")

_TYPES = {float: ParameterType.PARAMETER_DOUBLE, int: ParameterType.PARAMETER_INTEGER,
          bool: ParameterType.PARAMETER_BOOL, str: ParameterType.PARAMETER_STRING}
_ARRAYS = {float: ParameterType.PARAMETER_DOUBLE_ARRAY, int: ParameterType.PARAMETER_INTEGER_ARRAY,
           bool: ParameterType.PARAMETER_BOOL_ARRAY, str: ParameterType.PARAMETER_STRING_ARRAY}


def schema(cls=Settings, prefix: str = "") -> Iterator[tuple[str, ParameterDescriptor, bool]]:
    """(name, descriptor, optional) of every parameter of a settings class, depth first."""
    hints = typing.get_type_hints(cls)
    for field in dataclasses.fields(cls):
        if field.metadata.get("internal"):
            continue
        name = f"{prefix}{field.name}"
        if name in OPTION_SECTIONS:
            continue
        optional, annotation = optional_type(hints[field.name])
        if dataclasses.is_dataclass(annotation) and not field.metadata.get("convert"):
            yield from schema(annotation, f"{name}.")
            continue
        yield name, descriptor(name, annotation, field.metadata), optional


def descriptor(name: str, annotation, meta) -> ParameterDescriptor:
    description = meta.get("description", "")
    if meta.get("choices"):
        description += f" (one of {', '.join(meta['choices'])})"
    if typing.get_origin(annotation) is tuple:
        kind = _ARRAYS[typing.get_args(annotation)[0]]
    else:
        kind = _TYPES.get(annotation, ParameterType.PARAMETER_STRING)  # converted fields (the scene) are names
    result = ParameterDescriptor(name=name, type=kind, description=description, read_only=name not in RUNTIME)
    low = 0.0 if meta.get("positive") else meta.get("minimum")
    if low is not None and kind == ParameterType.PARAMETER_DOUBLE:
        result.floating_point_range = [FloatingPointRange(from_value=float(low), to_value=sys.float_info.max)]
    elif low is not None and kind == ParameterType.PARAMETER_INTEGER:
        result.integer_range = [IntegerRange(from_value=int(low), to_value=2 ** 31 - 1)]
    return result


def declare(node: Node, overrides: dict[str, Parameter]) -> Settings:
    """Declare every parameter on `node` from its overrides (params file and -p) and return the
    settings they make. ValueError for an unknown, a missing or a bad value."""
    known = set()
    for name, described, optional in schema():
        known.add(name)
        if name not in overrides:
            if optional:
                continue
            raise ValueError(f"{name}: missing (set it in the params file)")
        try:
            node.declare_parameter(name, Parameter.Type(described.type), described)
        except (InvalidParameterTypeException, InvalidParameterValueException) as error:
            raise ValueError(f"{name}: {error}") from None
    for name, parameter in overrides.items():
        section = next((s for s in OPTION_SECTIONS if name.startswith(f"{s}.")), None)
        if section is not None:
            node.declare_parameter(name, parameter.value, ParameterDescriptor(
                name=name, description=f"passed to the solver as it is ({section})", read_only=True))
        elif name not in known and name not in ROS_PARAMETERS:
            raise ValueError(f"{name}: unknown parameter")
    return Settings.from_mapping(tree(node))


def tree(node: Node) -> dict[str, Any]:
    """The node's declared parameters as the nested settings tree."""
    out: dict[str, Any] = {}
    for name, parameter in node.get_parameters_by_prefix("").items():
        if name in ROS_PARAMETERS:
            continue
        keys = name.split(".")
        branch = out
        for key in keys[:-1]:
            branch = branch.setdefault(key, {})
        value = parameter.value
        branch[keys[-1]] = list(value) if hasattr(value, "tolist") or isinstance(value, (list, tuple)) else value
    return out
