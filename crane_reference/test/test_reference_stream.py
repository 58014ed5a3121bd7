"""ReferenceStream without ROS: compiled runs of several steps against one step at a time.

The stream computes ahead in compiled runs of up to :data:`CHUNK_STEPS` steps and keeps the solver state
only at their ends; a re-target inside a run continues from the computed step there (its t, q, qd and
work accounts: the method restarts under the new constraints).  A stream asked for one step at a time
has every step at a run's end: both must give the same reference, before and after a re-target that
falls inside a run.
"""

from __future__ import annotations

import numpy as np
import pytest

from crane_reference.control.feedforward import RigidInverseDynamics
from crane_reference.dynamics.kinematics import forward_kinematics
from crane_reference.model.chain import build_model
from crane_reference.model.config import load_config
from crane_reference.model.parameters import Task
from crane_reference.model.profiles import Constant, QuinticRise
from crane_reference.motion.constraints import ArealRate, ConstraintSet, EllipseXY, HeightZ
from crane_reference.motion.simulation import Scenario
from crane_reference.stream.reference_stream import CHUNK_STEPS, ReferenceStream
from crane_reference.stream.targets import UnreachableTargetError, check_task, reach
from crane_reference.stream.warmup import warm_up

STEP = 1e-3  # [s]
RETARGET_AT = 0.2037  # [s], inside a run of CHUNK_STEPS steps
END = 0.8  # [s], after the 0.5 s blend


def follow(stream: ReferenceStream, until: float, one_step_at_a_time: bool) -> None:
    if not one_step_at_a_time:
        stream.compute(until)
        return
    while stream.computed_until < until:
        stream.compute(stream.computed_until + 0.5 * STEP)


def test_chunked_and_stepwise_streams_agree_across_a_retarget():
    params = load_config()
    targets = Task(ellipse_a=3.2, ellipse_b=2.1, z_increment=0.1, rise_time=5.0)
    streams = []
    for one_step_at_a_time in (False, True):
        stream = ReferenceStream(params, "flexible", step=STEP, blend_time=0.5)
        follow(stream, 0.35, one_step_at_a_time)
        stream.retarget(RETARGET_AT, targets)
        follow(stream, END, one_step_at_a_time)
        streams.append(stream)
    assert CHUNK_STEPS > 1 and RETARGET_AT % (CHUNK_STEPS * STEP) > STEP  # the re-target is inside a run
    for tau in np.linspace(0.0, END, 241):
        chunked, stepwise = (s.sample(tau) for s in streams)
        np.testing.assert_array_equal(chunked.q, stepwise.q)
        np.testing.assert_array_equal(chunked.qd, stepwise.qd)
        np.testing.assert_array_equal(chunked.effort, stepwise.effort)
    # the re-target took effect: E heads for the new ellipse
    p = streams[0].sample(END).ee_position
    assert abs((p[0] / 3.2) ** 2 + (p[1] / 2.1) ** 2 - 1.0) < 1e-9


OMEGA = QuinticRise(0.0, 0.8, 0.0, 1.0)  # [rad/s], E's parametric-angle rate along the ellipse


def areal_task_constraints(task: Task, z_static: float) -> ConstraintSet:
    """The paper's ellipse and height and the first-order row x y' - y x' = a b omega(t): E runs along the
    ellipse with the parametric-angle rate omega (the column slew becomes dependent)."""
    ab = task.ellipse_a * task.ellipse_b

    def rate(t: float) -> tuple[float, float, float]:
        return tuple(ab * value for value in OMEGA(t))

    return ConstraintSet((EllipseXY(Constant(task.ellipse_a), Constant(task.ellipse_b)),
                          HeightZ(QuinticRise(z_static, task.z_increment, 0.0, task.rise_time)), ArealRate(rate)))


def test_streams_and_retargets_a_first_order_constraint_set():
    """A stream of the areal-rate set follows the row x y' - y x' = a b omega(t) (checked from E's
    kinematics) before and after a re-target to a larger ellipse, stays on the new ellipse after the
    blend, and its velocities stay continuous through the re-target."""
    params = load_config()
    names = build_model(params, "rigid").joint_names
    dependent = (names.index("boom_luff"), names.index("knuckle"), names.index("column_slew"))
    stream = ReferenceStream(params, "rigid", step=STEP, blend_time=0.3, task_constraints=areal_task_constraints,
                             dependent=dependent)
    new = Task(ellipse_a=3.2, ellipse_b=2.1, z_increment=0.2, rise_time=5.0)
    stream.compute(0.6)
    stream.retarget(0.5, new)
    stream.compute(1.2)
    dynamics = stream.scenario.dynamics

    def areal_rate(tau: float) -> float:
        s = stream.sample(tau)
        p, C = dynamics.end_effector(s.q)
        v = C @ s.qd
        return p[0] * v[1] - p[1] * v[0]

    for tau in np.arange(0.05, 0.5, 0.05):
        assert areal_rate(tau) == pytest.approx(3.0 * 2.0 * OMEGA(tau)[0], abs=1e-9)
    for tau in np.arange(0.85, 1.2, 0.05):
        assert areal_rate(tau) == pytest.approx(3.2 * 2.1 * OMEGA(tau)[0], abs=1e-9)
        x, y, _ = stream.sample(tau).ee_position
        assert abs((x / 3.2) ** 2 + (y / 2.1) ** 2 - 1.0) < 1e-9
    taus = np.arange(0.0, 1.2, STEP)
    qd = np.array([stream.sample(tau).qd for tau in taus])
    jumps = np.max(np.abs(np.diff(qd, axis=0)), axis=1)
    around = (taus[1:] > 0.45) & (taus[1:] < 0.55)
    assert np.max(jumps[around]) <= 2.0 * np.max(jumps[~around])  # no step in the velocity at the re-target


def test_samples_between_steps_are_the_hermite_spline_and_the_kinematics_there():
    """A batch of samples off the step grid: q and qd equal scipy's CubicHermiteSpline through the computed
    steps (q with qd, qd with qdd), E's position and the orientation of its frame equal the kinematics at
    the sampled q (from E's Jacobian routine and the dynamics terms)."""
    from scipy.interpolate import CubicHermiteSpline
    from scipy.spatial.transform import Rotation

    stream = ReferenceStream(load_config(), "flexible", step=STEP)
    stream.compute(0.1)
    grid = stream.samples(np.arange(0.0, 0.1 + STEP / 2, STEP))
    times, q, qd, qdd = grid.t, grid.q, grid.qd, grid.qdd
    at = np.sort(np.random.default_rng(3).uniform(0.0, 0.1, 37))
    samples = stream.samples(at)
    np.testing.assert_allclose(samples.q, CubicHermiteSpline(times, q, qd, axis=0)(at), rtol=0, atol=1e-12)
    np.testing.assert_allclose(samples.qd, CubicHermiteSpline(times, qd, qdd, axis=0)(at), rtol=0, atol=1e-10)
    dynamics = stream.scenario.dynamics
    for s in samples.rows():
        np.testing.assert_allclose(s.ee_position, dynamics.end_effector(s.q)[0], rtol=0, atol=1e-12)
        rotation = dynamics.terms(s.t, s.q, s.qd).ee_rotation
        np.testing.assert_allclose(Rotation.from_quat(s.ee_quaternion).as_matrix(), rotation, rtol=0, atol=1e-12)
    assert samples.t.tolist() == at.tolist()


def _geometric_reach(scenario: Scenario, z: float) -> tuple[float, float]:
    """The rigid crane's reach [m] from the column's axis at height z by plane geometry: the boom and the knuckle
    arm turn in the vertical plane of the column's axis about the luff pivot (r_p, z_p), so E at height z lies at
    r = r_p + sqrt(L^2 - (z - z_p)^2) for a pivot-to-E distance L between the folded and the stretched arm
    (L_min, L_max: forward kinematics over the knuckle angle)."""
    model, chain = scenario.model, scenario.dynamics.chain
    q = model.initial_q.copy()
    q[model.drive_joint] = 0.0
    pivot = forward_kinematics(q, chain.kinds, chain.axes, chain.origins)[0][model.index("boom_luff")][:3, 3]
    arm = np.repeat(q[None], 20001, axis=0)
    arm[:, model.index("knuckle")] = np.linspace(-np.pi, np.pi, 20001)
    distance = np.linalg.norm(scenario.dynamics.end_effector_poses(arm)[0] - pivot, axis=1)
    near, far = (pivot[0] + np.sqrt(length ** 2 - (z - pivot[2]) ** 2) for length in (distance.min(), distance.max()))
    return float(near), float(far)


def test_reach_is_the_arms_geometric_reach(params):
    """E's reach from the column's axis at a height z, found by continuation on the position constraints,
    equals plane geometry for the rigid crane (:func:`_geometric_reach`), to within the 1 mm resolution plus
    what the singular-value margin 1e-3 cuts off near the fold and the stretch."""
    scenario = Scenario(params, "rigid")
    for z in (scenario.z_static, scenario.z_static + 0.2):
        near, far = _geometric_reach(scenario, z)
        low, high = reach(scenario, params.task.ellipse_b, [z], 1e-3)
        assert near <= low <= near + 5e-3 and far - 5e-3 <= high <= far


def test_a_circle_is_accepted_inside_the_geometric_reach_and_refused_outside(params):
    """The target check walks the whole ellipse: a circle at E's static height (z_increment 0) 2 cm inside the
    rigid crane's geometric reach (:func:`_geometric_reach`) is accepted, one 2 cm outside it is refused at the
    walk's first point (0, -r), named; so is one 2 cm inside the fold."""
    scenario = Scenario(params, "rigid")
    near, far = _geometric_reach(scenario, scenario.z_static)
    for radius in (far - 0.02, near + 0.02):
        check_task(scenario, Task(radius, radius, 0.0, 5.0), scenario.z_static, 1e-3)
    for radius in (far + 0.02, near - 0.02):
        with pytest.raises(UnreachableTargetError, match=rf"ellipse point \(0.000, {-radius:.3f}\) m at z = "
                                                         rf"{scenario.z_static:.3f} m is out of the crane's reach"):
            check_task(scenario, Task(radius, radius, 0.0, 5.0), scenario.z_static, 1e-3)


def test_warm_up_makes_every_kernel_the_stream_uses_ready(kernel_signatures):
    """After ``warm_up`` a stream at its default step (computing, sampling on and between its steps, under a
    speed ramp, previews, a target check and a re-target) makes no kernel version the warm-up did not make:
    a node never compiles, or loads from the cache, while it publishes."""
    warm_up(("rigid",))
    before = kernel_signatures()
    params = load_config()
    stream = ReferenceStream(params, "rigid")
    stream.compute(0.3)
    stream.samples([0.01, 0.01234, 0.0500001])
    stream.pause(0.05)
    stream.samples([0.06, 0.0712, 0.2])
    stream.resume(0.1)
    stream.preview(0.1, 0.2, 5)
    stream.check_targets(Task(ellipse_a=3.2, ellipse_b=2.1, z_increment=0.1, rise_time=5.0))
    stream.retarget(0.15, Task(ellipse_a=3.2, ellipse_b=2.1, z_increment=0.1, rise_time=5.0), checked=True)
    stream.compute(0.5)
    stream.samples([0.41, 0.4123])
    assert kernel_signatures() == before


def test_history_compaction_keeps_every_sample(monkeypatch):
    """A stream whose history storage starts at 64 rows (compacted and grown many times while it computes,
    forgets old motion and re-targets) serves the same samples as one that starts with room for all."""
    from crane_reference.stream import history

    targets = Task(ellipse_a=3.2, ellipse_b=2.1, z_increment=0.1, rise_time=5.0)
    served = []
    for capacity in (100_000, 64):
        monkeypatch.setattr(history.History.__init__, "__defaults__", (capacity,))
        stream = ReferenceStream(load_config(), "rigid", step=STEP, blend_time=0.3)
        taus = []
        for i in range(12):
            tau = 0.1 * i
            stream.compute(tau + 0.3)
            if i == 5:
                stream.retarget(tau + 0.0537, targets)
                stream.compute(tau + 0.3)
            stream.release(tau, 0.05)
            taus += [tau + 0.013 * j for j in range(8)]
            served.append(stream.samples(taus[-8:]))
    half = len(served) // 2
    for wide, narrow in zip(served[:half], served[half:], strict=True):
        for name in ("t", "q", "qd", "effort", "ee_position", "ee_quaternion", "residual_distance"):
            np.testing.assert_array_equal(getattr(narrow, name), getattr(wide, name), err_msg=name)


def test_the_feedforward_is_the_rigid_crane_s_inverse_dynamics_and_the_effort_adds_the_drive():
    """On the rigid crane under ideal constraints the constraint forces are all that M qdd + h - Q leaves (Q with
    gravity, springs, damping and the drive): a sample's feedforward at the actuated joints converges to the O(n)
    inverse dynamics of its q, qd and qdd (RigidInverseDynamics, a second formulation: RNEA against the stream's
    J^T lambda) as h^2 (the integrator's qdd meets (8) to O(h^2)); its effort adds the drive's torque (4000 N m
    over [0, 1) s, config/crane.yaml) on the drive's joint alone."""
    config = load_config()
    inverse, differences = None, {}
    for step in (1e-3, 5e-4):
        stream = ReferenceStream(config, "rigid", step=step)
        stream.compute(1.5)
        inverse = inverse or RigidInverseDynamics(config, stream.joint_names)
        actuated = [stream.joint_names.index(name) for name in config.actuated]
        drive = stream.joint_names.index(config.drive_joint)
        for tau, torque in ((0.25, 4000.0), (0.75, 4000.0), (1.25, 0.0)):  # step times: the steps themselves
            s = stream.sample(tau)
            truth = inverse(s.t, s.q, s.qd, s.qdd)
            differences[step, tau] = np.abs(s.feedforward[actuated] - truth).max() / np.abs(truth).max()
            drive_torque = np.zeros_like(s.effort)
            drive_torque[drive] = torque
            np.testing.assert_allclose(s.effort - s.feedforward, drive_torque, rtol=0, atol=1e-9)
    for tau in (0.25, 0.75, 1.25):
        assert differences[1e-3, tau] < 1e-4 and 3.5 < differences[1e-3, tau] / differences[5e-4, tau] < 4.5
