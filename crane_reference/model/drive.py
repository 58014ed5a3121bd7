"""Column drive: the generalized force t_dr^(2) on psi2 (positive increases psi2).

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

from .parameters import CraneParameters, FlexibleDrive, TorqueDrive
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


Drive = TorqueSource | SpringDrive


def column_drive(config: CraneParameters, torque: float | None = None,
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
