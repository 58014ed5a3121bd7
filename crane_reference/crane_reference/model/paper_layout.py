"""The paper's crane family: crane files in the layout of the paper's crane (sections ``base``, ``column``,
``boom``, ``link4``, ``payload``, ``drive``, ``damping``, ``initial``, ``task``), read as
:class:`~crane_reference.model.parameters.CraneParameters` and turned into the
:class:`~crane_reference.model.description.CraneDescription` they describe (:func:`paper_description`): a
base on support springs, the column on ``column_slew`` (driven), the flexible boom on ``boom_luff`` and link 4
on ``knuckle``, with E and the payload at link 4's ``end_effector`` and the dependent coordinates (3.2)
psi(3,0) and psi4.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from . import fields as f
from .description import REVOLUTE, Beam, CraneDescription, JointDescription, LinkDescription, PointOnLink, SprungBase
from .parameters import Boom, CraneParameters, Damping, InitialConfiguration, LastLink, Task

SECTIONS = ("gravity", "base", "column", "boom", "link4", "payload", "drive")
"""The required top-level keys of the layout (``damping``, ``initial`` and ``task`` are optional)."""
_DAMPING_FIELDS = {"support": ("s", f.NON_NEGATIVE), "boom": ("s", f.NON_NEGATIVE)}
_INITIAL_FIELDS = {"column": ("rad", f.ANY), "boom": ("rad", f.ANY), "knuckle": ("rad", f.ANY)}
ACTUATED = ("column_slew", "boom_luff", "knuckle")
"""The paper's crane's actuated joints, psi2, psi(3,0) and psi4 (also the coordinates the paper plots)."""
DEPENDENT = ("boom_luff", "knuckle")
"""The paper's dependent coordinates (3.2), psi(3,0) and psi4."""
Z_AXIS = np.array([0.0, 0.0, 1.0])


def parse_parameters(value: object) -> CraneParameters:
    """A mapping in the paper's layout as :class:`CraneParameters` (raises :class:`~.fields.FieldError`)."""
    data = f.section(value, "", SECTIONS, optional=("damping", "initial", "task"))
    base = f.section(data["base"], "base", (*f.BODY_KEYS, "supports"))
    payload = f.section(data["payload"], "payload", ("mass",))
    return CraneParameters(
        gravity=f.number(data["gravity"], "gravity", "m/s^2", f.NON_NEGATIVE),
        base=f.rigid_body(base, "base"),
        supports=f.supports(base["supports"], "base.supports"),
        column=f.rigid_body(f.section(data["column"], "column", f.BODY_KEYS), "column"),
        boom=_boom(data["boom"], "boom"),
        link4=_last_link(data["link4"], "link4"),
        payload_mass=f.number(payload["mass"], "payload.mass", "kg", f.NON_NEGATIVE),
        drive=f.drive(data["drive"], "drive"),
        damping=f.optional_section(data.get("damping", {}), "damping", Damping, _DAMPING_FIELDS),
        initial=f.optional_section(data.get("initial", {}), "initial", InitialConfiguration, _INITIAL_FIELDS),
        task=f.optional_section(data.get("task", {}), "task", Task, f.TASK_FIELDS),
    )


def _boom(value: object, path: str) -> Boom:
    data = f.section(value, path, ("pivot", "length", "youngs_modulus", "shear_modulus", "density", "section",
                                   "rfe_count"))
    return Boom(
        pivot=f.vector(data["pivot"], f.join(path, "pivot"), "m"),
        length=f.number(data["length"], f.join(path, "length"), "m", f.POSITIVE),
        youngs_modulus=f.number(data["youngs_modulus"], f.join(path, "youngs_modulus"), "Pa", f.POSITIVE),
        shear_modulus=f.number(data["shear_modulus"], f.join(path, "shear_modulus"), "Pa", f.POSITIVE),
        density=f.number(data["density"], f.join(path, "density"), "kg/m^3", f.POSITIVE),
        section=f.beam_section(data["section"], f.join(path, "section")),
        rfe_count=f.integer(data["rfe_count"], f.join(path, "rfe_count"), 1),
    )


def _last_link(value: Mapping[str, Any], path: str) -> LastLink:
    data = f.section(value, path, (*f.BODY_KEYS, "end_effector", "offset_angle"))
    return LastLink(
        body=f.rigid_body(data, path),
        end_effector=f.vector(data["end_effector"], f.join(path, "end_effector"), "m"),
        offset_angle=f.number(data["offset_angle"], f.join(path, "offset_angle"), "rad"),
    )


def _frame(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rotation, translation
    return T


def paper_description(params: CraneParameters) -> CraneDescription:
    """The crane of ``params`` as a chain description.

    The luff frame is the column frame turned by +pi/2 about x, so that its z axis (the luff axis) is the
    column's -y axis and a positive luff lifts the boom's x axis towards the column's z axis; the knuckle
    frame is at the boom's tip, turned by link 4's ``offset_angle`` about z."""
    boom, link4 = params.boom, params.link4
    c, s = np.cos(0.5 * np.pi), np.sin(0.5 * np.pi)
    luff = _frame(np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]]), boom.pivot)
    c, s = np.cos(link4.offset_angle), np.sin(link4.offset_angle)
    knuckle = _frame(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), np.array([boom.length, 0.0, 0.0]))
    initial = params.initial
    links = (
        LinkDescription("column", None, JointDescription("column_slew", REVOLUTE, Z_AXIS, np.eye(4), initial.column),
                        body=params.column),
        LinkDescription("boom", "column", JointDescription("boom_luff", REVOLUTE, Z_AXIS, luff, initial.boom),
                        beam=Beam(boom.length, boom.section, boom.youngs_modulus, boom.shear_modulus, boom.density,
                                  boom.rfe_count, params.damping.boom)),
        LinkDescription("link4", "boom", JointDescription("knuckle", REVOLUTE, Z_AXIS, knuckle, initial.knuckle),
                        body=link4.body),
    )
    return CraneDescription(
        name="crane",
        gravity=params.gravity,
        base=SprungBase(params.base, params.supports, params.damping.support),
        links=links,
        drive=params.drive,
        drive_joint="column_slew",
        actuated=ACTUATED,
        end_effector=PointOnLink("link4", np.asarray(link4.end_effector, dtype=float)),
        dependent=DEPENDENT,
        payload=params.payload_mass,
        task=params.task,
    )
