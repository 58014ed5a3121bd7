"""Checks of single fields of a crane file, shared by its layouts (:mod:`.config`).

Each check returns the value in its model type or raises :class:`FieldError`, whose message names the dotted
path of the field, the offending value and what is allowed, e.g. ``base.mass = -3.0: must be a finite number
> 0 [kg]``; :func:`crane_reference.model.config.parse_config` prefixes the file.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping, Sequence
from typing import Any, TypeVar

import numpy as np

from .parameters import BeamSection, FlexibleDrive, RigidBody, SupportSpring, TorqueDrive

ANY = ""
POSITIVE = "> 0"
NON_NEGATIVE = ">= 0"

BODY_KEYS = ("mass", "center_of_mass", "inertia")
INERTIA_DIAGONAL = ("ixx", "iyy", "izz")
INERTIA_PRODUCTS = ("ixy", "ixz", "iyz")
SECTION_KEYS = ("area", "second_moment_y", "second_moment_z", "torsion_constant")
DRIVE_KEYS = {
    "torque": ("torque", "start", "end"),
    "flexible": ("stiffness", "travel", "start", "duration"),
}
TASK_FIELDS = {
    "ellipse_a": ("m", POSITIVE),
    "ellipse_b": ("m", POSITIVE),
    "z_increment": ("m", ANY),
    "rise_time": ("s", POSITIVE),
}
MIN_SUPPORTS = 3
# Relative slack for the triangle inequality of principal moments, so that bodies on its boundary
# (thin plates: I1 + I2 = I3 exactly) are not rejected because of rounding in the eigenvalues.
TRIANGLE_SLACK = 1e-9
# Support positions count as collinear when they deviate from a line by less than this fraction of
# their extent.
COLLINEAR_TOLERANCE = 1e-9

T = TypeVar("T")


class FieldError(Exception):
    """A problem with one field; :func:`crane_reference.model.config.parse_config` prefixes the source and
    raises ConfigError."""


def join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def invalid(path: str, value: object, requirement: str) -> FieldError:
    return FieldError(f"{path} = {value!r}: {requirement}")


def section(value: object, path: str, required: Sequence[str],
             optional: Sequence[str] = ()) -> Mapping[str, Any]:
    """``value`` as a mapping with all ``required`` keys and no keys other than ``optional`` ones."""
    allowed = ", ".join((*required, *optional))
    where = path or "the top level"
    if not isinstance(value, Mapping):
        raise invalid(path or "<top level>", value, f"must be a mapping with keys {allowed}")
    for key in value:
        if key not in required and key not in optional:
            raise FieldError(f"{join(path, str(key))}: unknown key; allowed keys of {where}: {allowed}")
    for key in required:
        if key not in value:
            raise FieldError(f"{join(path, key)}: missing; required keys of {where}: {', '.join(required)}")
    return value


def is_real(value: object) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def number(value: object, path: str, unit: str, rule: str = ANY) -> float:
    """``value`` as a finite float obeying ``rule`` (``ANY``, ``POSITIVE`` or ``NON_NEGATIVE``)."""
    requirement = f"must be a finite number{' ' + rule if rule else ''} [{unit}]"
    if not is_real(value):
        raise invalid(path, value, f"{requirement}, not a {type(value).__name__}{yaml_hint(value)}")
    number = float(value)
    if not math.isfinite(number) or (rule == POSITIVE and number <= 0) or (
            rule == NON_NEGATIVE and number < 0):
        raise invalid(path, value, requirement)
    return number


def yaml_hint(value: object) -> str:
    """A hint for numbers that YAML 1.1 reads as strings, such as ``1e6`` or ``2.1e11``."""
    if isinstance(value, str):
        try:
            float(value)
        except ValueError:
            return ""
        return " (YAML reads a number with an exponent only with a dot and a signed exponent, e.g. 2.1e+11)"
    return ""


def integer(value: object, path: str, minimum: int) -> int:
    if not isinstance(value, numbers.Integral) or isinstance(value, (bool, np.bool_)) or value < minimum:
        raise invalid(path, value, f"must be an integer >= {minimum}")
    return int(value)


def vector(value: object, path: str, unit: str, rule: str = ANY) -> np.ndarray:
    """``value`` as a float array of 3 finite numbers, each obeying ``rule``."""
    if not isinstance(value, (list, tuple, np.ndarray)) or len(value) != 3:
        element = f"finite numbers{' ' + rule if rule else ''}"
        raise invalid(path, value, f"must be a list of 3 {element} [{unit}]")
    return np.array([number(item, f"{path}[{i}]", unit, rule) for i, item in enumerate(value)])


# --- bodies ---------------------------------------------------------------------------------------


def inertia(value: object, path: str) -> np.ndarray:
    """Symmetric inertia tensor about the centre of mass from ``{ixx, iyy, izz, ixy, ixz, iyz}`` (tensor
    elements as in URDF, products default 0); positive definite, principal moments obeying the
    triangle inequality."""
    data = section(value, path, INERTIA_DIAGONAL, optional=INERTIA_PRODUCTS)
    ixx, iyy, izz = (number(data[key], join(path, key), "kg m^2") for key in INERTIA_DIAGONAL)
    ixy, ixz, iyz = (number(data.get(key, 0.0), join(path, key), "kg m^2") for key in INERTIA_PRODUCTS)
    tensor = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    i1, i2, i3 = np.linalg.eigvalsh(tensor)  # ascending
    principal = f"principal moments I1 = {i1:.6g}, I2 = {i2:.6g}, I3 = {i3:.6g} [kg m^2]"
    if i1 <= 0:
        raise invalid(path, value, f"must be positive definite (all principal moments > 0); {principal}")
    if i1 + i2 < i3 * (1 - TRIANGLE_SLACK):
        raise invalid(path, value, f"{principal} violate the triangle inequality I1 + I2 >= I3 "
                                    f"(I1 + I2 = {i1 + i2:.6g} < I3 = {i3:.6g}); each principal moment "
                                    "must not exceed the sum of the other two")
    return tensor


def rigid_body(data: Mapping[str, Any], path: str) -> RigidBody:
    return RigidBody(
        mass=number(data["mass"], join(path, "mass"), "kg", POSITIVE),
        center_of_mass=vector(data["center_of_mass"], join(path, "center_of_mass"), "m"),
        inertia=inertia(data["inertia"], join(path, "inertia")),
    )


def beam_section(value: object, path: str) -> BeamSection:
    """A beam's cross-section: area [m^2], second moments of area and torsion constant [m^4], all > 0."""
    data = section(value, path, SECTION_KEYS)
    return BeamSection(*(number(data[key], join(path, key), unit, POSITIVE)
                         for key, unit in zip(SECTION_KEYS, ("m^2", "m^4", "m^4", "m^4"), strict=True)))


def supports(value: object, path: str) -> tuple[SupportSpring, ...]:
    """At least three support springs, not all on one line, each with some stiffness."""
    if not isinstance(value, (list, tuple)) or len(value) < MIN_SUPPORTS:
        raise invalid(path, value, f"must be a list of at least {MIN_SUPPORTS} support springs "
                                    "{position: [x, y, z], stiffness: [sx, sy, sz]}")
    springs = tuple(support(item, f"{path}[{i}]") for i, item in enumerate(value))
    offsets = np.array([spring.position - springs[0].position for spring in springs])
    extent = max(float(np.max(np.linalg.norm(offsets, axis=1))), 1.0)
    if np.linalg.matrix_rank(offsets, tol=COLLINEAR_TOLERANCE * extent) < 2:
        positions = [spring.position.tolist() for spring in springs]
        raise invalid(path, positions, f"the support positions are collinear; at least {MIN_SUPPORTS} "
                                        "supports not all on one line are needed")
    return springs


def support(value: object, path: str) -> SupportSpring:
    data = section(value, path, ("position", "stiffness"))
    stiffness_path = join(path, "stiffness")
    stiffness = vector(data["stiffness"], stiffness_path, "N/m", NON_NEGATIVE)
    if not stiffness.sum() > 0:
        raise invalid(stiffness_path, data["stiffness"], "components must be >= 0 with a sum > 0 [N/m]")
    position = vector(data["position"], join(path, "position"), "m")
    return SupportSpring(position=position, stiffness=stiffness)


def drive(value: object, path: str, also: Sequence[str] = ()) -> TorqueDrive | FlexibleDrive:
    """A ``torque`` or ``flexible`` drive, each with its own keys besides ``type`` (and the keys ``also``,
    required, which the caller reads)."""
    every_key = tuple(dict.fromkeys(key for keys in DRIVE_KEYS.values() for key in keys))
    kind = section(value, path, ("type", *also), optional=every_key)["type"]
    if not (isinstance(kind, str) and kind in DRIVE_KEYS):
        raise invalid(join(path, "type"), kind, f"must be one of {', '.join(map(repr, DRIVE_KEYS))}")
    data = section(value, path, ("type", *also, *DRIVE_KEYS[kind]))
    start = number(data["start"], join(path, "start"), "s", NON_NEGATIVE)
    if kind == "flexible":
        return FlexibleDrive(
            stiffness=number(data["stiffness"], join(path, "stiffness"), "N m/rad", POSITIVE),
            travel=number(data["travel"], join(path, "travel"), "rad"),
            start=start,
            duration=number(data["duration"], join(path, "duration"), "s", POSITIVE),
        )
    end = number(data["end"], join(path, "end"), "s")
    if end <= start:
        raise invalid(join(path, "end"), data["end"], f"must be > {path}.start = {start} [s]")
    return TorqueDrive(torque=number(data["torque"], join(path, "torque"), "N m"), start=start, end=end)


def optional_section(value: object, path: str, cls: type[T], fields: Mapping[str, tuple[str, str]]) -> T:
    """Dataclass ``cls`` from a section whose keys are all optional (defaults from ``cls()``);
    ``fields`` maps each key to its unit and rule."""
    data = section(value, path, (), optional=tuple(fields))
    defaults = cls()
    return cls(**{key: number(data.get(key, getattr(defaults, key)), join(path, key), unit, rule)
                  for key, (unit, rule) in fields.items()})
