"""The numerical core's failures, each driven by a real input, against independent truths about why it fails.

* A stretched arm: E sent along a circle growing past the crane's reach stops with ConstraintSingularityError,
  at a pose where the boom and link 4 are aligned (E as far from the luff pivot as their lengths allow).
* A target rising out of reach while the crane moves stops the integrator (IntegrationError naming when), the arm
  stretched as E climbs; the stream's check of the same targets refuses them before anything moves.
* A crane without a static equilibrium (a trolley free to roll down an inclined jib) is refused with
  EquilibriumError naming the unbalanced force, m g sin(slope).
* A torque that overflows the accelerations, one that leaves a linear system of the step unsolvable, or one
  that throws the configuration beyond what the constraints can meet: the step that fails is named, the
  stream goes to ERROR, holds its last valid sample at rest and publishes nothing that is not finite.
* A torque the integrator cannot follow: the sample held is the last step that converged, as single steps find.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from cranes import CONFIG, with_trolley

from crane_reference.dynamics.kinematics import forward_kinematics
from crane_reference.model.config import load_config, parse_config, read_yaml
from crane_reference.model.parameters import Task, TorqueDrive
from crane_reference.model.profiles import Blend, Constant
from crane_reference.motion.constraints import paper_constraints
from crane_reference.motion.equilibrium import EquilibriumError
from crane_reference.motion.integration import IntegrationError
from crane_reference.motion.programmed_motion import ConstraintSingularityError, ProgrammedMotion
from crane_reference.motion.simulation import MotionStepper, Scenario
from crane_reference.stream.reference_stream import ERROR, ReferenceStream
from crane_reference.stream.targets import UnreachableTargetError, check_task, reach

BOOM, LINK4 = 2.546, 1.2  # [m] the packaged crane's boom and E's distance from the knuckle (config/crane.yaml)


def _run_until_it_fails(motion: ProgrammedMotion, q0: np.ndarray, seconds: float, step: float = 1e-3):
    """Step ``motion`` from rest at q0 until it raises; the error and the last state computed."""
    stepper = MotionStepper(motion, 0.0, q0, np.zeros_like(q0), step)
    last = stepper.state
    with pytest.raises(Exception) as info:
        while stepper.state.t < seconds:
            last = stepper.state
            stepper.advance()
    return info.value, last


def _pivot_to_e(scenario: Scenario, q: np.ndarray) -> float:
    """|E - luff pivot| [m] at q (the pivot: the origin of the boom's frame)."""
    chain = scenario.dynamics.chain
    T, _ = forward_kinematics(np.ascontiguousarray(q), chain.kinds, chain.axes, chain.origins)
    pivot = T[scenario.model.index("boom_luff"), :3, 3]
    return float(np.linalg.norm(scenario.dynamics.end_effector(q)[0] - pivot))


def test_a_circle_past_the_reach_stretches_the_arm_into_a_singular_pose():
    scenario = Scenario(load_config(), "rigid")
    _, outer = reach(scenario, 2.0, (scenario.z_static,), 0.0)  # [m]: E can be held up to here at its height
    radius = outer + 0.01
    constraints = paper_constraints(Blend(Constant(3.0), Constant(radius), 0.0, 3.0),
                                    Blend(Constant(2.0), Constant(radius), 0.0, 3.0), Constant(scenario.z_static))
    error, last = _run_until_it_fails(ProgrammedMotion(scenario.dynamics, constraints), scenario.equilibrium.q, 4.0)
    assert isinstance(error, ConstraintSingularityError), error
    assert "stretch/fold singularity" in str(error)
    assert _pivot_to_e(scenario, last.q) == pytest.approx(BOOM + LINK4, abs=2e-3)  # boom and link 4 in line


def test_a_target_rising_out_of_reach_stops_the_integrator_and_the_check_refuses_it():
    task = Task(3.0, 2.0, 5.0, 1.0)  # E to rise by 5 m within a second: far above what the arm reaches
    scenario = Scenario(load_config(), "rigid", task)
    with pytest.raises(UnreachableTargetError, match=r"ellipse point \(.*\) m at z = "):
        check_task(scenario, task, scenario.z_static, 0.1)
    error, last = _run_until_it_fails(scenario.motion, scenario.equilibrium.q, 1.0)
    assert isinstance(error, IntegrationError) and "did not converge" in str(error), error
    assert f"t = {last.t:.3f}" in str(error)
    assert _pivot_to_e(scenario, last.q) > 0.99 * (BOOM + LINK4)  # it failed with the arm nearly straight


def test_a_trolley_free_on_an_inclined_jib_has_no_static_equilibrium():
    """The loader crane with a 100 kg trolley beyond E, free to roll along the jib (no spring, no drive): held on
    the task, the jib keeps its slope, so gravity's component along it, m g sin(slope), is never balanced."""
    scenario = Scenario(parse_config(with_trolley(read_yaml(CONFIG / "loader_crane.yaml"))), "rigid")
    with pytest.raises(EquilibriumError, match=r"largest unbalanced generalized force .* N on roll ") as info:
        scenario.equilibrium  # noqa: B018 (computed on first use)
    jib = scenario.model.index("knuckle")
    q = scenario.model.initial_q
    chain = scenario.dynamics.chain
    T, _ = forward_kinematics(np.ascontiguousarray(q), chain.kinds, chain.axes, chain.origins)
    slope = math.asin(T[jib, 2, 0])  # the jib's x axis against the horizontal
    unbalanced = float(str(info.value).split("generalized force ")[1].split()[0])  # [N], to 3 digits
    assert unbalanced == pytest.approx(100.0 * scenario.model.gravity * abs(math.sin(slope)), rel=5e-3)


@pytest.mark.parametrize(("torque", "failure"), [
    (1.7e308, "IntegrationError: the step from t = 0.05 s with h = 0.0005 s overflowed: its state or accelerations "
              "are not finite"),  # near the largest double
    (1e10, "IntegrationError: the step from t = 0.05 s with h = 0.0005 s met a linear system it cannot solve"),
    (1e15, "ProjectionError: position or velocity constraints cannot be met at t = 0.0505 s"),  # the step's end
])
def test_a_torque_beyond_reason_stops_at_its_first_step_and_holds_the_last_valid_sample(torque, failure):
    """A column torque switched on at 0.05 s throws the step's predicted configuration so far that the step from
    0.05 s fails, naming why (an overflow, a linear system it cannot solve, or position constraints it cannot
    meet at the step's end); the stream goes to ERROR and holds its last sample (finite, at rest) for every time
    asked beyond it."""
    params = replace(load_config(), drive=TorqueDrive(torque=torque, start=0.05, end=1.0))
    stream = ReferenceStream(params, "rigid", step=5e-4)
    stream.compute(0.5)
    assert stream.state == ERROR and stream.last_error.startswith(failure), stream.last_error
    held = stream.samples(np.linspace(0.051, 2.0, 50))  # beyond the last valid step
    assert np.all(np.isfinite(held.q)) and np.all(held.qd == 0.0)
    np.testing.assert_array_equal(held.q, np.broadcast_to(held.q[0], held.q.shape))  # one sample, held


def test_the_held_sample_is_the_last_step_before_the_failing_one():
    """The column's largest allowed torque (1e6 N m) spins the slew faster than 0.5 ms steps follow: the stream
    computes ahead in runs of hundreds of steps, and holds the state of the last step that converged, the one
    that single steps from the same start reach before they fail."""
    params = replace(load_config(), drive=TorqueDrive(torque=1e6, start=0.0, end=1.0))
    stream = ReferenceStream(params, "rigid", step=5e-4)
    stream.compute(1.0)
    assert stream.state == ERROR and "did not converge" in stream.last_error, stream.last_error
    scenario = Scenario(params, "rigid")
    error, last = _run_until_it_fails(scenario.motion, scenario.equilibrium.q, 1.0, step=5e-4)
    assert isinstance(error, IntegrationError) and f"t = {last.t:.6g} s" in str(error)
    held = stream.sample(0.9)
    assert held.t == pytest.approx(last.t, abs=1e-12)
    np.testing.assert_allclose(held.q, last.q, rtol=0, atol=1e-12)
