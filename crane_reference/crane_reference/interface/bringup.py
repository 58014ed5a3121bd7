"""The closed loop over ROS without launch: the three nodes' parameters (shared by
``launch/closed_loop.launch.py`` and ``crane-reference loop``) and what ``crane-reference loop`` records.

The reference node publishes its preview over about a second (the controller reads the reference there, as
joint_trajectory_controller reads its trajectory) and its joint states (the recording's reference): in lock-step
a point and a sample every control period, and the reference and the controller follow the plant's /clock; in
real time a point every 10 ms and samples at 100 Hz (the controller and the recording interpolate).
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
REALTIME_POINT_PERIOD = 0.01  # [s] between preview points in real time
REALTIME_PUBLISH_RATE = 100  # [Hz] of the reference's joint states in real time


def closed_loop_parameters(clock_mode: str, control_rate: int, model: str = "flexible", config_file: str = "",
                           namespace: str = "") -> dict[str, dict[str, object]]:
    """The parameters of the reference node, the plant and the controller (in ``namespace``), by node name.
    The preview is transient-local on both ends (rclpy's ``qos_overrides``): a controller that starts after the
    reference node still gets its last preview, which in lock-step is the only one until the plant moves."""
    crane = {"model": model, "config_file": config_file}
    lockstep = clock_mode == "lockstep"
    # lock-step: a preview point per control period, so that the controller reads the computed steps themselves;
    # real time: one per REALTIME_POINT_PERIOD (the controller interpolates), and the joint states at most at
    # REALTIME_PUBLISH_RATE, so that the reference node leaves the plant the CPU its periods need
    spacing = 1 if lockstep else max(1, round(REALTIME_POINT_PERIOD * control_rate))
    points = min(1000, round(PREVIEW_HORIZON * control_rate / spacing) + 1)
    parts = (*namespace.strip("/").split("/"), NODE_NAME, "reference_preview")
    preview = "/" + "/".join(part for part in parts if part)
    latched = {f"qos_overrides.{preview}.{end}.durability": "transient_local" for end in ("publisher", "subscription")}
    publish_rate = min(control_rate, MAX_PUBLISH_RATE if lockstep else REALTIME_PUBLISH_RATE)
    return {NODE_NAME: {**crane, "preview.points": points, "preview.horizon": (points - 1) * spacing / control_rate,
                        "publish_rate": publish_rate, "use_sim_time": lockstep,
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
