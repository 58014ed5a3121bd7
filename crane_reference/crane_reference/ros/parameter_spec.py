"""A node parameter as one row of a table, in the manner of generate_parameter_library: from a row come the
``ParameterDescriptor`` (:meth:`ParameterSpec.descriptor`, with a ``FloatingPointRange`` or ``IntegerRange``), the
validation (:meth:`ParameterSpec.check`, a reason naming the parameter and what is allowed), the declaration
(:func:`declare`), the typed field (:attr:`ParameterSpec.field`, generated into :mod:`.parameter_values`) and the
rows of ``config/*.yaml`` and ``docs/parameters.md`` (:mod:`.parameter_generation`).

Integer values for double parameters (``-p ellipse.a:=3``, ``ellipse.a: 3`` in a YAML file, or
``ros2 param set /crane_reference ellipse.a 3``) are accepted: rclpy 7 checks a statically typed
parameter's type before any user callback and rejects them, so

* at start-up, :func:`declare` reads the override of any type (the nodes declare their overrides as they
  come, ``automatically_declare_parameters_from_overrides``; else it declares the parameter with
  ``dynamic_typing=True`` first), undeclares it and declares it again, statically typed, with the value
  converted to float (``ignore_override=True``);
* at run time, :func:`coerce_parameters` is a *pre*-set callback (``Node.add_pre_set_parameters_callback``,
  run before rclpy's type and range checks) that turns such integers into doubles.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, replace
from typing import Any

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import ParameterNotDeclaredException
from rclpy.node import Node
from rclpy.parameter import Parameter

from ..model.description import CraneDescription

JOINT = "<joint>"
"""The place of the joint's name in a per-joint row's name (``drive_damping.<joint>``)."""

Value = bool | int | float | str | list[str]
ROS_TYPES = {"bool": Parameter.Type.BOOL, "integer": Parameter.Type.INTEGER, "double": Parameter.Type.DOUBLE,
             "string": Parameter.Type.STRING, "string_array": Parameter.Type.STRING_ARRAY}
"""A row's ``type`` (generate_parameter_library's names) and the ROS parameter type it declares."""
_TYPE_NAMES = {"bool": "a boolean", "integer": "an integer", "double": "a number", "string": "a string",
               "string_array": "a list of distinct, non-empty strings"}


class ParameterError(ValueError):
    """A parameter value that :func:`check` rejects (the message is the reason)."""


@dataclass(frozen=True)
class ParameterSpec:
    """One node parameter (or a row of them, one per joint).  ``bounds`` are inclusive [low, high] (as in ROS
    ranges); ``choices`` the allowed strings (empty: any non-empty string, unless ``empty_allowed``);
    ``from_config`` gives the default from the crane description instead of ``default``."""

    name: str
    type: str
    default: Value
    description: str
    unit: str = ""
    bounds: tuple[float, float] | None = None
    choices: tuple[str, ...] = ()
    empty_allowed: bool = False
    read_only: bool = False
    from_config: Callable[[CraneDescription], Value] | None = None
    from_crane: bool = False
    """A per-joint row whose defaults the node computes from the crane (its model) when it starts."""

    @property
    def ros_type(self) -> Parameter.Type:
        return ROS_TYPES[self.type]

    @property
    def per_joint(self) -> bool:
        """Whether the row stands for one parameter per joint (its name holds :data:`JOINT`, its default comes
        from the crane: :meth:`for_joint`), as generate_parameter_library's ``__map_`` parameters."""
        return JOINT in self.name

    @property
    def field(self) -> str:
        """The field of the typed values (:mod:`.parameter_values`): the name with dots as underscores, a
        per-joint row's without its joint (a dict by joint name)."""
        return field_name(self.name.replace(f".{JOINT}", ""))

    def name_for(self, joint: str) -> str:
        """The name of a per-joint row's parameter for ``joint``."""
        return self.name.replace(JOINT, joint)

    def for_joint(self, joint: str, default: Value | None = None) -> ParameterSpec:
        """The parameter of a per-joint row for ``joint``, with the crane's ``default`` (None: the row's)."""
        return replace(self, name=self.name_for(joint), default=self.default if default is None else default,
                       description=self.description.replace(JOINT, joint))

    def default_for(self, config: CraneDescription | None) -> Value:
        """Default value, taken from ``config`` where the parameter comes from the crane description."""
        if self.from_config is not None and config is not None:
            return self.coerce(self.from_config(config))
        return self.default

    def allowed(self) -> str:
        """What the parameter accepts, in words (used in every rejection reason)."""
        unit = f" {self.unit}" if self.unit else ""
        if self.choices:
            return f"must be one of {', '.join(map(repr, self.choices))}"
        if self.bounds is not None:
            low, high = self.bounds
            integers = " (integers accepted)" if self.type == "double" else ""
            return f"must be {_TYPE_NAMES[self.type]} in [{low:g}, {high:g}]{unit}{integers}"
        if self.type == "string" and not self.empty_allowed:
            return "must be a non-empty string"
        return f"must be {_TYPE_NAMES[self.type]}"

    def descriptor(self) -> ParameterDescriptor:
        """Statically typed ParameterDescriptor with description, range and read-only flag."""
        descriptor = ParameterDescriptor(
            name=self.name, type=self.ros_type.value, read_only=self.read_only,
            description=f"{self.description}{f' [{self.unit}]' if self.unit else ''}",
            additional_constraints=self.allowed())
        if self.bounds is not None and self.type == "double":
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(self.bounds[0]), to_value=float(self.bounds[1]), step=0.0)]
        elif self.bounds is not None:
            descriptor.integer_range = [IntegerRange(
                from_value=int(self.bounds[0]), to_value=int(self.bounds[1]), step=1)]
        return descriptor

    def coerce(self, value: Any) -> Any:
        """An integer for a double parameter as a float; every other value unchanged."""
        if self.type == "double" and isinstance(value, int) and not isinstance(value, bool):
            return float(value)
        return value

    def check(self, value: Any) -> str | None:
        """``None`` if ``value`` (already coerced) is allowed, else the reason, naming the parameter."""
        if self.type == "string_array":
            strings = isinstance(value, list | tuple) and all(isinstance(v, str) and v for v in value)
            invalid = not strings or not value or len(set(value)) != len(value)
            return f"{self.name} = {value!r}: {self.allowed()}" if invalid else None
        python_type = {"bool": bool, "integer": int, "double": float, "string": str}[self.type]
        wrong_type = not isinstance(value, python_type) or (python_type is int and isinstance(value, bool))
        invalid = (wrong_type
                   or (self.type == "double" and not math.isfinite(value))
                   or (self.bounds is not None and not self.bounds[0] <= value <= self.bounds[1])
                   or (self.choices and value not in self.choices)
                   or (self.type == "string" and not self.empty_allowed and not value))
        return f"{self.name} = {value!r}: {self.allowed()}" if invalid else None


def field_name(name: str) -> str:
    """The typed values' field of the parameter ``name``: dots become underscores (``ellipse.a``: ``ellipse_a``)."""
    return name.replace(".", "_")


def coerce_parameters(parameters: list[Parameter], specs: dict[str, ParameterSpec]) -> list[Parameter]:
    """Pre-set callback: integer values of the table's double parameters become doubles (all else unchanged)."""
    return [Parameter(p.name, Parameter.Type.DOUBLE, float(p.value))
            if p.name in specs and specs[p.name].type == "double" and p.type_ is Parameter.Type.INTEGER else p
            for p in parameters]


def check(parameters: Iterable[Parameter], specs: dict[str, ParameterSpec]) -> str | None:
    """``None`` if every parameter of the table ``specs`` has an allowed value, else the first reason."""
    for parameter in parameters:
        spec = specs.get(parameter.name)
        reason = spec.check(spec.coerce(parameter.value)) if spec is not None else None
        if reason is not None:
            return reason
    return None


def pre_set_callback(node: Node, specs: dict[str, ParameterSpec]) -> Callable[[list[Parameter]],
                                                                                    list[Parameter]]:
    """``node``'s pre-set callback (the only one: rclpy concatenates the lists its pre-set callbacks return),
    run before rclpy's own checks: :func:`refuse_unknown`, then :func:`coerce_parameters` of the table
    ``specs``."""
    def pre_set(parameters: list[Parameter]) -> list[Parameter]:
        refuse_unknown(node, parameters)
        return coerce_parameters(parameters, specs)
    return pre_set


def unknown_overrides(node: Node, known: Iterable[str]) -> list[str]:
    """The names ``node`` was given overrides for (``-p``, a params file, ``parameter_overrides``) that are not
    its parameters (``known``: the names of its table).  The node declares every override
    (``automatically_declare_parameters_from_overrides``), so they are the declared names that neither the table
    nor rclpy itself declares (the parameters of a bare node of the same context, without the command line's
    arguments; it offers no service, so the graph never lists one of it)."""
    bare = Node(f"{node.get_name()}_bare", context=node.context, use_global_arguments=False,
                start_parameter_services=False, enable_rosout=False,
                parameter_overrides=[Parameter("start_type_description_service", value=False)])
    try:
        builtin = set(bare.get_parameters_by_prefix(""))
    finally:
        bare.destroy_node()
    known = set(known)
    return sorted(name for name in node.get_parameters_by_prefix("")
                  if name not in known and name not in builtin and not name.startswith("qos_overrides."))


def parameter_names(node: Node) -> str:
    """The names of ``node``'s parameters, sorted, for messages."""
    return ", ".join(sorted(node.get_parameters_by_prefix("")))


def refuse_unknown(node: Node, parameters: Iterable[Parameter]) -> None:
    """Raise rclpy's ParameterNotDeclaredException for parameters ``node`` does not have, naming them and the
    node's parameters (rclpy's own message lists neither)."""
    unknown = [p.name for p in parameters if not node.has_parameter(p.name)]
    if unknown:
        raise ParameterNotDeclaredException(f"{', '.join(unknown)}: not a parameter of "
                                            f"{node.get_fully_qualified_name()}; its parameters are "
                                            f"{parameter_names(node)}")


def declare(node: Node, spec: ParameterSpec, config: CraneDescription | None = None) -> Value:
    """Declare ``spec`` on ``node`` (override, else its default for ``config``) and return the value.

    The override may be an integer for a double parameter (see the module doc for the two-step
    declaration; a node that declares its overrides has it declared already); a value
    :meth:`ParameterSpec.check` rejects raises :class:`ParameterError`.
    """
    if node.has_parameter(spec.name):  # declared from its override (automatically_declare_parameters_from_overrides)
        value = spec.coerce(node.get_parameter(spec.name).value)
    else:
        probe = ParameterDescriptor(dynamic_typing=True)
        value = spec.coerce(node.declare_parameter(spec.name, spec.default_for(config), probe).value)
    node.undeclare_parameter(spec.name)
    reason = spec.check(value)
    if reason is not None:
        raise ParameterError(reason)
    node.declare_parameter(spec.name, value, spec.descriptor(), ignore_override=True)
    return value


def refuse_unknown_overrides(node: Node, known: Iterable[str]) -> None:
    """:class:`ParameterError` naming the overrides of ``node`` that are not among the ``known`` names of its
    table (:func:`unknown_overrides`) and the node's parameters."""
    unknown = unknown_overrides(node, known)
    if unknown:
        raise ParameterError(f"unknown parameter(s) {', '.join(unknown)}; the node's parameters are "
                             f"{parameter_names(node)}")


def typed_fields(table: Iterable[ParameterSpec], values: dict[str, Value],
                 joints: Iterable[str] = ()) -> dict[str, Any]:
    """The typed values' fields (:attr:`ParameterSpec.field`) of the parameters ``values`` by name: a string
    array as a tuple, a per-joint row as a dict over ``joints``."""
    fields: dict[str, Any] = {}
    for spec in table:
        if spec.per_joint:
            fields[spec.field] = {joint: values[spec.name_for(joint)] for joint in joints}
        elif spec.name in values:
            value = values[spec.name]
            fields[spec.field] = tuple(value) if isinstance(value, list | tuple) else value
    return fields
