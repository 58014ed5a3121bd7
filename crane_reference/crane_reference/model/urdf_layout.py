"""Crane files that take their chain from a URDF: a robot's URDF plus a short YAML overlay.

::

    urdf: knuckle_crane.urdf          # the robot (a path relative to this file)
    gravity: 9.81
    base: {type: fixed}               # or sprung: {type: sprung, supports, damping} (the base's mass: the URDF's)
    flexible:                         # URDF links that are uniform beams (RFE)
      main_boom: {section, youngs_modulus, shear_modulus, density, rfe_count, damping, length}
    joints:                           # optional, per URDF joint: initial, stiffness, damping
      telescope: {stiffness: 1.5e+7, damping: 1.5e+4}
    drive: {joint: column_slew, type: torque, torque: 3000.0, start: 0.0, end: 1.0}
    actuated: [column_slew, main_luff, knuckle]
    end_effector: {link: hook, point: [0.0, 0.0, 0.0]}   # any URDF link, fixed ones included
    dependent: auto
    payload: {mass: 300.0}
    task: {ellipse_a, ellipse_b, z_increment, rise_time}

The URDF is parsed with ``urdf_parser_py`` (ROS's urdfdom_py; docs/description.md says why).  Its movable
joints (revolute, continuous, prismatic) become the description's joints, with their origins, axes and
limits; its links their bodies (the inertial's mass, centre of mass and inertia, turned from the inertial frame
into the link's frame).  A link on a ``fixed`` joint is merged into its parent (masses added about the common
centre of mass), and a point on it (E, the payload) is carried into the parent's frame.  The base is the root
link (a fixed base), or the link on a ``floating`` joint from the root at the identity (a sprung base, whose
mass it carries; without a floating joint a sprung base's mass is the root link's).  A link named in
``flexible`` is a uniform beam along its x axis: its length is the x of its child joint's origin (or
``length``, which must then agree), and the URDF's mass for it, if any, must be the beam's rho A L within
:data:`MASS_TOLERANCE`.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from urdf_parser_py.urdf import URDF

from . import fields as f
from .chain import chain_order
from .description import (
    BASE,
    BASE_JOINTS,
    PRISMATIC,
    REVOLUTE,
    Beam,
    CraneDescription,
    JointDescription,
    LinkDescription,
    PointOnLink,
    SprungBase,
)
from .description_layout import AUTO, BASE_TYPES, joint_name, listed_joints, point_on_link, rpy_matrix, vertical_axis
from .parameters import RigidBody, Task
from .urdf import WORLD, description_links_urdf

SECTIONS = ("urdf", "gravity", "base", "drive", "actuated", "end_effector")
OPTIONAL = ("name", "flexible", "joints", "dependent", "payload", "task")
BEAM_KEYS = ("section", "youngs_modulus", "shear_modulus", "density", "rfe_count")
MASS_TOLERANCE = 0.01
"""Relative difference allowed between a flexible link's URDF mass and its beam's rho A L."""
LENGTH_TOLERANCE = 1e-9
"""[m] how far a flexible link's child joint may lie off its x axis, or from its given ``length``."""
MOVABLE = {"revolute": REVOLUTE, "continuous": REVOLUTE, "prismatic": PRISMATIC}


def parse_urdf_description(value: object, source: Path | None) -> CraneDescription:
    """A mapping in the URDF layout as a :class:`CraneDescription` (raises :class:`~.fields.FieldError`);
    ``source`` is the overlay's file (the ``urdf`` path is relative to its folder)."""
    data = f.section(value, "", SECTIONS, optional=OPTIONAL)
    robot = _robot(data["urdf"], source)
    rigid = _rigid_frames(robot)
    flexible = f.section(data.get("flexible", {}), "flexible", (), optional=tuple(robot.link_map))
    overrides = f.section(data.get("joints", {}), "joints", (), optional=tuple(robot.joint_map))
    kind = f.section(data["base"], "base", ("type",), optional=("supports", "damping"))["type"]
    if kind not in BASE_TYPES:
        raise f.invalid("base.type", kind, f"must be one of {', '.join(BASE_TYPES)}")
    root = _base_link(robot, kind)
    links = _links(robot, rigid, root, flexible, overrides)
    try:
        chain_order(links)
    except ValueError as err:
        raise f.FieldError(f"urdf: {err}") from None
    taken = (*BASE_JOINTS, WORLD, BASE) if kind == "sprung" else (WORLD,)
    clashing = [name for name in [*(j.name for j in robot.joints), *(link.name for link in links)] if name in taken]
    if clashing:
        raise f.FieldError(f"urdf: {', '.join(clashing)}: with a {kind} base the names {', '.join(taken)} are "
                           "taken (the root and a sprung base's body and coordinates); rename them")
    base = None
    if kind == "sprung":
        base_data = f.section(data["base"], "base", ("type", "supports"), optional=("damping",))
        body = _merged_body(robot, rigid, root)
        if body is None:
            raise f.FieldError(f"base: a sprung base needs a mass: the URDF's base link {root!r} has none")
        base = SprungBase(body, f.supports(base_data["supports"], "base.supports"),
                          f.number(base_data.get("damping", 0.0), "base.damping", "s", f.NON_NEGATIVE))
    else:
        f.section(data["base"], "base", ("type",))
    names = [link.name for link in links]
    joints = [link.joint.name for link in links]
    f.section(data["drive"], "drive", ("joint", "type"), optional=tuple(
        dict.fromkeys(key for keys in f.DRIVE_KEYS.values() for key in keys)))
    end_effector = _on_a_link(_carried(point_on_link(data["end_effector"], "end_effector", [*names, *rigid]), rigid),
                              "end_effector", root)
    payload = f.section(data.get("payload", {"mass": 0.0}), "payload", ("mass",), optional=("link", "point"))
    payload_at = None
    if "link" in payload or "point" in payload:
        payload_at = _on_a_link(_carried(point_on_link(
            {"link": payload.get("link", data["end_effector"].get("link")),
             "point": payload.get("point", [0.0, 0.0, 0.0])}, "payload", [*names, *rigid]), rigid), "payload", root)
    dependent = data.get("dependent", AUTO)
    return CraneDescription(
        name=str(data.get("name", robot.name)),
        gravity=f.number(data["gravity"], "gravity", "m/s^2", f.NON_NEGATIVE),
        base=base,
        links=tuple(links),
        drive=f.drive(data["drive"], "drive", also=("joint",)),
        drive_joint=joint_name(data["drive"]["joint"], "drive.joint", joints),
        actuated=listed_joints(data["actuated"], "actuated", joints),
        end_effector=end_effector,
        dependent=None if dependent == AUTO else listed_joints(dependent, "dependent", joints),
        payload=f.number(payload["mass"], "payload.mass", "kg", f.NON_NEGATIVE),
        payload_at=payload_at,
        task=f.optional_section(data.get("task", {}), "task", Task, f.TASK_FIELDS),
    )


def _robot(value: object, source: Path | None) -> URDF:
    if not isinstance(value, str) or not value:
        raise f.invalid("urdf", value, "must be the path of a URDF file (relative to this file)")
    path = Path(value) if source is None or Path(value).is_absolute() else source.parent / value
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as err:
        raise f.invalid("urdf", value, f"cannot read {path}: {err}") from None
    try:
        return URDF.from_xml_string(text)
    except Exception as err:  # urdf_parser_py raises what its XML and reflection layers raise
        raise f.invalid("urdf", value, f"{path} is not a valid URDF: {err}") from None


def _transform(origin) -> np.ndarray:
    T = np.eye(4)
    if origin is not None:
        T[:3, 3] = origin.xyz if origin.xyz is not None else (0.0, 0.0, 0.0)
        T[:3, :3] = rpy_matrix(np.asarray(origin.rpy if origin.rpy is not None else (0.0, 0.0, 0.0), dtype=float))
    return T


def _base_link(robot: URDF, kind: str) -> str:
    """The URDF link that is the base: the root, or the child of a floating joint from it (a sprung base)."""
    root = robot.get_root()
    floating = [j for j in robot.joints if j.type == "floating"]
    if not floating:
        return root
    joint = floating[0]
    if len(floating) > 1 or joint.parent != root:
        raise f.FieldError(f"urdf: floating joints {', '.join(j.name for j in floating)}: a crane has at most one, "
                           "from the root link to its base")
    if kind != "sprung":
        raise f.invalid("base.type", kind, f"must be 'sprung': the URDF's base {joint.child!r} is on the floating "
                                           f"joint {joint.name!r}")
    if not np.allclose(_transform(joint.origin), np.eye(4), rtol=0.0, atol=0.0):
        raise f.FieldError(f"urdf: floating joint {joint.name!r} has an origin; a sprung base's frame is the world's "
                           "at rest, so the floating joint's origin must be the identity")
    return joint.child


def _rigid_frames(robot: URDF) -> dict[str, tuple[str, np.ndarray]]:
    """For each link on a ``fixed`` joint: the link it is rigidly part of (the first ancestor on a movable joint,
    or the root) and its frame in that link's frame."""
    out: dict[str, tuple[str, np.ndarray]] = {}
    pending = [j for j in robot.joints if j.type == "fixed"]
    while pending:  # a fixed joint whose parent is itself on a pending fixed joint waits for it
        ready = [j for j in pending if not any(other.child == j.parent for other in pending)]
        if not ready:
            raise f.FieldError(f"urdf: fixed joints {', '.join(j.name for j in pending)} form a loop")
        for joint in ready:
            owner, frame = out.get(joint.parent, (joint.parent, np.eye(4)))
            out[joint.child] = (owner, frame @ _transform(joint.origin))
            pending.remove(joint)
    return out


def _body(link) -> RigidBody | None:
    """A URDF link's inertial in the link's frame (None without one or with zero mass)."""
    inertial = link.inertial
    if inertial is None or not inertial.mass:
        return None
    T = _transform(inertial.origin)
    R = T[:3, :3]
    i = inertial.inertia
    tensor = np.array([[i.ixx, i.ixy, i.ixz], [i.ixy, i.iyy, i.iyz], [i.ixz, i.iyz, i.izz]], dtype=float)
    return RigidBody(float(inertial.mass), T[:3, 3].copy(), R @ tensor @ R.T)


def _merged_body(robot: URDF, rigid: dict[str, tuple[str, np.ndarray]], name: str) -> RigidBody | None:
    """The mass of link ``name`` with every link fixed to it, about their common centre of mass, in its frame."""
    parts = [(_body(robot.link_map[name]), np.eye(4))]
    parts += [(_body(robot.link_map[child]), frame) for child, (owner, frame) in rigid.items() if owner == name]
    bodies = [(body, frame) for body, frame in parts if body is not None]
    if not bodies:
        return None
    placed = [(b.mass, frame[:3, :3] @ b.center_of_mass + frame[:3, 3], frame[:3, :3] @ b.inertia @ frame[:3, :3].T)
              for b, frame in bodies]
    mass = sum(m for m, _, _ in placed)
    center = sum(m * c for m, c, _ in placed) / mass
    inertia = sum(tensor + m * (np.dot(c - center, c - center) * np.eye(3) - np.outer(c - center, c - center))
                  for m, c, tensor in placed)
    return RigidBody(mass, center, inertia)


def _on_a_link(point: PointOnLink, path: str, base: str) -> PointOnLink:
    """``point``, unless it is on the base (a link fixed to it): :class:`~.fields.FieldError` naming ``path``."""
    if point.link == base:
        raise f.FieldError(f"{path}.link: it is fixed to the base {base!r}; E and the payload are on a moving link")
    return point


def _carried(point: PointOnLink, rigid: dict[str, tuple[str, np.ndarray]]) -> PointOnLink:
    """A point on a link fixed to another, on that other link."""
    if point.link not in rigid:
        return point
    owner, frame = rigid[point.link]
    return PointOnLink(owner, frame[:3, :3] @ point.point + frame[:3, 3])


def _links(robot: URDF, rigid: dict[str, tuple[str, np.ndarray]], root: str, flexible: Mapping[str, Any],
           overrides: Mapping[str, Any]) -> list[LinkDescription]:
    movable = [j for j in robot.joints if j.type not in ("fixed", "floating")]
    unsupported = [j for j in movable if j.type not in MOVABLE]
    if unsupported:
        raise f.FieldError(f"urdf: joint {unsupported[0].name!r} is {unsupported[0].type!r}; a crane's joints are "
                           f"{', '.join(MOVABLE)} (or fixed)")
    for name in flexible:
        if name in rigid or name == root:
            raise f.invalid(f"flexible.{name}", name, "must be a link on a revolute, continuous or prismatic joint "
                                                      "(not the base or a link on a fixed joint)")
    links = []
    for joint in movable:
        parent = rigid.get(joint.parent, (joint.parent, np.eye(4)))
        origin = parent[1] @ _transform(joint.origin)
        children = [j for j in movable if rigid.get(j.parent, (j.parent,))[0] == joint.child]
        links.append(LinkDescription(joint.child, None if parent[0] == root else parent[0],
                                     _joint(joint, origin, overrides), _merged_body(robot, rigid, joint.child)
                                     if joint.child not in flexible else None,
                                     _beam(robot, rigid, joint.child, flexible[joint.child], children)
                                     if joint.child in flexible else None))
    return links


def _joint(joint, origin: np.ndarray, overrides: Mapping[str, Any]) -> JointDescription:
    path = f"joints.{joint.name}"
    data = f.section(overrides.get(joint.name, {}), path, (), optional=("initial", "stiffness", "damping"))
    kind = MOVABLE[joint.type]
    axis = np.asarray(joint.axis if joint.axis is not None else (1.0, 0.0, 0.0), dtype=float)
    length = float(np.linalg.norm(axis))
    if not length > 0.0:
        raise f.FieldError(f"urdf: joint {joint.name!r} has a zero axis")
    limits = None
    if joint.type != "continuous" and joint.limit is not None and joint.limit.upper > joint.limit.lower:
        limits = (float(joint.limit.lower), float(joint.limit.upper))
    unit = "rad" if kind == REVOLUTE else "m"
    force = "N m" if kind == REVOLUTE else "N"
    return JointDescription(
        name=joint.name, kind=kind, axis=axis / length, origin=origin,
        initial=f.number(data.get("initial", 0.0), f.join(path, "initial"), unit),
        limits=limits,
        stiffness=f.number(data.get("stiffness", 0.0), f.join(path, "stiffness"), f"{force}/{unit}", f.NON_NEGATIVE),
        damping=f.number(data.get("damping", 0.0), f.join(path, "damping"), f"{force} s/{unit}", f.NON_NEGATIVE),
    )


def _beam(robot: URDF, rigid: dict[str, tuple[str, np.ndarray]], name: str, value: object, children: list) -> Beam:
    path = f"flexible.{name}"
    data = f.section(value, path, BEAM_KEYS, optional=("damping", "length", "vertical_axis"))
    section = f.beam_section(data["section"], f.join(path, "section"))
    density = f.number(data["density"], f.join(path, "density"), "kg/m^3", f.POSITIVE)
    length = f.number(data["length"], f.join(path, "length"), "m", f.POSITIVE) if "length" in data else None
    if len(children) > 1:
        raise f.FieldError(f"{path}: {len(children)} joints hang on it; a crane is one serial chain")
    if children:
        child = children[0]
        parent = rigid.get(child.parent, (child.parent, np.eye(4)))
        tip = (parent[1] @ _transform(child.origin))[:3, 3]
        if not np.all(np.abs(tip[1:]) <= LENGTH_TOLERANCE) or not tip[0] > 0.0:
            raise f.FieldError(f"{path}: its child joint {child.name!r} is at {tip.tolist()} m in its frame; a "
                               "flexible link is a beam along its x axis, so the joint must be at (L, 0, 0), L > 0")
        if length is not None and abs(length - tip[0]) > LENGTH_TOLERANCE:
            raise f.invalid(f.join(path, "length"), length, f"must be the x of its child joint's origin, {tip[0]!r} m "
                                                             "(or be left out)")
        length = float(tip[0])
    if length is None:
        raise f.FieldError(f"{f.join(path, 'length')}: missing; the link has no child joint to take it from")
    fixed = [child for child, (owner, _) in rigid.items() if owner == name and _body(robot.link_map[child])]
    if fixed:
        raise f.FieldError(f"{path}: links {', '.join(fixed)} with mass are fixed to it; a flexible link is a uniform "
                           "beam: give their mass to a link of their own on a joint, or leave it out")
    urdf_body = _merged_body(robot, rigid, name)
    beam_mass = density * section.area * length
    if urdf_body is not None and abs(urdf_body.mass - beam_mass) > MASS_TOLERANCE * beam_mass:
        raise f.FieldError(f"{path}: the URDF gives link {name!r} {urdf_body.mass:.6g} kg, its beam rho A L = "
                           f"{density:g} * {section.area:g} * {length:g} = {beam_mass:.6g} kg (more than "
                           f"{MASS_TOLERANCE:.0%} apart): fix the section, the density or the URDF's mass")
    return Beam(length, section,
                f.number(data["youngs_modulus"], f.join(path, "youngs_modulus"), "Pa", f.POSITIVE),
                f.number(data["shear_modulus"], f.join(path, "shear_modulus"), "Pa", f.POSITIVE),
                density, f.integer(data["rfe_count"], f.join(path, "rfe_count"), 1),
                f.number(data.get("damping", 0.0), f.join(path, "damping"), "s", f.NON_NEGATIVE),
                vertical_axis(data.get("vertical_axis", "y"), f.join(path, "vertical_axis")))


def description_to_urdf(description: CraneDescription) -> tuple[str, dict[str, Any]]:
    """The description as a URDF of its links (a flexible link as one link with its beam's mass) and the
    overlay that, with it, describes the same crane (:func:`parse_urdf_description`; ``urdf`` left for the
    caller to fill in)."""
    overlay: dict[str, Any] = {"name": description.name, "gravity": description.gravity}
    base = description.base
    overlay["base"] = ({"type": "fixed"} if base is None else
                       {"type": "sprung", "damping": base.damping,
                        "supports": [{"position": s.position.tolist(), "stiffness": s.stiffness.tolist()}
                                     for s in base.supports]})
    overlay["flexible"] = {link.name: {
        "section": {"area": b.section.area, "second_moment_y": b.section.second_moment_y,
                    "second_moment_z": b.section.second_moment_z, "torsion_constant": b.section.torsion_constant},
        "youngs_modulus": b.youngs_modulus, "shear_modulus": b.shear_modulus, "density": b.density,
        "rfe_count": b.rfe_count, "damping": b.damping, "length": b.length, "vertical_axis": b.vertical_axis}
        for link in description.links if (b := link.beam) is not None}
    overlay["joints"] = {j.name: {"initial": j.initial, "stiffness": j.stiffness, "damping": j.damping}
                         for j in description.joints}
    drive = {"joint": description.drive_joint, **{k: v for k, v in vars(description.drive).items()}}
    drive["type"] = "torque" if hasattr(description.drive, "torque") else "flexible"
    overlay["drive"] = drive
    overlay["actuated"] = list(description.actuated)
    overlay["end_effector"] = {"link": description.end_effector.link,
                               "point": np.asarray(description.end_effector.point).tolist()}
    overlay["dependent"] = AUTO if description.dependent is None else list(description.dependent)
    overlay["payload"] = {"mass": description.payload}
    if description.payload_at is not None:
        overlay["payload"].update(link=description.payload_at.link, point=description.payload_at.point.tolist())
    overlay["task"] = dict(vars(description.task))
    return description_links_urdf(description), overlay
