"""Loading and validation of the crane description ``config/crane.yaml``.

:func:`load_config` reads a YAML file (by default the packaged ``config/crane.yaml``) and
:func:`parse_config` turns the parsed mapping into :class:`~crane_reference.model.parameters.CraneParameters`.
Every problem raises :class:`ConfigError` whose message names the source, the dotted path of the
field, the offending value and what is allowed, e.g.::

    crane.yaml: base.mass = -3.0: must be a finite number > 0 [kg]
"""

from __future__ import annotations

import math
import numbers
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import yaml

from crane_reference.model.parameters import (
    BeamSection,
    Boom,
    CraneParameters,
    Damping,
    FlexibleDrive,
    InitialConfiguration,
    LastLink,
    RigidBody,
    SupportSpring,
    Task,
    TorqueDrive,
)

PACKAGE = "crane_reference"
DEFAULT_FILE = Path("config") / "crane.yaml"

_ANY = ""
_POSITIVE = "> 0"
_NON_NEGATIVE = ">= 0"

_BODY_KEYS = ("mass", "center_of_mass", "inertia")
_INERTIA_DIAGONAL = ("ixx", "iyy", "izz")
_INERTIA_PRODUCTS = ("ixy", "ixz", "iyz")
_SECTION_KEYS = ("area", "second_moment_y", "second_moment_z", "torsion_constant")
_DRIVE_KEYS = {
    "torque": ("torque", "start", "end"),
    "flexible": ("stiffness", "travel", "start", "duration"),
}
# Optional sections: key -> (unit, rule); defaults from the dataclasses.
_DAMPING_FIELDS = {"support": ("s", _NON_NEGATIVE), "boom": ("s", _NON_NEGATIVE)}
_INITIAL_FIELDS = {"column": ("rad", _ANY), "boom": ("rad", _ANY), "knuckle": ("rad", _ANY)}
_TASK_FIELDS = {
    "ellipse_a": ("m", _POSITIVE),
    "ellipse_b": ("m", _POSITIVE),
    "z_increment": ("m", _ANY),
    "rise_time": ("s", _POSITIVE),
}
_MIN_SUPPORTS = 3
# Relative slack for the triangle inequality of principal moments, so that bodies on its boundary
# (thin plates: I1 + I2 = I3 exactly) are not rejected because of rounding in the eigenvalues.
_TRIANGLE_SLACK = 1e-9
# Support positions count as collinear when they deviate from a line by less than this fraction of
# their extent.
_COLLINEAR_TOLERANCE = 1e-9


_T = TypeVar("_T", Damping, InitialConfiguration, Task)


class ConfigError(ValueError):
    """An invalid or unreadable crane configuration."""


class _FieldError(Exception):
    """A problem with one field; :func:`parse_config` prefixes the source and raises ConfigError."""


def default_config_path() -> Path:
    """The packaged ``config/crane.yaml``: next to the package source (a source checkout or an
    editable install), else in the package's ament share directory (an installed ROS package)."""
    source_tree = Path(__file__).resolve().parents[2] / DEFAULT_FILE
    if source_tree.is_file():
        return source_tree
    try:
        from ament_index_python.packages import get_package_share_directory

        installed = Path(get_package_share_directory(PACKAGE)) / DEFAULT_FILE
    except (ImportError, LookupError, OSError) as err:
        raise ConfigError(f"no default configuration: {source_tree} does not exist and the ament "
                          f"index has no share directory for {PACKAGE} ({err})") from err
    if not installed.is_file():
        raise ConfigError(f"no default configuration: neither {source_tree} nor {installed} exists")
    return installed


class _Yaml12FloatLoader(yaml.SafeLoader):
    """SafeLoader that also reads YAML 1.2 floats such as ``1e6`` and ``2.1e11`` as numbers (YAML 1.1,
    which PyYAML implements, requires a dot and a signed exponent)."""


_Yaml12FloatLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:\d+\.?\d*|\.\d+)[eE][-+]?\d+$"),
    list("-+0123456789."),
)


def load_config(path: str | os.PathLike[str] | None = None) -> CraneParameters:
    """Read and validate a crane description; ``None`` loads :func:`default_config_path`.

    Raises :class:`ConfigError` (naming the file) if the file cannot be read, is not valid YAML or
    does not describe a valid crane.
    """
    file = default_config_path() if path is None else Path(path)
    try:
        with file.open(encoding="utf-8") as stream:
            data = yaml.load(stream, Loader=_Yaml12FloatLoader)
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f"{file}: cannot read: {err}") from err
    except yaml.YAMLError as err:
        raise ConfigError(f"{file}: not valid YAML: {err}") from err
    return parse_config(data, source=str(file))


def parse_config(data: Mapping[str, Any], source: str = "<dict>") -> CraneParameters:
    """Validate a crane description (the mapping ``yaml.safe_load`` gives for ``crane.yaml``).

    ``source`` names the origin of ``data`` in error messages.  Vectors become float arrays of shape
    (3,), inertia tensors float arrays of shape (3, 3).  The sections ``damping``, ``initial`` and
    ``task`` and each of their keys are optional (defaults from :mod:`crane_reference.model.parameters`).
    """
    try:
        return _crane(data)
    except _FieldError as err:
        raise ConfigError(f"{source}: {err}") from None


def _crane(value: object) -> CraneParameters:
    data = _section(value, "", ("gravity", "base", "column", "boom", "link4", "payload", "drive"),
                    optional=("damping", "initial", "task"))
    base = _section(data["base"], "base", (*_BODY_KEYS, "supports"))
    payload = _section(data["payload"], "payload", ("mass",))
    return CraneParameters(
        gravity=_number(data["gravity"], "gravity", "m/s^2", _NON_NEGATIVE),
        base=_rigid_body(base, "base"),
        supports=_supports(base["supports"], "base.supports"),
        column=_rigid_body(_section(data["column"], "column", _BODY_KEYS), "column"),
        boom=_boom(data["boom"], "boom"),
        link4=_last_link(data["link4"], "link4"),
        payload_mass=_number(payload["mass"], "payload.mass", "kg", _NON_NEGATIVE),
        drive=_drive(data["drive"], "drive"),
        damping=_optional_section(data.get("damping", {}), "damping", Damping, _DAMPING_FIELDS),
        initial=_optional_section(data.get("initial", {}), "initial", InitialConfiguration, _INITIAL_FIELDS),
        task=_optional_section(data.get("task", {}), "task", Task, _TASK_FIELDS),
    )


# --- generic checks -------------------------------------------------------------------------------


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _invalid(path: str, value: object, requirement: str) -> _FieldError:
    return _FieldError(f"{path} = {value!r}: {requirement}")


def _section(value: object, path: str, required: Sequence[str],
             optional: Sequence[str] = ()) -> Mapping[str, Any]:
    """``value`` as a mapping with all ``required`` keys and no keys other than ``optional`` ones."""
    allowed = ", ".join((*required, *optional))
    where = path or "the top level"
    if not isinstance(value, Mapping):
        raise _invalid(path or "<top level>", value, f"must be a mapping with keys {allowed}")
    for key in value:
        if key not in required and key not in optional:
            raise _FieldError(f"{_join(path, str(key))}: unknown key; allowed keys of {where}: {allowed}")
    for key in required:
        if key not in value:
            raise _FieldError(f"{_join(path, key)}: missing; required keys of {where}: {', '.join(required)}")
    return value


def _is_real(value: object) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_))


def _number(value: object, path: str, unit: str, rule: str = _ANY) -> float:
    """``value`` as a finite float obeying ``rule`` (``_ANY``, ``_POSITIVE`` or ``_NON_NEGATIVE``)."""
    requirement = f"must be a finite number{' ' + rule if rule else ''} [{unit}]"
    if not _is_real(value):
        raise _invalid(path, value, f"{requirement}, not a {type(value).__name__}{_yaml_hint(value)}")
    number = float(value)
    if not math.isfinite(number) or (rule == _POSITIVE and number <= 0) or (
            rule == _NON_NEGATIVE and number < 0):
        raise _invalid(path, value, requirement)
    return number


def _yaml_hint(value: object) -> str:
    """A hint for numbers that YAML 1.1 reads as strings, such as ``1e6`` or ``2.1e11``."""
    if isinstance(value, str):
        try:
            float(value)
        except ValueError:
            return ""
        return " (YAML reads a number with an exponent only with a dot and a signed exponent, e.g. 2.1e+11)"
    return ""


def _integer(value: object, path: str, minimum: int) -> int:
    if not isinstance(value, numbers.Integral) or isinstance(value, (bool, np.bool_)) or value < minimum:
        raise _invalid(path, value, f"must be an integer >= {minimum}")
    return int(value)


def _vector(value: object, path: str, unit: str, rule: str = _ANY) -> np.ndarray:
    """``value`` as a float array of 3 finite numbers, each obeying ``rule``."""
    if not isinstance(value, (list, tuple, np.ndarray)) or len(value) != 3:
        element = f"finite numbers{' ' + rule if rule else ''}"
        raise _invalid(path, value, f"must be a list of 3 {element} [{unit}]")
    return np.array([_number(item, f"{path}[{i}]", unit, rule) for i, item in enumerate(value)])


# --- bodies ---------------------------------------------------------------------------------------


def _inertia(value: object, path: str) -> np.ndarray:
    """Symmetric inertia tensor about the centre of mass from ``{ixx, iyy, izz, ixy, ixz, iyz}`` (tensor
    elements as in URDF, products default 0); positive definite, principal moments obeying the
    triangle inequality."""
    data = _section(value, path, _INERTIA_DIAGONAL, optional=_INERTIA_PRODUCTS)
    ixx, iyy, izz = (_number(data[key], _join(path, key), "kg m^2") for key in _INERTIA_DIAGONAL)
    ixy, ixz, iyz = (_number(data.get(key, 0.0), _join(path, key), "kg m^2") for key in _INERTIA_PRODUCTS)
    tensor = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
    i1, i2, i3 = np.linalg.eigvalsh(tensor)  # ascending
    principal = f"principal moments I1 = {i1:.6g}, I2 = {i2:.6g}, I3 = {i3:.6g} [kg m^2]"
    if i1 <= 0:
        raise _invalid(path, value, f"must be positive definite (all principal moments > 0); {principal}")
    if i1 + i2 < i3 * (1 - _TRIANGLE_SLACK):
        raise _invalid(path, value, f"{principal} violate the triangle inequality I1 + I2 >= I3 "
                                    f"(I1 + I2 = {i1 + i2:.6g} < I3 = {i3:.6g}); each principal moment "
                                    "must not exceed the sum of the other two")
    return tensor


def _rigid_body(data: Mapping[str, Any], path: str) -> RigidBody:
    return RigidBody(
        mass=_number(data["mass"], _join(path, "mass"), "kg", _POSITIVE),
        center_of_mass=_vector(data["center_of_mass"], _join(path, "center_of_mass"), "m"),
        inertia=_inertia(data["inertia"], _join(path, "inertia")),
    )


def _supports(value: object, path: str) -> tuple[SupportSpring, ...]:
    """At least three support springs, not all on one line, each with some stiffness."""
    if not isinstance(value, (list, tuple)) or len(value) < _MIN_SUPPORTS:
        raise _invalid(path, value, f"must be a list of at least {_MIN_SUPPORTS} support springs "
                                    "{position: [x, y, z], stiffness: [sx, sy, sz]}")
    springs = tuple(_support(item, f"{path}[{i}]") for i, item in enumerate(value))
    offsets = np.array([spring.position - springs[0].position for spring in springs])
    extent = max(float(np.max(np.linalg.norm(offsets, axis=1))), 1.0)
    if np.linalg.matrix_rank(offsets, tol=_COLLINEAR_TOLERANCE * extent) < 2:
        positions = [spring.position.tolist() for spring in springs]
        raise _invalid(path, positions, f"the support positions are collinear; at least {_MIN_SUPPORTS} "
                                        "supports not all on one line are needed")
    return springs


def _support(value: object, path: str) -> SupportSpring:
    data = _section(value, path, ("position", "stiffness"))
    stiffness_path = _join(path, "stiffness")
    stiffness = _vector(data["stiffness"], stiffness_path, "N/m", _NON_NEGATIVE)
    if not stiffness.sum() > 0:
        raise _invalid(stiffness_path, data["stiffness"], "components must be >= 0 with a sum > 0 [N/m]")
    position = _vector(data["position"], _join(path, "position"), "m")
    return SupportSpring(position=position, stiffness=stiffness)


def _boom(value: object, path: str) -> Boom:
    data = _section(value, path, ("pivot", "length", "youngs_modulus", "shear_modulus", "density", "section",
                                  "rfe_count"))
    section_path = _join(path, "section")
    section = _section(data["section"], section_path, _SECTION_KEYS)
    area, second_moment_y, second_moment_z, torsion_constant = (
        _number(section[key], _join(section_path, key), unit, _POSITIVE)
        for key, unit in zip(_SECTION_KEYS, ("m^2", "m^4", "m^4", "m^4"), strict=True)
    )
    return Boom(
        pivot=_vector(data["pivot"], _join(path, "pivot"), "m"),
        length=_number(data["length"], _join(path, "length"), "m", _POSITIVE),
        youngs_modulus=_number(data["youngs_modulus"], _join(path, "youngs_modulus"), "Pa", _POSITIVE),
        shear_modulus=_number(data["shear_modulus"], _join(path, "shear_modulus"), "Pa", _POSITIVE),
        density=_number(data["density"], _join(path, "density"), "kg/m^3", _POSITIVE),
        section=BeamSection(area, second_moment_y, second_moment_z, torsion_constant),
        rfe_count=_integer(data["rfe_count"], _join(path, "rfe_count"), 1),
    )


def _last_link(value: object, path: str) -> LastLink:
    data = _section(value, path, (*_BODY_KEYS, "end_effector", "offset_angle"))
    return LastLink(
        body=_rigid_body(data, path),
        end_effector=_vector(data["end_effector"], _join(path, "end_effector"), "m"),
        offset_angle=_number(data["offset_angle"], _join(path, "offset_angle"), "rad"),
    )


# --- drive and optional sections ------------------------------------------------------------------


def _drive(value: object, path: str) -> TorqueDrive | FlexibleDrive:
    """A ``torque`` or ``flexible`` drive, each with its own keys besides ``type``."""
    every_key = tuple(dict.fromkeys(key for keys in _DRIVE_KEYS.values() for key in keys))
    kind = _section(value, path, ("type",), optional=every_key)["type"]
    if not (isinstance(kind, str) and kind in _DRIVE_KEYS):
        raise _invalid(_join(path, "type"), kind, f"must be one of {', '.join(map(repr, _DRIVE_KEYS))}")
    data = _section(value, path, ("type", *_DRIVE_KEYS[kind]))
    start = _number(data["start"], _join(path, "start"), "s", _NON_NEGATIVE)
    if kind == "flexible":
        return FlexibleDrive(
            stiffness=_number(data["stiffness"], _join(path, "stiffness"), "N m/rad", _POSITIVE),
            travel=_number(data["travel"], _join(path, "travel"), "rad"),
            start=start,
            duration=_number(data["duration"], _join(path, "duration"), "s", _POSITIVE),
        )
    end = _number(data["end"], _join(path, "end"), "s")
    if end <= start:
        raise _invalid(_join(path, "end"), data["end"], f"must be > {path}.start = {start} [s]")
    return TorqueDrive(torque=_number(data["torque"], _join(path, "torque"), "N m"), start=start, end=end)


def _optional_section(value: object, path: str, cls: type[_T], fields: Mapping[str, tuple[str, str]]) -> _T:
    """Dataclass ``cls`` from a section whose keys are all optional (defaults from ``cls()``);
    ``fields`` maps each key to its unit and rule."""
    data = _section(value, path, (), optional=tuple(fields))
    defaults = cls()
    return cls(**{key: _number(data.get(key, getattr(defaults, key)), _join(path, key), unit, rule)
                  for key, (unit, rule) in fields.items()})
