"""Results of a programmed-motion run: samples, interpolation and CSV / NPZ export.

Units: s, m, rad, N, N m, J.  E's pose is given in the world frame {0}; its orientation is the
rotation of link 4's frame as a quaternion (x, y, z, w).  ``reactions`` are the multipliers lambda
(ideal constraints) or the dependent joints' torques (servo-constraints); ``constraint_forces`` the
generalized force they exert (A^T lambda, the KKT form of (8), or tau on the dependent joints);
``drive_torque`` the column drive t_dr^(2); their sum is the generalized effort task and drive require.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from pathlib import Path
from typing import NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

from .programmed_motion import MotionSolution


@dataclass(frozen=True)
class MotionSample:
    """One instant of the motion (E's orientation as the rotation matrix of link 4's frame)."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    reactions: np.ndarray
    constraint_forces: np.ndarray
    drive_torque: float
    ee_position: np.ndarray
    ee_rotation: np.ndarray
    ee_velocity: np.ndarray
    residual: np.ndarray
    residual_distance: np.ndarray
    kdc_min_singular_value: float
    kinetic_energy: float
    potential_energy: float
    work_drive: float
    work_constraints: float
    work_damping: float


def make_sample(t: float, q: np.ndarray, qd: np.ndarray, solution: MotionSolution, work: np.ndarray) -> MotionSample:
    """Assemble a :class:`MotionSample` from the solution of (8) at (t, q, qd) and the work done so far by the
    drive, the constraint forces and the dampers."""
    dyn, con = solution.dynamics, solution.constraints
    return MotionSample(t, q, qd, solution.qdd, solution.reactions, solution.constraint_forces, solution.drive_torque,
                  dyn.ee_position, dyn.ee_rotation, dyn.ee_jacobian @ qd, con.residual, con.distance,
                  solution.kdc_min_singular_value, solution.kinetic_energy, solution.potential_energy,
                  float(work[0]), float(work[1]), float(work[2]))


def cubic_hermite(t: float | np.ndarray, times: np.ndarray, values: np.ndarray, rates: np.ndarray) -> np.ndarray:
    """The piecewise cubic Hermite interpolant of ``values`` (N, ...) with derivatives ``rates`` at the
    increasing ``times`` (N,), at t (scalar or (M,)) inside [times[0], times[-1]]: on [t_k, t_k+1] with
    h = t_k+1 - t_k and s = (t - t_k) / h,

        y = (2s^3 - 3s^2 + 1) y_k + (s^3 - 2s^2 + s) h y'_k + (-2s^3 + 3s^2) y_k+1 + (s^3 - s^2) h y'_k+1.

    (scipy's CubicHermiteSpline, without its set-up cost for the two-point case of the online sampler.)"""
    times = np.asarray(times, dtype=float)
    t_array = np.asarray(t, dtype=float)
    k = np.clip(np.searchsorted(times, t_array, side="right") - 1, 0, max(times.size - 2, 0))
    if times.size == 1:
        return np.broadcast_to(values[0], (*t_array.shape, *values.shape[1:])).copy()
    h = times[k + 1] - times[k]
    s = (t_array - times[k]) / h
    shape = (*s.shape, *(1,) * (values.ndim - 1))
    return hermite_segment(s.reshape(shape), h.reshape(shape), values[k], rates[k], values[k + 1], rates[k + 1])


def hermite_segment(s: np.ndarray, h: np.ndarray, y0: np.ndarray, rate0: np.ndarray, y1: np.ndarray,
                    rate1: np.ndarray) -> np.ndarray:
    """The cubic of :func:`cubic_hermite` on one interval of length h at s = (t - t_k) / h, for values y0, y1
    and derivatives rate0, rate1 at its ends (s and h broadcast against the values)."""
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    return h00 * y0 + h10 * h * rate0 + h01 * y1 + h11 * h * rate1


def generalized_effort(constraint_forces: np.ndarray, drive_torque: float | np.ndarray,
                       drive_joint: int) -> np.ndarray:
    """The generalized force task and drive require: the constraint forces plus the drive torque on its
    joint (last axis: coordinates; a single sample or stacked ones)."""
    effort = np.array(constraint_forces, dtype=float)
    effort[..., drive_joint] += drive_torque
    return effort


class MotionRows(NamedTuple("MotionRowFields", [(f.name, np.ndarray) for f in fields(MotionSample)])):
    """Samples of the motion stacked, a row a step (first axis: sample): the fields of :class:`MotionSample`, each
    an array, as the integrator's runs give them (:meth:`~.simulation.MotionStepper.advance_until`)."""

    __slots__ = ()

    @classmethod
    def stacked(cls, samples: list[MotionSample]) -> MotionRows:
        """The fields of ``samples`` stacked into arrays."""
        return cls(*(np.array([getattr(s, name) for s in samples]) for name in cls._fields))

    @classmethod
    def joined(cls, parts: list[MotionRows]) -> MotionRows:
        """Consecutive rows, in order."""
        return cls(*(np.concatenate(columns) for columns in zip(*parts, strict=True)))

    def take(self, rows: slice | np.ndarray) -> MotionRows:
        """The ``rows`` (a slice or indices)."""
        return MotionRows(*(column[rows] for column in self))


@dataclass(frozen=True)
class Trajectory:
    """Samples of one run stacked into arrays (first axis: time)."""

    variant: str
    joint_names: tuple[str, ...]
    drive_joint: int
    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    reactions: np.ndarray
    constraint_forces: np.ndarray
    drive_torque: np.ndarray
    ee_position: np.ndarray
    ee_quaternion: np.ndarray
    ee_velocity: np.ndarray
    residual: np.ndarray
    residual_distance: np.ndarray
    kdc_min_singular_value: np.ndarray
    kinetic_energy: np.ndarray
    potential_energy: np.ndarray
    work_drive: np.ndarray
    work_constraints: np.ndarray
    work_damping: np.ndarray

    @classmethod
    def from_samples(cls, variant: str, joint_names: list[str], drive_joint: int,
                     samples: list[MotionSample]) -> Trajectory:
        return cls.from_rows(variant, joint_names, drive_joint, MotionRows.stacked(samples))

    @classmethod
    def from_rows(cls, variant: str, joint_names: list[str], drive_joint: int, rows: MotionRows) -> Trajectory:
        """From the rows of a run (E's orientation as a quaternion, scalar last)."""
        arrays = rows._asdict()
        arrays["ee_quaternion"] = Rotation.from_matrix(arrays.pop("ee_rotation")).as_quat()
        return cls(variant=variant, joint_names=tuple(joint_names), drive_joint=drive_joint, **arrays)

    @classmethod
    def concatenated(cls, parts: list[Trajectory]) -> Trajectory:
        """The samples of consecutive runs of one model, in order."""
        first = parts[0]
        return cls(first.variant, first.joint_names, first.drive_joint,
                   *(np.concatenate([getattr(part, name) for part in parts]) for name in _SAMPLED))

    def subsampled(self, stride: int = 1, count: int | None = None) -> Trajectory:
        """Every ``stride``-th sample (the first ``count`` of them)."""
        return type(self)(self.variant, self.joint_names, self.drive_joint,
                          *(getattr(self, name)[::stride][:count] for name in _SAMPLED))

    @property
    def total_energy(self) -> np.ndarray:
        return self.kinetic_energy + self.potential_energy

    @property
    def energy_balance_error(self) -> np.ndarray:
        """E(t) - E(0) - (work of drive + constraint forces + dampers) [J]; zero for the exact motion."""
        work = self.work_drive + self.work_constraints + self.work_damping
        return self.total_energy - self.total_energy[0] - work

    @property
    def effort(self) -> np.ndarray:
        """Generalized forces of constraints and drive (N, n)."""
        return generalized_effort(self.constraint_forces, self.drive_torque, self.drive_joint)

    def coordinate(self, name: str) -> np.ndarray:
        return self.q[:, self.joint_names.index(name)]

    def interpolate(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """q, qd (cubic Hermite: C1 and consistent with the stored rates) and E's position at t."""
        return (cubic_hermite(t, self.t, self.q, self.qd), cubic_hermite(t, self.t, self.qd, self.qdd),
                cubic_hermite(t, self.t, self.ee_position, self.ee_velocity))

    def columns(self) -> tuple[list[str], np.ndarray]:
        """CSV layout: t, one column per joint, ee_x ee_y ee_z, then velocities, E's orientation,
        residuals, energies and work."""
        names = ["t", *self.joint_names, "ee_x", "ee_y", "ee_z",
                 *(f"{n}_velocity" for n in self.joint_names),
                 "ee_qx", "ee_qy", "ee_qz", "ee_qw",
                 *(f"constraint{i + 1}_distance_m" for i in range(self.residual.shape[1])),
                 "drive_torque", "kinetic_energy", "potential_energy", "work_drive", "work_constraints",
                 "work_damping", "kdc_min_singular_value"]
        data = np.column_stack([self.t, self.q, self.ee_position, self.qd, self.ee_quaternion,
                                self.residual_distance, self.drive_torque, self.kinetic_energy,
                                self.potential_energy, self.work_drive, self.work_constraints, self.work_damping,
                                self.kdc_min_singular_value])
        return names, data

    def to_csv(self, path: str | Path) -> None:
        """Write the CSV at full double precision (17 significant digits)."""
        names, data = self.columns()
        np.savetxt(path, data, delimiter=",", header=",".join(names), comments="", fmt="%.17g")

    def to_npz(self, path: str | Path) -> None:
        np.savez_compressed(path, joint_names=np.array(self.joint_names), variant=self.variant,
                            drive_joint=self.drive_joint, **{name: getattr(self, name) for name in _SAMPLED})

    @classmethod
    def from_npz(cls, path: str | Path) -> Trajectory:
        with np.load(path) as data:
            arrays = {k: data[k] for k in data.files}
        return cls(variant=str(arrays.pop("variant")), joint_names=tuple(str(n) for n in arrays.pop("joint_names")),
                   drive_joint=int(arrays.pop("drive_joint")), **arrays)


_SAMPLED = tuple(f.name for f in fields(Trajectory) if f.name not in ("variant", "joint_names", "drive_joint"))
"""The fields of :class:`Trajectory` with one row per sample."""
