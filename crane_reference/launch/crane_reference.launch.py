"""Bring-up of the crane reference: the crane_reference node, robot_state_publisher with the URDF of the
same model fed by the node's reference joint states, and RViz showing the crane, the target ellipse,
E's trail and pose.

    ros2 launch crane_reference crane_reference.launch.py [model:=flexible|rigid] [config_file:=crane.yaml]
        [params_file:=node.yaml] [rviz:=true|false] [namespace:=crane1] [frame_prefix:=crane1/]
        [autostart:=true|false] [use_sim_time:=false|true]

All three nodes run in ``namespace`` ('' = the root) with ``use_sim_time``.  ``model``, ``config_file`` and
``frame_prefix`` given here override the params file; left empty, the params file's values hold (else the
node's defaults), and robot_state_publisher gets the same ones: the URDF of that model and crane description
(generated here, at launch) and that frame prefix, so that ``namespace:=crane1 frame_prefix:=crane1/`` and
``crane2`` run side by side on one /tf.  Its joint_states input is remapped to the node's ~/joint_states by a
name relative to the namespace, so the reference never lands on the joint_states topic of measured state.
The RViz config names its topics relative to the namespace too; its fixed frame is the URDF's root link,
``world``, with the prefix.

The node is a lifecycle node started as launch_ros's ``LifecycleNode``.  With ``autostart`` (the argument,
else the params file's, else true) the launch drives it: it emits configure, and activate once configuring
has ended in inactive (the node's own ``autostart`` is then off, so nothing transitions twice); without, it
waits unconfigured for a lifecycle manager or ``ros2 lifecycle set``.
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, OpaqueFunction, RegisterEventHandler
from launch.conditions import IfCondition
from launch.events import matches_action
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node
from launch_ros.event_handlers import OnStateTransition
from launch_ros.events.lifecycle import ChangeState
from lifecycle_msgs.msg import Transition

PACKAGE = "crane_reference"
NODE_NAME = "crane_reference"


def _node_parameters(params_file: str, namespace: str) -> dict:
    """The node's values in a params file: its ``/**`` section, then the one of the node's fully qualified name
    (``/<namespace>/crane_reference``, or the bare name in the root namespace)."""
    import yaml

    if not params_file:
        return {}
    with open(params_file, encoding="utf-8") as file:
        sections = yaml.safe_load(file) or {}
    qualified = "/".join(part for part in ("", *namespace.strip("/").split("/"), NODE_NAME) if part)
    names = {"/**", "/" + qualified} | ({NODE_NAME} if qualified == NODE_NAME else set())
    values = {}
    for key in sorted(sections, key=lambda key: key != "/**"):
        if key in names:
            values.update(sections[key].get("ros__parameters", {}))
    return values


def _nodes(context):
    from crane_reference.model.chain import build_model
    from crane_reference.model.config import load_config
    from crane_reference.model.urdf import model_to_urdf

    given = {name: LaunchConfiguration(name).perform(context)
             for name in ("model", "config_file", "frame_prefix", "autostart")}
    params_file = LaunchConfiguration("params_file").perform(context)
    namespace = LaunchConfiguration("namespace").perform(context)
    use_sim_time = LaunchConfiguration("use_sim_time").perform(context).lower() in ("true", "1")
    overrides = {name: value for name, value in given.items() if value}  # empty: the params file's value holds
    effective = {"model": "flexible", "config_file": "", "frame_prefix": "", "autostart": True,
                 **_node_parameters(params_file, namespace), **overrides}
    drive_lifecycle = str(effective["autostart"]).lower() in ("true", "1")
    overrides["autostart"] = False  # the launch drives the lifecycle (drive_lifecycle), or nobody here does
    urdf = model_to_urdf(build_model(load_config(effective["config_file"] or None), effective["model"]))
    share = get_package_share_directory(PACKAGE)
    clock = {"use_sim_time": use_sim_time}
    rviz_arguments = ["-d", os.path.join(share, "rviz", "crane_reference.rviz")]
    if effective["frame_prefix"]:
        rviz_arguments += ["-f", effective["frame_prefix"] + "world"]
    node = LifecycleNode(package=PACKAGE, executable="node", name=NODE_NAME, namespace=namespace, output="screen",
                         parameters=[params_file, overrides, clock])

    def transition(transition_id: int) -> EmitEvent:
        return EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(node), transition_id=transition_id))

    lifecycle = [RegisterEventHandler(OnStateTransition(target_lifecycle_node=node, start_state="configuring",
                                                        goal_state="inactive",
                                                        entities=[transition(Transition.TRANSITION_ACTIVATE)])),
                 transition(Transition.TRANSITION_CONFIGURE)] if drive_lifecycle else []
    return [
        node, *lifecycle,
        Node(package="robot_state_publisher", executable="robot_state_publisher", name="robot_state_publisher",
             namespace=namespace,
             parameters=[{"robot_description": urdf, "frame_prefix": effective["frame_prefix"]}, clock],
             remappings=[("joint_states", f"{NODE_NAME}/joint_states")]),
        Node(package="rviz2", executable="rviz2", name="rviz2", namespace=namespace, arguments=rviz_arguments,
             parameters=[clock], condition=IfCondition(LaunchConfiguration("rviz"))),
    ]


def generate_launch_description():
    share = get_package_share_directory(PACKAGE)
    return LaunchDescription([
        DeclareLaunchArgument("model", default_value="", choices=["", "flexible", "rigid"],
                              description="crane model variant ('' = the params file's, else flexible)"),
        DeclareLaunchArgument("config_file", default_value="",
                              description="crane description YAML ('' = the params file's, else the packaged one)"),
        DeclareLaunchArgument("frame_prefix", default_value="",
                              description="prefix of the frames of the node and robot_state_publisher ('' = the "
                                          "params file's, else none), e.g. crane1/"),
        DeclareLaunchArgument("params_file", default_value=os.path.join(share, "config", "node.yaml"),
                              description="parameters of the crane_reference node"),
        DeclareLaunchArgument("rviz", default_value="true", description="start RViz"),
        DeclareLaunchArgument("autostart", default_value="", choices=["", "true", "false"],
                              description="configure and activate the node from the launch ('' = the params "
                                          "file's autostart, else true)"),
        DeclareLaunchArgument("namespace", default_value="", description="namespace of all nodes ('' = root)"),
        DeclareLaunchArgument("use_sim_time", default_value="false", choices=["true", "false"],
                              description="follow /clock (the node publishes nothing until it ticks)"),
        OpaqueFunction(function=_nodes),
    ])
