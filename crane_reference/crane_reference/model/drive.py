"""The drive: the generalized force t_dr on its joint (the paper's column drive on psi2; positive along +q).

* :class:`TorqueSource` - a prescribed torque profile (the paper's 4000 N m for 0 <= t < 1 s).
* :class:`SpringDrive` - the paper's flexible drive, E_p,dr = 1/2 s_dr (psi_a - psi2)^2, i.e. the
  generalized force -dE_p,dr/dpsi2 = s_dr (psi_a(t) - psi2), following a motor angle psi_a(t).

Both hand the compiled solver (tau0, s_dr, psi_a, dpsi_a/dt) with t_dr = tau0 + s_dr (psi_a - psi2);
the energies and powers of the drive follow from these (:func:`crane_reference.dynamics.terms.energy_accounts`):
a torque source delivers t_dr * dpsi2/dt; for the spring drive the stored energy E_p,dr is counted as
potential energy and the motor feeds s_dr (psi_a - psi2) * dpsi_a/dt.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .description import CraneDescription
from .parameters import FlexibleDrive, TorqueDrive
from .profiles import Profile, QuinticRise


@dataclass(frozen=True)
class TorqueSource:
    torque_value: float
    start: float
    end: float

    @property
    def breakpoints(self) -> tuple[float, ...]:
        """Times where the torque jumps (an integrator should step onto them)."""
        return (self.start, self.end)

    def kernel_parameters(self, t: float | np.ndarray, left_limit: bool = False) -> np.ndarray:
        """(tau0, s_dr, psi_a, dpsi_a/dt) = (t_dr(t), 0, 0, 0), for the compiled solver (shape (4,), or
        (N, 4) for N times); with ``left_limit`` the limit from below, t_dr(t-) (for a step ending on a jump)."""
        on = ((self.start < t) & (t <= self.end)) if left_limit else ((self.start <= t) & (t < self.end))
        parameters = np.zeros((*np.shape(t), 4))
        parameters[..., 0] = np.where(on, self.torque_value, 0.0)
        return parameters


@dataclass(frozen=True)
class SpringDrive:
    stiffness: float
    motor_angle: Profile

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return ()

    def kernel_parameters(self, t: float | np.ndarray, left_limit: bool = False) -> np.ndarray:
        """(tau0, s_dr, psi_a, dpsi_a/dt) = (0, s_dr, psi_a(t), dpsi_a/dt), for the compiled solver (shape (4,),
        or (N, 4) for N times; continuous in t, so ``left_limit`` changes nothing)."""
        angle, rate, _ = self.motor_angle(t)
        parameters = np.zeros((*np.shape(t), 4))
        parameters[..., 1], parameters[..., 2], parameters[..., 3] = self.stiffness, angle, rate
        return parameters


class Actuated:
    """A column drive with actuators: generalized forces tau_a (n,) [N m on joints, N on prismatic
    coordinates] added on the coordinates (positive along +q), commanded over one interval at a time and
    linear in time on it (equal ends: a zero-order hold).  The kernels get the drive's parameters followed
    by tau_a (:data:`crane_reference.dynamics.terms.DRIVE_PARAMETERS`); the accounts count tau_a^T qd as
    power fed in.  A new command jumps the forces at its start time: the integrator must restart there
    (:meth:`crane_reference.motion.simulation.MotionStepper.forces_changed`).  Before the first command
    tau_a = 0."""

    def __init__(self, drive: TorqueSource | SpringDrive, dof: int):
        self.drive = drive
        self.dof = dof
        self._interval = (-np.inf, np.inf)
        self._ends = (np.zeros(dof), np.zeros(dof))

    @property
    def breakpoints(self) -> tuple[float, ...]:
        return self.drive.breakpoints

    def command(self, start: float, end: float, forces_start: np.ndarray, forces_end: np.ndarray) -> None:
        """tau_a over [start, end] [s]: ``forces_start`` at start, ``forces_end`` at end, linear between."""
        if not end > start:
            raise ValueError(f"actuation interval [{start}, {end}] s: the end must be after the start")
        ends = (np.asarray(forces_start, dtype=float), np.asarray(forces_end, dtype=float))
        for name, forces in zip(("forces_start", "forces_end"), ends, strict=True):
            if forces.shape != (self.dof,) or not np.all(np.isfinite(forces)):
                raise ValueError(f"actuation {name}: must be {self.dof} finite generalized forces, got {forces}")
        self._interval, self._ends = (start, end), ends

    def forces(self, t: float | np.ndarray) -> np.ndarray:
        """tau_a at t (shape (n,), or (N, n) for N times) inside the commanded interval."""
        (start, end), (first, last) = self._interval, self._ends
        t = np.asarray(t, dtype=float)
        slack = 1e-9 * max(1.0, abs(end))
        if np.any(t < start - slack) or np.any(t > end + slack):
            raise ValueError(f"actuation asked at t = {t} s, outside its commanded interval [{start}, {end}] s")
        if not np.isfinite(end - start):
            return np.broadcast_to(first, (*t.shape, self.dof)).copy()
        share = ((t - start) / (end - start))[..., None]
        return (1.0 - share) * first + share * last

    def kernel_parameters(self, t: float | np.ndarray, left_limit: bool = False) -> np.ndarray:
        """The drive's (tau0, s_dr, psi_a, dpsi_a/dt) followed by tau_a at t (shape (4 + n,) or (N, 4 + n))."""
        return np.concatenate((self.drive.kernel_parameters(t, left_limit), self.forces(t)), axis=-1)


Drive = TorqueSource | SpringDrive | Actuated


def column_drive(config: CraneDescription, torque: float | None = None,
                 duration: float | None = None) -> TorqueDrive | FlexibleDrive:
    """The column drive of ``config``: its flexible drive as it is, else its torque profile with
    ``torque`` [N m] applied for ``duration`` [s] from its start (by default the config's own)."""
    if isinstance(config.drive, FlexibleDrive):
        return config.drive
    torque = config.drive.torque if torque is None else torque
    duration = config.drive.end - config.drive.start if duration is None else duration
    return TorqueDrive(torque=torque, start=config.drive.start, end=config.drive.start + duration)


def make_drive(spec: TorqueDrive | FlexibleDrive, psi2_start: float) -> Drive:
    """Drive model from its configuration; the motor angle of a spring drive starts at ``psi2_start``."""
    if isinstance(spec, TorqueDrive):
        return TorqueSource(spec.torque, spec.start, spec.end)
    return SpringDrive(spec.stiffness, QuinticRise(psi2_start, spec.travel, spec.start, spec.duration))
