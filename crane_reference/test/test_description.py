"""Crane descriptions (crane_reference.model.description_layout, .chain) against independent truths.

* The paper's crane: config/crane.yaml (description layout) and data/paper_layout_crane.yaml (the paper's
  layout) give the same chain, both variants.
* The chain of a described joint about a general axis moves as a rotation about that axis (Rodrigues'
  formula), whatever frame the builder gives it.
* The constrained accelerations of the example loader crane (fixed base, two flexible links, a sprung
  prismatic stage) against the Lagrange-multiplier (KKT) system at random consistent states.
* The dependent coordinates chosen from the task Jacobian: the minor with the largest smallest singular
  value, checked by enumerating the minors with numpy's SVD.
* Every kind of bad description is refused with the field and what is allowed, before anything is computed.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest
import yaml
from cranes import CONFIG, EXAMPLES, PAPER_LAYOUT, expect_config_error

from crane_reference.analysis.study.case import SINGULARITY_MARGIN
from crane_reference.dynamics.chain_dynamics import CraneDynamics
from crane_reference.dynamics.kinematics import forward_kinematics
from crane_reference.model.chain import VARIANTS, build_model
from crane_reference.model.config import ConfigError, load_config, parse_config, read_yaml
from crane_reference.model.drive import TorqueSource
from crane_reference.model.urdf import model_to_urdf
from crane_reference.model.urdf_layout import description_to_urdf, parse_urdf_description
from crane_reference.motion.simulation import Scenario, simulate
from crane_reference.stream.targets import check_task

LOADER = CONFIG / "loader_crane.yaml"
SAMPLES = 6
KKT_TOLERANCE = 1e-9  # relative


@pytest.fixture(scope="module")
def loader() -> dict[str, Scenario]:
    params = load_config(LOADER)
    return {variant: Scenario(params, variant) for variant in VARIANTS}


@pytest.fixture
def data() -> dict[str, Any]:
    """A fresh, modifiable copy of the loader crane's file as parsed."""
    return copy.deepcopy(_LOADER_DATA)


_LOADER_DATA = read_yaml(LOADER)




# --- the paper's crane in both layouts ----------------------------------------------------------------


@pytest.mark.parametrize("variant", VARIANTS)
def test_both_layouts_of_the_paper_crane_give_the_same_chain(variant):
    described, paper = (build_model(load_config(path), variant) for path in (CONFIG / "crane.yaml", PAPER_LAYOUT))
    assert described.joint_names == paper.joint_names
    for a, b in zip(described.joints, paper.joints, strict=True):
        assert (a.kind, a.axis) == (b.kind, b.axis)
        np.testing.assert_allclose(a.origin, b.origin, rtol=0.0, atol=1e-15)
    assert [(body.name, body.joint) for body in described.bodies] == [(body.name, body.joint) for body in paper.bodies]
    for a, b in zip(described.bodies, paper.bodies, strict=True):
        np.testing.assert_array_equal(a.inertia.pseudo_inertia(), b.inertia.pseudo_inertia())
    for name in ("stiffness", "support_stiffness", "beam_stiffness", "damping_matrix", "initial_q",
                 "end_effector_point"):
        np.testing.assert_array_equal(getattr(described, name), getattr(paper, name))
    assert (described.end_effector_joint, described.drive_joint, described.dependent_joints,
            described.actuated_joints) == (paper.end_effector_joint, paper.drive_joint, paper.dependent_joints,
                                           paper.actuated_joints)


# --- general axes --------------------------------------------------------------------------------------


def _rodrigues(axis: np.ndarray, angle: float) -> np.ndarray:
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


@pytest.mark.parametrize("axis", [[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0],
                                  [0.6, 0.0, 0.8], [1 / 3, -2 / 3, 2 / 3]])
def test_a_joint_about_any_axis_rotates_about_it(data, axis):
    """The knuckle about ``axis``: E, the payload and the jib's tip turn about the knuckle's axis through the
    knuckle's origin by R(axis, angle) (Rodrigues), the knuckle's frame being the stage's tip."""
    data["links"][3]["joint"]["axis"] = axis
    data["links"][3]["beam"]["rfe_count"] = 1
    model = build_model(parse_config(data), "flexible")
    chain = CraneDynamics(model, TorqueSource(0.0, 0.0, 0.0)).chain
    knuckle = model.index("knuckle")
    q = model.initial_q.copy()
    q[knuckle] = 0.0
    T0, _ = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
    e0 = T0[model.end_effector_joint, :3, :3] @ model.end_effector_point + T0[model.end_effector_joint, :3, 3]
    stage = T0[model.index("telescope")]  # the knuckle's origin is 0.5 m out along the stage's x axis
    pivot = stage[:3, :3] @ np.array([0.5, 0.0, 0.0]) + stage[:3, 3]
    world_axis = stage[:3, :3] @ np.asarray(axis) / np.linalg.norm(axis)
    for angle in (0.3, -1.2, 2.5):
        q[knuckle] = angle
        T, _ = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)
        e = T[model.end_effector_joint, :3, :3] @ model.end_effector_point + T[model.end_effector_joint, :3, 3]
        np.testing.assert_allclose(e, pivot + _rodrigues(world_axis, angle) @ (e0 - pivot), rtol=0.0, atol=1e-14)


# --- the loader crane ----------------------------------------------------------------------------------


def _random_consistent_state(scenario: Scenario, rng: np.random.Generator):
    """(t, q, qd) on the constraints near the start: slew, stage and RFE angles perturbed, q_dc projected,
    random velocities, qd_dc from (7)."""
    motion, model = scenario.motion, scenario.model
    t = rng.uniform(0.0, 1.0)
    q = scenario.equilibrium.q.copy()
    qd = rng.normal(scale=0.3, size=model.dof)
    springs = [int(k) for link in model.flexible_links for k in link.springs]
    q[springs] += rng.normal(scale=1e-2, size=len(springs))
    q[model.index("column_slew")] += rng.uniform(-0.5, 0.5)
    q[model.index("telescope")] += rng.uniform(-0.02, 0.02)
    q, kinematics = motion.project_positions(t, q)
    return t, q, motion.dependent_velocities(t, q, qd, kinematics)


@pytest.mark.parametrize("variant", VARIANTS)
def test_loader_crane_accelerations_equal_the_kkt_system(loader, variant):
    scenario = loader[variant]
    motion, n = scenario.motion, scenario.model.dof
    rng = np.random.default_rng(11)
    for _ in range(SAMPLES):
        t, q, qd = _random_consistent_state(scenario, rng)
        solution = motion.solve(t, q, qd)
        terms = scenario.dynamics.terms(t, q, qd)
        A, c = solution.constraints.A, solution.constraints.c
        m = A.shape[0]
        kkt = np.block([[terms.M, -A.T], [A, np.zeros((m, m))]])
        x = np.linalg.solve(kkt, np.concatenate((terms.Q - terms.h, c)))
        assert np.linalg.norm(solution.qdd - x[:n]) <= KKT_TOLERANCE * np.linalg.norm(x[:n])
        assert np.linalg.norm(solution.reactions - x[n:]) <= KKT_TOLERANCE * np.linalg.norm(x[n:])


def test_loader_crane_chain(loader):
    """What the description says, in the chain: a fixed base (no base coordinates), 3 RFE angles per
    spring-damping element of each flexible link, the stage's spring and damper on its coordinate only."""
    model = loader["flexible"].model
    assert model.joint_names[:3] == ["column_slew", "main_luff", "main_boom_sde1_bend_vertical"]
    assert model.dof == 4 + 3 * 3 + 3 * 3
    assert [link.name for link in model.flexible_links] == ["main_boom", "jib"]
    k = model.index("telescope")
    assert model.stiffness[k, k] == 1.5e7 and model.damping_matrix[k, k] == 1.5e4
    assert np.count_nonzero(model.stiffness[k]) == 1 and np.count_nonzero(model.damping_matrix[k]) == 1
    assert np.all(model.support_stiffness == 0.0)
    assert loader["rigid"].model.dof == 4


def test_the_chosen_dependent_coordinates_are_the_best_minor(loader):
    """Every pair of joints that may be dependent (free of springs and dampers, not the drive's), enumerated
    here: the pair chosen has the largest smallest singular value of Phi_p C[:, pair] at the start."""
    scenario = loader["flexible"]
    model, dynamics = scenario.model, scenario.dynamics
    p, C = dynamics.end_effector(model.initial_q)
    A = scenario.motion.constraints.position_jacobian(0.0, p) @ C
    free = [k for k in range(model.dof) if not np.any(dynamics.chain.stiffness[k]) and
            not np.any(dynamics.chain.damping[k]) and k != model.drive_joint]
    best = max(((i, j) for a, i in enumerate(free) for j in free[a + 1:]),
               key=lambda pair: np.linalg.svd(A[:, pair], compute_uv=False)[-1])
    assert tuple(model.dependent_joints) == best
    assert [model.joint_names[k] for k in best] == ["main_luff", "knuckle"]


def test_named_dependent_joints_that_cannot_solve_the_task_are_refused(data):
    data["dependent"] = ["column_slew", "main_luff"]  # the slew cannot change E's height with the luff fixed
    params = parse_config(data)
    with pytest.raises(ConfigError, match=r"dependent = \['column_slew', 'main_luff'\]: these joints cannot"):
        Scenario(params, "rigid")


def test_no_joints_left_to_solve_the_task_is_refused(data):
    data["links"][1]["joint"]["stiffness"] = 1e6  # the luff on a spring: only the knuckle is free
    with pytest.raises(ConfigError, match=r"the task has 2 constraints, and only 1 joints \(knuckle\) are free"):
        Scenario(parse_config(data), "rigid")


# --- bad descriptions ----------------------------------------------------------------------------------


@pytest.mark.parametrize(("where", "value", "fragments"), [
    ((2, "parent"), "boom", ("links:", "do not hang on the base", "telescope")),  # a parent that is no link
    ((0, "parent"), "jib", ("links:", "a loop")),
    ((3, "parent"), "main_boom", ("links:", "all hang on 'main_boom'", "one serial chain")),  # a branch
    ((3, "name"), "main_boom", ("links[3].name = 'main_boom'", "used once")),
])
def test_links_that_are_not_one_serial_chain_of_distinct_names(data, where, value, fragments):
    data["links"][where[0]][where[1]] = value
    expect_config_error(data, *fragments)


def test_a_duplicated_joint_name(data):
    data["links"][3]["joint"]["name"] = "main_luff"
    expect_config_error(data, "links[3].joint.name = 'main_luff'", "used once")


def test_an_unknown_key(data):
    data["links"][1]["beam"]["colour"] = "red"
    expect_config_error(data, "links[1].beam.colour: unknown key", "allowed keys")


@pytest.mark.parametrize(("where", "value", "message"), [
    (("links", 1, "beam", "section", "area"), -1.0, "links[1].beam.section.area = -1.0: must be a finite number > 0"),
    (("links", 0, "inertial", "mass"), 0.0, "links[0].inertial.mass = 0.0: must be a finite number > 0 [kg]"),
    (("links", 3, "beam", "rfe_count"), 0, "links[3].beam.rfe_count = 0: must be an integer >= 1"),
    (("links", 2, "joint", "type"), "helical", "links[2].joint.type = 'helical': must be one of revolute, prismatic"),
    (("links", 2, "joint", "axis"), [1.0, 1.0, 0.0], "links[2].joint.axis = [1.0, 1.0, 0.0]: must be a unit vector"),
    (("links", 2, "joint", "stiffness"), -1.0, "links[2].joint.stiffness = -1.0: must be a finite number >= 0"),
    (("end_effector", "link"), "base", "end_effector.link = 'base': must be a link of the chain (not the base)"),
    (("drive", "joint"), "wrist", "drive.joint = 'wrist': must be a joint of the chain"),
    (("actuated",), ["column_slew", "wrist"], "actuated[1] = 'wrist': must be a joint of the chain"),
    (("dependent",), ["main_luff", "elbow"], "dependent[1] = 'elbow': must be a joint of the chain"),
    (("base", "type"), "floating", "base.type = 'floating': must be one of fixed, sprung"),
])
def test_bad_fields_are_named(data, where, value, message):
    target = data
    for key in where[:-1]:
        target = target[key]
    target[where[-1]] = value
    expect_config_error(data, message)


def test_a_link_is_rigid_or_flexible(data):
    data["links"][1]["inertial"] = data["links"][0]["inertial"]
    expect_config_error(data, "links[1]: must have either 'inertial'", "not both or neither")


def test_a_sprung_base_needs_its_mass_and_supports(data):
    data["base"] = {"type": "sprung", "mass": 1000.0}
    expect_config_error(data, "base.center_of_mass: missing")


def test_the_packaged_examples_load_by_name():
    """A bare file name that is not in the working directory is looked up in the package's config/."""
    assert load_config("loader_crane.yaml").name == "loader_crane"


# --- URDF ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("crane", EXAMPLES)
def test_a_description_read_back_from_its_urdf_and_overlay_is_the_same_chain(tmp_path, crane):
    """description -> (URDF of its links, overlay) -> description: the same chain, both variants."""
    params = load_config(CONFIG / crane)
    text, overlay = description_to_urdf(params)
    (tmp_path / "robot.urdf").write_text(text)
    (tmp_path / "robot.yaml").write_text(yaml.safe_dump({"urdf": "robot.urdf", **overlay}))
    again = load_config(tmp_path / "robot.yaml")
    for variant in VARIANTS:
        assert_same_chain(build_model(again, variant), build_model(params, variant), atol=1e-14)


def assert_same_chain(a, b, atol: float) -> None:
    assert a.joint_names == b.joint_names
    for x, y in zip(a.joints, b.joints, strict=True):
        assert (x.kind, x.axis) == (y.kind, y.axis), x.name
        np.testing.assert_allclose(x.origin, y.origin, rtol=0.0, atol=atol, err_msg=x.name)
    assert [body.joint for body in a.bodies] == [body.joint for body in b.bodies]
    for x, y in zip(a.bodies, b.bodies, strict=True):
        np.testing.assert_allclose(x.inertia.pseudo_inertia(), y.inertia.pseudo_inertia(), rtol=1e-13, atol=atol)
    for name in ("stiffness", "damping_matrix", "initial_q", "end_effector_point"):
        np.testing.assert_allclose(getattr(a, name), getattr(b, name), rtol=1e-14, atol=atol, err_msg=name)
    assert (a.end_effector_joint, a.drive_joint, a.dependent_joints, a.actuated_joints) == (
        b.end_effector_joint, b.drive_joint, b.dependent_joints, b.actuated_joints)


@pytest.mark.parametrize("crane", EXAMPLES)
def test_the_chain_urdf_reads_back_to_the_same_chain(tmp_path, crane):
    """``crane-reference urdf`` (every coordinate a joint, every RFE a link) read by urdf_parser_py as a crane
    file's URDF: the same joints, frames and bodies (its springs are the overlay's, so they are not compared)."""
    params = load_config(CONFIG / crane)
    model = build_model(params, "flexible")
    (tmp_path / "chain.urdf").write_text(model_to_urdf(model))
    read = build_model(parse_urdf_description(
        {"urdf": "chain.urdf", "gravity": params.gravity, "base": {"type": "fixed"},
         "drive": {"joint": model.joint_names[model.drive_joint], "type": "torque", "torque": 0.0, "start": 0.0,
                   "end": 1.0},
         "actuated": list(model.actuated_joints), "end_effector": {"link": "end_effector", "point": [0, 0, 0]}},
        tmp_path / "overlay.yaml"), "flexible")
    assert read.joint_names == model.joint_names
    for x, y in zip(read.joints, model.joints, strict=True):
        assert (x.kind, x.axis) == (y.kind, y.axis), x.name
        np.testing.assert_allclose(x.origin, y.origin, rtol=0.0, atol=1e-14, err_msg=x.name)
    mass = {b.joint: 0.0 for b in model.bodies}
    for body in model.bodies:
        mass[body.joint] += body.inertia.mass
    assert {b.joint: b.inertia.mass for b in read.bodies} == pytest.approx(mass, rel=1e-14)
    assert read.end_effector_joint == model.end_effector_joint
    np.testing.assert_allclose(read.end_effector_point, model.end_effector_point, atol=1e-15)


def test_a_urdf_link_named_flexible_must_exist(tmp_path):
    data = read_yaml(CONFIG / "knuckle_boom_crane.yaml")
    data["flexible"]["jib_2"] = data["flexible"].pop("main_boom")
    data["urdf"] = str(CONFIG / data["urdf"])
    expect_config_error(data, "flexible.jib_2: unknown key", "allowed keys of flexible: pedestal, king")


def test_a_flexible_urdf_link_with_another_mass_is_refused():
    data = read_yaml(CONFIG / "knuckle_boom_crane.yaml")
    data["urdf"] = str(CONFIG / data["urdf"])
    data["flexible"]["main_boom"]["density"] = 2700.0  # aluminium: a third of the URDF's 192.9 kg
    expect_config_error(data, "flexible.main_boom: the URDF gives link 'main_boom' 192.9 kg", "rho A L", "66.3")


def test_a_flexible_urdf_link_whose_child_is_off_its_axis_is_refused(tmp_path):
    text = (CONFIG / "knuckle_boom_crane.urdf").read_text().replace('<origin xyz="4.0 0 0" rpy="0 0 0"/>',
                                                                    '<origin xyz="4.0 0 0.2" rpy="0 0 0"/>')
    (tmp_path / "crane.urdf").write_text(text)
    data = read_yaml(CONFIG / "knuckle_boom_crane.yaml")
    data["urdf"] = str(tmp_path / "crane.urdf")
    expect_config_error(data, "flexible.main_boom: its child joint 'fold' is at [4.0, 0.0, 0.2]", "(L, 0, 0)")


def test_a_missing_urdf_is_named():
    data = read_yaml(CONFIG / "knuckle_boom_crane.yaml")
    data["urdf"] = "/nowhere/crane.urdf"
    expect_config_error(data, "urdf = '/nowhere/crane.urdf': cannot read")


def test_urdf_fixed_links_are_merged_and_carry_their_points():
    """The cab (fixed to the king post) adds its mass about the common centre of mass (parallel axes, written
    out here); E on the hook (fixed to the jib) is the hook's origin in the jib's frame."""
    params = load_config(CONFIG / "knuckle_boom_crane.yaml")
    king = params.links[0].body
    m1, c1, m2, c2 = 400.0, np.array([0.0, 0.0, 0.9]), 150.0, np.array([-0.5, 0.6, 0.8])
    center = (m1 * c1 + m2 * c2) / (m1 + m2)
    steiner = sum(m * (np.dot(c - center, c - center) * np.eye(3) - np.outer(c - center, c - center))
                  for m, c in ((m1, c1), (m2, c2)))
    own = np.diag([116.5, 116.5, 25.0]) + np.diag([17.5, 22.5, 17.5])
    assert king.mass == 550.0
    np.testing.assert_allclose(king.center_of_mass, center, rtol=0.0, atol=1e-15)
    np.testing.assert_allclose(king.inertia, own + steiner, rtol=1e-14)
    assert params.end_effector.link == "jib"
    np.testing.assert_array_equal(params.end_effector.point, [2.5, 0.0, -0.3])


def test_the_readmes_example_crane_runs():
    """The crane file the README shows under "Your own crane" (copied from there): it loads, its whole task is
    reachable, and a second of its motion stays on the constraints."""
    readme = (CONFIG.parent.parent / "README.md").read_text()
    section = readme[readme.index("## Your own crane"):]
    start = section.index("```yaml") + len("```yaml")
    params = parse_config(yaml.safe_load(section[start:section.index("```", start)]), source="README.md")
    scenario = Scenario(params, "flexible")
    check_task(scenario, scenario.task, scenario.z_static, SINGULARITY_MARGIN)
    trajectory = simulate(scenario.motion, scenario.equilibrium.q, 1.0, step=5e-4)
    assert trajectory.residual_distance.max() <= 1e-12


def _knuckle_with(tmp_path, old: str, new: str) -> dict[str, Any]:
    """The knuckle-boom crane's file with ``old`` in its URDF replaced by ``new``."""
    text = (CONFIG / "knuckle_boom_crane.urdf").read_text()
    assert old in text
    (tmp_path / "crane.urdf").write_text(text.replace(old, new))
    data = read_yaml(CONFIG / "knuckle_boom_crane.yaml")
    data["urdf"] = str(tmp_path / "crane.urdf")
    return data


_LAMP = """<joint name="lamp_mount" type="fixed"><origin xyz="1.0 0 0.1"/><parent link="{parent}"/>
    <child link="lamp"/></joint>
  <link name="lamp"><inertial><mass value="5"/><inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/>
    </inertial></link>
</robot>"""


def test_a_urdf_branch_is_refused(tmp_path):
    branch = _LAMP.replace('type="fixed"', 'type="revolute"').replace("<child", '<axis xyz="0 0 1"/><limit '
                                                                      'lower="-1" upper="1" effort="1" '
                                                                      'velocity="1"/><child')
    data = _knuckle_with(tmp_path, "</robot>", branch.format(parent="king"))
    expect_config_error(data, "urdf: links main_boom, lamp all hang on 'king'", "one serial chain")


def test_a_urdf_with_the_names_of_the_base_coordinates_is_refused(tmp_path):
    """On a sprung base the names of its coordinates are taken (on a fixed one they are ordinary joints, as in
    the chain URDF of a sprung crane read back above)."""
    data = _knuckle_with(tmp_path, 'name="fold"', 'name="base_yaw"')
    data["joints"]["base_yaw"] = data["joints"].pop("fold")
    data["actuated"] = ["slew", "luff", "base_yaw"]
    data["base"] = {"type": "sprung", "supports": [{"position": [1.0, 0.0, 0.0], "stiffness": [1e7, 1e7, 1e7]}]}
    expect_config_error(data, "urdf: base_yaw: with a sprung base the names", "rename them")


def test_e_on_a_link_fixed_to_the_base_is_refused(tmp_path):
    data = _knuckle_with(tmp_path, "</robot>", _LAMP.format(parent="pedestal"))
    data["end_effector"]["link"] = "lamp"
    expect_config_error(data, "end_effector.link: it is fixed to the base 'pedestal'", "on a moving link")


def test_a_flexible_urdf_link_carrying_a_fixed_mass_is_refused(tmp_path):
    data = _knuckle_with(tmp_path, "</robot>", _LAMP.format(parent="main_boom"))
    expect_config_error(data, "flexible.main_boom: links lamp with mass are fixed to it", "uniform beam")


def test_a_dependent_joint_on_a_spring_is_refused(data):
    data["dependent"] = ["telescope", "knuckle"]
    with pytest.raises(ConfigError, match=r"dependent = \['telescope', 'knuckle'\]: telescope carry a spring"):
        Scenario(parse_config(data), "rigid")


@pytest.mark.parametrize("field", ["drive.joint", "dependent"])
def test_a_base_coordinate_is_no_drive_or_dependent_joint(field):
    data = read_yaml(CONFIG / "crane.yaml")
    if field == "drive.joint":
        data["drive"]["joint"] = "base_yaw"
        message = "drive.joint = 'base_yaw': must be a joint of the chain"
    else:
        data["dependent"] = ["base_z", "base_pitch"]
        message = "dependent[0] = 'base_z': must be a joint of the chain"
    expect_config_error(data, message)


def test_the_slew_axis_must_be_the_world_z_axis(data):
    """The ellipse is centred on the world z axis; a column stood off it cannot walk it with its slew angle."""
    data["links"][0]["joint"]["origin"]["xyz"] = [0.3, 0.0, 1.0]
    with pytest.raises(ConfigError, match=r"links: the ellipse task needs a slew joint.*the world z axis"):
        _ = Scenario(parse_config(data), "rigid").slew
