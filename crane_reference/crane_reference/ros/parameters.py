"""The ROS parameters of the crane_reference node: one declared, validated table (ros2_controllers style).

:data:`PARAMETERS` lists every parameter with its type, default, description, unit, allowed range or
choices and whether it is read-only (structural: fixed once the node runs); :mod:`.parameter_spec` makes the
descriptors, the validation and the declaration of its rows, and :mod:`.parameter_generation` the typed values
(:class:`~.parameter_values.NodeParameterValues`), ``config/node.yaml`` and ``docs/parameters.md``.

Values from the crane description: the defaults of the task (``ellipse.*``, ``z.*``) and of the drive
(``drive.*``) are the config file's ``task`` and ``drive`` sections.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import replace

from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter

from ..interface.messages import MAX_PUBLISH_RATE
from ..model.chain import VARIANTS
from ..model.config import ConfigError, load_config
from ..model.description import CraneDescription
from ..model.paper_layout import ACTUATED as PAPER_ACTUATED
from ..model.parameters import Task, TorqueDrive
from ..motion.integration import CUTOFF, RESOLVED_BANDWIDTH
from ..motion.steps import ONLINE_STEP
from .parameter_spec import (
    ParameterSpec,
    declare,
    field_name,
    refuse_unknown_overrides,
    typed_fields,
)
from .parameter_values import NodeParameterValues


def _torque_drive(config: CraneDescription) -> TorqueDrive:
    """The config's torque drive, or the default torque profile if the config has a flexible drive."""
    return config.drive if isinstance(config.drive, TorqueDrive) else TorqueDrive()


PARAMETERS: tuple[ParameterSpec, ...] = (
    ParameterSpec("config_file", "string", "", "Crane file (docs/description.md; a bare name is looked up in the "
                  "package's config/, e.g. loader_crane.yaml); "
                  "'' loads the packaged default", empty_allowed=True, read_only=True),
    ParameterSpec("model", "string", "flexible", "Crane model variant: 'flexible' (each flexible link cut into its "
                  "rigid finite elements) or 'rigid' (one element each)", choices=VARIANTS, read_only=True),
    ParameterSpec("integrator.step", "double", ONLINE_STEP, "Step of the integrator; a step resolves the modes below "
                  f"min({CUTOFF / math.pi:g} pi / step, 2 pi {RESOLVED_BANDWIDTH / (2.0 * math.pi):g} Hz) and damps "
                  "the others", "s", (1e-5, 1e-2), read_only=True),
    ParameterSpec("publish_rate", "integer", 100, "Rate of joint_states and ~/end_effector_pose; sample k is "
                  "stamped start + k / publish_rate", "Hz", (1, MAX_PUBLISH_RATE), read_only=True),
    ParameterSpec("frame_id", "string", "world", "Frame of ~/end_effector_pose, ~/reference_preview and ~/markers "
                  "(the world frame {0} of the crane)"),
    ParameterSpec("frame_prefix", "string", "", "Prefix of the frames the node names (frame_prefix + frame_id), as "
                  "robot_state_publisher's frame_prefix prefixes the URDF's links: the same prefix on both lets "
                  "several cranes share /tf (e.g. 'crane1/')", empty_allowed=True),
    ParameterSpec("ellipse.a", "double", 3.0, "Semi-axis of E's ellipse along world x (constraint (5.1)); "
                  "default: task.ellipse_a of the config file", "m", (0.1, 20.0),
                  from_config=lambda c: c.task.ellipse_a),
    ParameterSpec("ellipse.b", "double", 2.0, "Semi-axis of E's ellipse along world y (constraint (5.1)); "
                  "default: task.ellipse_b of the config file", "m", (0.1, 20.0),
                  from_config=lambda c: c.task.ellipse_b),
    ParameterSpec("z.increment", "double", 0.2, "Rise of E's height above its static value z_E,s (constraint "
                  "(5.2)); default: task.z_increment of the config file", "m", (-10.0, 10.0),
                  from_config=lambda c: c.task.z_increment),
    ParameterSpec("z.rise_time", "double", 5.0, "Duration t_c of the quintic height rise (5.2); default: "
                  "task.rise_time of the config file", "s", (0.01, 3600.0),
                  from_config=lambda c: c.task.rise_time),
    ParameterSpec("drive.torque", "double", 4000.0, "Column drive torque of the torque profile (from drive.start "
                  "of the config file for drive.duration); default: the config file's torque drive; unused "
                  "if the config file has a flexible drive", "N m", (-1e6, 1e6), read_only=True,
                  from_config=lambda c: _torque_drive(c).torque),
    ParameterSpec("drive.duration", "double", 1.0, "Duration of the column drive torque; default: end - start of "
                  "the config file's torque drive; unused if the config file has a flexible drive", "s",
                  (1e-3, 3600.0), read_only=True,
                  from_config=lambda c: _torque_drive(c).end - _torque_drive(c).start),
    ParameterSpec("blend_time", "double", 2.0, "Duration of the C2 blend of the constraint parameters after a "
                  "change of ellipse.* or z.*", "s", (0.01, 600.0)),
    ParameterSpec("command_lead", "double", 0.03, "A change of ellipse.*, z.* or speed_scaling and ~/pause "
                  "take effect at the last sample stamped within this time of their acceptance, at least the "
                  "one after the next to publish (the frames made beyond it are made again); a longer lead "
                  "tolerates a more loaded machine (diagnostics: {command}_margin_s)", "s", (0.001, 1.0)),
    ParameterSpec("preview.horizon", "double", 1.0, "Time span of ~/reference_preview", "s", (0.01, 10.0)),
    ParameterSpec("preview.points", "integer", 11, "Points of ~/reference_preview: the first at the sample's "
                  "stamp (header.stamp, time_from_start 0), then evenly spaced to the horizon", "", (2, 1000)),
    ParameterSpec("preview.rate", "double", 10.0, "Rate of ~/reference_preview (every round(publish_rate / "
                  "preview.rate)-th sample, at least every sample)", "Hz", (0.1, 1000.0)),
    ParameterSpec("preview.joints", "string_array", list(PAPER_ACTUATED), "Joints of ~/reference_preview (names "
                  "of the model's coordinates, see `crane-reference urdf`); default the crane's actuated joints",
                  from_config=lambda c: list(c.actuated)),
    ParameterSpec("preview.effort", "bool", False, "Fill the efforts of ~/reference_preview with the feedforward "
                  "a controller adds at each of its joints: the constraint forces of the motion at its own speed, "
                  "without the drive's torque, which the plant applies itself (~/joint_states' efforts include it)"),
    ParameterSpec("speed_scaling", "double", 1.0, "Speed of the reference relative to the programmed motion "
                  "(0: at rest); changes are C2 ramps over speed_scaling.ramp_time", "", (0.0, 1.0)),
    ParameterSpec("speed_scaling.ramp_time", "double", 1.0, "Duration of a speed-scaling ramp (also of "
                  "~/pause, resume and the stop before ~/restart)", "s", (0.01, 60.0), read_only=True),
    ParameterSpec("autostart", "bool", True, "Configure and activate the (lifecycle) node at once; if false, it "
                  "waits unconfigured for a lifecycle manager or `ros2 lifecycle set`", read_only=True),
    ParameterSpec("action_monitor_rate", "double", 10.0, "Rate at which an active ~/retarget goal is checked and its "
                  "feedback published (joint_trajectory_controller's parameter of that name)", "Hz", (0.1, 1000.0),
                  read_only=True),
    ParameterSpec("status_period", "double", 5.0, "Period of the one-line status log", "s", (0.1, 3600.0)),
    ParameterSpec("solver_process", "bool", True, "Compute the reference in a process of its own (its own Python "
                  "interpreter, so the solver and the publisher never wait for each other); false: in a thread of "
                  "the node's process", read_only=True),
)
SPECS: dict[str, ParameterSpec] = {spec.name: spec for spec in PARAMETERS}


class NodeParameters(NodeParameterValues):
    """The node's parameter values (:class:`~.parameter_values.NodeParameterValues`, generated from
    :data:`PARAMETERS`).  Immutable: a change is a new instance (:meth:`changed`)."""

    @classmethod
    def from_values(cls, values: dict) -> NodeParameters:
        """From every parameter's value by parameter name (string arrays become tuples)."""
        return cls(**typed_fields(PARAMETERS, values))

    def changed(self, parameters: Iterable[Parameter]) -> NodeParameters:
        """These values with the table's ``parameters`` set (others ignored)."""
        return replace(self, **typed_fields(PARAMETERS, {p.name: SPECS[p.name].coerce(p.value) for p in parameters
                                                         if p.name in SPECS}))

    def targets(self) -> Task:
        """The task of the target parameters (ellipse.*, z.*)."""
        return Task(**{field: getattr(self, field_name(name)) for name, field in TARGET_PARAMETERS.items()})


TARGET_PARAMETERS = {"ellipse.a": "ellipse_a", "ellipse.b": "ellipse_b", "z.increment": "z_increment",
                     "z.rise_time": "rise_time"}
# parameters whose change is a request to the running solver (refused once it has stopped)
COMMANDING_PARAMETERS = {*TARGET_PARAMETERS, "speed_scaling"}


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


def declare_all(node: Node) -> tuple[NodeParameters, tuple[ParameterSpec, ...]]:
    """Declare every parameter of the table on ``node`` (``config_file`` first: it gives the others'
    defaults, see :attr:`~.parameter_spec.ParameterSpec.from_config`) and return their values;
    :class:`~.parameter_spec.ParameterError` for an override of a name the node lacks
    (:func:`~.parameter_spec.unknown_overrides`).  Also the parameters left to declare: where the crane file cannot
    be loaded, those whose defaults come from it and that have no override are declared once it loads
    (:func:`declare_from_config`, at configure, which reports why it cannot); their values meanwhile are the
    table's defaults."""
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
    refuse_unknown_overrides(node, SPECS)
    return values, pending


def declare_from_config(node: Node, pending: tuple[ParameterSpec, ...], config: CraneDescription,
                        values: NodeParameters) -> NodeParameters:
    """Declare the ``pending`` parameters of :func:`declare_all` with their defaults from ``config``; ``values``
    with theirs."""
    return values.changed([Parameter(spec.name, value=declare(node, spec, config)) for spec in pending])


