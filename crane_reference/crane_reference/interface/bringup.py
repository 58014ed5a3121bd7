"""The closed loop over ROS without launch: the three nodes' parameters (shared by
``launch/closed_loop.launch.py`` and ``crane-reference loop``) and what ``crane-reference loop`` records.

The reference node publishes its preview over about a second (the controller reads the reference there, as
joint_trajectory_controller reads its trajectory) and its joint states (the recording's reference): in lock-step
a point and a sample every control period, and the reference and the controller follow the plant's /clock; in
real time a point every 10 ms and samples at 100 Hz (the controller and the recording interpolate).

In lock-step the reference's motion starts at the plant's clock start, whenever each node comes up.  In real time
the reference's motion would start when its node is active, and the plant's time when its first command comes:
a reference node that came up first would have the plant, still at rest, chase a motion seconds under way.  So
in real time the two are started unconfigured and brought up in :data:`REALTIME_START`'s order: the reference's
motion starts once the plant runs, at rest where the plant is held (both at the static equilibrium with E on
the task's start point).
"""

from __future__ import annotations

from collections.abc import Iterable
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
REALTIME_START = ((NODE_NAME, "configure"), (PLANT_NODE, "configure"), (PLANT_NODE, "activate"),
                  (NODE_NAME, "activate"))
"""The lifecycle transitions that bring up the real-time loop, each once the one before has ended: the reference
node activated last (see the module docstring)."""
RECORDED_HISTORY = 1000
"""Keep-last depth of the publishers of what ``crane-reference loop`` records (the plant's joint states, pose
and tip deflection, the reference's joint states), which are also transient local: a second at 1 kHz, so that
a recorder that lags, or whose subscription is matched after the first messages, loses nothing (a reliable
writer drops what it no longer keeps; a volatile one sends nothing from before the match)."""


def closed_loop_parameters(clock_mode: str, control_rate: int, model: str = "flexible", config_file: str = "",
                           namespace: str = "", feedforward: str = "none") -> dict[str, dict[str, object]]:
    """The parameters of the reference node, the plant and the controller (in ``namespace``), by node name, with
    the controller's ``feedforward`` (``reference``: the preview carries its efforts); in real time the two
    lifecycle nodes do not start themselves (:data:`REALTIME_START` brings them up).  The preview is
    transient-local on both ends (rclpy's ``qos_overrides``): a controller that starts after the reference node
    still gets its last preview, which in lock-step is the only one until the plant moves."""
    crane = {"model": model, "config_file": config_file}
    lockstep = clock_mode == "lockstep"
    # lock-step: a preview point per control period, so that the controller reads the computed steps themselves;
    # real time: one per REALTIME_POINT_PERIOD (the controller interpolates), and the joint states at most at
    # REALTIME_PUBLISH_RATE, so that the reference node leaves the plant the CPU its periods need
    spacing = 1 if lockstep else max(1, round(REALTIME_POINT_PERIOD * control_rate))
    points = min(1000, round(PREVIEW_HORIZON * control_rate / spacing) + 1)
    def topic(node: str, name: str) -> str:
        return "/" + "/".join(part for part in (*namespace.strip("/").split("/"), node, name) if part)

    preview = topic(NODE_NAME, "reference_preview")
    latched = {f"qos_overrides.{preview}.{end}.durability": "transient_local" for end in ("publisher", "subscription")}
    recorded = {node: {f"qos_overrides.{topic(node, name)}.publisher.{policy}": value for name in names
                       for policy, value in (("depth", RECORDED_HISTORY), ("durability", "transient_local"))}
                for node, names in ((NODE_NAME, ("joint_states",)),
                                    (PLANT_NODE, ("joint_states", "end_effector_pose", "tip_deflection")))}
    publish_rate = min(control_rate, MAX_PUBLISH_RATE if lockstep else REALTIME_PUBLISH_RATE)
    return {NODE_NAME: {**crane, "preview.points": points, "preview.horizon": (points - 1) * spacing / control_rate,
                        "preview.effort": feedforward == "reference", "publish_rate": publish_rate,
                        "use_sim_time": lockstep, "autostart": lockstep, **recorded[NODE_NAME],
                        **{name: value for name, value in latched.items() if ".publisher." in name}},
            PLANT_NODE: {**crane, "clock_mode": clock_mode, "control_rate": control_rate, "all_coordinates": True,
                         "autostart": lockstep, **recorded[PLANT_NODE]},
            CONTROLLER_NODE: {**crane, "control_rate": control_rate, "feedforward": feedforward,
                              "use_sim_time": lockstep, **{name: value for name, value in latched.items()
                                                           if ".subscription." in name}}}


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


def missing_messages(states: Iterable[int], poses: Iterable[int], deflections: Iterable[int],
                     references: Iterable[int], first: int, end: int, period_ns: int, reference_period_ns: int,
                     lockstep: bool) -> dict[str, int]:
    """What a recording of the loop from stamp ``first`` to ``end`` [ns] lacks, by topic (none: complete): the
    plant's pose and tip deflection of each state recorded (the plant publishes the three together); in lock-step
    also the plant's states of every period of ``period_ns`` (real time may miss periods: none is published) and
    the reference's samples of every ``reference_period_ns`` (the recording interpolates the reference between
    its samples: exact only where none is missing); the reference's samples reaching ``end``."""
    states = sorted(k for k in states if first <= k <= end)
    poses, deflections, references = set(poses), set(deflections), sorted(references)
    missing = {"end_effector_pose": sum(k not in poses for k in states),
               "tip_deflection": sum(k not in deflections for k in states)}
    inside = [k for k in references if first <= k <= end]
    if lockstep:
        missing["joint_states"] = (end - first) // period_ns + 1 - len(states)
        spanned = (inside[-1] - inside[0]) // reference_period_ns + 1 if inside else 0
        missing["reference joint_states"] = spanned - len(inside)
    if not references or references[-1] < end:
        missing["reference joint_states"] = missing.get("reference joint_states", 0) + 1
    return {topic: count for topic, count in missing.items() if count > 0}
