"""Independent checks of :class:`CraneDynamics`.

* Pinocchio, run on the URDF of the same chain (:func:`crane_reference.model.urdf.model_to_urdf`): mass matrix
  (CRBA), gravity and velocity terms (RNEA) and the end-effector frame, its Jacobian and its
  velocity-product acceleration, at random configurations of both model variants of every packaged crane
  (:data:`cranes.EXAMPLES`).
* Finite differences (no Pinocchio): C = dp_E/dq, and d = d/dt (C qd) along q(t) = q + qd t.
* Round trip of the URDF roll-pitch-yaw conversion.

Pinocchio's ``continuous`` joints have nq = 2 (cos, sin) and nv = 1, so its configuration vector is
converted from q; its velocity vector is qd itself.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pinocchio as pin
import pytest
from cranes import CONFIG, DRIVE_OFF, EXAMPLES

from crane_reference.dynamics.chain_dynamics import CraneDynamics
from crane_reference.model.chain import PRISMATIC, VARIANTS, ChainModel, build_model, rotation
from crane_reference.model.config import load_config
from crane_reference.model.description import BASE_JOINTS
from crane_reference.model.drive import TorqueSource
from crane_reference.model.urdf import matrix_to_rpy, model_to_urdf

SAMPLES = 6
TOLERANCES = {  # relative, ||ours - Pinocchio|| / ||Pinocchio||
    "mass_matrix": 1e-10,
    "gravity": 1e-10,
    "velocity_terms": 1e-9,
    "ee_position": 1e-12,
    "ee_rotation": 1e-12,
    "ee_jacobian": 1e-12,
    "ee_bias": 1e-9,
}


@dataclass(frozen=True)
class Case:
    model: ChainModel
    dynamics: CraneDynamics
    pin_model: pin.Model


@pytest.fixture(scope="module", params=[(crane, variant) for crane in EXAMPLES for variant in VARIANTS],
                ids=lambda p: f"{p[0]}-{p[1]}")
def case(request: pytest.FixtureRequest) -> Case:
    crane, variant = request.param
    params = load_config(CONFIG / crane)
    model = build_model(params, variant)
    pin_model = pin.buildModelFromXML(model_to_urdf(model))
    pin_model.gravity = pin.Motion(np.array([0.0, 0.0, -model.gravity]), np.zeros(3))
    return Case(model, CraneDynamics(model, TorqueSource(0.0, 0.0, 0.0)), pin_model)  # Q: gravity and springs


def random_state(model: ChainModel, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """q: base translations and angles ~1e-2 (m, rad), RFE angles ~0.05 rad, other prismatic joints in
    [-0.5, 0.5] m, other angles in [-pi, pi]; qd: ~0.1 for the base, ~0.5 for the RFE angles, ~1 otherwise."""
    q = np.empty(model.dof)
    qd_scale = np.empty(model.dof)
    springs = {int(k) for link in model.flexible_links for k in link.springs}
    for k, name in enumerate(model.joint_names):
        if name in BASE_JOINTS:
            q[k], qd_scale[k] = rng.normal(scale=1e-2), 0.1
        elif k in springs:
            q[k], qd_scale[k] = rng.normal(scale=0.05), 0.5
        elif model.joints[k].kind == PRISMATIC:
            q[k], qd_scale[k] = rng.uniform(-0.5, 0.5), 1.0
        else:
            q[k], qd_scale[k] = rng.uniform(-np.pi, np.pi), 1.0
    return q, rng.normal(scale=qd_scale)


def pin_configuration(pin_model: pin.Model, q: np.ndarray) -> np.ndarray:
    """Pinocchio configuration: (cos, sin) for a continuous joint, the coordinate itself otherwise."""
    q_pin = np.empty(pin_model.nq)
    for joint in pin_model.joints[1:]:
        value = q[joint.idx_v]
        if joint.nq == 2:
            q_pin[joint.idx_q:joint.idx_q + 2] = np.cos(value), np.sin(value)
        else:
            q_pin[joint.idx_q] = value
    return q_pin


def relative(ours: np.ndarray, reference: np.ndarray) -> float:
    return float(np.linalg.norm(ours - reference) / np.linalg.norm(reference))


def pinocchio_errors(case: Case, q: np.ndarray, qd: np.ndarray) -> dict[str, float]:
    """Relative differences to Pinocchio of every quantity in TOLERANCES at (q, qd), t = DRIVE_OFF."""
    model, pin_model = case.model, case.pin_model
    data = pin_model.createData()
    q_pin = pin_configuration(pin_model, q)
    zeros = np.zeros(model.dof)
    terms = case.dynamics.terms(DRIVE_OFF, q, qd)
    at_rest = case.dynamics.terms(DRIVE_OFF, q, zeros)

    M = pin.crba(pin_model, data, q_pin)
    M = np.triu(M) + np.triu(M, 1).T
    gravity = pin.computeGeneralizedGravity(pin_model, data, q_pin).copy()
    velocity_terms = pin.rnea(pin_model, data, q_pin, qd, zeros) - gravity

    ee = pin_model.getFrameId("end_effector")
    pin.forwardKinematics(pin_model, data, q_pin, qd, zeros)
    pin.updateFramePlacements(pin_model, data)
    placement = data.oMf[ee]
    pin.computeJointJacobians(pin_model, data, q_pin)
    jacobian = pin.getFrameJacobian(pin_model, data, ee, pin.LOCAL_WORLD_ALIGNED)[:3]
    bias = pin.getFrameClassicalAcceleration(pin_model, data, ee, pin.LOCAL_WORLD_ALIGNED).linear

    return {
        "mass_matrix": relative(terms.M, M),
        "gravity": relative(-(at_rest.Q + model.stiffness @ q), gravity),
        "velocity_terms": relative(terms.h, velocity_terms),
        "ee_position": relative(terms.ee_position, placement.translation),
        "ee_rotation": relative(terms.ee_rotation, placement.rotation),
        "ee_jacobian": relative(terms.ee_jacobian, jacobian),
        "ee_bias": relative(terms.ee_bias, bias),
    }


def max_pinocchio_errors(case: Case, seed: int = 0) -> dict[str, float]:
    """Largest relative differences over SAMPLES random states."""
    rng = np.random.default_rng(seed)
    samples = [pinocchio_errors(case, *random_state(case.model, rng)) for _ in range(SAMPLES)]
    return {name: max(s[name] for s in samples) for name in TOLERANCES}


@pytest.fixture(scope="module")
def errors(case: Case) -> dict[str, float]:
    return max_pinocchio_errors(case)


def test_urdf_joints_match_the_chain(case: Case) -> None:
    assert list(case.pin_model.names)[1:] == case.model.joint_names
    assert case.pin_model.nv == case.model.dof
    assert [j.idx_v for j in case.pin_model.joints[1:]] == list(range(case.model.dof))


def test_urdf_mass_matches_the_chain(case: Case) -> None:
    total = sum(b.inertia.mass for b in case.model.bodies)
    assert sum(inertia.mass for inertia in case.pin_model.inertias) == pytest.approx(total, rel=1e-14)


@pytest.mark.parametrize("quantity", TOLERANCES)
def test_matches_pinocchio(errors: dict[str, float], quantity: str) -> None:
    assert errors[quantity] <= TOLERANCES[quantity]


def test_ee_jacobian_is_the_derivative_of_the_position(case: Case) -> None:
    rng = np.random.default_rng(1)
    dynamics, eps = case.dynamics, 1e-6
    for _ in range(SAMPLES):
        q, qd = random_state(case.model, rng)
        C = dynamics.terms(DRIVE_OFF, q, qd).ee_jacobian
        forward = [dynamics.terms(DRIVE_OFF, q + e, qd).ee_position for e in eps * np.eye(case.model.dof)]
        backward = [dynamics.terms(DRIVE_OFF, q - e, qd).ee_position for e in eps * np.eye(case.model.dof)]
        finite = (np.array(forward) - np.array(backward)).T / (2.0 * eps)
        np.testing.assert_allclose(C, finite, rtol=0.0, atol=1e-7)


def test_ee_bias_is_the_rate_of_the_jacobian_along_the_velocity(case: Case) -> None:
    rng = np.random.default_rng(2)
    dynamics, eps = case.dynamics, 1e-5
    for _ in range(SAMPLES):
        q, qd = random_state(case.model, rng)
        d = dynamics.terms(DRIVE_OFF, q, qd).ee_bias
        forward = dynamics.terms(DRIVE_OFF, q + eps * qd, qd).ee_jacobian @ qd
        backward = dynamics.terms(DRIVE_OFF, q - eps * qd, qd).ee_jacobian @ qd
        assert relative(d, (forward - backward) / (2.0 * eps)) <= 1e-6


def rpy_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    return rotation(2, yaw) @ rotation(1, pitch) @ rotation(0, roll)


def test_rpy_convention_is_urdf() -> None:
    np.testing.assert_allclose(rpy_matrix(0.3, -0.7, 2.1), pin.rpy.rpyToMatrix(0.3, -0.7, 2.1), atol=1e-15)


def test_rpy_round_trip_of_random_rotations() -> None:
    rng = np.random.default_rng(3)
    for quaternion in rng.normal(size=(200, 4)):
        R = pin.Quaternion(*(quaternion / np.linalg.norm(quaternion))).toRotationMatrix()
        roll, pitch, yaw = matrix_to_rpy(R)
        assert abs(pitch) <= 0.5 * np.pi
        np.testing.assert_allclose(rpy_matrix(roll, pitch, yaw), R, rtol=0.0, atol=1e-14)


def test_rpy_recovers_the_angles_away_from_gimbal_lock() -> None:
    rng = np.random.default_rng(4)
    for _ in range(200):
        angles = rng.uniform(-np.pi, np.pi), rng.uniform(-1.5, 1.5), rng.uniform(-np.pi, np.pi)
        np.testing.assert_allclose(matrix_to_rpy(rpy_matrix(*angles)), angles, rtol=0.0, atol=1e-12)


@pytest.mark.parametrize("pitch", [0.5 * np.pi, -0.5 * np.pi, 0.5 * np.pi - 1e-9, -0.5 * np.pi + 1e-7,
                                   0.5 * np.pi - 1e-5])
def test_rpy_round_trip_at_and_near_gimbal_lock(pitch: float) -> None:
    rng = np.random.default_rng(5)
    for roll, yaw in rng.uniform(-np.pi, np.pi, size=(50, 2)):
        R = rpy_matrix(roll, pitch, yaw)
        roll_out, pitch_out, yaw_out = matrix_to_rpy(R)
        assert pitch_out == pytest.approx(pitch, abs=1e-7)
        np.testing.assert_allclose(rpy_matrix(roll_out, pitch_out, yaw_out), R, rtol=0.0, atol=1e-14)
