"""The ROS parameters of the crane_plant node: one declared, validated table, as :mod:`.parameters` gives the
reference node (the same :class:`~.parameter_spec.ParameterSpec` rows, typed values in :class:`PlantParameters`).

The drives' damping defaults come from the crane (:func:`~crane_reference.control.plant_server.default_drive_damping`
of the config file and model), one parameter per actuated joint, ``drive_damping.<joint>``, as ros2_control
names per-joint gains.
"""

from __future__ import annotations

from rclpy.node import Node

from ..control.plant import BANDWIDTH, DAMPING_RATIO
from ..control.plant_server import PlantSettings, default_drive_damping
from ..model.chain import VARIANTS
from ..model.config import load_config
from ..model.paper_layout import ACTUATED as PAPER_ACTUATED
from ..motion.simulation import Scenario
from ..motion.steps import PLANT_STEP
from .parameter_spec import (
    ParameterSpec,
    declare,
    refuse_unknown_overrides,
    typed_fields,
)
from .parameter_values import PlantParameterValues

CLOCK_MODES = ("realtime", "lockstep")
MAX_CONTROL_RATE = 1000  # [Hz]

PLANT_PARAMETERS: tuple[ParameterSpec, ...] = (
    ParameterSpec("config_file", "string", "", "Crane file (docs/description.md; a bare name is looked up in the "
                  "package's config/); '' loads the packaged default", empty_allowed=True, read_only=True),
    ParameterSpec("model", "string", "flexible", "Crane model variant: 'flexible' (each flexible link cut into its "
                  "rigid finite elements) or 'rigid' (one element each)", choices=VARIANTS, read_only=True),
    ParameterSpec("integrator.step", "double", PLANT_STEP, "Step of the plant's integrator (a control period is a "
                  "whole number of steps)", "s", (1e-5, 1e-2), read_only=True),
    ParameterSpec("control_rate", "integer", 1000, "Rate of the control periods: a command holds over one, and the "
                  "state is published after each", "Hz", (1, MAX_CONTROL_RATE), read_only=True),
    ParameterSpec("joints", "string_array", list(PAPER_ACTUATED), "The joints of ~/commands, in their order (a "
                  "permutation of the crane's actuated joints, by default those), as a forward command controller's "
                  "joints", read_only=True, from_config=lambda c: list(c.actuated)),
    ParameterSpec("drive_damping.<joint>", "double", 0.0, "Damping kd of the <joint> drive's velocity loop: the drive "
                  "applies the commanded effort minus kd times the joint's velocity; one per actuated joint, default: "
                  f"the D gain of a {BANDWIDTH:g} Hz, {DAMPING_RATIO:g}-damped joint loop on the crane (as "
                  "`crane-reference track`)", "N m s/rad or N s/m", (0.0, 1e9), read_only=True, from_crane=True),
    ParameterSpec("command_timeout", "double", 0.1, "With no command accepted for this long (real time), the plant "
                  "applies the hold command (the efforts that hold the configuration where the timeout began) and "
                  "WARNs", "s", (0.001, 3600.0)),
    ParameterSpec("clock_mode", "string", "realtime", "'realtime': a control period every period of the wall "
                  "clock, like a robot; 'lockstep': the plant publishes /clock and advances one period per command "
                  "received (deterministic, as fast as the loop runs)", choices=CLOCK_MODES, read_only=True),
    ParameterSpec("clock_start", "double", 1.0, "lockstep: the /clock time of the plant's start (ROS time 0 means "
                  "'no clock yet' to nodes with use_sim_time)", "s", (1e-9, 1e9), read_only=True),
    ParameterSpec("all_coordinates", "bool", False, "~/joint_states gives every coordinate of the model (supports, "
                  "boom springs), not only the joints", read_only=True),
    ParameterSpec("frame_id", "string", "world", "Frame of ~/end_effector_pose (the world frame {0} of the crane)"),
    ParameterSpec("frame_prefix", "string", "", "Prefix of the frames the node names, as robot_state_publisher's "
                  "frame_prefix", empty_allowed=True),
    ParameterSpec("autostart", "bool", True, "Configure and activate the (lifecycle) node at once", read_only=True),
)


class PlantParameters(PlantParameterValues):
    """The plant node's parameter values (:class:`~.parameter_values.PlantParameterValues`)."""

    def settings(self) -> PlantSettings:
        """The plant's settings (:class:`~crane_reference.control.plant_server.PlantSettings`); ValueError if
        they do not fit together (e.g. a rate that is not a whole number of steps)."""
        return PlantSettings(self.model, self.integrator_step, float(self.control_rate), self.joints,
                             tuple(self.drive_damping[joint] for joint in self.joints), self.command_timeout,
                             self.all_coordinates)


def declare_plant(node: Node) -> tuple[PlantParameters, dict[str, ParameterSpec]]:
    """Declare the table on ``node`` (the joints and the damping's defaults from its config file and model, one
    ``drive_damping.<joint>`` per actuated joint) and return the values and the parameters declared;
    :class:`~.parameter_spec.ParameterError` for a value the table refuses or an unknown override."""
    values: dict = {}
    specs: dict[str, ParameterSpec] = {}
    config = None
    for spec in PLANT_PARAMETERS:
        if spec.per_joint:
            damping = default_drive_damping(Scenario(config, values["model"]), config.actuated)
            concrete = [spec.for_joint(joint, kd) for joint, kd in zip(config.actuated, damping, strict=True)]
        else:
            concrete = [spec]
        for row in concrete:
            specs[row.name] = row
            values[row.name] = declare(node, row, config)
        if spec.name == "model":
            config = load_config(values["config_file"] or None)
    refuse_unknown_overrides(node, specs)
    return PlantParameters(**typed_fields(PLANT_PARAMETERS, values, config.actuated)), specs
