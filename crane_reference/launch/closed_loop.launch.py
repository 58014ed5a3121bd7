"""Bring-up of the closed loop over ROS: the reference node, the crane as a plant and the example controller.

    ros2 launch crane_reference closed_loop.launch.py [clock_mode:=lockstep|realtime] [namespace:=crane1]
        [model:=flexible|rigid] [config_file:=crane.yaml] [control_rate:=1000] [feedforward:=none|reference]

* ``crane_reference`` (lifecycle): the reference, its preview with a point every control period over the
  next second (the controller reads the reference there, as joint_trajectory_controller reads its
  trajectory), its joint states at the control rate;
* ``crane_plant`` (lifecycle): the actuated crane of the same model and config under effort commands (its
  joint states with every coordinate);
* ``crane_controller``: the example controller, to be replaced by one's own (it reads
  ``crane_reference/reference_preview`` and ``crane_plant/joint_states`` and writes
  ``crane_plant/commands``, names relative to the namespace).

With ``clock_mode:=lockstep`` (default) the plant publishes /clock and advances one control period per
command, and the other two follow it (``use_sim_time``): a deterministic run, as fast as the three processes
allow; the lifecycle nodes configure and activate themselves (their ``autostart``).  With ``realtime`` the plant
runs on the wall clock, like a robot, and nobody uses sim time; the launch brings the two lifecycle nodes up in
turn (``REALTIME_START``: the reference node activated once the plant runs, so that its motion starts at rest
where the plant is held).  The parameters are
:func:`crane_reference.interface.bringup.closed_loop_parameters`'s (``crane-reference loop`` starts the same
three nodes where launch is not installed).
"""

import itertools

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, OpaqueFunction, RegisterEventHandler
from launch.events import matches_action
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import LifecycleNode, Node
from launch_ros.event_handlers import OnStateTransition
from launch_ros.events.lifecycle import ChangeState
from lifecycle_msgs.msg import Transition

PACKAGE = "crane_reference"


def _nodes(context):
    from crane_reference.interface.bringup import CONTROLLER_NODE, PLANT_NODE, REALTIME_START, closed_loop_parameters
    from crane_reference.interface.messages import NODE_NAME

    arguments = {name: LaunchConfiguration(name).perform(context)
                 for name in ("clock_mode", "namespace", "model", "config_file", "control_rate", "feedforward")}
    namespace = arguments["namespace"]
    parameters = closed_loop_parameters(arguments["clock_mode"], int(arguments["control_rate"]), arguments["model"],
                                        arguments["config_file"], namespace, arguments["feedforward"])
    lifecycle = {name: LifecycleNode(package=PACKAGE, executable=executable, name=name, namespace=namespace,
                                     output="screen", parameters=[parameters[name]])
                 for name, executable in ((NODE_NAME, "node"), (PLANT_NODE, "plant"))}
    return [*lifecycle.values(),
            Node(package=PACKAGE, executable="controller", name=CONTROLLER_NODE, namespace=namespace, output="screen",
                 parameters=[parameters[CONTROLLER_NODE]]),
            *(_in_turn(lifecycle, REALTIME_START) if arguments["clock_mode"] == "realtime" else [])]


TRANSITIONS = {"configure": (Transition.TRANSITION_CONFIGURE, "configuring", "inactive"),
               "activate": (Transition.TRANSITION_ACTIVATE, "activating", "active")}
"""A lifecycle transition's id, its transition state and the state it reaches."""


def _in_turn(nodes, steps):
    """The lifecycle transitions ``steps`` ((node name, transition), ...) of the lifecycle ``nodes`` (by name), each
    emitted once the one before has reached its state."""
    def emit(name, which):
        return EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(nodes[name]),
                                           transition_id=TRANSITIONS[which][0]))

    actions = [emit(*steps[0])]
    for (name, which), after in itertools.pairwise(steps):
        _, passing, reached = TRANSITIONS[which]
        actions.append(RegisterEventHandler(OnStateTransition(target_lifecycle_node=nodes[name], start_state=passing,
                                                              goal_state=reached, entities=[emit(*after)],
                                                              handle_once=True)))
    return actions


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
        DeclareLaunchArgument("feedforward", default_value="none", choices=["none", "reference"],
                              description="the controller's feedforward: none, or the reference preview's efforts"),
        OpaqueFunction(function=_nodes),
    ])
