"""Closed-loop runs of the actuated crane (crane_reference.analysis.tracking).

Independent truths: the task written out here (the ellipse and eq. (5.2)) for a plant that never sees the
programmed constraints; the closed-loop poles of J qdd = tau under PD; the linearised closed loop
(finite differences of the continuous equations of motion, scipy's matrix exponential) for the
simulated digital loop; the work-energy theorem with the actuators' work.
"""

from __future__ import annotations

import math
import threading
from dataclasses import replace

import numpy as np
import pytest
from scipy.linalg import expm
from test_simulation import quintic_z

from crane_reference.analysis.tracking.ahead import ComputedAhead
from crane_reference.analysis.tracking.closed_loop import TrackingSpec, run_tracking
from crane_reference.control.controller import JointController, JointGains, bandwidth_gains
from crane_reference.control.feedforward import RigidInverseDynamics
from crane_reference.control.plant import Plant, held_start
from crane_reference.model.drive import Actuated, TorqueSource, column_drive
from crane_reference.model.paper_layout import ACTUATED as ACTUATED_JOINTS
from crane_reference.motion.simulation import Scenario, simulate, simulated_runs
from crane_reference.motion.steps import ONLINE_STEP

ZERO_GAINS = {name: JointGains(0.0, 0.0) for name in ACTUATED_JOINTS}


def path_errors(params, run) -> tuple[float, float]:
    """Largest |(x/a)^2 + (y/b)^2 - 1| and |z - z_a(t)| [m] of the plant's E over the run."""
    scenario = Scenario(params, run.spec.variant)
    x, y, z = run.plant.ee_position.T
    task = params.task
    z_a = quintic_z(run.t, scenario.z_static, task.z_increment, task.rise_time)
    return (float(np.abs((x / task.ellipse_a) ** 2 + (y / task.ellipse_b) ** 2 - 1.0).max()),
            float(np.abs(z - z_a).max()))


@pytest.mark.slow
def test_exact_feedforward_makes_the_rigid_crane_follow_the_task(params):
    """Rigid crane, reference realised by the luff and knuckle torques, its rigid inverse dynamics as the
    only command: the plant (no programmed constraints) keeps E on the ellipse and the z quintic, across the
    drive's torque jump at 1 s, with the integrator's second-order error."""
    errors = {}
    for step in (1e-3, 5e-4):
        spec = TrackingSpec(variant="rigid", realisation="servo", gains=ZERO_GAINS, feedforward="rigid",
                            duration=2.0, step=step, rate=1.0 / step, reference_step=step)  # both at one step
        errors[step] = path_errors(params, run_tracking(params, spec))
    assert max(errors[1e-3]) <= 5e-6, errors
    assert all(coarse / fine >= 3.0 for coarse, fine in zip(errors[1e-3], errors[5e-4], strict=True)), errors


@pytest.mark.slow
@pytest.mark.parametrize(("variant", "relative"), [("rigid", 1e-3), ("flexible", 0.05)])
def test_the_plant_energy_balance_closes_with_the_actuators_work(params, variant, relative):
    """E(t) - E(0) = work of the drive, the actuators and the dampers (the joint drives' velocity loops
    among them), PD with feedforward following the ideal reference: the error is second order in the step
    (over a step 4 times smaller it falls at least 12-fold: 16 for second order, 4 for first; a single halving
    is not in the asymptotic range on the rigid crane, where round-off in the commands moves the 1 ms error by
    a fifth) and small against the actuators' net work; without the commands' work it would be off by tens of
    kJ."""
    errors, work = {}, {}
    for step in (1e-3, 2.5e-4):
        run = run_tracking(params, TrackingSpec(variant=variant, duration=1.5, step=step, rate=1.0 / step,
                                                reference_step=step))
        errors[step] = np.abs(run.plant.energy_balance_error).max()
        work[step] = np.abs(run.powers()).sum() * step
        assert run.plant.work_drive[-1] >= 1e4
    assert errors[1e-3] <= relative * work[1e-3] and errors[1e-3] / errors[2.5e-4] >= 12.0, (errors, work)


def linearised_closed_loop(plant: Plant, q_rest: np.ndarray, hold: np.ndarray, gains: list[JointGains]) -> np.ndarray:
    """A of dx/dt = A x, x = (q - q_rest, qd), for the continuous loop tau = hold + kp (q_rest - q) - kd qd on
    the actuated joints of ``plant`` (never commanded, no joint damping of its own, the drive off): central
    differences of M^-1 (Q + tau - h)."""
    n, act = plant.model.dof, plant.actuated
    kp, kd = np.array([g.kp for g in gains]), np.array([g.kd for g in gains])

    def acceleration(x: np.ndarray) -> np.ndarray:
        q, qd = q_rest + x[:n], x[n:]
        terms = plant.dynamics.terms(0.5, q, qd)
        forces = terms.Q - terms.h
        forces[act] += hold - kp * (q - q_rest)[act] - kd * qd[act]
        return np.linalg.solve(terms.M, forces)

    A = np.zeros((2 * n, 2 * n))
    A[:n, n:] = np.eye(n)
    for j in range(2 * n):
        dx = np.zeros(2 * n)
        dx[j] = 1e-7
        A[n:, j] = (acceleration(dx) - acceleration(-dx)) / 2e-7
    return A


@pytest.mark.slow
def test_a_pd_controlled_joint_decays_as_its_linearised_closed_loop(params):
    """The rigid crane at rest, held by its actuators (PD about the held pose plus the holding torques),
    the knuckle started 2 mrad off: the digital loop at 5 kHz follows exp(A t) x0 of the linearised
    continuous loop, i.e. decays at the rate and turns at the frequency of its eigenvalues."""
    still = replace(params, drive=column_drive(params, 0.0), task=replace(params.task, z_increment=0.0))
    start = held_start(Scenario(still, "rigid"))
    step = 2e-4
    free = Plant(still, "rigid", start, step)  # never commanded: its model, M at rest, the linearisation
    q_rest = start.q.copy()
    knuckle = free.model.index("knuckle")
    offset = q_rest.copy()
    offset[knuckle] += 2e-3
    inertia = free.dynamics.terms(0.0, q_rest, np.zeros_like(q_rest)).M[free.actuated, free.actuated]
    gains = [bandwidth_gains(J, 1.5, 0.15) for J in inertia]
    controller = JointController(gains, step)
    plant = Plant(still, "rigid", replace(start, q=offset), step, controller.damping)
    still_joints = np.zeros(len(ACTUATED_JOINTS))
    duration = 1.5
    for k in range(round(duration / step)):
        command = controller((q_rest - plant.q)[plant.actuated], still_joints, plant.qd[plant.actuated],
                             start.torques)
        plant.actuate((k + 1) * step, command, command)
    trajectory, _ = plant.trajectory()
    A = linearised_closed_loop(free, q_rest, start.torques, gains)
    x0 = np.concatenate([offset - q_rest, np.zeros_like(q_rest)])
    linear = np.array([expm(A * t) @ x0 for t in trajectory.t[::25]])[:, knuckle]
    simulated = trajectory.q[::25, knuckle] - q_rest[knuckle]
    eigenvalues = np.linalg.eigvals(A)
    slowest = eigenvalues[np.argmin(np.abs(eigenvalues.real))]
    assert slowest.real < 0 and abs(slowest.imag) > 0  # an oscillating, decaying closed loop
    assert abs(simulated[-1]) <= 0.3 * abs(simulated[0])  # it has decayed visibly over the run
    assert np.abs(simulated - linear).max() <= 0.02 * 2e-3, np.abs(simulated - linear).max()


def test_bandwidth_gains_place_the_poles_of_a_single_joint():
    """J qdd = -kp q - kd qd: the roots of J s^2 + kd s + kp have |s| = w and -Re s / |s| = zeta."""
    J, bandwidth, zeta = 123.0, 3.0, 0.4
    gains = bandwidth_gains(J, bandwidth, zeta, integral=True)
    roots = np.roots([J, gains.kd, gains.kp])
    assert np.abs(roots) == pytest.approx(2 * math.pi * bandwidth, rel=1e-12)
    assert -roots.real / np.abs(roots) == pytest.approx(zeta, rel=1e-12)
    assert gains.ki == pytest.approx(gains.kp * 2 * math.pi * bandwidth / 10)


def test_saturation_cuts_counts_and_stops_the_integral():
    controller = JointController([JointGains(10.0, 2.0, ki=100.0, limit=5.0), JointGains(1.0, 0.0)], period=0.01)
    still, moving = np.zeros(2), np.array([0.5, 0.0])
    first = controller(np.array([1.0, 1.0]), still, moving, still)
    # 10 N m - 2 N m s/rad * 0.5 rad/s wanted, cut to 5 N m; the drive applies command - kd qd
    assert (first - controller.damping * moving).tolist() == [5.0, 1.0]
    second = controller(np.array([1.0, 1.0]), still, still, still)
    assert second.tolist() == [5.0, 1.0]
    assert controller.saturated_ticks.tolist() == [2, 0]
    third = controller(np.array([0.1, 0.0]), still, still, still)
    assert third[0] == pytest.approx(1.0)  # no integral wound up while saturated: kp e only


def test_actuated_drive_holds_linearly_and_refuses_times_outside_its_command():
    drive = Actuated(TorqueSource(10.0, 0.0, 1.0), dof=3)
    assert np.all(drive.kernel_parameters(0.5) == [10.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    drive.command(0.0, 0.1, np.array([0.0, 1.0, 2.0]), np.array([1.0, 1.0, 0.0]))
    assert drive.forces(0.05) == pytest.approx([0.5, 1.0, 1.0])
    assert drive.kernel_parameters(np.array([0.0, 0.1])).shape == (2, 7)
    with pytest.raises(ValueError, match="outside its commanded interval"):
        drive.forces(0.2)
    with pytest.raises(ValueError, match="forces_end"):
        drive.command(0.0, 0.1, np.zeros(3), np.array([0.0, np.nan, 0.0]))


@pytest.mark.parametrize(("changes", "message"), [
    ({"rate": 300.0}, "whole number of integrator steps"),
    ({"controller": "lqr"}, "controller = 'lqr': must be one of pd, pid"),
    ({"feedforward": "exact"}, "feedforward"),
    ({"reference_step": 3e-4}, "reference_step"),
    ({"duration": math.nan}, "duration"),
])
def test_a_bad_spec_names_the_field(changes, message):
    with pytest.raises(ValueError, match=message):
        TrackingSpec(**changes)
    with pytest.raises(ValueError, match="joint 'wrist'"):
        TrackingSpec(limits={"wrist": 1.0}).check_joints(ACTUATED_JOINTS)
    with pytest.raises(ValueError, match="gain kd"):
        JointGains(1.0, -1.0)


@pytest.mark.slow
def test_cli_track_writes_series_summary_and_figure(tmp_path, capsys):
    from crane_reference import cli

    assert cli.main(["track", "--model", "rigid", "--duration", "0.3", "--out", str(tmp_path),
                     "--gains", "boom_luff=2e5,1e4", "--torque-limit", "3e4"]) == 0
    for name in ("tracking_pd_ff-none.csv", "tracking_pd_ff-rigid.npz", "summary.json", "summary.md", "tracking.png"):
        assert (tmp_path / name).stat().st_size > 0
    table = np.genfromtxt(tmp_path / "tracking_pd_ff-rigid.csv", delimiter=",", names=True)
    assert table["t_s"][-1] == pytest.approx(0.3) and np.all(np.abs(table["boom_luff_torque_nm"]) <= 3e4 + 1e-6)
    assert "E off the ellipse" in capsys.readouterr().out
    assert cli.main(["track", "--gains", "wrist=1,2", "--out", str(tmp_path)]) == 2
    assert "joint 'wrist' must be one of column_slew, boom_luff, knuckle" in capsys.readouterr().err


def test_the_compiled_closed_loop_is_the_per_tick_loop(params):
    """Plant.follow (the controller's ticks and the plant's steps in one compiled call) against the loop of
    one Plant.actuate per tick with the Python JointController, on the flexible crane through the drive's
    torque jump at 1 s, with torque limits that saturate and a feedforward that changes within ticks: the
    same motion, torques, work and saturated ticks to round-off."""
    scenario = Scenario(params, "flexible")
    start = held_start(scenario)
    step, per, duration = 1e-3, 2, 1.1  # a 500 Hz controller
    times = step * per * np.arange(round(duration / (step * per)) + 1)
    gains = [JointGains(2e6, 1e4, 1e5, limit=limit) for limit in (8e3, 6e4, 3e4)]
    rng = np.random.default_rng(7)
    reference_q = start.q[np.newaxis, :] + 0.02 * np.sin(3.0 * times)[:, np.newaxis]
    reference_qd = 0.06 * np.cos(3.0 * times)[:, np.newaxis] * np.ones(start.q.size)
    feedforward = start.torques + rng.normal(0.0, 100.0, (times.size, 3))
    feedforward_end = feedforward + 50.0  # a tick's command ends 50 N m above where the next one starts
    limits = np.array([g.limit for g in gains])
    runs = []
    for compiled in (False, True):
        controller = JointController(gains, step * per)
        plant = Plant(params, "flexible", start, step, controller.damping)
        actuated = plant.actuated
        if compiled:
            ticks = np.arange(times.size - 1)
            for chunk in (ticks[:137], ticks[137:]):
                plant.follow(times[chunk + 1], reference_q[np.ix_(chunk, actuated)],
                             reference_qd[np.ix_(chunk, actuated)], feedforward[chunk[0]:chunk[-1] + 2],
                             feedforward_end[chunk[0]:chunk[-1] + 2], controller)
        else:
            for k in range(times.size - 1):
                torque = controller(reference_q[k, actuated] - plant.q[actuated], reference_qd[k, actuated],
                                    plant.qd[actuated], feedforward[k])
                plant.actuate(times[k + 1], torque, np.clip(torque + (feedforward_end[k + 1] - feedforward[k]),
                                                            -limits, limits))
        runs.append((*plant.trajectory(), controller))
    (slow, slow_torques, slow_controller), (fast, fast_torques, fast_controller) = runs
    assert slow.t.size == fast.t.size and np.any(slow_controller.saturated_ticks > 0)
    np.testing.assert_array_equal(fast_controller.saturated_ticks, slow_controller.saturated_ticks)
    np.testing.assert_allclose(fast.t, slow.t, rtol=0, atol=1e-12)
    for name in ("q", "qd", "qdd", "constraint_forces", "ee_position", "kinetic_energy", "work_drive",
                 "work_damping"):
        a, b = getattr(fast, name), getattr(slow, name)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9 * max(1.0, np.abs(b).max()), err_msg=name)
    np.testing.assert_allclose(fast_torques, slow_torques, rtol=0, atol=1e-9 * np.abs(slow_torques).max())


def test_rigid_feedforward_is_m_qdd_plus_h_minus_q(params):
    """RigidInverseDynamics (O(n) inverse dynamics, rows at once) against M qdd + h - Q assembled from the
    rigid crane's mass matrix and terms at random states, before and at the drive's jump."""
    model = Scenario(params, "rigid").model
    inverse = RigidInverseDynamics(params, model.joint_names)
    rng = np.random.default_rng(5)
    q = model.initial_q + rng.normal(0.0, 0.2, (6, model.dof))
    qd, qdd = rng.normal(0.0, 0.5, (2, 6, model.dof))
    times = np.array([0.0, 0.3, 0.999, 1.0, 1.0, 2.0])
    for left_limit in (False, True):
        rows = inverse(times, q, qd, qdd, left_limit)
        for i in range(times.size):
            terms = inverse.dynamics.terms(times[i], q[i], qd[i], left_limit)
            expected = (terms.M @ qdd[i] + terms.h - terms.Q)[[model.index(name) for name in ACTUATED_JOINTS]]
            np.testing.assert_allclose(rows[i], expected, rtol=1e-10, atol=1e-8 * np.abs(expected).max())
            np.testing.assert_allclose(inverse(times[i], q[i], qd[i], qdd[i], left_limit), rows[i], rtol=1e-13)


def test_references_computed_ahead_are_simulates_and_hand_on_a_failure(params):
    """The runs computed in a thread ahead of the loop join into simulate's trajectory, bit for bit, for two
    motions at once (the task's and the rigid feedforward's); a failure while computing reaches the reader."""
    motions = [Scenario(params, variant) for variant in ("flexible", "rigid")]
    ahead = ComputedAhead([s.motion for s in motions],
                          [simulated_runs(s.motion, s.equilibrium.q, 0.3, step=1e-3, chunk=0.1, every_row=False)
                           for s in motions])
    early, _ = ahead.through(0.1)
    assert all(r.t[-1] >= 0.1 - 1e-12 for r in early)
    computed, finished = ahead.through(0.3)
    assert finished
    for s, trajectory in zip(motions, computed, strict=True):
        expected = simulate(s.motion, s.equilibrium.q, 0.3, step=1e-3, chunk=0.1, every_row=False)
        np.testing.assert_array_equal(trajectory.t, expected.t)
        np.testing.assert_array_equal(trajectory.q, expected.q)
        np.testing.assert_array_equal(trajectory.qd, expected.qd)
        np.testing.assert_array_equal(trajectory.qdd, expected.qdd)

    def held_back(runs, go: threading.Event):
        yield next(runs)  # the start
        yield next(runs)  # the first run
        go.wait()
        yield from runs

    go = threading.Event()
    ahead = ComputedAhead([s.motion for s in motions], [
        simulated_runs(motions[0].motion, motions[0].equilibrium.q, 0.3, step=1e-3, chunk=0.1, every_row=False),
        held_back(simulated_runs(motions[1].motion, motions[1].equilibrium.q, 0.3, step=1e-3, chunk=0.04,
                                 every_row=False), go)])
    try:
        first, _ = ahead.through(0.04 - 1e-9)  # the first motion is a run of 0.1 s ahead of the second's 0.04 s
        np.testing.assert_array_equal(first[0].t, computed[0].t[:first[1].t.size])
        assert first[0].t[-1] == first[1].t[-1] == pytest.approx(0.04)
    finally:
        go.set()
        ahead.close()

    def failing():
        yield from simulated_runs(motions[1].motion, motions[1].equilibrium.q, 0.1, step=1e-3, every_row=False)
        raise FloatingPointError("the solver failed")

    with pytest.raises(FloatingPointError, match="the solver failed"):
        ComputedAhead([motions[1].motion], [failing()]).through(0.2)


def test_the_reference_is_the_node_s_where_its_step_divides_the_plant_s():
    """By default the reference is integrated with the node's online step (so that ``track`` and ``loop`` follow the
    same reference), or with the plant's step where the node's does not divide it."""
    assert TrackingSpec().reference_step == ONLINE_STEP and TrackingSpec().reference_stride == round(1e-3 / ONLINE_STEP)
    assert TrackingSpec(step=2.5e-4, rate=4000.0).reference_step == 2.5e-4
