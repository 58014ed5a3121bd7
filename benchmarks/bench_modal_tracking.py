"""Design study for an O(n) step (issue 53): the modal correction with its resolved modes tracked at every step,
prototyped in NumPy around the package's compiled step, against the package's correction computed afresh every
REFRESH_INTERVAL.  Prints the figures the closing notes and docs/performance.md quote.

    python benchmarks/bench_modal_tracking.py [--minutes 10] [--cutoff 0.3] [--variants refresh tracked tracked-spring]

The undamped default crane at the node's 0.5 ms, ``--minutes`` of the paper's task, with the modes resolved below
omega h = ``--cutoff`` pi: the 40-250 Hz RMS of psi2, psi(3,0), psi4 over the last 10 s as a share of that over
5-15 s (each window filtered with 1 s of motion on both sides), and the mean energy over both windows (no drive, no
dampers, fixed constraints after 5 s: it must stay).

In every variant the full eigenproblem of the pencil (K_r, M_r) is solved every REFRESH_INTERVAL of motion, as the
package does; the variants differ in what happens between:

- ``refresh``: the package's integrator as it is (compiled throughout).  Between refreshes the damping of the
  unresolved modes, D_u = M_r Phi_u diag(2 zeta omega_u) Phi_u^T M_r, comes from an earlier configuration.
- ``tracked``: at every step from 1.5 s the resolved modes Phi_r follow the configuration by one shift-inverted
  subspace iteration from the last ones, X = (K_r + s M_r)^-1 M_r Phi_r (s = SHIFT), and a Rayleigh-Ritz step on X
  (both matrices at the step's start; as many modes as the last refresh resolved); Delta M_r = M_r Phi_r diag(c)
  Phi_r^T M_r from them, and the last refresh's D_u projected off them, P^T D_u P with P = I - Phi_r Phi_r^T M_r, so
  that no resolved mode is damped.
- ``tracked-spring``: as ``tracked`` with D_u = alpha h P^T K_r P, alpha = 2 zeta / cutoff: the unresolved modes'
  damping ratio grows as zeta omega h / cutoff from zeta at the cutoff; the spring matrix less its part on the
  resolved modes needs none of the unresolved modes (an O(n) step's form: sparse plus rank r).

The tracked variants step in Python (one compiled step per call), which is slow: their wall time is printed.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import time

import numpy as np
from bench_accuracy import COORDINATES, VIBRATION_BAND, filtered
from scipy.linalg import cho_factor, cho_solve, eigh

from crane_reference.dynamics.structures import ModalCorrection
from crane_reference.model.config import load_config
from crane_reference.motion.integration import REFRESH_INTERVAL, UNRESOLVED_DAMPING, StepState
from crane_reference.motion.simulation import MotionStepper, Scenario
from crane_reference.motion.steps import ONLINE_STEP

TRACKING_FROM = 1.5  # [s]: after the drive's torque ends at 1 s
SHIFT = 1.0  # [rad^2/s^2]: K_r + SHIFT M_r is positive definite with a mode no spring resists
VARIANTS = ("refresh", "tracked", "tracked-spring")


class Tracker:
    """The modal terms of the ``tracked`` and ``tracked-spring`` variants (see the module docstring) for the
    step h of ``scenario``'s undamped crane."""

    def __init__(self, scenario: Scenario, h: float, cutoff: float, spring: bool):
        motion = scenario.motion
        chain, independent = motion.dynamics.chain, motion.partition.independent
        self.stiffness = chain.stiffness[np.ix_(independent, independent)].copy()
        drive_row = list(independent).index(chain.drive_joint)
        self.stiffness[drive_row, drive_row] += motion.dynamics.drive.kernel_parameters(TRACKING_FROM)[1]
        self.h, self.cutoff, self.spring = h, cutoff, spring
        self.refreshed, self.modes, self.unresolved_damping = -math.inf, np.empty((0, 0)), np.empty((0, 0))

    def refresh(self, reduced_mass: np.ndarray, t: float) -> None:
        """The full eigenproblem: the resolved modes and (``tracked``) the unresolved modes' damping D_u."""
        omega_squared, modes = eigh(self.stiffness, reduced_mass)
        omega = np.sqrt(np.maximum(omega_squared, 0.0))
        resolved = omega * self.h < self.cutoff
        self.modes = modes[:, resolved]
        if not self.spring:
            on_unresolved = reduced_mass @ modes[:, ~resolved]
            self.unresolved_damping = on_unresolved @ np.diag(2.0 * UNRESOLVED_DAMPING * omega[~resolved]) \
                @ on_unresolved.T
        self.refreshed = t

    def correction(self, reduced_mass: np.ndarray, t: float) -> ModalCorrection:
        """Delta M_r and D_u at the configuration of ``reduced_mass``, the resolved modes tracked from the last."""
        if t - self.refreshed >= REFRESH_INTERVAL - 0.5 * self.h:
            self.refresh(reduced_mass, t)
        iterate = cho_solve(cho_factor(self.stiffness + SHIFT * reduced_mass), reduced_mass @ self.modes)
        omega_squared, ritz = eigh(iterate.T @ self.stiffness @ iterate, iterate.T @ reduced_mass @ iterate)
        self.modes = iterate @ ritz
        on_resolved = reduced_mass @ self.modes
        half = 0.5 * np.sqrt(np.maximum(omega_squared, 0.0)) * self.h
        ratio = np.ones_like(half)
        ratio[half > 0.0] = half[half > 0.0] / np.tan(half[half > 0.0])
        inertia = on_resolved @ np.diag(1.0 - ratio**2) @ on_resolved.T
        projector = np.eye(reduced_mass.shape[0]) - self.modes @ on_resolved.T
        if self.spring:
            alpha = 2.0 * UNRESOLVED_DAMPING / self.cutoff
            damping = alpha * self.h * projector.T @ self.stiffness @ projector
        else:
            damping = projector.T @ self.unresolved_damping @ projector
        return ModalCorrection(0.5 * (inertia + inertia.T), 0.5 * (damping + damping.T), t, self.h)


def reduced_mass_at(state: StepState) -> np.ndarray:
    """M_r = B^T M B at the state (its evaluation's M and B)."""
    B = state.solution.velocity_map
    return B.T @ state.solution.dynamics.M @ B


def run(variant: str, minutes: float, cutoff: float) -> None:
    """One variant over ``minutes`` of motion: the RMS and energy of its two windows, printed."""
    scenario = Scenario(load_config(), "flexible")
    q0, h = scenario.equilibrium.q, ONLINE_STEP
    stepper = MotionStepper(scenario.motion, 0.0, q0, np.zeros_like(q0), h)  # every row: its energy
    stepper.integrator.cutoff = cutoff
    end = minutes * 60.0
    windows = ((5.0, 15.0), (end - 10.0, end))
    columns = [scenario.model.joint_names.index(name) for name in COORDINATES]
    start = time.perf_counter()
    kept = []  # per window: times, the three coordinates, energies, with 1 s on both sides for the filter
    if variant == "refresh":
        for a, b in windows:
            while stepper.state.t < a - 1.0 - 1e-9:
                stepper.advance_until(min(stepper.state.t + 10.0, a - 1.0))
            rows = stepper.advance_until(b + 1.0)
            kept.append((rows.t, rows.q[:, columns], rows.kinetic_energy + rows.potential_energy))
    else:
        stepper.advance_until(TRACKING_FROM)
        state, integrator = stepper.state, stepper.integrator
        tracker = Tracker(scenario, h, cutoff, spring=variant == "tracked-spring")
        samples: list[list[tuple[float, np.ndarray, float]]] = [[], []]
        for k in range(1, round((end + 1.0 - TRACKING_FROM) / h) + 1):
            state = dataclasses.replace(state, correction=tracker.correction(reduced_mass_at(state), state.t))
            state = integrator.step(state, TRACKING_FROM + k * h)
            for window, (a, b) in zip(samples, windows, strict=True):
                if a - 1.0 <= state.t <= b + 1.0:
                    window.append((state.t, state.q[columns],
                                   state.solution.kinetic_energy + state.solution.potential_energy))
        kept = [(np.array([s[0] for s in w]), np.array([s[1] for s in w]), np.array([s[2] for s in w]))
                for w in samples]
    results = []
    for (t, x, energy), (a, b) in zip(kept, windows, strict=True):
        inside = (t > a) & (t < b)
        results.append((filtered(t, x, "bandpass", VIBRATION_BAND)[inside].std(axis=0), energy[inside].mean()))
    (early, early_energy), (late, late_energy) = results
    shares = " / ".join(f"{share:.1%}" for share in late / early)
    print(f"[modal tracking] {variant}, cutoff {cutoff / math.pi:g} pi, {minutes:g} min at h={h * 1e3:g} ms "
          f"({time.perf_counter() - start:.0f} s wall): 40-250 Hz RMS psi2/psi30/psi4 over the last 10 s {shares} of "
          f"5-15 s; energy mean {early_energy:.4f} J and {late_energy:.4f} J ({late_energy - early_energy:+.3f} J)",
          flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=10.0, help="minutes of motion per variant")
    parser.add_argument("--cutoff", type=float, default=0.3, help="omega h [pi rad] from which a mode is not resolved")
    parser.add_argument("--variants", nargs="+", choices=VARIANTS, default=list(VARIANTS))
    args = parser.parse_args()
    for variant in args.variants:
        run(variant, args.minutes, args.cutoff * math.pi)


if __name__ == "__main__":
    main()
