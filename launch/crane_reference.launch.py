"""Bring-up of the crane reference: the crane_reference node, robot_state_publisher with the URDF of the
same model fed by the node's reference joint states, and RViz showing the crane, the target ellipse,
E's trail and pose.

    ros2 launch crane_reference crane_reference.launch.py [model:=flexible|rigid] [config_file:=crane.yaml]
        [params_file:=node.yaml] [rviz:=true|false] [namespace:=crane1] [use_sim_time:=false|true]

All three nodes run in ``namespace`` ('' = the root) with ``use_sim_time``.  robot_state_publisher takes the
URDF as its own parameter (generated here, at launch, from the same crane description and model variant as
the node's) and publishes robot_description and the TF frames; its joint_states input is remapped to the
node's ~/joint_states by a name relative to the namespace, so the reference never lands on the
joint_states topic of measured state.  The RViz config names its topics relative to the namespace too.
RViz's fixed frame is the URDF root link, ``world``; TF stays global (/tf, /tf_static).
"""

import os

from ament_index_python.packages import get_package_share_directory
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from launch import LaunchDescription

PACKAGE = "crane_reference"
NODE_NAME = "crane_reference"


def _nodes(context):
    from crane_reference.model.chain import build_model
    from crane_reference.model.config import load_config
    from crane_reference.model.urdf import model_to_urdf

    model = LaunchConfiguration("model").perform(context)
    config_file = LaunchConfiguration("config_file").perform(context)
    params_file = LaunchConfiguration("params_file").perform(context)
    namespace = LaunchConfiguration("namespace").perform(context)
    use_sim_time = LaunchConfiguration("use_sim_time").perform(context).lower() in ("true", "1")
    urdf = model_to_urdf(build_model(load_config(config_file or None), model))
    share = get_package_share_directory(PACKAGE)
    clock = {"use_sim_time": use_sim_time}
    return [
        Node(package=PACKAGE, executable="node", name=NODE_NAME, namespace=namespace, output="screen",
             parameters=[params_file, {"model": model, "config_file": config_file}, clock]),
        Node(package="robot_state_publisher", executable="robot_state_publisher", name="robot_state_publisher",
             namespace=namespace, parameters=[{"robot_description": urdf}, clock],
             remappings=[("joint_states", f"{NODE_NAME}/joint_states")]),
        Node(package="rviz2", executable="rviz2", name="rviz2", namespace=namespace,
             arguments=["-d", os.path.join(share, "rviz", "crane_reference.rviz")], parameters=[clock],
             condition=IfCondition(LaunchConfiguration("rviz"))),
    ]


def generate_launch_description():
    share = get_package_share_directory(PACKAGE)
    return LaunchDescription([
        DeclareLaunchArgument("model", default_value="flexible", choices=["flexible", "rigid"],
                              description="crane model variant"),
        DeclareLaunchArgument("config_file", default_value="",
                              description="crane description YAML ('' = the packaged config/crane.yaml)"),
        DeclareLaunchArgument("params_file", default_value=os.path.join(share, "config", "node.yaml"),
                              description="parameters of the crane_reference node"),
        DeclareLaunchArgument("rviz", default_value="true", description="start RViz"),
        DeclareLaunchArgument("namespace", default_value="", description="namespace of all nodes ('' = root)"),
        DeclareLaunchArgument("use_sim_time", default_value="false", choices=["true", "false"],
                              description="follow /clock (the node publishes nothing until it ticks)"),
        OpaqueFunction(function=_nodes),
    ])
