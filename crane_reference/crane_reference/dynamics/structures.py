"""Named data passed to and returned by the compiled kernels (numba-compatible named tuples).

In the spirit of Pinocchio's Model / Data: :class:`ChainData` is the immutable description of the
chain (built once per model by :class:`~crane_reference.dynamics.chain_dynamics.CraneDynamics`),
:class:`Partition` and :class:`StepSettings` fix the problem and the method, :class:`ModalCorrection` is the
method's own state, and the kernels return :class:`Evaluation`, :class:`EvaluatedStep` and :class:`StepRows` by name.
Every field is documented here once.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class ChainData(NamedTuple):
    """The serial chain in the layout of the kernels.

    ``kinds`` (n,) joint kind (0 prismatic, 1 revolute), ``axes`` (n,) local axis index, ``origins``
    (n, 4, 4) constant offsets; ``body_joint`` (b,) the joint each body moves with, ``body_H`` (b, 4, 4)
    their pseudo-inertia matrices in the joint frame; ``gravity`` [m/s^2] (along -z);
    ``ee_joint`` and ``ee_point`` (3,): E's frame and position in it; ``stiffness`` K and ``damping``
    D (n, n), ``damped`` whether D has a non-zero entry; ``drive_joint``: the coordinate the column drive
    acts on (psi2); ``root_size``: the joints up to the last that K or D couples to another (an off-diagonal
    entry), the root block of :mod:`~crane_reference.dynamics.articulated`."""

    kinds: np.ndarray
    axes: np.ndarray
    origins: np.ndarray
    body_joint: np.ndarray
    body_H: np.ndarray  # noqa: N815 (the paper's H)
    gravity: float
    ee_joint: int
    ee_point: np.ndarray
    stiffness: np.ndarray
    damping: np.ndarray
    damped: bool
    drive_joint: int
    root_size: int


class Coefficients(NamedTuple):
    """Quadric task constraints stacked in z = (p, p') [m, m/s] (see :mod:`crane_reference.motion.constraints`):
    Q (m, 3, 6, 6), g (m, 3, 6), c (m, 3) (second axis: value, first and second time derivative; a
    holonomic row uses the p block only, a first-order row the value and first derivative only) and
    ``order`` (m,): 0 holonomic, 1 first order.  For a run of steps Q, g, c carry a leading step axis."""

    Q: np.ndarray
    g: np.ndarray
    c: np.ndarray
    order: np.ndarray


class Partition(NamedTuple):
    """Coordinate partitioning (eqs. (2)-(3)): ``independent`` q_ic; ``dependent`` q_dc (dependent[i] is
    solved from constraint i); ``integrated`` the coordinates the integrator advances, q_ic then those
    made dependent by first-order constraints (q_vd); ``holonomic_dependent`` q_hd, solved from the
    position constraints; ``servo``: servo-constraints (P = E_ic) instead of ideal ones (P = B)."""

    independent: np.ndarray
    dependent: np.ndarray
    integrated: np.ndarray
    holonomic_dependent: np.ndarray
    servo: bool


class StepSettings(NamedTuple):
    """The integrator's rules (see :mod:`crane_reference.motion.integration`): at least ``evaluations``
    Newton evaluations per step, then until the last velocity correction is at most ``tolerance`` [rad/s or
    m/s], at most ``max_iterations``; ``projection_tolerance`` [rad] of Newton on the position constraints;
    the modal correction is computed again after ``refresh_interval`` [s] of motion (and for a new step
    size); modes at or above omega_c = min(``cutoff`` [rad] / h, ``resolved_bandwidth`` [rad/s])
    (:func:`~crane_reference.dynamics.modal_correction.cutoff_angular_frequency`) are not resolved by the step and
    get the damping ratio ``unresolved_damping`` omega / omega_c (stiffness-proportional: ``unresolved_damping`` at
    omega_c); between, the resolved modes are tracked to the configuration after every
    ``mode_tracking_interval`` [s] of motion (:func:`~crane_reference.dynamics.modal_correction.tracked_correction`;
    0: every step, inf: never); without ``modal`` there is no modal correction (the plain trapezoidal rule, for
    comparison); with ``articulated`` the Newton iteration matrix is solved by the articulated-body recursion and
    Woodbury's identity (:mod:`~crane_reference.dynamics.iteration_matrix`), else factored densely; with
    ``subspace_refresh`` a refresh for the same step size iterates the last modes
    (:func:`~crane_reference.dynamics.modal_correction.refreshed_correction`), else solves the full eigenproblem."""

    evaluations: int
    tolerance: float
    max_iterations: int
    projection_tolerance: float
    refresh_interval: float
    cutoff: float
    resolved_bandwidth: float
    unresolved_damping: float
    mode_tracking_interval: float
    modal: bool
    articulated: bool
    subspace_refresh: bool


class ModalCorrection(NamedTuple):
    """The integrator's modal terms in the independent coordinates (n_ic, n_ic), computed at ``time`` [s]
    for the step ``step`` [s] (see :func:`crane_reference.dynamics.modal_correction.modal_correction`): ``inertia``
    Delta M_r, removed from the reduced mass so that the trapezoidal rule turns each resolved mode by
    exactly omega h per step, and ``damping`` D_u, which gives each resolved mode its exact decay per step
    and damps the modes the step does not resolve; ``modes`` (n_ic, n_ic), whose first ``resolved`` columns are
    the resolved modes Phi_r (Phi_r^T M_r Phi_r = I, ascending in frequency) at the configuration of the terms, and
    whose next columns are the modes above them as the last refresh computed them (all of them by the full
    eigenproblem; :data:`~crane_reference.dynamics.modal_correction.GUARD_MODES` of them by subspace iteration,
    then zeros): the next iterated refresh starts from the resolved and those guard columns; ``tracked`` [s], when
    the modes were
    last tracked or computed; and the same terms by the resolved modes alone, which the residual and the articulated
    iteration matrix use: ``on_resolved`` U = M_r Phi_r (its first ``resolved`` columns; zeros beyond),
    ``inertia_weights`` c and ``damping_weights`` e - beta omega^2 (the first ``resolved`` entries) and
    ``unresolved_beta`` beta [s], with Delta M_r = U diag(c) U^T and D_u = U diag(e - beta omega^2) U^T + beta K_r."""

    inertia: np.ndarray
    damping: np.ndarray
    modes: np.ndarray
    resolved: int
    time: float
    step: float
    tracked: float
    on_resolved: np.ndarray
    inertia_weights: np.ndarray
    damping_weights: np.ndarray
    unresolved_beta: float


class ChainTerms(NamedTuple):
    """The chain's terms at (q, qd): mass matrix M, velocity terms h, gravity forces, total gravity
    potential, E's position, the rotation of its frame, its Jacobian C (3, n) and bias d (p'' = C qdd + d)."""

    M: np.ndarray
    h: np.ndarray
    gravity_forces: np.ndarray
    gravity_potential: float
    ee_position: np.ndarray
    ee_rotation: np.ndarray
    ee_jacobian: np.ndarray
    ee_bias: np.ndarray


class Projection(NamedTuple):
    """q on the position constraints (the holonomically dependent coordinates solved), the frames T and
    twists S, E's position and Jacobian there, and whether Newton converged."""

    q: np.ndarray
    T: np.ndarray
    S: np.ndarray
    ee_position: np.ndarray
    ee_jacobian: np.ndarray
    solved: bool


class RefreshInputs(NamedTuple):
    """What a refresh of the modal correction reads at a configuration q with velocity map B: the reduced mass
    M_r = B^T M B, the twists S and the world pseudo-inertias Hw."""

    reduced_mass: np.ndarray
    S: np.ndarray
    Hw: np.ndarray


class TrialState(NamedTuple):
    """A state the integrator tries: q (on the position constraints, or with q_hd as predicted), qd with
    qd_dc from the velocity constraints, the frames T and twists S, E's position and Jacobian, and whether
    the constraints were met."""

    q: np.ndarray
    qd: np.ndarray
    T: np.ndarray
    S: np.ndarray
    ee_position: np.ndarray
    ee_jacobian: np.ndarray
    solved: bool


class StateTerms(NamedTuple):
    """What (7)-(8) need at (q, qd) before the accelerations are known: :class:`Accelerations` without qdd,
    with the particular solution e_dc of the acceleration constraints (qdd = B qdd_ic + e)."""

    M: np.ndarray
    h: np.ndarray
    forces: np.ndarray
    gravity_forces: np.ndarray
    gravity_potential: float
    ee_position: np.ndarray
    ee_rotation: np.ndarray
    ee_jacobian: np.ndarray
    ee_bias: np.ndarray
    A: np.ndarray
    c: np.ndarray
    velocity_map: np.ndarray
    particular: np.ndarray


class Accelerations(NamedTuple):
    """What (8) needs and gives at (q, qd): mass matrix M, velocity terms h, generalized forces Q (gravity,
    springs, dampers, drive) and the gravity forces Q_g among them, total gravity potential, E's position,
    frame rotation, Jacobian C (3, n) and bias d (p'' = C qdd + d), the constraint rows A (m, n) and
    right-hand side c of A qdd = c, the velocity map B (n, n_ic) and qdd."""

    M: np.ndarray
    h: np.ndarray
    forces: np.ndarray
    gravity_forces: np.ndarray
    gravity_potential: float
    ee_position: np.ndarray
    ee_rotation: np.ndarray
    ee_jacobian: np.ndarray
    ee_bias: np.ndarray
    A: np.ndarray
    c: np.ndarray
    velocity_map: np.ndarray
    qdd: np.ndarray


class Evaluation(NamedTuple):
    """:class:`Accelerations` (``terms``) completed with the constraint residuals (Phi or Psi), their
    gradients (Phi_p or Psi_v, (m, 3)), distances |residual| / |gradient| and velocity-level residuals;
    the reactions (lambda for ideal constraints, the dependent joints' torques for servo-constraints),
    their generalized force M qdd + h - forces, and the accounts (see :data:`ACCOUNTS`)."""

    terms: Accelerations
    residual: np.ndarray
    gradients: np.ndarray
    distance: np.ndarray
    velocity_residual: np.ndarray
    reactions: np.ndarray
    constraint_forces: np.ndarray
    accounts: np.ndarray


ACCOUNTS = ("kinetic_energy", "potential_energy", "drive_torque", "drive_power", "constraint_power",
            "damping_power", "kdc_min_singular_value")
"""Columns of :attr:`Evaluation.accounts`: E_k, E_p [J], t_dr [N m], the powers fed in by the drive, the
constraint forces and the dampers [W], and sigma_min(K_dc)."""
SINGULAR_VALUE, DRIVE_TORQUE = ACCOUNTS.index("kdc_min_singular_value"), ACCOUNTS.index("drive_torque")
"""Columns of :data:`ACCOUNTS`: sigma_min(K_dc) and the drive torque."""
POWERS = np.array([ACCOUNTS.index(name) for name in ("drive_power", "constraint_power", "damping_power")])
"""Columns of :data:`ACCOUNTS` whose time integrals are the work terms (drive, constraints, dampers)."""



class EvaluatedStep(NamedTuple):
    """One integration step: q, qd at its end, the evaluation there, the integrated coordinates' accelerations
    at its start and the one before (the next step's ``earlier``), the modal correction it used, ``status``
    (:data:`STATUS_MESSAGES`) and the Newton iterations."""

    q: np.ndarray
    qd: np.ndarray
    evaluation: Evaluation
    earlier: np.ndarray
    correction: ModalCorrection
    status: int
    iterations: int


CONVERGED, NOT_CONVERGED, CONSTRAINTS_UNSOLVABLE, NON_FINITE = 0, 1, 2, 3
STATUS_MESSAGES = {
    NOT_CONVERGED: "the step from t = {t0:.6g} s with h = {h:g} s did not converge in {iterations} Newton iterations",
    CONSTRAINTS_UNSOLVABLE: "position or velocity constraints cannot be met at t = {t1:.6g} s: the target is not "
                            "reachable",
    NON_FINITE: "the step from t = {t0:.6g} s with h = {h:g} s overflowed: its state or accelerations are not "
                "finite (forces or speeds beyond floating point)",
}
"""A step's ``status``: converged, Newton did not converge, the constraints could not be solved, or the step
overflowed; the messages of the failures (formatted with t0, t1, h and iterations)."""


class StepStart(NamedTuple):
    """The state an integration step starts from: the time ``t`` [s], q, qd and the integrator's qdd there, the
    velocity map B there (``velocity_map``), the integrated coordinates' accelerations at the two steps' starts
    before (``earlier`` (2, n_x), NaN where unknown) and the modal ``correction`` in use."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    velocity_map: np.ndarray
    earlier: np.ndarray
    correction: ModalCorrection


class StepEnd(NamedTuple):
    """One integration step's end: q, qd and the integrator's qdd, the velocity map B, the integrated
    coordinates' accelerations at the step's start and the one before (the next step's ``earlier``), E's
    position, the rotation of its frame and its velocity, sigma_min(K_dc), the modal correction used, ``status``
    (:data:`STATUS_MESSAGES`) and the Newton iterations (the full :class:`Evaluation` there is computed only
    where it is read)."""

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    velocity_map: np.ndarray
    earlier: np.ndarray
    ee_position: np.ndarray
    ee_rotation: np.ndarray
    ee_velocity: np.ndarray
    kdc_min_singular_value: float
    correction: ModalCorrection
    status: int
    iterations: int


class StepRows(NamedTuple):
    """Per-step results of a compiled run (first axis: step): q, qd, qdd, the reactions and their
    generalized force, E's position, rotation matrix and velocity, the constraint residuals and
    distances, the accounts (:data:`ACCOUNTS`) and the Newton iterations (reactions, residuals and accounts
    NaN on the rows a run did not evaluate, but for sigma_min(K_dc))."""

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    reactions: np.ndarray
    constraint_forces: np.ndarray
    ee_position: np.ndarray
    ee_rotation: np.ndarray
    ee_velocity: np.ndarray
    residual: np.ndarray
    residual_distance: np.ndarray
    accounts: np.ndarray
    iterations: np.ndarray


class Run(NamedTuple):
    """A compiled run of steps: how many completed, the status of the last one (0 when all
    converged), the per-step rows and the last :class:`EvaluatedStep`."""

    completed: int
    status: int
    rows: StepRows
    last: EvaluatedStep


class PlantModel(NamedTuple):
    """The actuated plant as the compiled closed loop steps it: the constraint coefficients ``k`` (the plant has
    none), its ``partition``, ``chain`` and integrator ``settings``, the ``actuated`` coordinates (n_a,) and the
    joint drives' velocity loops ``joint_damping`` kd (n_a,) [N m s/rad or N s/m]."""

    k: Coefficients
    partition: Partition
    chain: ChainData
    settings: StepSettings
    actuated: np.ndarray
    joint_damping: np.ndarray


class PlannedSteps(NamedTuple):
    """Integration steps planned ahead (``MotionStepper.step_plan``): their end ``times`` (S,) [s], ``on_jump`` (S,)
    where a step ends on a jump of the column drive's torque, and the column drive's parameters at the step ends,
    left limits there (``inner`` (S, 4)), and at the start and the step ends, right limits, where the integrator
    restarts (``inner_after`` (S + 1, 4))."""

    times: np.ndarray
    on_jump: np.ndarray
    inner: np.ndarray
    inner_after: np.ndarray


class Ticks(NamedTuple):
    """What the controller's ticks of a compiled closed loop read: tick k ends at ``ends`` [k] (K,) [s] and spans
    the steps first_step[k] .. first_step[k + 1] - 1 (``first_step`` (K + 1,)); the reference ``reference_q`` and
    ``reference_qd`` (K, n_a) and the feedforward at its start ``feedforward_start`` (K, n_a) and at the next
    tick's (``feedforward_end`` (K + 1, n_a)) [N m or N]."""

    ends: np.ndarray
    first_step: np.ndarray
    reference_q: np.ndarray
    reference_qd: np.ndarray
    feedforward_start: np.ndarray
    feedforward_end: np.ndarray


class ControllerArrays(NamedTuple):
    """A joint controller as the compiled loop ticks it (``control.controller.JointController``): kp, kd, ki and
    the torque ``limit`` per joint, its tick ``period`` [s], and per joint its ``integral`` and the ``saturated``
    ticks (both updated in place)."""

    kp: np.ndarray
    kd: np.ndarray
    ki: np.ndarray
    limit: np.ndarray
    period: float
    integral: np.ndarray
    saturated: np.ndarray


class LoopRows(NamedTuple):
    """Per-row results of a compiled closed loop (first axis: the start, then every step): q, qd and the
    integrator's qdd, the constraint forces, the accounts (:data:`ACCOUNTS`), the work accounts (drive,
    constraints, dampers) [J], E's position, rotation matrix and velocity, and the actuator torques [N m]."""

    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    constraint_forces: np.ndarray
    accounts: np.ndarray
    work: np.ndarray
    ee_position: np.ndarray
    ee_rotation: np.ndarray
    ee_velocity: np.ndarray
    torques: np.ndarray


class LoopRun(NamedTuple):
    """A compiled closed loop: ticks and steps completed, the status of the last step, the rows (the start's
    and the completed steps'), the plant's state at the end (t [s], the evaluation there, the modal
    correction and the earlier accelerations to continue from) and the last tick's command (2, n_a) [N m]
    at its start and end."""

    ticks: int
    steps: int
    status: int
    rows: LoopRows
    t: float
    last: Evaluation
    correction: ModalCorrection
    earlier: np.ndarray
    command: np.ndarray


class LinkTip(NamedTuple):
    """Where a flexible link's tip deflection is measured (:mod:`.deflection`): its RFE angles ``springs`` (indices
    into q), the chain's index of its first element's frame (``root``) and of its last element's (``last``), and
    the beam's end ``point`` (3,) [m] in the last element's frame."""

    springs: np.ndarray
    root: int
    last: int
    point: np.ndarray


class PlantCarry(NamedTuple):
    """The actuated plant's state carried from one control period to the next in arrays that
    :func:`~.closed_loop.held_period` updates in place: the time ``clock`` (1,) [s], q and qd, the work accounts
    (3,) [J], the modal correction (:class:`ModalCorrection`: ``inertia``, ``damping``, ``modes``, ``on_resolved``,
    ``inertia_weights``, ``damping_weights``, ``modal`` (5,) its time and step [s], the number of resolved modes,
    when they were tracked [s] and the unresolved modes' rate [s]); the position and velocity terms of the evaluation
    at the last step's end, on which (8) is solved again as the next period's command makes the forces jump (those
    of :class:`Accelerations` but Q and qdd: M, h, Q_g, the ``gravity_potential`` (1,) [J], E's position (3,) [m]
    and rotation (3, 3) in the world frame, C, d, A, c and B); and beside q and qd what the plant reports: the
    actuator ``torques`` (n_a,) [N m or N] at the period's end, E's ``ee_quaternion`` (x, y, z, w) in the world frame
    and the tip ``deflection`` (3,) [m] (:func:`~.deflection.deflection_at`)."""

    clock: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    work: np.ndarray
    inertia: np.ndarray
    damping: np.ndarray
    modes: np.ndarray
    on_resolved: np.ndarray
    inertia_weights: np.ndarray
    damping_weights: np.ndarray
    modal: np.ndarray
    M: np.ndarray
    h: np.ndarray
    gravity_forces: np.ndarray
    gravity_potential: np.ndarray
    ee_position: np.ndarray
    ee_rotation: np.ndarray
    ee_jacobian: np.ndarray
    ee_bias: np.ndarray
    A: np.ndarray
    c: np.ndarray
    velocity_map: np.ndarray
    torques: np.ndarray
    ee_quaternion: np.ndarray
    deflection: np.ndarray
