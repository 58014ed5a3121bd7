"""The ROS parameters of the crane_reference node: one declared, validated table (ros2_controllers style).

:data:`PARAMETERS` lists every parameter with its type, default, description, unit, allowed range or
choices and whether it is read-only (structural: fixed once the node runs).  From it come the
``ParameterDescriptor`` (:meth:`ParameterSpec.descriptor`, with a ``FloatingPointRange`` or
``IntegerRange``), the validation (:func:`check`, a reason naming the parameter and what is allowed)
and the declaration (:func:`declare`).

Integer values for double parameters (``-p ellipse.a:=3``, ``ellipse.a: 3`` in a YAML file, or
``ros2 param set /crane_reference ellipse.a 3``) are accepted: rclpy 7 checks a statically typed
parameter's type before any user callback and rejects them, so

* at start-up, :func:`declare` reads the override of any type (the node declares its overrides as they
  come, ``automatically_declare_parameters_from_overrides``; else it declares the parameter with
  ``dynamic_typing=True`` first), undeclares it and declares it again, statically typed, with the value
  converted to float (``ignore_override=True``);
* at run time, :func:`coerce_parameters` is a *pre*-set callback (``Node.add_pre_set_parameters_callback``,
  run before rclpy's type and range checks) that turns such integers into doubles.

Values from the crane description: the defaults of the task (``ellipse.*``, ``z.*``) and of the drive
(``drive.*``) are the config file's ``task`` and ``drive`` sections.
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

from ..interface.messages import MAX_PUBLISH_RATE
from ..model.chain import VARIANTS
from ..model.config import ConfigError, load_config
from ..model.description import CraneDescription
from ..model.paper_layout import ACTUATED as PAPER_ACTUATED
from ..model.parameters import Task, TorqueDrive
from ..motion.steps import ONLINE_STEP

Value = bool | int | float | str | list[str]
BOOL, INTEGER, DOUBLE, STRING, STRING_ARRAY = (Parameter.Type.BOOL, Parameter.Type.INTEGER, Parameter.Type.DOUBLE,
                                               Parameter.Type.STRING, Parameter.Type.STRING_ARRAY)
_TYPE_NAMES = {BOOL: "a boolean", INTEGER: "an integer", DOUBLE: "a number", STRING: "a string",
               STRING_ARRAY: "a list of distinct, non-empty strings"}


class ParameterError(ValueError):
    """A parameter value that :func:`check` rejects (the message is the reason)."""


def _torque_drive(config: CraneDescription) -> TorqueDrive:
    """The config's torque drive, or the default torque profile if the config has a flexible drive."""
    return config.drive if isinstance(config.drive, TorqueDrive) else TorqueDrive()


@dataclass(frozen=True)
class ParameterSpec:
    """One node parameter.  ``bounds`` are inclusive [low, high] (as in ROS ranges); ``choices`` the
    allowed strings (empty: any non-empty string, unless ``empty_allowed``); ``from_config`` gives the
    default from the crane description instead of ``default``."""

    name: str
    type: Parameter.Type
    default: Value
    description: str
    unit: str = ""
    bounds: tuple[float, float] | None = None
    choices: tuple[str, ...] = ()
    empty_allowed: bool = False
    read_only: bool = False
    from_config: Callable[[CraneDescription], Value] | None = None

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
            integers = " (integers accepted)" if self.type is DOUBLE else ""
            return f"must be {_TYPE_NAMES[self.type]} in [{low:g}, {high:g}]{unit}{integers}"
        if self.type is STRING and not self.empty_allowed:
            return "must be a non-empty string"
        return f"must be {_TYPE_NAMES[self.type]}"

    def descriptor(self) -> ParameterDescriptor:
        """Statically typed ParameterDescriptor with description, range and read-only flag."""
        descriptor = ParameterDescriptor(
            name=self.name, type=self.type.value, read_only=self.read_only,
            description=f"{self.description}{f' [{self.unit}]' if self.unit else ''}",
            additional_constraints=self.allowed())
        if self.bounds is not None and self.type is DOUBLE:
            descriptor.floating_point_range = [FloatingPointRange(
                from_value=float(self.bounds[0]), to_value=float(self.bounds[1]), step=0.0)]
        elif self.bounds is not None:
            descriptor.integer_range = [IntegerRange(
                from_value=int(self.bounds[0]), to_value=int(self.bounds[1]), step=1)]
        return descriptor

    def coerce(self, value: Any) -> Any:
        """An integer for a double parameter as a float; every other value unchanged."""
        if self.type is DOUBLE and isinstance(value, int) and not isinstance(value, bool):
            return float(value)
        return value

    def check(self, value: Any) -> str | None:
        """``None`` if ``value`` (already coerced) is allowed, else the reason, naming the parameter."""
        if self.type is STRING_ARRAY:
            strings = isinstance(value, list | tuple) and all(isinstance(v, str) and v for v in value)
            invalid = not strings or not value or len(set(value)) != len(value)
            return f"{self.name} = {value!r}: {self.allowed()}" if invalid else None
        python_type = {BOOL: bool, INTEGER: int, DOUBLE: float, STRING: str}[self.type]
        wrong_type = not isinstance(value, python_type) or (python_type is int and isinstance(value, bool))
        invalid = (wrong_type
                   or (self.type is DOUBLE and not math.isfinite(value))
                   or (self.bounds is not None and not self.bounds[0] <= value <= self.bounds[1])
                   or (self.choices and value not in self.choices)
                   or (self.type is STRING and not self.empty_allowed and not value))
        return f"{self.name} = {value!r}: {self.allowed()}" if invalid else None


PARAMETERS: tuple[ParameterSpec, ...] = (
    ParameterSpec("config_file", STRING, "", "Crane file (docs/description.md; a bare name is looked up in the "
                  "package's config/, e.g. loader_crane.yaml); "
                  "'' loads the packaged default", empty_allowed=True, read_only=True),
    ParameterSpec("model", STRING, "flexible", "Crane model variant: 'flexible' (each flexible link cut into its "
                  "rigid finite elements) or 'rigid' (one element each)", choices=VARIANTS, read_only=True),
    ParameterSpec("integrator.step", DOUBLE, ONLINE_STEP, "Step of the integrator", "s",
                  (1e-5, 1e-2), read_only=True),
    ParameterSpec("publish_rate", INTEGER, 100, "Rate of joint_states and ~/end_effector_pose; sample k is "
                  "stamped start + k / publish_rate", "Hz", (1, MAX_PUBLISH_RATE), read_only=True),
    ParameterSpec("frame_id", STRING, "world", "Frame of ~/end_effector_pose, ~/reference_preview and ~/markers "
                  "(the world frame {0} of the crane)"),
    ParameterSpec("frame_prefix", STRING, "", "Prefix of the frames the node names (frame_prefix + frame_id), as "
                  "robot_state_publisher's frame_prefix prefixes the URDF's links: the same prefix on both lets "
                  "several cranes share /tf (e.g. 'crane1/')", empty_allowed=True),
    ParameterSpec("ellipse.a", DOUBLE, 3.0, "Semi-axis of E's ellipse along world x (constraint (5.1)); "
                  "default: task.ellipse_a of the config file", "m", (0.1, 20.0),
                  from_config=lambda c: c.task.ellipse_a),
    ParameterSpec("ellipse.b", DOUBLE, 2.0, "Semi-axis of E's ellipse along world y (constraint (5.1)); "
                  "default: task.ellipse_b of the config file", "m", (0.1, 20.0),
                  from_config=lambda c: c.task.ellipse_b),
    ParameterSpec("z.increment", DOUBLE, 0.2, "Rise of E's height above its static value z_E,s (constraint "
                  "(5.2)); default: task.z_increment of the config file", "m", (-10.0, 10.0),
                  from_config=lambda c: c.task.z_increment),
    ParameterSpec("z.rise_time", DOUBLE, 5.0, "Duration t_c of the quintic height rise (5.2); default: "
                  "task.rise_time of the config file", "s", (0.01, 3600.0),
                  from_config=lambda c: c.task.rise_time),
    ParameterSpec("drive.torque", DOUBLE, 4000.0, "Column drive torque of the torque profile (from drive.start "
                  "of the config file for drive.duration); default: the config file's torque drive; unused "
                  "if the config file has a flexible drive", "N m", (-1e6, 1e6), read_only=True,
                  from_config=lambda c: _torque_drive(c).torque),
    ParameterSpec("drive.duration", DOUBLE, 1.0, "Duration of the column drive torque; default: end - start of "
                  "the config file's torque drive; unused if the config file has a flexible drive", "s",
                  (1e-3, 3600.0), read_only=True,
                  from_config=lambda c: _torque_drive(c).end - _torque_drive(c).start),
    ParameterSpec("blend_time", DOUBLE, 2.0, "Duration of the C2 blend of the constraint parameters after a "
                  "change of ellipse.* or z.*", "s", (0.01, 600.0)),
    ParameterSpec("command_lead", DOUBLE, 0.03, "A change of ellipse.*, z.* or speed_scaling and ~/pause "
                  "take effect at the last sample stamped within this time of their acceptance, at least the "
                  "one after the next to publish (the frames made beyond it are made again); a longer lead "
                  "tolerates a more loaded machine (diagnostics: {command}_margin_s)", "s", (0.001, 1.0)),
    ParameterSpec("preview.horizon", DOUBLE, 1.0, "Time span of ~/reference_preview", "s", (0.01, 10.0)),
    ParameterSpec("preview.points", INTEGER, 11, "Points of ~/reference_preview: the first at the sample's "
                  "stamp (header.stamp, time_from_start 0), then evenly spaced to the horizon", "", (2, 1000)),
    ParameterSpec("preview.rate", DOUBLE, 10.0, "Rate of ~/reference_preview (every round(publish_rate / "
                  "preview.rate)-th sample, at least every sample)", "Hz", (0.1, 1000.0)),
    ParameterSpec("preview.joints", STRING_ARRAY, list(PAPER_ACTUATED), "Joints of ~/reference_preview (names "
                  "of the model's coordinates, see `crane-reference urdf`); default the crane's actuated joints",
                  from_config=lambda c: list(c.actuated)),
    ParameterSpec("preview.effort", BOOL, False, "Fill the efforts of ~/reference_preview with the feedforward "
                  "a controller adds at each of its joints: the constraint forces of the motion at its own speed, "
                  "without the drive's torque, which the plant applies itself (~/joint_states' efforts include it)"),
    ParameterSpec("speed_scaling", DOUBLE, 1.0, "Speed of the reference relative to the programmed motion "
                  "(0: at rest); changes are C2 ramps over speed_scaling.ramp_time", "", (0.0, 1.0)),
    ParameterSpec("speed_scaling.ramp_time", DOUBLE, 1.0, "Duration of a speed-scaling ramp (also of "
                  "~/pause, resume and the stop before ~/restart)", "s", (0.01, 60.0), read_only=True),
    ParameterSpec("autostart", BOOL, True, "Configure and activate the (lifecycle) node at once; if false, it "
                  "waits unconfigured for a lifecycle manager or `ros2 lifecycle set`", read_only=True),
    ParameterSpec("action_monitor_rate", DOUBLE, 10.0, "Rate at which an active ~/retarget goal is checked and its "
                  "feedback published (joint_trajectory_controller's parameter of that name)", "Hz", (0.1, 1000.0),
                  read_only=True),
    ParameterSpec("status_period", DOUBLE, 5.0, "Period of the one-line status log", "s", (0.1, 3600.0)),
    ParameterSpec("solver_process", BOOL, True, "Compute the reference in a process of its own (its own Python "
                  "interpreter, so the solver and the publisher never wait for each other); false: in a thread of "
                  "the node's process", read_only=True),
)
SPECS: dict[str, ParameterSpec] = {spec.name: spec for spec in PARAMETERS}


def field_name(name: str) -> str:
    """The :class:`NodeParameters` field of the parameter ``name`` (dots become underscores)."""
    return name.replace(".", "_")


@dataclass(frozen=True)
class NodeParameters:
    """The node's parameter values, one typed field per entry of :data:`PARAMETERS` in its order (the field of
    ``ellipse.a`` is ``ellipse_a``: :func:`field_name`), as generate_parameter_library gives a controller its
    ``Params`` struct.  Immutable: a change is a new instance (:meth:`changed`)."""

    config_file: str
    model: str
    integrator_step: float
    publish_rate: int
    frame_id: str
    frame_prefix: str
    ellipse_a: float
    ellipse_b: float
    z_increment: float
    z_rise_time: float
    drive_torque: float
    drive_duration: float
    blend_time: float
    command_lead: float
    preview_horizon: float
    preview_points: int
    preview_rate: float
    preview_joints: tuple[str, ...]
    preview_effort: bool
    speed_scaling: float
    speed_scaling_ramp_time: float
    autostart: bool
    action_monitor_rate: float
    status_period: float
    solver_process: bool

    @classmethod
    def from_values(cls, values: dict[str, Value]) -> NodeParameters:
        """From every parameter's value by parameter name (string arrays become tuples)."""
        return cls(**{field_name(name): _frozen(value) for name, value in values.items()})

    def changed(self, parameters: Iterable[Parameter]) -> NodeParameters:
        """These values with the table's ``parameters`` set (others ignored)."""
        return replace(self, **{field_name(p.name): _frozen(SPECS[p.name].coerce(p.value))
                                for p in parameters if p.name in SPECS})

    def targets(self) -> Task:
        """The task of the target parameters (ellipse.*, z.*)."""
        return Task(**{field: getattr(self, field_name(name)) for name, field in TARGET_PARAMETERS.items()})


def _frozen(value: Value) -> Value | tuple[str, ...]:
    return tuple(value) if isinstance(value, list | tuple) else value
TARGET_PARAMETERS = {"ellipse.a": "ellipse_a", "ellipse.b": "ellipse_b", "z.increment": "z_increment",
                     "z.rise_time": "rise_time"}
# parameters whose change is a request to the running solver (refused once it has stopped)
COMMANDING_PARAMETERS = {*TARGET_PARAMETERS, "speed_scaling", "blend_time"}


def reach_descriptor(spec: ParameterSpec, low: float, high: float) -> ParameterDescriptor:
    """``spec``'s descriptor with the range [low, high] m: E's reach from the column's axis at the start and
    target heights (what rqt_reconfigure's sliders and rclpy's range check use; every change is still checked
    around the whole ellipse)."""
    descriptor = spec.descriptor()
    descriptor.floating_point_range = [FloatingPointRange(from_value=low, to_value=high, step=0.0)]
    descriptor.additional_constraints = (
        f"must be a number in [{low:g}, {high:g}] m: E's reach from the column's axis at the start and target "
        "heights (computed at configure); the whole ellipse is checked when it is set")
    return descriptor


def coerce_parameters(parameters: list[Parameter], specs: dict[str, ParameterSpec] = SPECS) -> list[Parameter]:
    """Pre-set callback: integer values of the table's double parameters become doubles (all else unchanged)."""
    return [Parameter(p.name, DOUBLE, float(p.value))
            if p.name in specs and specs[p.name].type is DOUBLE and p.type_ is INTEGER else p
            for p in parameters]


def check(parameters: Iterable[Parameter], specs: dict[str, ParameterSpec] = SPECS) -> str | None:
    """``None`` if every parameter of the table ``specs`` has an allowed value, else the first reason."""
    for parameter in parameters:
        spec = specs.get(parameter.name)
        reason = spec.check(spec.coerce(parameter.value)) if spec is not None else None
        if reason is not None:
            return reason
    return None


def declare_all(node: Node) -> tuple[NodeParameters, tuple[ParameterSpec, ...]]:
    """Declare every parameter of the table on ``node`` (``config_file`` first: it gives the others'
    defaults, see :attr:`ParameterSpec.from_config`) and return their values; :class:`ParameterError` for an
    override of a name the node lacks (:func:`unknown_overrides`).  Also the parameters left to declare: where the
    crane file cannot be loaded, those whose defaults come from it and that have no override are declared once
    it loads (:func:`declare_from_config`, at configure, which reports why it cannot); their values meanwhile are
    the table's defaults."""
    config_file = declare(node, SPECS["config_file"])
    try:
        config = load_config(config_file or None)
    except ConfigError:
        config = None
    pending = tuple(spec for spec in PARAMETERS if config is None and spec.from_config is not None
                    and not node.has_parameter(spec.name))
    values = NodeParameters.from_values({"config_file": config_file, **{
        spec.name: spec.default if spec in pending else declare(node, spec, config)
        for spec in PARAMETERS if spec.name != "config_file"}})
    unknown = unknown_overrides(node)
    if unknown:
        raise ParameterError(f"unknown parameter(s) {', '.join(unknown)}; the node's parameters are "
                             f"{parameter_names(node)}")
    return values, pending


def declare_from_config(node: Node, pending: tuple[ParameterSpec, ...], config: CraneDescription,
                        values: NodeParameters) -> NodeParameters:
    """Declare the ``pending`` parameters of :func:`declare_all` with their defaults from ``config``; ``values``
    with theirs."""
    return values.changed([Parameter(spec.name, value=declare(node, spec, config)) for spec in pending])


def pre_set_callback(node: Node, specs: dict[str, ParameterSpec] = SPECS) -> Callable[[list[Parameter]],
                                                                                    list[Parameter]]:
    """``node``'s pre-set callback (the only one: rclpy concatenates the lists its pre-set callbacks return),
    run before rclpy's own checks: :func:`refuse_unknown`, then :func:`coerce_parameters` of the table
    ``specs``."""
    def pre_set(parameters: list[Parameter]) -> list[Parameter]:
        refuse_unknown(node, parameters)
        return coerce_parameters(parameters, specs)
    return pre_set


def unknown_overrides(node: Node, known: Iterable[str] = SPECS) -> list[str]:
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
