"""The bring-up files, checked without launch_ros, robot_state_publisher or RViz (not on this machine):
the launch file runs against stand-ins of the launch API and names only executables, packages, files
and topics that exist; the RViz config is valid YAML and shows the node's topics in the URDF's frame."""

from __future__ import annotations

import ast
import importlib.util
import re
import sys
import types
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
import yaml

from crane_reference.interface import messages
from crane_reference.interface.bringup import RECORDED_HISTORY, missing_messages
from crane_reference.model.chain import build_model
from crane_reference.model.config import load_config
from crane_reference.model.urdf import model_to_urdf

ROOT = Path(__file__).resolve().parent.parent
LAUNCH = ROOT / "launch" / "crane_reference.launch.py"
RVIZ = ROOT / "rviz" / "crane_reference.rviz"


class Recorded:
    """Stand-in of a launch action or substitution: keeps its arguments."""

    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


class LifecycleNode(Recorded):
    """Stand-in of launch_ros's LifecycleNode (name and namespace are required keywords, as in Jazzy)."""

    def __init__(self, *, name, namespace, **kwargs):
        super().__init__(name=name, namespace=namespace, **kwargs)


class Transition:
    """Stand-in of lifecycle_msgs/msg/Transition: the transition ids of its definition (Transition.msg)."""

    TRANSITION_CONFIGURE = 1
    TRANSITION_ACTIVATE = 3


class LaunchConfiguration(Recorded):
    def perform(self, context):
        return context[self.args[0]]


def stand_ins(share: Path) -> dict[str, types.ModuleType]:
    modules = {}
    for name, attributes in {
        "launch": {"LaunchDescription": Recorded},
        "launch.actions": {"DeclareLaunchArgument": Recorded, "OpaqueFunction": Recorded, "EmitEvent": Recorded,
                           "RegisterEventHandler": Recorded},
        "launch.conditions": {"IfCondition": Recorded},
        "launch.events": {"matches_action": lambda action: ("matches", action)},
        "launch.substitutions": {"LaunchConfiguration": LaunchConfiguration},
        "launch_ros": {},
        "launch_ros.actions": {"Node": Recorded, "LifecycleNode": LifecycleNode},
        "launch_ros.event_handlers": {"OnStateTransition": Recorded},
        "launch_ros.events": {},
        "launch_ros.events.lifecycle": {"ChangeState": Recorded},
        "lifecycle_msgs": {},
        "lifecycle_msgs.msg": {"Transition": Transition},
        "ament_index_python": {},
        "ament_index_python.packages": {"get_package_share_directory": lambda package: str(share)},
    }.items():
        module = types.ModuleType(name)
        module.__dict__.update(attributes)
        modules[name] = module
    return modules


def launch(monkeypatch, tmp_path, **overrides):
    """The launch file's description and the nodes it starts with its default arguments (and
    ``overrides``), against a share directory laid out as setup.py installs it."""
    share = tmp_path / "share"
    for source, target in (("config/node.yaml", "config/node.yaml"), ("rviz/crane_reference.rviz",
                                                                       "rviz/crane_reference.rviz")):
        (share / target).parent.mkdir(parents=True, exist_ok=True)
        (share / target).write_bytes((ROOT / source).read_bytes())
    for name, module in stand_ins(share).items():
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location("crane_reference_launch", LAUNCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    arguments = {a.args[0]: a.kwargs["default_value"] for a in description.args[0] if not a.kwargs.get("function")
                 and a.args}
    (opaque,) = [a for a in description.args[0] if "function" in a.kwargs]
    actions = opaque.kwargs["function"]({**arguments, **overrides})
    nodes = {node.kwargs["package"]: node for node in actions if "package" in node.kwargs}
    nodes["lifecycle"] = [action for action in actions if "package" not in action.kwargs]
    return arguments, nodes, share


@pytest.fixture
def launched(monkeypatch, tmp_path):
    return launch(monkeypatch, tmp_path)


def resolve(name: str, namespace: str, node: str) -> str:
    """A topic name as ROS 2 resolves it for ``node`` in ``namespace`` (design article "Topic and Service
    name mapping"): absolute names stay, ``~`` is the node's own namespace, others are relative to the
    node's namespace."""
    base = "/" + namespace.strip("/") if namespace.strip("/") else ""
    if name.startswith("/"):
        return name
    if name.startswith("~"):
        return f"{base}/{node}{name[1:]}"
    return f"{base}/{name}"


def test_launch_file_parses_and_declares_its_arguments(launched):
    ast.parse(LAUNCH.read_text())
    arguments, _, share = launched
    assert arguments == {"model": "", "config_file": "", "frame_prefix": "", "autostart": "",
                         "params_file": str(share / "config" / "node.yaml"), "rviz": "true", "namespace": "",
                         "use_sim_time": "false"}


def test_launch_starts_the_node_robot_state_publisher_and_rviz_consistently(launched):
    _, nodes, share = launched
    assert set(nodes) == {"crane_reference", "robot_state_publisher", "rviz2", "lifecycle"}
    assert isinstance(nodes["crane_reference"], LifecycleNode)
    node = nodes["crane_reference"].kwargs
    # the executable ros2 run / launch finds: installed by setup.py into lib/crane_reference
    setup = (ROOT / "setup.py").read_text()
    assert node["executable"] == "node"
    assert '(f"lib/{PACKAGE}", ["scripts/node", "scripts/plant", "scripts/controller"])' in setup
    assert node["name"] == messages.NODE_NAME
    params_file, overrides, _ = node["parameters"]
    assert Path(params_file).is_file() and overrides == {"autostart": False}  # the launch drives the lifecycle
    assert all(n.kwargs["namespace"] == "" and {"use_sim_time": False} in n.kwargs["parameters"]
               for name, n in nodes.items() if name != "lifecycle")
    rsp = nodes["robot_state_publisher"].kwargs
    assert rsp["executable"] == "robot_state_publisher"
    # the URDF of the same model as the node's, fed by the node's own joint states
    assert rsp["parameters"][0] == {"robot_description": model_to_urdf(build_model(load_config(), "flexible")),
                                    "frame_prefix": ""}
    ((remapped, target),) = rsp["remappings"]
    assert remapped == "joint_states"
    assert resolve(target, "", "robot_state_publisher") == resolve(messages.JOINT_STATES_TOPIC, "", messages.NODE_NAME)
    rviz = nodes["rviz2"].kwargs
    assert rviz["executable"] == "rviz2" and rviz["arguments"][0] == "-d" and Path(rviz["arguments"][1]).is_file()
    assert len(rviz["arguments"]) == 2  # the config's fixed frame
    assert rviz["condition"].args[0].args == ("rviz",)
    # setup.py installs the launch file and the RViz config where the launch file looks for them
    assert '(f"share/{PACKAGE}/launch", glob("launch/*.launch.py"))' in setup
    assert '(f"share/{PACKAGE}/rviz", glob("rviz/*.rviz"))' in setup
    assert Path(rviz["arguments"][1]).relative_to(share) == Path("rviz/crane_reference.rviz")


def test_rviz_config_shows_the_node_topics_in_the_urdf_frame():
    config = yaml.safe_load(RVIZ.read_text())
    manager = config["Visualization Manager"]
    fixed_frame = manager["Global Options"]["Fixed Frame"]
    urdf = ET.fromstring(model_to_urdf(build_model(load_config(), "flexible")))
    links = {link.get("name") for link in urdf.iter("link")}
    children = {joint.find("child").get("link") for joint in urdf.iter("joint")}
    assert fixed_frame in links and fixed_frame not in children  # the root link
    displays = {d["Class"]: d for d in manager["Displays"]}
    for namespace in ("", "crane1", "/site/crane2"):  # relative names follow the namespace of the bring-up
        node_topics = {resolve(topic, namespace, messages.NODE_NAME)
                       for topic in (messages.MARKERS_TOPIC, messages.END_EFFECTOR_POSE_TOPIC)}
        shown = {resolve(d["Topic"]["Value"], namespace, "rviz2") for d in displays.values() if "Topic" in d}
        assert shown == node_topics
        description = displays["rviz_default_plugins/RobotModel"]["Description Topic"]["Value"]
        assert resolve(description, namespace, "rviz2") == resolve("robot_description", namespace,
                                                                   "robot_state_publisher")
    assert displays["rviz_default_plugins/RobotModel"]["Description Topic"]["Durability Policy"] == "Transient Local"
    assert all(re.fullmatch(r"rviz_(default_plugins|common)/\w+", d["Class"]) for d in manager["Displays"])


@pytest.mark.parametrize("namespace", ["crane1", "/site/crane2"])
def test_launch_in_a_namespace_with_sim_time(monkeypatch, tmp_path, namespace):
    """namespace:=... and use_sim_time:=true reach all three nodes; robot_state_publisher still reads the
    node's joint states (both names resolved in that namespace), never the namespace's measured ones."""
    _, nodes, _ = launch(monkeypatch, tmp_path, namespace=namespace, use_sim_time="true")
    assert all(n.kwargs["namespace"] == namespace and {"use_sim_time": True} in n.kwargs["parameters"]
               for name, n in nodes.items() if name != "lifecycle")
    ((_, target),) = nodes["robot_state_publisher"].kwargs["remappings"]
    read = resolve(target, namespace, "robot_state_publisher")
    assert read == resolve(messages.JOINT_STATES_TOPIC, namespace, messages.NODE_NAME)
    assert read != resolve("joint_states", namespace, "robot_state_publisher")


def test_a_params_file_is_not_overridden_and_frame_prefix_reaches_every_node(monkeypatch, tmp_path):
    """A user's params file keeps its model, crane description and frame prefix (robot_state_publisher and RViz
    follow them); the launch arguments, when given, override them for all three nodes."""
    crane = tmp_path / "crane.yaml"
    crane.write_text((ROOT / "config" / "crane.yaml").read_text())
    params = tmp_path / "mine.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {"model": "rigid", "publish_rate": 50}},
                                      "/crane1/crane_reference": {"ros__parameters": {"frame_prefix": "crane1/",
                                                                                      "config_file": str(crane)}}}))
    _, nodes, _ = launch(monkeypatch, tmp_path, params_file=str(params), namespace="crane1")
    node, rsp, rviz = (nodes[name].kwargs for name in ("crane_reference", "robot_state_publisher", "rviz2"))
    assert node["parameters"][:2] == [str(params), {"autostart": False}]
    assert rsp["parameters"][0] == {"robot_description": model_to_urdf(build_model(load_config(crane), "rigid")),
                                    "frame_prefix": "crane1/"}
    assert rviz["arguments"][2:] == ["-f", "crane1/world"]
    _, nodes, _ = launch(monkeypatch, tmp_path, params_file=str(params), namespace="crane1", model="flexible",
                         frame_prefix="c2/")
    node, rsp, rviz = (nodes[name].kwargs for name in ("crane_reference", "robot_state_publisher", "rviz2"))
    assert node["parameters"][1] == {"model": "flexible", "frame_prefix": "c2/", "autostart": False}
    assert rsp["parameters"][0]["frame_prefix"] == "c2/" and rviz["arguments"][2:] == ["-f", "c2/world"]
    assert rsp["parameters"][0]["robot_description"] == model_to_urdf(build_model(load_config(crane), "flexible"))
    _, nodes, _ = launch(monkeypatch, tmp_path, params_file=str(params), namespace="crane2")  # not crane1's section
    assert nodes["robot_state_publisher"].kwargs["parameters"][0]["frame_prefix"] == ""


@pytest.mark.parametrize("autostart", ["", "true", "false"])
def test_the_launch_drives_the_lifecycle_unless_autostart_is_off(monkeypatch, tmp_path, autostart):
    """With autostart (the argument, else the params file's: true in config/node.yaml) the launch emits configure
    and, once configuring ends in inactive, activate, both for the node it starts; the node's own autostart is
    off so that nothing transitions twice.  With autostart:=false it emits nothing: the node waits unconfigured."""
    _, nodes, _ = launch(monkeypatch, tmp_path, autostart=autostart)
    node = nodes["crane_reference"]
    assert node.kwargs["parameters"][1]["autostart"] is False
    if autostart == "false":
        assert nodes["lifecycle"] == []
        return
    handler, configure = nodes["lifecycle"]
    assert configure.kwargs["event"].kwargs == {"lifecycle_node_matcher": ("matches", node),
                                                "transition_id": Transition.TRANSITION_CONFIGURE}
    (on_inactive,) = handler.args
    assert on_inactive.kwargs["target_lifecycle_node"] is node
    assert (on_inactive.kwargs["start_state"], on_inactive.kwargs["goal_state"]) == ("configuring", "inactive")
    (activate,) = on_inactive.kwargs["entities"]
    assert activate.kwargs["event"].kwargs == {"lifecycle_node_matcher": ("matches", node),
                                               "transition_id": Transition.TRANSITION_ACTIVATE}


CLOSED_LOOP = ROOT / "launch" / "closed_loop.launch.py"


def closed_loop(monkeypatch, tmp_path, **overrides):
    """The nodes closed_loop.launch.py starts with its default arguments and ``overrides``, by name."""
    for name, module in stand_ins(tmp_path).items():
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location("closed_loop_launch", CLOSED_LOOP)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    arguments = {a.args[0]: a.kwargs["default_value"] for a in description.args[0] if a.args}
    (opaque,) = [a for a in description.args[0] if "function" in a.kwargs]
    actions = opaque.kwargs["function"]({**arguments, **overrides})
    return ({node.kwargs["name"]: node for node in actions if "name" in node.kwargs},
            [action for action in actions if "name" not in action.kwargs])


@pytest.mark.ros  # reads the nodes' parameter tables (rclpy)
@pytest.mark.parametrize("clock_mode", ["lockstep", "realtime"])
@pytest.mark.parametrize("namespace", ["", "crane1"])
def test_the_closed_loop_launch_connects_the_three_nodes(monkeypatch, tmp_path, clock_mode, namespace):
    from crane_reference.ros import controller_node, plant_node
    from crane_reference.ros.controller_parameters import CONTROLLER_PARAMETERS
    from crane_reference.ros.parameters import SPECS
    from crane_reference.ros.plant_parameters import PLANT_PARAMETERS

    nodes, _ = closed_loop(monkeypatch, tmp_path, clock_mode=clock_mode, namespace=namespace, control_rate="1000")
    assert set(nodes) == {messages.NODE_NAME, plant_node.NODE_NAME, controller_node.NODE_NAME}
    setup = (ROOT / "setup.py").read_text()
    for node in nodes.values():
        assert f'"scripts/{node.kwargs["executable"]}"' in setup and node.kwargs["namespace"] == namespace
    assert isinstance(nodes["crane_reference"], LifecycleNode) and isinstance(nodes["crane_plant"], LifecycleNode)
    (reference,), (plant,), (controller,) = (nodes[name].kwargs["parameters"] for name in
                                             ("crane_reference", "crane_plant", "crane_controller"))
    qos = {name for name in (*reference, *plant, *controller) if name.startswith("qos_overrides.")}
    assert set(reference) - {"use_sim_time"} - qos <= set(SPECS)
    assert set(plant) - qos <= {spec.name for spec in PLANT_PARAMETERS}
    assert set(controller) - {"use_sim_time"} - qos <= {spec.name for spec in CONTROLLER_PARAMETERS}
    for node, parameters, topic in ((messages.NODE_NAME, reference, messages.JOINT_STATES_TOPIC),
                                    (plant_node.NODE_NAME, plant, messages.JOINT_STATES_TOPIC),
                                    (plant_node.NODE_NAME, plant, messages.END_EFFECTOR_POSE_TOPIC),
                                    (plant_node.NODE_NAME, plant, messages.TIP_DEFLECTION_TOPIC)):
        # what `crane-reference loop` records, kept for a recorder that lags or is matched late
        overrides = f"qos_overrides.{resolve(topic, namespace, node)}.publisher"
        assert parameters[f"{overrides}.depth"] == RECORDED_HISTORY
        assert parameters[f"{overrides}.durability"] == "transient_local"
    assert controller["feedforward"] == "none" and reference["preview.effort"] is False  # the launch's default
    preview = resolve(messages.REFERENCE_PREVIEW_TOPIC, namespace, messages.NODE_NAME)
    assert reference[f"qos_overrides.{preview}.publisher.durability"] == "transient_local"
    assert controller[f"qos_overrides.{preview}.subscription.durability"] == "transient_local"
    assert reference["use_sim_time"] == controller["use_sim_time"] == (clock_mode == "lockstep")
    assert plant["clock_mode"] == clock_mode and plant["control_rate"] == controller["control_rate"] == 1000
    # lock-step: a preview point every control period (the node spaces preview.points - 1 intervals over the
    # horizon), so that the controller reads computed steps; real time: every 10 ms
    spacing = 1e-3 if clock_mode == "lockstep" else 1e-2
    assert reference["preview.horizon"] / (reference["preview.points"] - 1) == pytest.approx(spacing, rel=1e-12)
    topics = {spec.name: spec.default for spec in CONTROLLER_PARAMETERS}
    assert resolve(topics["reference_topic"], namespace, "crane_controller") == resolve(
        messages.REFERENCE_PREVIEW_TOPIC, namespace, messages.NODE_NAME)
    assert resolve(topics["state_topic"], namespace, "crane_controller") == resolve(
        messages.JOINT_STATES_TOPIC, namespace, plant_node.NODE_NAME)
    assert resolve(topics["command_topic"], namespace, "crane_controller") == resolve(
        messages.COMMANDS_TOPIC, namespace, plant_node.NODE_NAME)


@pytest.mark.parametrize("clock_mode", ["lockstep", "realtime"])
def test_in_real_time_the_reference_node_is_activated_once_the_plant_runs(monkeypatch, tmp_path, clock_mode):
    """Real time: neither lifecycle node starts itself; the launch configures the reference node, then the plant,
    activates the plant, then the reference node, each transition emitted as the one before ends (followed here
    as launch follows its event handlers).  Lock-step: the nodes start themselves, and the launch emits nothing."""
    nodes, actions = closed_loop(monkeypatch, tmp_path, clock_mode=clock_mode)
    reference, plant = nodes["crane_reference"], nodes["crane_plant"]
    for node in (reference, plant):
        assert node.kwargs["parameters"][0]["autostart"] is (clock_mode == "lockstep")
    if clock_mode == "lockstep":
        assert actions == []
        return
    emitted = [action for action in actions if "event" in action.kwargs]
    handlers = [action.args[0].kwargs for action in actions if "event" not in action.kwargs]
    assert len(emitted) == 1
    states = {Transition.TRANSITION_CONFIGURE: ("configuring", "inactive"),
              Transition.TRANSITION_ACTIVATE: ("activating", "active")}
    order, event = [], emitted[0].kwargs["event"].kwargs
    while event is not None:
        (_, node), transition = event["lifecycle_node_matcher"], event["transition_id"]
        order.append((node.kwargs["name"], transition))
        following = [handler for handler in handlers if handler["target_lifecycle_node"] is node
                     and (handler["start_state"], handler["goal_state"]) == states[transition]]
        assert len(following) <= 1
        event = following[0]["entities"][0].kwargs["event"].kwargs if following else None
    configure, activate = Transition.TRANSITION_CONFIGURE, Transition.TRANSITION_ACTIVATE
    assert order == [("crane_reference", configure), ("crane_plant", configure), ("crane_plant", activate),
                     ("crane_reference", activate)]


def test_a_recording_of_the_loop_names_what_it_lacks():
    """missing_messages against recordings made by hand: complete ones lack nothing; a dropped pose, a plant state
    and a reference sample (lock-step) are counted by topic; real time may miss plant periods and publishes the
    reference at its own rate, so only the pose of a state and the reference's reach are checked."""
    ms = 10**6
    states = list(range(0, 101 * ms, ms))  # 0 .. 100 ms at 1 kHz
    complete = {"states": states, "poses": states, "deflections": states, "references": states}
    assert missing_messages(**complete, first=0, end=100 * ms, period_ns=ms, reference_period_ns=ms,
                            lockstep=True) == {}
    lossy = {"states": [k for k in states if k != 40 * ms], "poses": [k for k in states if k != 70 * ms],
             "deflections": states, "references": [k for k in states if k not in (10 * ms, 11 * ms)]}
    assert missing_messages(**lossy, first=0, end=100 * ms, period_ns=ms, reference_period_ns=ms, lockstep=True) == {
        "end_effector_pose": 1, "joint_states": 1, "reference joint_states": 2}
    realtime = {"states": lossy["states"], "poses": states, "deflections": states,
                "references": list(range(0, 91 * ms, 10 * ms))}  # 100 Hz, ending at 90 ms
    assert missing_messages(**realtime, first=0, end=100 * ms, period_ns=ms, reference_period_ns=10 * ms,
                            lockstep=False) == {"reference joint_states": 1}
