"""Crane files in the description layout: a serial chain of ``links`` (the schema is in docs/description.md).

::

    name: my_crane                      # optional; the robot's name in its URDF
    gravity: 9.81
    base: {type: fixed}                 # or {type: sprung, mass, center_of_mass, inertia, supports, damping}
    links:
      - name: column
        parent: base                    # optional: the link before (the base for the first)
        joint: {name: column_slew, type: revolute, axis: [0, 0, 1], origin: {xyz: [0, 0, 0], rpy: [0, 0, 0]},
                initial: 0.0, limits: {lower: -3.14, upper: 3.14}, stiffness: 0.0, damping: 0.0}
        inertial: {mass, center_of_mass, inertia}        # a rigid link, or
        beam: {length, section, youngs_modulus, shear_modulus, density, rfe_count, damping}   # a flexible one
    drive: {joint: column_slew, type: torque, torque: 4000.0, start: 0.0, end: 1.0}
    actuated: [column_slew, boom_luff, knuckle]
    end_effector: {link: link4, point: [1.2, 0.0, 0.0]}
    dependent: [boom_luff, knuckle]     # or auto (the default)
    payload: {mass: 500.0, link: link4, point: [1.2, 0.0, 0.0]}   # optional; at E by default
    task: {ellipse_a, ellipse_b, z_increment, rise_time}          # optional

Every check names the field (``links[2].joint.axis``) and what is allowed.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from . import fields as f
from .chain import chain_order
from .description import (
    BASE,
    BASE_JOINTS,
    JOINT_TYPES,
    Beam,
    CraneDescription,
    JointDescription,
    LinkDescription,
    PointOnLink,
    SprungBase,
)
from .parameters import Task

SECTIONS = ("gravity", "base", "links", "drive", "actuated", "end_effector")
OPTIONAL = ("name", "dependent", "payload", "task")
AUTO = "auto"
BASE_TYPES = ("fixed", "sprung")
VERTICAL_AXES = ("y", "z")
AXIS_TOLERANCE = 1e-9
"""How far from 1 the length of a joint axis may be (it is then normalised)."""


def parse_description(value: object) -> CraneDescription:
    """A mapping in the description layout as a :class:`CraneDescription` (raises :class:`~.fields.FieldError`)."""
    data = f.section(value, "", SECTIONS, optional=OPTIONAL)
    base = _base(data["base"], "base")
    links = _links(data["links"], "links")
    names = [link.name for link in links]
    joints = [link.joint.name for link in links]  # the base's coordinates are driven, actuated and solved by none
    drive = f.section(data["drive"], "drive", ("joint", "type"), optional=tuple(
        dict.fromkeys(key for keys in f.DRIVE_KEYS.values() for key in keys)))
    drive_joint = joint_name(drive["joint"], "drive.joint", joints)
    actuated = listed_joints(data["actuated"], "actuated", joints)
    end_effector = point_on_link(data["end_effector"], "end_effector", names)
    dependent = data.get("dependent", AUTO)
    payload = f.section(data.get("payload", {"mass": 0.0}), "payload", ("mass",), optional=("link", "point"))
    payload_at = None
    if "link" in payload or "point" in payload:
        payload_at = point_on_link({"link": payload.get("link", end_effector.link),
                             "point": payload.get("point", end_effector.point)}, "payload", names)
    return CraneDescription(
        name=_name(data.get("name", "crane"), "name"),
        gravity=f.number(data["gravity"], "gravity", "m/s^2", f.NON_NEGATIVE),
        base=base,
        links=links,
        drive=f.drive(data["drive"], "drive", also=("joint",)),
        drive_joint=drive_joint,
        actuated=actuated,
        end_effector=end_effector,
        dependent=None if dependent == AUTO else listed_joints(dependent, "dependent", joints),
        payload=f.number(payload["mass"], "payload.mass", "kg", f.NON_NEGATIVE),
        payload_at=payload_at,
        task=f.optional_section(data.get("task", {}), "task", Task, f.TASK_FIELDS),
    )


def _name(value: object, path: str) -> str:
    if not isinstance(value, str) or not value or not value.replace("_", "").replace("-", "").isalnum():
        raise f.invalid(path, value, "must be a non-empty name of letters, digits, '_' and '-'")
    return value


def listed_joints(value: object, path: str, allowed: list[str]) -> tuple[str, ...]:
    if not isinstance(value, (list, tuple)) or not value:
        raise f.invalid(path, value, f"must be a list of joint names (the joints: {', '.join(allowed)})")
    names = tuple(joint_name(item, f"{path}[{i}]", allowed) for i, item in enumerate(value))
    if len(set(names)) != len(names):
        raise f.invalid(path, list(value), "must name each joint once")
    return names


def joint_name(value: object, path: str, allowed: list[str]) -> str:
    if value not in allowed:
        raise f.invalid(path, value, f"must be a joint of the chain: {', '.join(allowed)}")
    return str(value)


def point_on_link(value: object, path: str, links: list[str]) -> PointOnLink:
    data = f.section(value, path, ("link", "point"))
    if data["link"] not in links:
        raise f.invalid(f.join(path, "link"), data["link"], f"must be a link of the chain (not the base): "
                                                            f"{', '.join(links)}")
    return PointOnLink(str(data["link"]), f.vector(data["point"], f.join(path, "point"), "m"))


def _base(value: object, path: str) -> SprungBase | None:
    kind = f.section(value, path, ("type",), optional=(*f.BODY_KEYS, "supports", "damping"))["type"]
    if kind not in BASE_TYPES:
        raise f.invalid(f.join(path, "type"), kind, f"must be one of {', '.join(BASE_TYPES)}")
    if kind == "fixed":
        f.section(value, path, ("type",))
        return None
    data = f.section(value, path, ("type", *f.BODY_KEYS, "supports"), optional=("damping",))
    return SprungBase(f.rigid_body(data, path), f.supports(data["supports"], f.join(path, "supports")),
                      f.number(data.get("damping", 0.0), f.join(path, "damping"), "s", f.NON_NEGATIVE))


def _links(value: object, path: str) -> tuple[LinkDescription, ...]:
    if not isinstance(value, (list, tuple)) or not value:
        raise f.invalid(path, value, "must be a list of links {name, parent, joint, inertial or beam}")
    links: list[LinkDescription] = []
    for i, item in enumerate(value):
        parent = links[-1].name if links else None
        links.append(_link(item, f"{path}[{i}]", parent))
    for kind, names in (("link", [link.name for link in links]), ("joint", [link.joint.name for link in links])):
        seen: set[str] = set()
        for i, name in enumerate(names):
            if name in seen or name == BASE or name in BASE_JOINTS:
                where = f"{path}[{i}].{'name' if kind == 'link' else 'joint.name'}"
                raise f.invalid(where, name, f"must be a {kind} name used once in the chain, not {BASE!r} or a "
                                             f"base coordinate ({', '.join(BASE_JOINTS)})")
            seen.add(name)
    try:
        return chain_order(links)
    except ValueError as err:
        raise f.FieldError(f"{path}: {err}") from None


def _link(value: object, path: str, parent: str | None) -> LinkDescription:
    data = f.section(value, path, ("name", "joint"), optional=("parent", "inertial", "beam"))
    if ("inertial" in data) == ("beam" in data):
        raise f.FieldError(f"{path}: must have either 'inertial' (a rigid link) or 'beam' (a flexible link), "
                           "not both or neither")
    parent_name = data.get("parent", parent)
    if parent_name is not None and not isinstance(parent_name, str):
        raise f.invalid(f.join(path, "parent"), parent_name, f"must be the name of a link, or {BASE!r}")
    parent_name = None if parent_name == BASE else parent_name
    body = beam = None
    if "inertial" in data:
        inertial = f.join(path, "inertial")
        body = f.rigid_body(f.section(data["inertial"], inertial, f.BODY_KEYS), inertial)
    else:
        beam = _beam(data["beam"], f.join(path, "beam"))
    return LinkDescription(_name(data["name"], f.join(path, "name")), parent_name,
                           _joint(data["joint"], f.join(path, "joint")), body, beam)


def _joint(value: object, path: str) -> JointDescription:
    data = f.section(value, path, ("name", "type", "axis"),
                     optional=("origin", "initial", "limits", "stiffness", "damping"))
    kind = data["type"]
    if kind not in JOINT_TYPES:
        raise f.invalid(f.join(path, "type"), kind, f"must be one of {', '.join(JOINT_TYPES)}")
    unit = "rad" if kind == "revolute" else "m"
    axis_path = f.join(path, "axis")
    axis = f.vector(data["axis"], axis_path, "1")
    length = float(np.linalg.norm(axis))
    if not abs(length - 1.0) <= AXIS_TOLERANCE:
        raise f.invalid(axis_path, data["axis"], f"must be a unit vector (its length is {length:.12g})")
    limits = None
    if "limits" in data:
        bounds = f.section(data["limits"], f.join(path, "limits"), ("lower", "upper"))
        limits = (f.number(bounds["lower"], f.join(path, "limits.lower"), unit),
                  f.number(bounds["upper"], f.join(path, "limits.upper"), unit))
        if not limits[0] < limits[1]:
            raise f.invalid(f.join(path, "limits.upper"), limits[1], f"must be > limits.lower = {limits[0]}")
    torque = "N m" if kind == "revolute" else "N"
    return JointDescription(
        name=_name(data["name"], f.join(path, "name")),
        kind=kind,
        axis=axis / length,
        origin=_origin(data.get("origin", {}), f.join(path, "origin")),
        initial=f.number(data.get("initial", 0.0), f.join(path, "initial"), unit),
        limits=limits,
        stiffness=f.number(data.get("stiffness", 0.0), f.join(path, "stiffness"), f"{torque}/{unit}", f.NON_NEGATIVE),
        damping=f.number(data.get("damping", 0.0), f.join(path, "damping"), f"{torque} s/{unit}", f.NON_NEGATIVE),
    )


def _origin(value: object, path: str) -> np.ndarray:
    """{xyz, rpy} as URDF has them: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    data = f.section(value, path, (), optional=("xyz", "rpy"))
    T = np.eye(4)
    T[:3, 3] = f.vector(data.get("xyz", [0.0, 0.0, 0.0]), f.join(path, "xyz"), "m")
    T[:3, :3] = rpy_matrix(f.vector(data.get("rpy", [0.0, 0.0, 0.0]), f.join(path, "rpy"), "rad"))
    return T


def rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) for (roll, pitch, yaw) [rad] (URDF's convention)."""
    (cr, cp, cy), (sr, sp, sy) = np.cos(rpy), np.sin(rpy)
    Rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
    Ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
    Rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return Rz @ Ry @ Rx


def _beam(value: Mapping[str, Any], path: str) -> Beam:
    data = f.section(value, path, ("length", "section", "youngs_modulus", "shear_modulus", "density", "rfe_count"),
                     optional=("damping", "vertical_axis"))
    return Beam(
        length=f.number(data["length"], f.join(path, "length"), "m", f.POSITIVE),
        section=f.beam_section(data["section"], f.join(path, "section")),
        youngs_modulus=f.number(data["youngs_modulus"], f.join(path, "youngs_modulus"), "Pa", f.POSITIVE),
        shear_modulus=f.number(data["shear_modulus"], f.join(path, "shear_modulus"), "Pa", f.POSITIVE),
        density=f.number(data["density"], f.join(path, "density"), "kg/m^3", f.POSITIVE),
        rfe_count=f.integer(data["rfe_count"], f.join(path, "rfe_count"), 1),
        damping=f.number(data.get("damping", 0.0), f.join(path, "damping"), "s", f.NON_NEGATIVE),
        vertical_axis=vertical_axis(data.get("vertical_axis", "y"), f.join(path, "vertical_axis")),
    )


def vertical_axis(value: object, path: str) -> str:
    """A beam's vertical axis, "y" or "z" (:class:`~.description.Beam`)."""
    if value not in VERTICAL_AXES:
        raise f.invalid(path, value, f"must be one of {', '.join(VERTICAL_AXES)} (the link axis that is up in the "
                                     "beam's plane of motion)")
    return str(value)
