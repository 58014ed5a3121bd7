"""The closed loop over ROS without launch: the three nodes' parameters (shared by
``launch/closed_loop.launch.py`` and ``crane-reference loop``) and what ``crane-reference loop`` records.

The reference node publishes its preview with a point every control period over about a second (the
controller reads the reference there, as joint_trajectory_controller reads its trajectory) and its joint
states at the control rate (the recording's reference); with ``lockstep`` the reference and the controller
follow the plant's /clock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .messages import MAX_PUBLISH_RATE, NODE_NAME

PLANT_NODE = "crane_plant"
CONTROLLER_NODE = "crane_controller"
CLOCK_START = 1.0
"""[s] the lock-step plant's /clock at its start (its ``clock_start`` default)."""
PREVIEW_HORIZON = 1.0  # [s], about


def closed_loop_parameters(clock_mode: str, control_rate: int, model: str = "flexible", config_file: str = "",
                           namespace: str = "") -> dict[str, dict[str, object]]:
    """The parameters of the reference node, the plant and the controller (in ``namespace``), by node name.
    The preview is transient-local on both ends (rclpy's ``qos_overrides``): a controller that starts after the
    reference node still gets its last preview, which in lock-step is the only one until the plant moves."""
    crane = {"model": model, "config_file": config_file}
    lockstep = clock_mode == "lockstep"
    points = min(1000, round(PREVIEW_HORIZON * control_rate) + 1)  # the sample's, then one per control period
    parts = (*namespace.strip("/").split("/"), NODE_NAME, "reference_preview")
    preview = "/" + "/".join(part for part in parts if part)
    latched = {f"qos_overrides.{preview}.{end}.durability": "transient_local" for end in ("publisher", "subscription")}
    return {NODE_NAME: {**crane, "preview.points": points, "preview.horizon": (points - 1) / control_rate,
                        "publish_rate": min(control_rate, MAX_PUBLISH_RATE), "use_sim_time": lockstep,
                        **{name: value for name, value in latched.items() if ".publisher." in name}},
            PLANT_NODE: {**crane, "clock_mode": clock_mode, "control_rate": control_rate, "all_coordinates": True},
            CONTROLLER_NODE: {**crane, "control_rate": control_rate, "use_sim_time": lockstep,
                              **{name: value for name, value in latched.items() if ".subscription." in name}}}


@dataclass(frozen=True)
class LoopRecording:
    """A closed loop over ROS as ``crane-reference loop`` records it, from the plant's start: the plant's
    states at ``t`` [s] (N,) (every coordinate: ``joint_names``, ``q``, ``qd`` (N, n); ``effort`` (N, n) [N m],
    E's ``ee_position`` (N, 3) [m] and ``ee_quaternion`` (N, 4), the tip ``deflection`` (N, 3) [m]); the reference
    node's samples at the same times (``reference_q``, ``reference_qd`` (N, n)); the ``wall`` time [s] from the
    plant's start to its last state."""

    joint_names: tuple[str, ...]
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    effort: np.ndarray
    ee_position: np.ndarray
    ee_quaternion: np.ndarray
    deflection: np.ndarray
    reference_q: np.ndarray
    reference_qd: np.ndarray
    wall: float
