"""The ROS parameters of the crane_plant node: one declared, validated table, as :mod:`.parameters` gives the
reference node (the same :class:`~.parameters.ParameterSpec` rows, typed values in :class:`PlantParameters`).

The drives' damping defaults come from the crane (:func:`~crane_reference.control.plant_server.default_drive_damping`
of the config file and model), one parameter per actuated joint, ``drive_damping.<joint>``, as ros2_control
names per-joint gains.
"""

from __future__ import annotations

from dataclasses import dataclass

from rclpy.node import Node

from ..control.plant import BANDWIDTH, DAMPING_RATIO
from ..control.plant_server import PlantSettings, default_drive_damping
from ..model.chain import VARIANTS
from ..model.config import load_config
from ..model.paper_layout import ACTUATED as PAPER_ACTUATED
from ..motion.simulation import Scenario
from ..motion.steps import PLANT_STEP
from .parameters import (
    BOOL,
    DOUBLE,
    INTEGER,
    STRING,
    STRING_ARRAY,
    ParameterError,
    ParameterSpec,
    declare,
    parameter_names,
    unknown_overrides,
)

CLOCK_MODES = ("realtime", "lockstep")
MAX_CONTROL_RATE = 1000  # [Hz]

PLANT_PARAMETERS: tuple[ParameterSpec, ...] = (
    ParameterSpec("config_file", STRING, "", "Crane file (docs/description.md; a bare name is looked up in the "
                  "package's config/); '' loads the packaged default", empty_allowed=True, read_only=True),
    ParameterSpec("model", STRING, "flexible", "Crane model variant: 'flexible' (each flexible link cut into its "
                  "rigid finite elements) or 'rigid' (one element each)", choices=VARIANTS, read_only=True),
    ParameterSpec("integrator.step", DOUBLE, PLANT_STEP, "Step of the plant's integrator (a control period is a "
                  "whole number of steps)", "s", (1e-5, 1e-2), read_only=True),
    ParameterSpec("control_rate", INTEGER, 1000, "Rate of the control periods: a command holds over one, and the "
                  "state is published after each", "Hz", (1, MAX_CONTROL_RATE), read_only=True),
    ParameterSpec("joints", STRING_ARRAY, list(PAPER_ACTUATED), "The joints of ~/commands, in their order (a "
                  "permutation of the crane's actuated joints, by default those), as a forward command controller's "
                  "joints", read_only=True, from_config=lambda c: list(c.actuated)),
    ParameterSpec("command_timeout", DOUBLE, 0.1, "With no command accepted for this long (real time), the plant "
                  "applies the hold command (the efforts that hold the configuration where the timeout began) and "
                  "WARNs", "s", (0.001, 3600.0)),
    ParameterSpec("clock_mode", STRING, "realtime", "'realtime': a control period every period of the wall "
                  "clock, like a robot; 'lockstep': the plant publishes /clock and advances one period per command "
                  "received (deterministic, as fast as the loop runs)", choices=CLOCK_MODES, read_only=True),
    ParameterSpec("clock_start", DOUBLE, 1.0, "lockstep: the /clock time of the plant's start (ROS time 0 means "
                  "'no clock yet' to nodes with use_sim_time)", "s", (1e-9, 1e9), read_only=True),
    ParameterSpec("all_coordinates", BOOL, False, "~/joint_states gives every coordinate of the model (supports, "
                  "boom springs), not only the joints", read_only=True),
    ParameterSpec("frame_id", STRING, "world", "Frame of ~/end_effector_pose (the world frame {0} of the crane)"),
    ParameterSpec("frame_prefix", STRING, "", "Prefix of the frames the node names, as robot_state_publisher's "
                  "frame_prefix", empty_allowed=True),
    ParameterSpec("autostart", BOOL, True, "Configure and activate the (lifecycle) node at once", read_only=True),
)
PLANT_SPECS: dict[str, ParameterSpec] = {spec.name: spec for spec in PLANT_PARAMETERS}
"""The table without the drives' damping, whose parameters follow the crane's actuated joints
(:func:`drive_damping_spec`)."""


def drive_damping_spec(joint: str, default: float) -> ParameterSpec:
    """``drive_damping.<joint>``, with the crane's default."""
    return ParameterSpec(f"drive_damping.{joint}", DOUBLE, default, f"Damping kd of the {joint} drive's velocity "
                         "loop: the drive applies the commanded effort minus kd times the joint's velocity; default: "
                         f"the D gain of a {BANDWIDTH:g} Hz, {DAMPING_RATIO:g}-damped joint loop on the crane (as "
                         "`crane-reference track`)", "N m s/rad or N s/m", (0.0, 1e9), read_only=True)


@dataclass(frozen=True)
class PlantParameters:
    """The plant node's parameter values (the field of ``integrator.step`` is ``integrator_step``; the drives'
    damping by joint name)."""

    config_file: str
    model: str
    integrator_step: float
    control_rate: int
    joints: tuple[str, ...]
    drive_damping: dict[str, float]
    command_timeout: float
    clock_mode: str
    clock_start: float
    all_coordinates: bool
    frame_id: str
    frame_prefix: str
    autostart: bool

    def settings(self) -> PlantSettings:
        """The plant's settings (:class:`~crane_reference.control.plant_server.PlantSettings`); ValueError if
        they do not fit together (e.g. a rate that is not a whole number of steps)."""
        return PlantSettings(self.model, self.integrator_step, float(self.control_rate), self.joints,
                             tuple(self.drive_damping[joint] for joint in self.joints), self.command_timeout,
                             self.all_coordinates)


def declare_plant(node: Node) -> tuple[PlantParameters, dict[str, ParameterSpec]]:
    """Declare the table on ``node`` (the joints and the damping's defaults from its config file and model, one
    ``drive_damping.<joint>`` per actuated joint) and return the values and the table declared;
    :class:`~.parameters.ParameterError` for a value the table refuses or an unknown override."""
    values = {}
    specs = dict(PLANT_SPECS)
    config = None
    for spec in PLANT_PARAMETERS:
        values[spec.name] = declare(node, spec, config)
        if spec.name == "model":
            config = load_config(values["config_file"] or None)
            scenario = Scenario(config, values["model"])
            damping = [drive_damping_spec(joint, kd) for joint, kd in
                       zip(config.actuated, default_drive_damping(scenario, config.actuated), strict=True)]
            specs.update({spec.name: spec for spec in damping})
            for damping_spec in damping:
                values[damping_spec.name] = declare(node, damping_spec)
    unknown = unknown_overrides(node, specs)
    if unknown:
        raise ParameterError(f"unknown parameter(s) {', '.join(unknown)}; the node's parameters are "
                             f"{parameter_names(node)}")
    return PlantParameters(values["config_file"], values["model"], values["integrator.step"],
                           values["control_rate"], tuple(values["joints"]),
                           {joint: values[f"drive_damping.{joint}"] for joint in config.actuated},
                           values["command_timeout"], values["clock_mode"], values["clock_start"],
                           values["all_coordinates"], values["frame_id"], values["frame_prefix"],
                           values["autostart"]), specs
