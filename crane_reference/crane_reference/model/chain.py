"""The crane as a serial kinematic chain of one-DOF joints, built from :class:`CraneParameters`.

Every generalized coordinate of eq. (1) is one joint of the chain, in the paper's order::

    base_x base_y base_z base_yaw base_pitch base_roll   q~(1) = x y z psi theta phi
    column_slew                                          q~(2) = psi2
    boom_luff                                            q~(3,0) = psi(3,0)
    boom_sde{r}_bend_vertical / _bend_lateral / _twist   q~(3,r) = psi theta phi, r = 1 .. n_rfe - 1
    knuckle                                              q~(4) = psi4

Joint k has a constant ``origin`` (the transform from the frame after joint k-1 to joint k's frame at
q_k = 0) followed by its motion: a rotation about, or a translation along, one axis of that frame.
The world transform of the frame after joint k is therefore
``T_k = T_{k-1} @ origin_k @ motion_k(q_k)``; a body rigidly attached to that frame has
``T^(l) = T_k``.  Bodies without mass (the intermediate frames of multi-axis joints) do not appear.

Springs are linear in q: E_p,spring = 1/2 q^T K q, with K holding the support springs of the paper,
sum_s U^(sup,s)T S^(sup,s) U^(sup,s) (the linearised form printed in the paper), and the RFE springs
S^(3) on the boom coordinates.  The ``flexible`` variant has ``rfe_count`` elements (24 DOF for the
paper's 6), the ``rigid`` variant one boom element (9 DOF).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .parameters import Boom, CraneParameters, RigidBody, SupportSpring
from .rfe import discretise_beam

PRISMATIC = 0
REVOLUTE = 1
AXES = {"x": 0, "y": 1, "z": 2}
VARIANTS = ("flexible", "rigid")
ACTUATED_JOINTS = ("column_slew", "boom_luff", "knuckle")
"""The joints the crane's actuators drive, psi2, psi(3,0) and psi4 (also the coordinates the paper plots)."""


@dataclass(frozen=True)
class Joint:
    """One generalized coordinate: ``kind`` PRISMATIC or REVOLUTE along/about local ``axis``."""

    name: str
    kind: int
    axis: int
    origin: np.ndarray


@dataclass(frozen=True)
class Body:
    """A rigid body attached to the frame after joint ``joint``; mass properties in that frame."""

    name: str
    joint: int
    inertia: RigidBody


@dataclass(frozen=True)
class ChainModel:
    """Serial chain, springs and task indices of one crane variant."""

    variant: str
    joints: tuple[Joint, ...]
    bodies: tuple[Body, ...]
    end_effector_joint: int
    end_effector_point: np.ndarray
    gravity: float
    stiffness: np.ndarray
    support_stiffness: np.ndarray
    boom_stiffness: np.ndarray
    drive_joint: int
    dependent_joints: tuple[int, ...]
    initial_q: np.ndarray

    @property
    def dof(self) -> int:
        return len(self.joints)

    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self.joints]

    def index(self, name: str) -> int:
        """Index of the coordinate called ``name``."""
        return self.joint_names.index(name)


def homogeneous(rotation: np.ndarray | None = None, translation=(0.0, 0.0, 0.0)) -> np.ndarray:
    """4x4 homogeneous transformation [[R, p], [0, 1]]."""
    T = np.eye(4)
    if rotation is not None:
        T[:3, :3] = rotation
    T[:3, 3] = translation
    return T


def rotation(axis: int, angle: float) -> np.ndarray:
    """Elementary rotation matrix about local axis 0, 1, 2 (x, y, z)."""
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    R = np.eye(3)
    R[i, i] = R[j, j] = c
    R[i, j], R[j, i] = -s, s
    return R


def support_stiffness(supports: tuple[SupportSpring, ...]) -> np.ndarray:
    """6x6 stiffness of the base: sum over springs of U^T S U with the paper's linearised

    U = [[1, 0, 0, -y,  z,  0],
         [0, 1, 0,  x,  0, -z],
         [0, 0, 1,  0, -x,  y]]   acting on q~(1) = (x, y, z, psi, theta, phi).
    """
    K = np.zeros((6, 6))
    for spring in supports:
        x, y, z = spring.position
        U = np.array([[1, 0, 0, -y, z, 0], [0, 1, 0, x, 0, -z], [0, 0, 1, 0, -x, y]], dtype=float)
        K += U.T @ np.diag(spring.stiffness) @ U
    return K


def _base_joints() -> list[Joint]:
    names = [("base_x", PRISMATIC, "x"), ("base_y", PRISMATIC, "y"), ("base_z", PRISMATIC, "z"),
             ("base_yaw", REVOLUTE, "z"), ("base_pitch", REVOLUTE, "y"), ("base_roll", REVOLUTE, "x")]
    return [Joint(name, kind, AXES[axis], np.eye(4)) for name, kind, axis in names]


def _boom_joints_and_bodies(boom: Boom, rfe_count: int,
                            first_joint: int) -> tuple[list[Joint], list[Body], np.ndarray, np.ndarray]:
    """Luff joint, the RFE spring triples and the element bodies; returns joints, bodies, the boom
    stiffness diagonal for these joints and the element lengths."""
    beam = discretise_beam(boom.length, rfe_count, boom.youngs_modulus, boom.shear_modulus,
                           boom.density, boom.section)
    # Luff frame: column frame rotated by +pi/2 about x, so that its z axis is the column's -y axis
    # and a positive rotation about it lifts the boom's x axis towards the column's z axis.
    joints = [Joint("boom_luff", REVOLUTE, AXES["z"], homogeneous(rotation(0, 0.5 * np.pi), boom.pivot))]
    bodies = [Body("boom_rfe0", first_joint, beam.bodies[0])]
    stiffness = [0.0]
    for r in range(1, rfe_count):
        at_spring = homogeneous(translation=(beam.lengths[r - 1], 0.0, 0.0))
        for suffix, axis, s in zip(("bend_vertical", "bend_lateral", "twist"), "zyx", beam.spring_stiffness[r - 1],
                                   strict=True):
            joints.append(Joint(f"boom_sde{r}_{suffix}", REVOLUTE, AXES[axis], at_spring if axis == "z" else np.eye(4)))
            stiffness.append(s)
        bodies.append(Body(f"boom_rfe{r}", first_joint + len(joints) - 1, beam.bodies[r]))
    return joints, bodies, np.array(stiffness), beam.lengths


def build_model(params: CraneParameters, variant: str = "flexible") -> ChainModel:
    """Chain model of the crane; ``variant`` is ``"flexible"`` (n_rfe from the config) or ``"rigid"``."""
    if variant not in VARIANTS:
        raise ValueError(f"model variant = {variant!r}: must be one of {', '.join(VARIANTS)}")
    rfe_count = params.boom.rfe_count if variant == "flexible" else 1
    joints = _base_joints()
    bodies = [Body("base", 5, params.base)]
    joints.append(Joint("column_slew", REVOLUTE, AXES["z"], np.eye(4)))
    bodies.append(Body("column", 6, params.column))
    boom_joints, boom_bodies, boom_diag, lengths = _boom_joints_and_bodies(params.boom, rfe_count, 7)
    joints += boom_joints
    bodies += boom_bodies
    knuckle_origin = homogeneous(rotation(2, params.link4.offset_angle), (lengths[-1], 0.0, 0.0))
    joints.append(Joint("knuckle", REVOLUTE, AXES["z"], knuckle_origin))
    knuckle = len(joints) - 1
    bodies.append(Body("link4", knuckle, params.link4.body))
    if params.payload_mass > 0.0:
        payload = RigidBody(params.payload_mass, np.asarray(params.link4.end_effector, float), np.zeros((3, 3)))
        bodies.append(Body("payload", knuckle, payload))

    n = len(joints)
    K_support = np.zeros((n, n))
    K_support[:6, :6] = support_stiffness(params.supports)
    K_boom = np.zeros((n, n))
    K_boom[7:7 + len(boom_diag), 7:7 + len(boom_diag)] = np.diag(boom_diag)
    q0 = np.zeros(n)
    q0[6], q0[7], q0[knuckle] = params.initial.column, params.initial.boom, params.initial.knuckle
    return ChainModel(
        variant=variant,
        joints=tuple(joints),
        bodies=tuple(bodies),
        end_effector_joint=knuckle,
        end_effector_point=np.asarray(params.link4.end_effector, dtype=float),
        gravity=params.gravity,
        stiffness=K_support + K_boom,
        support_stiffness=K_support,
        boom_stiffness=K_boom,
        drive_joint=6,
        dependent_joints=(7, knuckle),
        initial_q=q0,
    )

