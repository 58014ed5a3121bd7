"""Bring-up of the closed loop over ROS: the reference node, the crane as a plant and the example controller.

    ros2 launch crane_reference closed_loop.launch.py [clock_mode:=lockstep|realtime] [namespace:=crane1]
        [model:=flexible|rigid] [config_file:=crane.yaml] [control_rate:=1000]

* ``crane_reference`` (lifecycle): the reference, its preview with a point every control period over the
  next second (the controller reads the reference there, as joint_trajectory_controller reads its
  trajectory);
* ``crane_plant`` (lifecycle): the actuated crane of the same model and config under effort commands;
* ``crane_controller``: the example controller, to be replaced by one's own (it reads
  ``crane_reference/reference_preview`` and ``crane_plant/joint_states`` and writes
  ``crane_plant/commands``, names relative to the namespace).

With ``clock_mode:=lockstep`` (default) the plant publishes /clock and advances one control period per
command, and the other two follow it (``use_sim_time``): a deterministic run, as fast as the three processes
allow.  With ``realtime`` the plant runs on the wall clock, like a robot, and nobody uses sim time.  The
lifecycle nodes configure and activate themselves (their ``autostart``).
"""

from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node

from launch import LaunchDescription

PACKAGE = "crane_reference"
PREVIEW_HORIZON = 1.0  # [s], about


def _nodes(context):
    arguments = {name: LaunchConfiguration(name).perform(context)
                 for name in ("clock_mode", "namespace", "model", "config_file", "control_rate")}
    namespace, rate = arguments["namespace"], int(arguments["control_rate"])
    lockstep = arguments["clock_mode"] == "lockstep"
    crane = {"model": arguments["model"], "config_file": arguments["config_file"]}
    points = min(1000, round(PREVIEW_HORIZON * rate) + 1)  # the sample's, then one every control period
    reference = {**crane, "preview.points": points, "preview.horizon": (points - 1) / rate, "use_sim_time": lockstep}
    plant = {**crane, "clock_mode": arguments["clock_mode"], "control_rate": rate}
    controller = {**crane, "control_rate": rate, "use_sim_time": lockstep}
    return [
        LifecycleNode(package=PACKAGE, executable="node", name="crane_reference", namespace=namespace,
                      output="screen", parameters=[reference]),
        LifecycleNode(package=PACKAGE, executable="plant", name="crane_plant", namespace=namespace, output="screen",
                      parameters=[plant]),
        Node(package=PACKAGE, executable="controller", name="crane_controller", namespace=namespace,
             output="screen", parameters=[controller]),
    ]


def generate_launch_description():
    return LaunchDescription([
        DeclareLaunchArgument("clock_mode", default_value="lockstep", choices=["lockstep", "realtime"],
                              description="the plant's clock: lockstep (it publishes /clock) or realtime"),
        DeclareLaunchArgument("namespace", default_value="", description="namespace of all nodes ('' = root)"),
        DeclareLaunchArgument("model", default_value="flexible", choices=["flexible", "rigid"],
                              description="crane model variant of the reference and the plant"),
        DeclareLaunchArgument("config_file", default_value="",
                              description="crane description YAML ('' = the packaged one)"),
        DeclareLaunchArgument("control_rate", default_value="1000", description="the plant's control rate [Hz]"),
        OpaqueFunction(function=_nodes),
    ])
