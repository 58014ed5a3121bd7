"""The plant node's core (crane_reference.control.plant_server), against independent truths.

* The hold efforts at the held start are the torques of the servo-constraint equilibrium that
  ``held_start`` solves (another computation: static equilibrium with the luff and knuckle as
  servo-constraints), less the column drive's torque.
* Under the efforts that hold it, the crane with its column drive off stays at rest.
* A command held over the ticks (HeldPeriods, one compiled call per period) is the per-tick Python path
  (Plant.actuate through the Actuated drive) with the same efforts: q, qd, E's pose, and what the period
  computes beside them (the actuator torques, E's quaternion against scipy's, the tip deflection against the
  module that computes it from q).
* Refused commands (length, NaN, inf) change nothing: a run with them interleaved is the run without them,
  bit for bit; a command ordered by a permuted ``joints`` is the same command.
* A timeout starts the hold command (counted), and the next command ends it.
* The quaternion of a rotation matrix against scipy's.
* The example controller's preview sampling: exact on cubic motion; a state waits for a preview that spans
  it and is answered once.
"""

from __future__ import annotations

import math
from contextlib import suppress
from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from crane_reference.control import held_periods
from crane_reference.control.controller import JointController, JointGains
from crane_reference.control.held_periods import HeldPeriods
from crane_reference.control.plant import Plant, held_start
from crane_reference.control.plant_server import CommandRefusedError, PlantServer, PlantSettings, warm_up_plant
from crane_reference.control.preview_tracking import Preview, PreviewTracker
from crane_reference.dynamics.deflection import TipDeflection
from crane_reference.dynamics.kinematics import quaternion
from crane_reference.model.paper_layout import ACTUATED as ACTUATED_JOINTS
from crane_reference.model.parameters import TorqueDrive
from crane_reference.motion.simulation import Scenario


@pytest.fixture(scope="module")
def still(params):
    """The default crane with its column drive off (nothing moves it but the commands)."""
    return replace(params, drive=TorqueDrive(torque=0.0))


def test_hold_efforts_at_the_held_start_are_the_servo_equilibrium_torques(params, flexible):
    server = PlantServer(params, PlantSettings())
    start = held_start(flexible)
    drive = params.drive.torque if isinstance(params.drive, TorqueDrive) else 0.0
    expected = start.torques - np.array([drive, 0.0, 0.0])
    assert server.hold_efforts(start.q) == pytest.approx(expected, rel=1e-9, abs=1e-6)


def test_the_crane_held_by_its_start_efforts_stays_at_rest(still):
    server = PlantServer(still, PlantSettings())
    q0 = server.q.copy()
    start = held_start(Scenario(still, "flexible"))
    for k in range(200):
        server.command(start.torques, k * 1e-3)
        state = server.tick(k * 1e-3)
    assert np.abs(server.q - q0).max() < 1e-9
    assert np.abs(server.qd).max() < 1e-8
    assert state.effort == pytest.approx(start.torques, rel=1e-9)


def test_held_commands_are_the_per_tick_python_path(still):
    start = held_start(Scenario(still, "flexible"))
    kd = np.array([4e4, 4e4, 1.3e4])
    efforts = start.torques + np.array([[2e3, -1e3, 50.0], [-1e3, 3e3, -20.0], [0.0, 0.0, 0.0]])
    ends = 0.05 * np.arange(1, 4)
    compiled = HeldPeriods(Plant(still, "flexible", start, 1e-3, kd), 0.05, start.torques)
    for u in efforts:
        compiled.advance(u)
    python = Plant(still, "flexible", start, 1e-3, kd)
    for end, u in zip(ends, efforts, strict=True):
        python.actuate(end, u, u)
    carry, sample = compiled.carry, python.stepper.sample
    assert compiled.t == python.t == pytest.approx(0.15)
    assert np.abs(carry.q - python.q).max() < 1e-9
    assert np.abs(carry.qd - python.qd).max() < 1e-7
    assert np.abs(carry.ee_position - sample.ee_position).max() < 1e-9
    assert np.abs(carry.ee_rotation - sample.ee_rotation).max() < 1e-9
    assert np.abs(python.q - start.q).max() > 1e-3  # the commands moved it
    torques = python.trajectory()[1][-1]
    assert np.abs(carry.torques - torques).max() < 1e-9 * np.abs(torques).max()
    expected = Rotation.from_matrix(sample.ee_rotation).as_quat()
    assert np.abs(carry.ee_quaternion - expected * np.sign(expected[3])).max() < 1e-9
    model, chain = python.model, python.dynamics.chain
    deflection = TipDeflection(model, chain, link_frame=False)(python.q)[0]  # the plant's frame
    assert np.abs(deflection).max() > 1e-5  # the commands bent the boom
    assert np.abs(carry.deflection - deflection).max() < 1e-9 * np.abs(deflection).max() + 1e-12


def test_held_periods_across_plans_and_drive_jumps_are_the_per_tick_python_path(params, monkeypatch):
    """Two periods planned at a time, the column torque jumping within a period (off the step grid) and at a
    period's end: the periods step as Plant.actuate does, restarting at the jumps."""
    monkeypatch.setattr(held_periods, "PLANNED_PERIODS", 2)
    crane = replace(params, drive=TorqueDrive(torque=800.0, start=0.0235, end=0.05))
    start = held_start(Scenario(crane, "flexible"))
    kd = np.array([4e4, 4e4, 1.3e4])
    period, count = 0.01, 7
    efforts = start.torques + np.outer(np.sin(np.arange(count)), [1e3, -5e2, 30.0])
    compiled = HeldPeriods(Plant(crane, "flexible", start, 1e-3, kd), period, start.torques)
    python = Plant(crane, "flexible", start, 1e-3, kd)
    for k, u in enumerate(efforts):
        compiled.advance(u)
        python.actuate((k + 1) * period, u, u)
        assert compiled.t == python.t
        assert np.abs(compiled.carry.q - python.q).max() < 1e-9
        assert np.abs(compiled.carry.qd - python.qd).max() < 1e-7
    assert 0.0235 in python.trajectory()[0].t  # the Python path stepped onto the jump


def test_a_follow_without_ticks_is_refused(still):
    plant = Plant(still, "flexible", held_start(Scenario(still, "flexible")), 1e-3)
    controller = JointController([JointGains(1.0, 0.0)] * 3, 1e-3)
    none = np.empty((0, 3))
    with pytest.raises(ValueError, match="ends: no tick"):
        plant.follow(np.empty(0), none, none, none, none, controller)
    assert plant.t == 0.0


def _run(server, commands):
    states = []
    for k, command in enumerate(commands):
        for values in command:
            with suppress(CommandRefusedError):
                server.command(values, k * 1e-3)
        states.append(server.tick(k * 1e-3))
    return states


def test_refused_commands_change_nothing_and_are_counted(still):
    start = held_start(Scenario(still, "flexible"))
    good = [[start.torques + np.array([1e3 * math.sin(k / 7), 500.0, 0.0])] for k in range(40)]
    bad = [[1.0, 2.0], [math.nan, 0.0, 0.0], [0.0, math.inf, 0.0], [1.0, 2.0, 3.0, 4.0]]
    with_bad = [command + ([bad[k % 4]] if k % 3 == 0 else []) for k, command in enumerate(good)]
    every = PlantSettings(all_coordinates=True)
    clean, server = PlantServer(still, every), PlantServer(still, every)
    expected, got = _run(clean, good), _run(server, with_bad)
    assert all(np.array_equal(a.q, b.q) and np.array_equal(a.qd, b.qd) for a, b in zip(expected, got, strict=True))
    assert server.refused == 14 and server.accepted == 40 and clean.refused == 0
    assert all(np.isfinite(s.q).all() for s in got)
    with pytest.raises(CommandRefusedError, match="2 values: a command has one effort"):
        server.command([1.0, 2.0], 1.0)
    with pytest.raises(CommandRefusedError, match="effort of boom_luff is not finite"):
        server.command([0.0, math.inf, 0.0], 1.0)


def test_a_command_in_permuted_joints_is_the_same_command(still):
    order = ("knuckle", "column_slew", "boom_luff")
    start = held_start(Scenario(still, "flexible"))
    kd = (4e4, 4e4, 1.3e4)
    default = PlantServer(still, PlantSettings(drive_damping=kd))
    permuted = PlantServer(still, PlantSettings(joints=order, drive_damping=tuple(kd[ACTUATED_JOINTS.index(j)]
                                                                               for j in order)))
    u = start.torques + np.array([2e3, -1e3, 30.0])
    for _ in range(5):
        default.command(u, 0.0)
        permuted.command([u[ACTUATED_JOINTS.index(j)] for j in order], 0.0)
        a, b = default.tick(0.0), permuted.tick(0.0)
    assert np.array_equal(a.q, [b.q[order.index(j)] for j in ACTUATED_JOINTS])
    assert b.effort == pytest.approx([a.effort[ACTUATED_JOINTS.index(j)] for j in order], rel=1e-12)


def test_a_timeout_starts_the_hold_command_and_a_command_ends_it(still):
    settings = PlantSettings(command_timeout=0.05)
    server = PlantServer(still, settings)
    start = held_start(Scenario(still, "flexible"))
    server.command(start.torques + np.array([5e3, 0.0, 0.0]), 0.0)  # slews the column
    for k in range(50):
        state = server.tick(k * 1e-3)
    assert not state.holding and server.timeouts == 0
    state = server.tick(0.051)
    assert state.holding and server.timeouts == 1
    for k in range(3000):  # held: the drives' damping brings the column to rest
        state = server.tick(0.052 + k * 1e-3)
    assert server.timeouts == 1 and abs(state.qd[0]) < 1e-3
    server.command(start.torques, 3.1)
    assert not server.tick(3.1).holding


@pytest.mark.parametrize("seed", range(6))
def test_quaternion_is_scipys(seed):
    rng = np.random.default_rng(seed)
    rotations = Rotation.random(50, random_state=rng)
    # the four branches of Shepperd's method: near the identity and near half-turns about x, y, z
    extra = Rotation.from_rotvec(np.array([[1e-3, 0, 0], [3.1, 0.1, 0], [0.1, 3.1, 0], [0, 0.1, 3.1]]))
    for rotation in [*rotations, *extra]:
        expected = rotation.as_quat()
        expected = expected if expected[3] >= 0 else -expected
        assert quaternion(rotation.as_matrix()) == pytest.approx(expected, abs=1e-14)


def test_settings_refuse_what_they_cannot_run():
    with pytest.raises(ValueError, match=r"joints = .*must name each of column_slew, boom_luff, knuckle once"):
        PlantSettings(joints=("column_slew", "boom_luff")).command_joints(ACTUATED_JOINTS)
    with pytest.raises(ValueError, match="whole number of integrator steps"):
        PlantSettings(rate=300.0)
    with pytest.raises(ValueError, match=r"drive_damping = .*one finite number >= 0"):
        PlantSettings(drive_damping=(1.0, -1.0, 0.0))
    with pytest.raises(ValueError, match="command_timeout = nan"):
        PlantSettings(command_timeout=math.nan)


def test_the_preview_is_sampled_exactly_on_cubic_motion():
    """Between a preview's points q is cubic Hermite in positions and velocities and qd in velocities and
    accelerations: exact on a cubic q(t) (joint_trajectory_controller's sampling of such points)."""
    times_ns = np.array([1_000_000_000, 1_100_000_000, 1_250_000_000, 1_300_000_000], dtype=np.int64)
    s = (times_ns - times_ns[0]) / 1e9
    coefficients = np.array([[0.3, -1.0, 2.0], [1.0, 0.5, -0.2], [-0.7, 0.0, 0.4], [2.0, -3.0, 1.0]])  # (4, J)
    q = lambda t: sum(c * t[:, None] ** k for k, c in enumerate(coefficients))  # noqa: E731
    qd = lambda t: sum(k * c * t[:, None] ** (k - 1) for k, c in enumerate(coefficients) if k)  # noqa: E731
    qdd = lambda t: sum(k * (k - 1) * c * t[:, None] ** (k - 2) for k, c in enumerate(coefficients) if k > 1)  # noqa: E731
    preview = Preview(times_ns, q(s), qd(s), qdd(s) + 0.0 * s[:, None])
    for t_ns in (1_000_000_000, 1_037_000_001, 1_180_000_000, 1_300_000_000):
        t = np.array([(t_ns - times_ns[0]) / 1e9])
        q_ref, qd_ref = preview.at(t_ns)
        assert q_ref == pytest.approx(q(t)[0], abs=1e-12)
        # qd is quadratic: cubic Hermite in qd and qdd reproduces it
        assert qd_ref == pytest.approx(qd(t)[0], abs=1e-12)


def test_the_tracker_waits_for_a_preview_and_answers_a_stamp_once():
    """A state waits for a preview that spans it; a stamp is answered once (a lock-step plant repeats a state until
    a command comes), and the commands are those of a JointController ticked once per stamp."""
    gains = [JointGains(100.0, 10.0, 1000.0)] * 3
    tracker, alone = PreviewTracker(ACTUATED_JOINTS, gains, 1e-3), JointController(gains, 1e-3)
    zeros, q_ref = np.zeros(3), np.array([1.0, 2.0, 3.0])
    assert tracker.take_state(1_000_000_000, zeros, zeros) is None  # no preview yet: waits
    preview = Preview(np.array([1_000_000_000, 2_000_000_000], dtype=np.int64), np.array([q_ref] * 2),
                      np.zeros((2, 3)), np.zeros((2, 3)))
    assert tracker.take_preview(preview) == pytest.approx(alone(q_ref, zeros, zeros, zeros))  # answered now
    assert tracker.take_state(1_000_000_000, zeros, zeros) is None  # the same stamp again: answered already
    assert tracker.take_state(999_000_000, zeros, zeros) is None  # older than the last answered
    assert tracker.take_state(1_001_000_000, zeros, zeros) == pytest.approx(alone(q_ref, zeros, zeros, zeros))
    assert tracker.take_state(3_000_000_000, zeros, zeros) is None  # beyond the preview: waits
    with pytest.raises(ValueError, match="plant state: position and velocity must be finite"):
        tracker.take_state(1_002_000_000, np.array([0.0, np.nan, 0.0]), zeros)
    with pytest.raises(ValueError, match="must increase strictly"):
        Preview(np.array([5, 5], dtype=np.int64), np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="velocities must be finite"):
        Preview(np.array([5, 6], dtype=np.int64), np.zeros((2, 3)), np.full((2, 3), np.inf), np.zeros((2, 3)))


def test_the_feedforward_is_the_preview_s_effort_linear_between_its_points():
    """With feedforward "reference" the command adds the preview's efforts at the state's time, linear between
    the points (joint_trajectory_controller's effort interpolation, written out here), a point's own on a point;
    a preview without efforts is refused, naming the parameter that gives them."""
    gains = [JointGains(100.0, 10.0)] * 3
    tracker, alone = PreviewTracker(ACTUATED_JOINTS, gains, 1e-3, "reference"), JointController(gains, 1e-3)
    times = np.array([1_000_000_000, 1_004_000_000, 1_010_000_000], dtype=np.int64)
    efforts = np.array([[100.0, -2e4, 5.0], [300.0, -1e4, -5.0], [0.0, 0.0, 0.0]])
    zeros = np.zeros((3, 3))
    with pytest.raises(ValueError, match=r"no efforts for feedforward 'reference' \(set preview.effort:=true"):
        tracker.take_preview(Preview(times, zeros, zeros, zeros))
    tracker.take_preview(Preview(times, zeros, zeros, zeros, efforts))
    for t_ns, effort in ((1_000_000_000, efforts[0]), (1_001_000_000, 0.75 * efforts[0] + 0.25 * efforts[1]),
                         (1_004_000_000, efforts[1]), (1_007_000_000, 0.5 * efforts[1] + 0.5 * efforts[2])):
        command = tracker.take_state(t_ns, np.zeros(3), np.zeros(3))
        np.testing.assert_allclose(command, alone(np.zeros(3), np.zeros(3), np.zeros(3), effort), rtol=1e-12)
    with pytest.raises(ValueError, match="feedforward = 'rigid': must be one of none, reference"):
        PreviewTracker(ACTUATED_JOINTS, gains, 1e-3, "rigid")


def test_warm_up_makes_every_kernel_the_plant_uses_ready(still, kernel_signatures):
    """After ``warm_up_plant`` a plant (another crane of the same model, permuted joints, every coordinate
    published, commands, a refusal, a timeout's hold command) makes no kernel version the warm-up did not make:
    the plant node never compiles, or loads from the cache, in a period."""
    warm_up_plant()
    before = kernel_signatures()
    server = PlantServer(still, PlantSettings(joints=("knuckle", "boom_luff", "column_slew"), command_timeout=0.002,
                                              all_coordinates=True))
    server.command([0.0, 1e4, 0.0], 0.0)
    with suppress(CommandRefusedError):
        server.command([math.nan, 0.0, 0.0], 0.0)
    for k in range(5):
        server.tick(k * 1e-3)
    assert server.holding
    assert kernel_signatures() == before
