"""The ROS parameters of the example controller node: one declared, validated table, as :mod:`.parameters` gives the
reference node (typed values: :class:`~.parameter_values.ControllerParameterValues`).

The gains are per joint, ``gains.<joint>.p`` [N m/rad], ``.d`` [N m s/rad] and ``.i`` [N m/(rad s)] (ros2_control's
names), with defaults from the crane (:func:`~crane_reference.control.plant.default_gains` of the crane of
``config_file`` and ``model``, as ``crane-reference track``; no integral action).
"""

from __future__ import annotations

from rclpy.node import Node

from ..control.plant import default_gains
from ..control.preview_tracking import PREVIEW_FEEDFORWARDS
from ..model.chain import VARIANTS
from ..model.config import load_config
from ..model.paper_layout import ACTUATED as PAPER_ACTUATED
from ..motion.simulation import Scenario
from .parameter_spec import (
    ParameterError,
    ParameterSpec,
    declare,
    refuse_unknown_overrides,
    typed_fields,
)
from .parameter_values import ControllerParameterValues
from .plant_parameters import MAX_CONTROL_RATE

GAIN_RANGE = (0.0, 1e12)

CONTROLLER_PARAMETERS: tuple[ParameterSpec, ...] = (
    ParameterSpec("config_file", "string", "", "Crane file (docs/description.md); '' loads the packaged default",
                  empty_allowed=True, read_only=True),
    ParameterSpec("model", "string", "flexible", "Crane model variant (for the default gains)", choices=VARIANTS,
                  read_only=True),
    ParameterSpec("joints", "string_array", list(PAPER_ACTUATED), "The joints of the commands, in their order (default "
                  "the crane's actuated joints)", read_only=True, from_config=lambda c: list(c.actuated)),
    ParameterSpec("control_rate", "integer", 1000, "The plant's control rate (the integral's period)", "Hz",
                  (1, MAX_CONTROL_RATE), read_only=True),
    ParameterSpec("feedforward", "string", "none", "The torque added to the feedback: 'none', or 'reference': the "
                  "preview's efforts (the reference node's preview.effort:=true)", choices=PREVIEW_FEEDFORWARDS,
                  read_only=True),
    ParameterSpec("gains.<joint>.p", "double", 0.0, "Proportional gain of <joint>; default: the crane's (as "
                  "`crane-reference track`)", "N m/rad", GAIN_RANGE, read_only=True, from_crane=True),
    ParameterSpec("gains.<joint>.d", "double", 0.0, "Derivative gain of <joint> (in the plant's drive: it equals the "
                  "plant's drive_damping.<joint>); default: the crane's", "N m s/rad", GAIN_RANGE, read_only=True,
                  from_crane=True),
    ParameterSpec("gains.<joint>.i", "double", 0.0, "Integral gain of <joint>", "N m/(rad s)", GAIN_RANGE,
                  read_only=True),
    ParameterSpec("reference_topic", "string", "crane_reference/reference_preview", "The reference node's preview "
                  "(trajectory_msgs/JointTrajectory; relative names resolve in the node's namespace)", read_only=True),
    ParameterSpec("state_topic", "string", "crane_plant/joint_states", "The plant's measured joint states",
                  read_only=True),
    ParameterSpec("command_topic", "string", "crane_plant/commands", "The plant's commands "
                  "(std_msgs/Float64MultiArray)", read_only=True),
)

CRANE_GAINS = {"gains.<joint>.p": lambda gains: gains.kp, "gains.<joint>.d": lambda gains: gains.kd}
"""The per-joint rows whose defaults are the crane's gains (:func:`~crane_reference.control.plant.default_gains`)."""


def declare_controller(node: Node) -> ControllerParameterValues:
    """Declare the table on ``node`` (the joints and the gains' defaults from its config file and model, the gains
    per joint of ``joints``) and return the values; :class:`~.parameter_spec.ParameterError` for a value the table
    refuses, joints that are not the crane's actuated ones, or an unknown override."""
    values: dict = {}
    config = joints = gains = None
    for spec in CONTROLLER_PARAMETERS:
        if spec.per_joint:
            if gains is None:
                gains = dict(zip(joints, default_gains(Scenario(config, values["model"]), joints), strict=True))
            crane = CRANE_GAINS.get(spec.name)
            for joint in joints:
                concrete = spec.for_joint(joint, None if crane is None else crane(gains[joint]))
                values[concrete.name] = declare(node, concrete)
            continue
        values[spec.name] = declare(node, spec, config)
        if spec.name == "model":
            config = load_config(values["config_file"] or None)
        elif spec.name == "joints":
            joints = tuple(values["joints"])
            if sorted(joints) != sorted(config.actuated):
                raise ParameterError(f"joints = {list(joints)}: must name each of {', '.join(config.actuated)} once")
    refuse_unknown_overrides(node, values)
    return ControllerParameterValues(**typed_fields(CONTROLLER_PARAMETERS, values, joints))
