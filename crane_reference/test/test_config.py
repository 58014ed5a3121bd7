"""Tests of crane_reference.model.config on crane files in the paper's layout (the packaged crane's numbers, in
data/paper_layout_crane.yaml): its values and the validation of bad input.  The description layout's own tests
are in test_description.py."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from cranes import PAPER_LAYOUT, expect_config_error

from crane_reference.model.chain import build_model
from crane_reference.model.config import ConfigError, default_config_path, load_config, parse_config
from crane_reference.model.paper_layout import parse_parameters
from crane_reference.model.parameters import CraneParameters, FlexibleDrive, RigidBody, TorqueDrive

DEFAULT_YAML = Path(__file__).resolve().parent.parent / "config" / "crane.yaml"

# Rectangular hollow section 250 x 150 x 8 mm: h along the boom's y axis, w along its z axis.
H, W, T = 0.25, 0.15, 0.008
HI, WI = H - 2 * T, W - 2 * T


_DEFAULT_DATA = yaml.safe_load(PAPER_LAYOUT.read_text(encoding="utf-8"))


@pytest.fixture
def data() -> dict[str, Any]:
    """A fresh, modifiable copy of the paper-layout YAML as parsed by yaml.safe_load."""
    return copy.deepcopy(_DEFAULT_DATA)




# --- the default crane ----------------------------------------------------------------------------


def test_default_path_is_the_packaged_file() -> None:
    assert default_config_path() == DEFAULT_YAML


def test_default_loads_with_expected_values(paper_params: CraneParameters) -> None:
    params = paper_params
    assert params.gravity == 9.81
    assert params.base.mass == 3000.0
    np.testing.assert_array_equal(params.base.center_of_mass, [0.0, 0.0, -0.3])
    assert len(params.supports) == 8
    for spring in params.supports:
        assert spring.position[2] == -0.6 and abs(spring.position[1]) == 1.2
        np.testing.assert_array_equal(spring.stiffness, [1.0e6, 1.0e6, 2.0e6])
    assert sorted({float(s.position[0]) for s in params.supports}) == [-1.8, -0.6, 0.6, 1.8]
    assert params.column.mass == 300.0
    assert params.boom.rfe_count == 6
    assert params.boom.length == 2.546
    boom = params.boom
    assert (boom.youngs_modulus, boom.shear_modulus, boom.density) == (2.1e11, 8.1e10, 7850.0)
    assert params.link4.body.mass == 50.0
    np.testing.assert_array_equal(params.link4.end_effector, [1.2, 0.0, 0.0])
    assert params.payload_mass == 500.0
    assert params.drive == TorqueDrive(torque=4000.0, start=0.0, end=1.0)
    assert (params.damping.support, params.damping.boom) == (0.0, 0.0)
    assert params.initial.column == pytest.approx(1.5 * math.pi)
    assert params.initial.boom == pytest.approx(0.25 * math.pi)
    assert params.initial.knuckle == pytest.approx(1.5 * math.pi)
    assert (params.task.ellipse_a, params.task.ellipse_b, params.task.z_increment) == (3.0, 2.0, 0.2)
    assert params.task.rise_time == 5.0


def test_default_arrays_are_float(paper_params: CraneParameters) -> None:
    params = paper_params
    for body in (params.base, params.column, params.link4.body):
        assert body.center_of_mass.shape == (3,) and body.center_of_mass.dtype == float
        assert body.inertia.shape == (3, 3) and body.inertia.dtype == float
        np.testing.assert_array_equal(body.inertia, body.inertia.T)
    assert params.boom.pivot.shape == (3,) and params.boom.pivot.dtype == float
    assert isinstance(params.boom.rfe_count, int)


def test_boom_section_is_the_rectangular_hollow_section(paper_params: CraneParameters) -> None:
    params = paper_params
    section = params.boom.section
    area = W * H - WI * HI
    mid_area = (H - T) * (W - T)
    mid_perimeter = 2 * ((H - T) + (W - T))
    assert section.area == pytest.approx(area, rel=1e-6)
    assert section.second_moment_z == pytest.approx((W * H**3 - WI * HI**3) / 12, rel=1e-6)
    assert section.second_moment_y == pytest.approx((H * W**3 - HI * WI**3) / 12, rel=1e-6)
    assert section.torsion_constant == pytest.approx(4 * mid_area**2 * T / mid_perimeter, rel=1e-6)
    assert section.second_moment_z > section.second_moment_y  # stiffer in the luffing plane


def test_boom_tip_is_two_metres_from_the_column_axis(paper_params: CraneParameters) -> None:
    params = paper_params
    reach = params.boom.pivot[0] + params.boom.length * math.cos(params.initial.boom)
    assert reach == pytest.approx(2.0, abs=1e-4)


def test_link4_hangs_vertically_in_the_initial_configuration(paper_params: CraneParameters) -> None:
    params = paper_params
    angle = params.initial.boom + params.initial.knuckle + params.link4.offset_angle
    assert (math.cos(angle), math.sin(angle)) == pytest.approx((0.0, -1.0), abs=1e-12)


def test_box_inertia_of_the_base(paper_params: CraneParameters) -> None:
    params = paper_params
    m, a, b, c = 3000.0, 4.0, 2.4, 0.6
    expected = np.diag([b**2 + c**2, a**2 + c**2, a**2 + b**2]) * m / 12
    np.testing.assert_allclose(params.base.inertia, expected)


@pytest.mark.parametrize("name", ["base", "column", "link4"])
def test_pseudo_inertia_identities(paper_params: CraneParameters, name: str) -> None:
    params = paper_params
    body: RigidBody = params.link4.body if name == "link4" else getattr(params, name)
    H = body.pseudo_inertia()
    c = body.center_of_mass
    assert H[3, 3] == body.mass
    np.testing.assert_allclose(H[:3, 3], body.mass * c)
    np.testing.assert_allclose(H, H.T)
    # tr(J_c) = integral of |r - c|^2 dm = tr(I_c) / 2.
    assert np.trace(H[:3, :3]) - body.mass * c @ c == pytest.approx(np.trace(body.inertia) / 2)


def test_load_config_with_explicit_path_equals_default() -> None:
    explicit, default = (build_model(load_config(path), "flexible") for path in (str(DEFAULT_YAML), None))
    assert explicit.joint_names == default.joint_names
    for a, b in zip(explicit.bodies, default.bodies, strict=True):
        np.testing.assert_array_equal(a.inertia.pseudo_inertia(), b.inertia.pseudo_inertia())


def test_optional_sections_default(data: dict[str, Any]) -> None:
    for key in ("damping", "initial", "task"):
        del data[key]
    data["damping"] = {"boom": 0.01}
    params = parse_parameters(data)
    assert (params.damping.support, params.damping.boom) == (0.0, 0.01)
    assert params.initial.knuckle == pytest.approx(1.5 * math.pi)
    assert params.task.rise_time == 5.0


def test_ints_are_accepted_for_floats(data: dict[str, Any]) -> None:
    data["base"]["mass"] = 3000
    params = parse_parameters(data)
    assert params.base.mass == 3000.0 and isinstance(params.base.mass, float)


def test_inertia_products(data: dict[str, Any]) -> None:
    data["column"]["inertia"]["ixy"] = 1.5
    np.testing.assert_array_equal(parse_parameters(data).column.inertia[0:2, 0:2], [[62.25, 1.5], [1.5, 62.25]])


def test_flexible_drive(data: dict[str, Any]) -> None:
    data["drive"] = {"type": "flexible", "stiffness": 1.0e5, "travel": 1.0, "start": 0.0, "duration": 4.0}
    assert parse_config(data).drive == FlexibleDrive(stiffness=1.0e5, travel=1.0, start=0.0, duration=4.0)


# --- bad input ------------------------------------------------------------------------------------


def test_negative_mass(data: dict[str, Any]) -> None:
    data["base"]["mass"] = -3.0
    message = expect_config_error(data, "base.mass = -3.0", "must be a finite number > 0 [kg]")
    assert message == "crane.yaml: base.mass = -3.0: must be a finite number > 0 [kg]"


def test_negative_payload_mass(data: dict[str, Any]) -> None:
    data["payload"]["mass"] = -1.0
    expect_config_error(data, "payload.mass = -1.0", ">= 0 [kg]")


def test_inertia_not_positive_definite(data: dict[str, Any]) -> None:
    data["column"]["inertia"]["ixy"] = 70.0  # eigenvalues 62.25 -+ 70 -> one negative
    expect_config_error(data, "column.inertia", "must be positive definite", "I1 = -7.75")


def test_inertia_triangle_inequality(data: dict[str, Any]) -> None:
    data["base"]["inertia"] = {"ixx": 1000.0, "iyy": 2000.0, "izz": 5000.0}
    expect_config_error(data, "base.inertia", "triangle inequality I1 + I2 >= I3", "I1 = 1000", "I2 = 2000",
                 "I3 = 5000")


@pytest.mark.parametrize("count", [0, 2.5, True])
def test_rfe_count(data: dict[str, Any], count: object) -> None:
    data["boom"]["rfe_count"] = count
    expect_config_error(data, f"boom.rfe_count = {count!r}", "must be an integer >= 1")


def test_missing_key(data: dict[str, Any]) -> None:
    del data["boom"]["section"]["area"]
    expect_config_error(data, "boom.section.area", "missing", "torsion_constant")


def test_missing_section(data: dict[str, Any]) -> None:
    del data["drive"]
    expect_config_error(data, "drive: missing")


def test_unknown_key(data: dict[str, Any]) -> None:
    data["base"]["colour"] = "yellow"
    expect_config_error(data, "base.colour: unknown key",
                 "allowed keys of base: mass, center_of_mass, inertia, supports")


def test_string_for_a_number(data: dict[str, Any]) -> None:
    data["boom"]["length"] = "long"
    expect_config_error(data, "boom.length = 'long'", "must be a finite number > 0 [m]", "not a str")


def test_yaml_exponent_without_sign_is_explained(data: dict[str, Any]) -> None:
    data["boom"]["youngs_modulus"] = "2.1e11"  # what PyYAML makes of 2.1e11
    expect_config_error(data, "boom.youngs_modulus = '2.1e11'", "> 0 [Pa]", "2.1e+11")


def test_bool_for_a_number(data: dict[str, Any]) -> None:
    data["payload"]["mass"] = True
    expect_config_error(data, "payload.mass = True", "must be a finite number >= 0 [kg]", "not a bool")


@pytest.mark.parametrize("value", [math.nan, math.inf])
def test_not_finite(data: dict[str, Any], value: float) -> None:
    data["base"]["supports"][3]["stiffness"][2] = value
    expect_config_error(data, f"base.supports[3].stiffness[2] = {value!r}", "must be a finite number >= 0 [N/m]")


def test_support_without_stiffness(data: dict[str, Any]) -> None:
    data["base"]["supports"][5]["stiffness"] = [0.0, 0.0, 0.0]
    expect_config_error(data, "base.supports[5].stiffness", "sum > 0")


def test_vector_of_wrong_length(data: dict[str, Any]) -> None:
    data["link4"]["end_effector"] = [1.2, 0.0]
    expect_config_error(data, "link4.end_effector = [1.2, 0.0]", "list of 3 finite numbers [m]")


def test_unknown_drive_type(data: dict[str, Any]) -> None:
    data["drive"]["type"] = "hydraulic"
    expect_config_error(data, "drive.type = 'hydraulic'", "must be one of 'torque', 'flexible'")


def test_drive_ends_before_it_starts(data: dict[str, Any]) -> None:
    data["drive"]["end"] = 0.0
    expect_config_error(data, "drive.end = 0.0", "must be > drive.start = 0.0 [s]")


def test_keys_of_the_other_drive_type(data: dict[str, Any]) -> None:
    data["drive"]["duration"] = 2.0
    expect_config_error(data, "drive.duration: unknown key", "type, torque, start, end")


def test_collinear_supports(data: dict[str, Any]) -> None:
    for spring in data["base"]["supports"]:
        spring["position"][1] = 0.0
    expect_config_error(data, "base.supports = ", "collinear", "at least 3")


def test_too_few_supports(data: dict[str, Any]) -> None:
    data["base"]["supports"] = data["base"]["supports"][:2]
    expect_config_error(data, "base.supports", "at least 3 support springs")


def test_top_level_not_a_mapping() -> None:
    expect_config_error([], "must be a mapping")  # type: ignore[arg-type]


def test_yaml_syntax_error_names_the_file(tmp_path: Path) -> None:
    broken = tmp_path / "broken_crane.yaml"
    broken.write_text("gravity: 9.81\nbase: {mass: [3000.0\n", encoding="utf-8")
    with pytest.raises(ConfigError, match=r"broken_crane\.yaml: not valid YAML"):
        load_config(broken)


def test_invalid_file_names_the_file(tmp_path: Path, data: dict[str, Any]) -> None:
    data["gravity"] = -9.81
    path = tmp_path / "bad_gravity.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    expected = r"bad_gravity\.yaml: gravity = -9\.81: must be a finite number >= 0 \[m/s\^2\]"
    with pytest.raises(ConfigError, match=expected):
        load_config(path)


def test_missing_file(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match=r"nowhere\.yaml: cannot read"):
        load_config(tmp_path / "nowhere.yaml")


def test_yaml_1_2_exponent_floats_are_numbers(tmp_path):
    """PyYAML (YAML 1.1) reads ``2.1e11`` as a string; the loader accepts it as the number it is."""
    text = default_config_path().read_text().replace("2.1e+11", "2.1e11").replace("8.1e+10", "81e9")
    path = tmp_path / "exponents.yaml"
    path.write_text(text)
    beam = load_config(path).flexible_links[0].beam
    assert beam.youngs_modulus == 2.1e11
    assert beam.shear_modulus == 8.1e10
