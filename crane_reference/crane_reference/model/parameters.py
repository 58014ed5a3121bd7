"""Physical parameters of the crane, as read from ``config/crane.yaml`` (SI units throughout).

Frames (all right-handed):

* ``{0}`` world: z up, gravity along -z; at rest the base frame coincides with it.
* ``{1}`` base frame: origin at the base reference point, z up.  Its motion is
  ``T1 = Trans(x, y, z) Rz(psi) Ry(theta) Rx(phi)`` (ZYX order, eq. (1)).
* ``{2}`` column frame: rotated by ``psi2`` about the base z axis (positive counter-clockwise seen from
  above).  The boom points along the column's +x axis, so ``psi2 = 3*pi/2`` points it along world -y.
* boom frames: x along the boom axis, y up in the luffing plane, z along the luff axis (which is the
  column's -y axis), so that a positive luff angle ``psi(3,0)`` raises the boom.
* link 4 frame: x along link 4 from the knuckle towards E; the knuckle axis is the boom tip's z axis.

The dataclasses hold numbers only; validation lives in :mod:`crane_reference.model.config`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class RigidBody:
    """Mass [kg], centre of mass [m] and inertia tensor about the centre of mass [kg m^2], all in the
    body's own frame."""

    mass: float
    center_of_mass: np.ndarray
    inertia: np.ndarray

    def pseudo_inertia(self) -> np.ndarray:
        """Pseudo-inertia matrix H = integral of [r; 1][r; 1]^T dm (4x4) in the body frame.

        With J_c = tr(I_c)/2 * 1 - I_c (the second-moment tensor about the centre of mass c),
        H = [[J_c + m c c^T, m c], [m c^T, m]].
        """
        c = np.asarray(self.center_of_mass, dtype=float)
        second_moment = 0.5 * np.trace(self.inertia) * np.eye(3) - self.inertia
        H = np.zeros((4, 4))
        H[:3, :3] = second_moment + self.mass * np.outer(c, c)
        H[:3, 3] = H[3, :3] = self.mass * c
        H[3, 3] = self.mass
        return H


@dataclass(frozen=True)
class SupportSpring:
    """One of the n_s support springs between base and ground: attachment point r = (x, y, z) in the
    base frame and stiffness diag(s_x, s_y, s_z) [N/m] (matrix S^(sup,s) of the paper)."""

    position: np.ndarray
    stiffness: np.ndarray


@dataclass(frozen=True)
class BeamSection:
    """Cross-section of the boom: area A [m^2], second moments of area I_y (bending about the boom's
    y axis, i.e. in the horizontal plane) and I_z (bending about z, i.e. in the luffing plane) [m^4],
    and the torsion constant J [m^4]."""

    area: float
    second_moment_y: float
    second_moment_z: float
    torsion_constant: float


@dataclass(frozen=True)
class Boom:
    """Link 3: a uniform prismatic beam along its x axis, hinged at ``pivot`` (column frame)."""

    pivot: np.ndarray
    length: float
    youngs_modulus: float
    shear_modulus: float
    density: float
    section: BeamSection
    rfe_count: int


@dataclass(frozen=True)
class LastLink:
    """Link 4: rigid body in its own frame, E at ``end_effector``; ``offset_angle`` is the constant
    built-in rotation about the knuckle axis added to psi4 [rad]."""

    body: RigidBody
    end_effector: np.ndarray
    offset_angle: float


@dataclass(frozen=True)
class Damping:
    """Stiffness-proportional (Rayleigh beta) damping coefficients [s]: D = beta_support * K_support +
    beta_boom * K_boom.  Zero (the paper's undamped model) by default."""

    support: float = 0.0
    boom: float = 0.0


@dataclass(frozen=True)
class TorqueDrive:
    """Column torque t_dr(t) = torque for start <= t < end, else 0 [N m]; positive increases psi2."""

    torque: float = 4000.0
    start: float = 0.0
    end: float = 1.0


@dataclass(frozen=True)
class FlexibleDrive:
    """Flexible drive t_dr = s_dr (psi_a(t) - psi2) with the motor angle psi_a moving by ``travel`` [rad]
    from its start value (the column's initial angle) along a quintic over [start, start + duration]."""

    stiffness: float
    travel: float
    start: float
    duration: float


@dataclass(frozen=True)
class InitialConfiguration:
    """Angles of configuration (9) [rad]: column psi2, boom luff psi(3,0), knuckle psi4."""

    column: float = 1.5 * np.pi
    boom: float = 0.25 * np.pi
    knuckle: float = 1.5 * np.pi


@dataclass(frozen=True)
class Task:
    """Programmed constraints (5.1)-(5.2): ellipse semi-axes a, b [m] in the world XY plane, centred
    on the world z axis; E's height rises by ``z_increment`` [m] along the quintic over ``rise_time``
    t_c [s] from its static value z_E,s."""

    ellipse_a: float = 3.0
    ellipse_b: float = 2.0
    z_increment: float = 0.2
    rise_time: float = 5.0


@dataclass(frozen=True)
class CraneParameters:
    """Everything ``config/crane.yaml`` describes."""

    gravity: float
    base: RigidBody
    supports: tuple[SupportSpring, ...]
    column: RigidBody
    boom: Boom
    link4: LastLink
    payload_mass: float
    drive: TorqueDrive | FlexibleDrive
    damping: Damping = field(default_factory=Damping)
    initial: InitialConfiguration = field(default_factory=InitialConfiguration)
    task: Task = field(default_factory=Task)
