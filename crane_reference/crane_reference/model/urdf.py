"""URDF description of a :class:`~crane_reference.model.ChainModel` (for RViz and for Pinocchio checks).

Mapping, chain model -> URDF:

* Root link ``world`` (the world frame {0}).
* Every coordinate k becomes one URDF joint with the same name, in the same order as
  ``model.joint_names``: revolute coordinates as ``revolute`` joints with their described limits or, without
  limits, ``continuous`` joints; prismatic ones as ``prismatic`` joints with their described limits or
  generous ones (+-100 m).  The joint ``origin`` (xyz, and rpy with the URDF
  convention R = Rz(yaw) Ry(pitch) Rx(roll)) is the constant transform ``Joint.origin`` and ``axis`` the
  local unit axis, so that the child frame of URDF joint k is the chain frame
  ``T_k = T_{k-1} @ origin_k @ motion_k(q_k)``.
* The child link of joint k is named after the first body attached to frame k (``base``, ``column``,
  ``boom_rfe0``, ``link4``, ...) or, if no body is attached, ``<joint name>_link`` (massless, no
  ``<inertial>``).  Every further body on the same frame (the payload) is a link of its own, attached
  through an identity ``fixed`` joint named ``<body>_fixed``.
* ``<inertial>``: the body's mass, origin at its centre of mass (rpy 0) and its inertia tensor about the
  centre of mass, all in frame k, exactly as in :class:`~crane_reference.model.parameters.RigidBody`.
* ``<visual>`` geometry only for display (it never affects the inertia): a sphere for a point mass, a
  cylinder for the column (from its frame origin up to the next joint, the boom pivot), and for every
  other body the uniform box with the body's mass and inertia, centred at its centre of mass and
  aligned with its principal axes (for a boom element this is the element itself).
* Link ``end_effector`` on the fixed joint ``end_effector_fixed`` at ``model.end_effector_point`` of the
  end-effector frame (same rotation as that frame).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Iterable

import numpy as np

from .chain import PRISMATIC, Body, ChainModel
from .description import BASE, CraneDescription
from .description import PRISMATIC as PRISMATIC_JOINT
from .parameters import RigidBody
from .rfe import segment_body

WORLD = "world"
"""The URDF's root link."""
PRISMATIC_LIMIT = 100.0  # [m], symmetric position limit of the base translations
PRISMATIC_EFFORT = 1.0e9  # [N or N m], URDF's required effort limit (the model sets none)
PRISMATIC_VELOCITY = 100.0  # [m/s or rad/s], URDF's required velocity limit (the model sets none)
MIN_VISUAL_SIZE = 0.05  # [m], smallest edge of a displayed box
POINT_MASS_RADIUS = 0.15  # [m], sphere drawn for a point mass
COLUMN_RADIUS = 0.2  # [m]
COLORS = {"steel": "0.55 0.57 0.6 1", "crane": "0.95 0.7 0.1 1", "payload": "0.8 0.15 0.1 1"}


def matrix_to_rpy(R: np.ndarray) -> tuple[float, float, float]:
    """URDF roll, pitch, yaw of a rotation matrix, R = Rz(yaw) Ry(pitch) Rx(roll), pitch in [-pi/2, pi/2].

    Yaw and pitch come from the first column; roll from Rz(yaw)^T R = Ry(pitch) Rx(roll), so that the
    three angles reproduce R to rounding even at (and near) pitch = +-pi/2, where only yaw - roll
    (or yaw + roll) is defined and the first column gives yaw = atan2(0, 0) = 0.
    """
    yaw = np.arctan2(R[1, 0], R[0, 0])
    c, s = np.cos(yaw), np.sin(yaw)
    pitch = np.arctan2(-R[2, 0], c * R[0, 0] + s * R[1, 0])
    roll = np.arctan2(s * R[0, 2] - c * R[1, 2], c * R[1, 1] - s * R[0, 1])
    return float(roll), float(pitch), float(yaw)


def _numbers(values: Iterable[float]) -> str:
    """Space-separated shortest round-trip representations (no precision lost in the XML; -0.0 as 0.0)."""
    return " ".join(repr(float(v) + 0.0) for v in values)


def _origin(parent: ET.Element, xyz: Iterable[float], R: np.ndarray | None = None) -> None:
    rpy = matrix_to_rpy(R) if R is not None else (0.0, 0.0, 0.0)
    ET.SubElement(parent, "origin", xyz=_numbers(xyz), rpy=_numbers(rpy))


def _link(robot: ET.Element, name: str) -> ET.Element:
    return ET.SubElement(robot, "link", name=name)


def _joint(robot: ET.Element, name: str, kind: str, parent: str, child: str,
           transform: np.ndarray) -> ET.Element:
    joint = ET.SubElement(robot, "joint", name=name, type=kind)
    _origin(joint, transform[:3, 3], transform[:3, :3])
    ET.SubElement(joint, "parent", link=parent)
    ET.SubElement(joint, "child", link=child)
    return joint


def _inertial(link: ET.Element, body: RigidBody) -> None:
    inertial = ET.SubElement(link, "inertial")
    _origin(inertial, body.center_of_mass)
    ET.SubElement(inertial, "mass", value=_numbers([body.mass]))
    ET.SubElement(inertial, "inertia", {f"i{'xyz'[i]}{'xyz'[j]}": _numbers([body.inertia[i][j]])
                                        for i in range(3) for j in range(i, 3)})


def _equivalent_box(body: RigidBody) -> tuple[np.ndarray, np.ndarray]:
    """Edge lengths and axes (columns, det +1) of the uniform box with the body's mass and inertia.

    About its principal axes a box a x b x c has I_1 = m (b^2 + c^2) / 12 etc., so a^2 = 6 (tr I - 2 I_1) / m;
    edges are at least MIN_VISUAL_SIZE.
    """
    inertia = np.asarray(body.inertia, dtype=float)
    if np.count_nonzero(inertia - np.diag(np.diag(inertia))) == 0:
        moments, axes = np.diag(inertia), np.eye(3)
    else:
        moments, axes = np.linalg.eigh(inertia)
        axes[:, 2] *= np.sign(np.linalg.det(axes))
    squares = 6.0 * (np.trace(inertia) - 2.0 * moments) / body.mass
    return np.maximum(np.sqrt(np.maximum(squares, 0.0)), MIN_VISUAL_SIZE), axes


def _visual(link: ET.Element, model: ChainModel, attached: Body) -> None:
    visual = ET.SubElement(link, "visual")
    body = attached.inertia
    if not np.any(body.inertia):
        _origin(visual, body.center_of_mass)
        ET.SubElement(ET.SubElement(visual, "geometry"), "sphere", radius=_numbers([POINT_MASS_RADIUS]))
        color = "payload"
    elif attached.name == "column":
        height = max(model.joints[attached.joint + 1].origin[2, 3], MIN_VISUAL_SIZE)
        _origin(visual, (0.0, 0.0, 0.5 * height))
        ET.SubElement(ET.SubElement(visual, "geometry"), "cylinder", radius=_numbers([COLUMN_RADIUS]),
                      length=_numbers([height]))
        color = "crane"
    else:
        size, axes = _equivalent_box(body)
        _origin(visual, body.center_of_mass, axes)
        ET.SubElement(ET.SubElement(visual, "geometry"), "box", size=_numbers(size))
        color = "steel" if attached.name == "base" else "crane"
    ET.SubElement(visual, "material", name=color)


def _movable_joint(robot: ET.Element, name: str, prismatic: bool, axis: np.ndarray,
                   limits: tuple[float, float] | None, parent: str, child: str, origin: np.ndarray) -> None:
    """A revolute (``continuous`` without limits) or prismatic (generous limits without) URDF joint."""
    if prismatic:
        kind, limits = "prismatic", limits or (-PRISMATIC_LIMIT, PRISMATIC_LIMIT)
    else:
        kind = "revolute" if limits else "continuous"
    element = _joint(robot, name, kind, parent, child, origin)
    ET.SubElement(element, "axis", xyz=_numbers(axis))
    if limits is not None:
        ET.SubElement(element, "limit", lower=_numbers([limits[0]]), upper=_numbers([limits[1]]),
                      effort=_numbers([PRISMATIC_EFFORT]), velocity=_numbers([PRISMATIC_VELOCITY]))


def model_to_urdf(model: ChainModel) -> str:
    """URDF (pretty-printed XML) of the chain, robot ``model.name``: same joints, frames and mass properties
    (see module doc)."""
    robot = ET.Element("robot", name=model.name)
    for color, rgba in COLORS.items():
        ET.SubElement(ET.SubElement(robot, "material", name=color), "color", rgba=rgba)
    _link(robot, WORLD)
    parent = WORLD
    frame_links = []
    for k, joint in enumerate(model.joints):
        bodies = [b for b in model.bodies if b.joint == k]
        child = bodies[0].name if bodies else f"{joint.name}_link"
        _movable_joint(robot, joint.name, joint.kind == PRISMATIC, np.eye(3)[joint.axis], joint.limits, parent, child,
                       joint.origin)
        link = _link(robot, child)
        for i, body in enumerate(bodies):
            if i > 0:
                link = _link(robot, body.name)
                _joint(robot, f"{body.name}_fixed", "fixed", child, body.name, np.eye(4))
            _inertial(link, body.inertia)
            _visual(link, model, body)
        frame_links.append(child)
        parent = child
    ee = np.eye(4)
    ee[:3, 3] = model.end_effector_point
    _joint(robot, "end_effector_fixed", "fixed", frame_links[model.end_effector_joint], "end_effector", ee)
    _link(robot, "end_effector")
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"


def description_links_urdf(description: CraneDescription) -> str:
    """URDF of a description's links as described (before the RFE cut): root link ``world`` (a fixed base) or
    ``base`` with the sprung base's mass on the floating joint ``base_floating`` from it, each link on its joint
    with the described origin, axis and limits, a
    flexible link as one link with its beam's mass (rho A L, centre at L/2, :func:`~.rfe.segment_body`); what
    URDF cannot say (springs, supports, the beams' sections, the task) is the overlay's
    (:func:`~.urdf_layout.description_to_urdf`)."""
    taken = {WORLD, BASE} & {link.name for link in description.links}
    if taken:
        raise ValueError(f"links {', '.join(sorted(taken))}: {WORLD!r} and {BASE!r} name the URDF's root and base")
    robot = ET.Element("robot", name=description.name)
    _link(robot, WORLD)
    base = WORLD
    if description.base is not None:
        _joint(robot, "base_floating", "floating", WORLD, BASE, np.eye(4))
        _inertial(_link(robot, BASE), description.base.body)
        base = BASE
    for link in description.links:
        joint = link.joint
        _movable_joint(robot, joint.name, joint.kind == PRISMATIC_JOINT, joint.axis, joint.limits,
                       link.parent or base, link.name, joint.origin)
        body = link.body if link.beam is None else segment_body(link.beam.length, link.beam.density,
                                                                 link.beam.section)
        element = _link(robot, link.name)
        if body is not None:
            _inertial(element, body)
    ET.indent(robot)
    return '<?xml version="1.0"?>\n' + ET.tostring(robot, encoding="unicode") + "\n"
