"""The default programmed motion: constraints, the z quintic, energy balance, export and CLI.

Independent truths: eq. (5.2) written out here, the ellipse equation, the work-energy theorem with the
work integrated by DOP853 as extra ODE states, and file round trips.
"""

from __future__ import annotations

import subprocess
import sys
import xml.etree.ElementTree as ET
from dataclasses import fields, replace

import numpy as np
import pytest
from convergence import errors_against_dop853

from crane_reference.model.config import default_config_path
from crane_reference.model.parameters import FlexibleDrive
from crane_reference.motion.simulation import Scenario, simulate, simulate_reference
from crane_reference.motion.trajectory import Trajectory


@pytest.fixture(scope="module")
def flexible_run(params):
    scenario = Scenario(params, "flexible")
    return scenario, simulate(scenario.motion, scenario.equilibrium.q, 10.0, step=1e-3)


def quintic_z(t: np.ndarray, z_s: float, z_inc: float, t_c: float) -> np.ndarray:
    """Eq. (5.2) as printed in the paper."""
    rise = z_s + 10 * z_inc / t_c**3 * t**3 - 15 * z_inc / t_c**4 * t**4 + 6 * z_inc / t_c**5 * t**5
    return np.where(t < t_c, rise, z_s + z_inc)


def test_default_motion_meets_the_programmed_constraints(params, flexible_run):
    scenario, tr = flexible_run
    x, y, z = tr.ee_position.T
    task = params.task
    assert np.max(np.abs((x / task.ellipse_a) ** 2 + (y / task.ellipse_b) ** 2 - 1.0)) <= 1e-9
    assert np.max(np.abs(z - quintic_z(tr.t, scenario.z_static, task.z_increment, task.rise_time))) <= 1e-9
    assert tr.residual_distance.max() <= 1e-9
    # the crane really moves: the drive slews it by more than a turn in 10 s
    assert tr.coordinate("column_slew")[-1] - tr.coordinate("column_slew")[0] > 2 * np.pi


def test_starts_on_the_ellipse_where_configuration_9_puts_e(params, flexible_run):
    scenario, tr = flexible_run
    assert np.allclose(tr.ee_position[0], [0.0, -params.task.ellipse_b, scenario.z_static], atol=1e-12)
    q9 = scenario.model.initial_q
    assert scenario.dynamics.end_effector(q9)[0] == pytest.approx([0.0, -2.0, scenario.z_static], abs=1e-12)


@pytest.mark.slow
def test_residuals_stay_below_1e_9_m_over_60_s(params):
    scenario = Scenario(params, "flexible")
    tr = simulate(scenario.motion, scenario.equilibrium.q, 60.0, step=2e-3)
    assert tr.t[-1] == pytest.approx(60.0)
    assert tr.residual_distance.max() <= 1e-9


@pytest.mark.slow
@pytest.mark.parametrize(("variant", "duration"), [("rigid", 10.0), ("flexible", 1.2)])
def test_energy_balance_of_the_converged_motion(params, variant, duration):
    """E(t) - E(0) = work of drive + constraint forces (no dampers by default), both integrated as
    ODE states by DOP853 at tight tolerance; relative to the largest work done."""
    scenario = Scenario(params, variant)
    times = np.linspace(0.0, duration, 201)
    tr = simulate_reference(scenario.motion, scenario.equilibrium.q, duration, times, rtol=1e-10, atol=1e-12)
    scale = np.max(np.abs(tr.work_drive) + np.abs(tr.work_constraints))
    assert scale > 1e3  # J: the drive really works
    assert np.max(np.abs(tr.energy_balance_error)) <= 1e-6 * scale


def test_energy_balance_is_second_order(params):
    """The integrator has no numerical dissipation of the resolved modes: the energy-balance error of the
    rigid model falls about fourfold when the step halves (second order), and is small."""
    scenario = Scenario(params, "rigid")
    errors = []
    for step in (4e-3, 2e-3):
        tr = simulate(scenario.motion, scenario.equilibrium.q, 3.0, step=step)
        errors.append(np.max(np.abs(tr.energy_balance_error)) / np.max(np.abs(tr.work_drive)))
    assert errors[1] < errors[0] / 3.0
    assert errors[1] < 1e-4


def test_integrator_converges_with_second_order_across_the_drive_jump(params):
    """Rigid crane over 2 s, through the torque switch-off at t = 1 s, against DOP853 at rtol 1e-11:
    halving the step cuts the largest coordinate error about fourfold (an O(h) slip at the jump,
    e.g. the last step of the pulse taken with the torque already off, would halve it only)."""
    scenario = Scenario(params, "rigid")
    errors = errors_against_dop853(scenario.motion, scenario.equilibrium.q, 2.0, (2e-3, 1e-3), 2e-3)
    assert errors[0] / errors[1] >= 3.5, f"errors {errors}: not second order"
    assert errors[1] <= 5e-5


def test_csv_and_npz_round_trip(tmp_path, flexible_run):
    _, tr = flexible_run
    tr.to_csv(tmp_path / "run.csv")
    tr.to_npz(tmp_path / "run.npz")
    header = (tmp_path / "run.csv").read_text().splitlines()[0].split(",")
    assert header[: 1 + len(tr.joint_names) + 3] == ["t", *tr.joint_names, "ee_x", "ee_y", "ee_z"]
    data = np.loadtxt(tmp_path / "run.csv", delimiter=",", skiprows=1)
    assert np.array_equal(data[:, 0], tr.t)  # full double precision
    assert np.array_equal(data[:, 1 : 1 + len(tr.joint_names)], tr.q)
    back = Trajectory.from_npz(tmp_path / "run.npz")
    assert back.joint_names == tr.joint_names
    assert np.array_equal(back.q, tr.q) and np.array_equal(back.ee_quaternion, tr.ee_quaternion)


def test_interpolation_reconstructs_dropped_samples(params):
    """Keep every other sample of a 1 ms run, interpolate at the dropped instants: the cubic Hermite
    reconstruction agrees with the dropped samples (rigid model, whose motion is resolved at 2 ms; the
    flexible boom's 213 Hz ringing is not)."""
    scenario = Scenario(params, "rigid")
    tr = simulate(scenario.motion, scenario.equilibrium.q, 0.8, step=1e-3)
    keep = slice(0, 801, 2)
    kept = Trajectory(**{f.name: (getattr(tr, f.name)[keep] if isinstance(getattr(tr, f.name), np.ndarray)
                                  else getattr(tr, f.name)) for f in fields(Trajectory)})
    dropped = slice(1, 800, 2)
    q, qd, p = kept.interpolate(tr.t[dropped])
    slow = [tr.joint_names.index(n) for n in ("column_slew", "boom_luff", "knuckle")]
    assert np.max(np.abs(q[:, slow] - tr.q[dropped][:, slow])) < 1e-7
    assert np.max(np.abs(qd[:, slow] - tr.qd[dropped][:, slow])) < 1e-5
    assert np.max(np.abs(p - tr.ee_position[dropped])) < 1e-7


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "crane_reference.cli", *args], capture_output=True, text=True,
                          timeout=300)


def test_cli_urdf_lists_the_joints_in_coordinate_order(flexible_run):
    scenario, _ = flexible_run
    result = run_cli("urdf", "--model", "flexible")
    assert result.returncode == 0, result.stderr
    moving = [j.get("name") for j in ET.fromstring(result.stdout).iter("joint") if j.get("type") != "fixed"]
    assert moving == scenario.model.joint_names


@pytest.mark.slow
def test_cli_simulate_writes_results_and_figure(tmp_path):
    result = run_cli("simulate", "--model", "both", "--duration", "0.2", "--out", str(tmp_path))
    assert result.returncode == 0, result.stderr
    assert "real-time factor" in result.stdout
    for name in ("rigid.csv", "rigid.npz", "flexible.csv", "flexible.npz", "figure2.png"):
        assert (tmp_path / name).stat().st_size > 0
    written = Trajectory.from_npz(tmp_path / "rigid.npz")  # every millisecond: the default output rate
    np.testing.assert_allclose(written.t, np.arange(201) * 1e-3, rtol=0.0, atol=1e-12)
    assert run_cli("simulate", "--duration", "0.2", "--rate", "300", "--out", str(tmp_path)).returncode == 2


def test_cli_reports_config_errors_by_field(tmp_path):
    bad = tmp_path / "bad.yaml"
    text = default_config_path().read_text()
    bad.write_text(text.replace("rfe_count: 6", "rfe_count: 0"))
    result = run_cli("urdf", "--config", str(bad))
    assert result.returncode == 2
    assert "links[1].beam.rfe_count = 0: must be an integer >= 1" in result.stderr



def test_cubic_hermite_equals_scipys_spline():
    """The one Hermite helper (Trajectory.interpolate and the online sampler) against scipy's
    CubicHermiteSpline on random data, vector-valued, at many points and at the knots."""
    from scipy.interpolate import CubicHermiteSpline

    from crane_reference.motion.trajectory import cubic_hermite

    rng = np.random.default_rng(5)
    times = np.sort(rng.uniform(0.0, 2.0, 30))
    values, rates = rng.normal(size=(30, 4)), rng.normal(size=(30, 4))
    at = np.concatenate([np.linspace(times[0], times[-1], 997), times])
    expected = CubicHermiteSpline(times, values, rates, axis=0)(at)
    np.testing.assert_allclose(cubic_hermite(at, times, values, rates), expected, rtol=0, atol=1e-13)
    one = times[7] + 1e-3  # a scalar time gives one row
    np.testing.assert_allclose(cubic_hermite(one, times, values, rates),
                               CubicHermiteSpline(times, values, rates, axis=0)(one), rtol=0, atol=1e-13)


@pytest.mark.slow
def test_a_stiff_flexible_drive_converges_and_follows_the_converged_run(params):
    """A flexible drive of stiffness s_dr = 1e8 N m/rad (the column's drive mode far above the step's
    frequency) acts on an independent coordinate like the other springs: the Newton iteration matrix carries
    h^2/4 s_dr, so each step converges, and over 0.1 s the run follows scipy's DOP853 (rtol 1e-10) on the
    same equations within 5e-5 rad in every coordinate."""
    drive = FlexibleDrive(stiffness=1e8, travel=1.0, start=0.0, duration=2.0)
    scenario = Scenario(replace(params, drive=drive), "flexible")
    q0 = scenario.equilibrium.q
    run = simulate(scenario.motion, q0, 0.1, step=1e-3)
    converged = simulate_reference(scenario.motion, q0, 0.1, run.t)
    assert np.max(np.abs(run.q - converged.q)) <= 5e-5
