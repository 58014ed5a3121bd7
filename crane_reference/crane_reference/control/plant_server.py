"""The plant node's ROS-free core: the actuated crane (:class:`~.plant.Plant`) driven by joint effort
commands one control period at a time, as ros2_control's forward command controllers drive a robot.

Commands.  A command is one effort u [N m, or N on a prismatic joint] per joint of ``joints`` (a permutation
of the crane's actuated joints, ``ChainModel.actuated_joints``), in that order, as a forward command controller's
``joints`` order its std_msgs/Float64MultiArray.  Each joint's drive closes a velocity loop, so the
torque it applies is

    tau = u - kd qd        (kd: the drive's damping [N m s/rad], ``PlantSettings.drive_damping``)

at every instant (exact in the integrator): a controller's D action lives in the drive, where a real
drive has it, because a D term held over a 1 kHz period is unstable on the flexible boom
(:mod:`.controller`).  A controller of :mod:`.controller` commands u_k of its tick.  u holds over the
control period (zero-order hold), from the tick after it is accepted.  A command of another length, or
with a NaN or an infinity, is refused with the reason (:class:`CommandRefusedError`), counted, and never
applied: the previous command goes on.

Timeout.  When no command has been accepted for ``command_timeout`` s (of the caller's clock: the
plant node's wall clock in real time), the plant applies the *hold command*: the efforts that balance
gravity, the springs and the drive at the actuated joints in the configuration q_h where the
timeout began, u(t) = (h(q_h, 0) - Q(q_h, t))[joints] (the drive's torque or motor angle goes on
with time); with the drives' damping the crane comes to rest near q_h, as a drive's hold does (its
flexible boom and supports ring out).  The next accepted command ends it.

Before the first command the plant holds its start (:func:`~.plant.held_start`: E on the task's start
point, at rest) with the efforts that hold it there.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..base.health import Level
from ..dynamics.cache import WarmUp, cache_counts
from ..dynamics.evaluation import imbalance_rows
from ..model.chain import VARIANTS
from ..model.config import load_config
from ..model.description import CraneDescription
from ..motion.simulation import Scenario
from ..motion.steps import PLANT_STEP
from .held_periods import HeldPeriods
from .plant import Plant, default_gains, held_start


class CommandRefusedError(ValueError):
    """A command the plant does not apply (the message is the reason)."""


@dataclass(frozen=True)
class PlantSettings:
    """The plant's settings: the crane ``variant``, the integrator ``step`` [s], the control ``rate`` [Hz] (a
    whole number of steps per period), the command's ``joints`` (a permutation of the crane's actuated joints;
    None: those, in the crane's order), the
    drives' damping kd per joint of ``joints`` [N m s/rad] (None: :func:`default_drive_damping`), the
    ``command_timeout`` [s] and whether the state gives ``all_coordinates`` or the ``joints`` only."""

    variant: str = "flexible"
    step: float = PLANT_STEP
    rate: float = 1000.0
    joints: tuple[str, ...] | None = None
    drive_damping: tuple[float, ...] | None = None
    command_timeout: float = 0.1
    all_coordinates: bool = False

    def __post_init__(self) -> None:
        if self.variant not in VARIANTS:
            raise ValueError(f"variant = {self.variant!r}: must be one of {', '.join(VARIANTS)}")
        for name in ("step", "rate", "command_timeout"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"{name} = {value}: must be a finite number > 0")
        if not abs(self.steps_per_period * self.step * self.rate - 1.0) <= 1e-9:
            raise ValueError(f"rate = {self.rate} Hz with step = {self.step} s: the control period must be a "
                             "whole number of integrator steps")
        if self.drive_damping is not None and (
                (self.joints is not None and len(self.drive_damping) != len(self.joints)) or not all(
                math.isfinite(kd) and kd >= 0.0 for kd in self.drive_damping)):
            raise ValueError(f"drive_damping = {list(self.drive_damping)}: must be one finite number >= 0 "
                             f"N m s/rad per joint of {list(self.joints or ['the actuated joints'])}")

    def command_joints(self, actuated: Sequence[str]) -> tuple[str, ...]:
        """The command's joints for a crane whose actuated joints are ``actuated``: ``joints``, checked to name
        each of them once, or ``actuated`` itself."""
        if self.joints is None:
            return tuple(actuated)
        if sorted(self.joints) != sorted(actuated):
            raise ValueError(f"joints = {list(self.joints)}: must name each of {', '.join(actuated)} once")
        return self.joints

    @property
    def steps_per_period(self) -> int:
        return max(1, round(1.0 / (self.rate * self.step)))

    @property
    def period(self) -> float:
        """[s] of one control period."""
        return self.steps_per_period * self.step


def default_drive_damping(scenario: Scenario, joints: Sequence[str]) -> tuple[float, ...]:
    """kd of :func:`~.plant.default_gains` per joint of ``joints`` (the D action a ``crane-reference track``
    controller with its default gains puts in the drives)."""
    return tuple(gains.kd for gains in default_gains(scenario, joints))


@dataclass(frozen=True)
class PlantState:
    """The plant at time ``t`` [s] (from its start): q, qd and the actuator ``effort`` u - kd qd [N m] of the
    published coordinates (:attr:`PlantServer.published`; effort 0 where no actuator acts), E's
    ``ee_position`` [m] and ``ee_quaternion`` (x, y, z, w) in the world frame {0}, the first flexible link's
    tip ``deflection`` [m] in its first element's frame (:mod:`~crane_reference.dynamics.deflection`; zero on
    the rigid boom) and whether the hold command acts (``holding``)."""

    t: float
    q: np.ndarray
    qd: np.ndarray
    effort: np.ndarray
    ee_position: np.ndarray
    ee_quaternion: np.ndarray
    deflection: np.ndarray
    holding: bool


class PlantServer:
    """The crane ``params`` under the commands of the module docstring, started at rest at its held start
    (a ValueError names a setting that does not fit the crane)."""

    def __init__(self, params: CraneDescription, settings: PlantSettings):
        self.settings = settings
        scenario = Scenario(params, settings.variant)
        actuated = scenario.model.actuated_joints
        self.joints = settings.command_joints(actuated)
        """The command's joints, in their order."""
        start = held_start(scenario)
        self.order = np.array([actuated.index(name) for name in self.joints], dtype=np.int64)
        """Where each of :attr:`joints` is among the crane's actuated joints."""
        damping = settings.drive_damping or default_drive_damping(scenario, self.joints)
        self.drive_damping = np.asarray(damping, dtype=float)
        """kd per joint of :attr:`joints` [N m s/rad]."""
        actuated_damping = np.empty(len(actuated))
        actuated_damping[self.order] = self.drive_damping
        self.plant = Plant(params, settings.variant, start, settings.step, actuated_damping, keep=False)
        """The crane at its start (:attr:`periods` carries it on)."""
        self.periods = HeldPeriods(self.plant, settings.period, start.torques)
        """The control periods done and the crane's state after them."""
        model = self.plant.model
        self.published = model.joint_names if settings.all_coordinates else self.joints
        """The coordinates of :class:`PlantState` (q, qd, effort), by name."""
        self._published = np.array([model.index(name) for name in self.published], dtype=np.int64)
        flexible = model.flexible_links[0] if model.flexible_links else None
        self.deflection_frame = (next(body.name for body in model.bodies if body.joint == flexible.root)
                                 if flexible is not None else "world")
        """The frame of the tip deflection: the URDF link of the first flexible link's first element."""
        self._command = start.torques.copy()  # u in the order of the actuated joints
        self._last_command = -math.inf  # when the last command was accepted [s, the caller's clock]
        self._held: np.ndarray | None = None  # q_h while the hold command acts
        self.accepted = 0
        self.refused = 0
        self.timeouts = 0
        """Commands accepted, refused, and the timeouts that started the hold command."""
        self.last_refusal = ""
        self.refused_last = False
        """The last command received was refused."""
        # the kernels of a period, of its state and of the hold command made ready now, not at the first command
        # (a period of its own on a copy of the state: the plant stays at its start)
        HeldPeriods(self.plant, settings.period, start.torques).advance(self._command)
        self.hold_efforts(self.q)
        self.state()

    def command(self, values: Sequence[float], now: float) -> None:
        """Accept the efforts ``values`` [N m] (order of :attr:`joints`) received at ``now`` [s, the
        caller's clock]; they act from the next :meth:`tick`.  :class:`CommandRefusedError` (counted) for a
        wrong length, NaN or inf."""
        joints = self.joints
        u = np.asarray(values, dtype=float)
        reason = None
        if u.ndim != 1 or u.size != len(joints):
            reason = f"{u.size} values: a command has one effort [N m] per joint of {list(joints)}"
        elif not np.all(np.isfinite(u)):
            bad = [name for name, value in zip(joints, u, strict=True) if not math.isfinite(value)]
            reason = f"effort of {', '.join(bad)} is not finite: a command must be finite numbers [N m]"
        if reason is not None:
            self.refused += 1
            self.last_refusal, self.refused_last = reason, True
            raise CommandRefusedError(reason)
        self._command = np.empty(self.order.size)
        self._command[self.order] = u
        self._last_command = now
        self._held = None
        self.accepted += 1
        self.refused_last = False

    @property
    def ticks(self) -> int:
        """Control periods done."""
        return self.periods.count

    @property
    def t(self) -> float:
        """[s] the plant's time."""
        return self.periods.t

    @property
    def q(self) -> np.ndarray:
        """q now (every coordinate; the next tick overwrites it: copy to keep)."""
        return self.periods.carry.q

    @property
    def qd(self) -> np.ndarray:
        """qd now (every coordinate; the next tick overwrites it: copy to keep)."""
        return self.periods.carry.qd

    def timed_out(self, now: float) -> bool:
        """No command accepted within ``command_timeout`` of ``now`` [s] (and at least one before)."""
        return math.isfinite(self._last_command) and now - self._last_command > self.settings.command_timeout

    def tick(self, now: float) -> PlantState:
        """Advance one control period under the command in force at ``now`` [s, the caller's clock]: the last
        accepted one, or the hold command once it :meth:`timed_out` (starting it counts a timeout)."""
        if self.timed_out(now) and self._held is None:
            self._held = self.q.copy()
            self.timeouts += 1
        if self._held is not None:
            self._command = self.hold_efforts(self._held)
        self.periods.advance(self._command)
        return self.state()

    @property
    def holding(self) -> bool:
        """The hold command acts (a timeout)."""
        return self._held is not None

    def hold_efforts(self, q: np.ndarray) -> np.ndarray:
        """u = (h(q, 0) - Q(q, t)) at the actuated joints (in the crane's order) [N m or N], t now: the efforts
        that hold the configuration q at rest."""
        plant = self.plant
        q = np.ascontiguousarray(q, dtype=float)[None, :]
        drives = plant.drive.drive.kernel_parameters(np.array([self.t]))
        return imbalance_rows(q, np.zeros_like(q), np.zeros_like(q), drives, plant.dynamics.chain)[0, plant.actuated]

    def state(self) -> PlantState:
        """The plant now (:class:`PlantState`)."""
        carry, rows = self.periods.carry, self._published
        effort = np.zeros(self.plant.model.dof)
        effort[self.plant.actuated] = carry.torques
        return PlantState(self.t, carry.q[rows], carry.qd[rows], effort[rows], carry.ee_position.copy(),
                          carry.ee_quaternion.copy(), carry.deflection.copy(), self.holding)


@dataclass(frozen=True)
class PlantHealth:
    """The plant's health as /diagnostics reports it: its ``level``, a ``message`` and the key/value pairs."""

    level: Level
    message: str
    values: dict[str, str]


def plant_health(server: PlantServer, doing: str, failure: str, missed_ticks: int, newly_missed: int) -> PlantHealth:
    """The worst first: the integration failed (``failure``: ERROR); the hold command acts (a timeout: WARN);
    the last command was refused (WARN); real-time periods missed since the last report (``newly_missed`` of
    ``missed_ticks`` in all, :mod:`.pacing`: WARN); else OK with what the node is ``doing``.  The values: plant
    time, ticks, commands accepted and refused, the last refusal, timeouts, missed ticks."""
    values = {"time_s": f"{server.t:.6f}", "ticks": str(server.ticks), "commands_accepted": str(server.accepted),
              "commands_refused": str(server.refused), "last_refusal": server.last_refusal,
              "timeouts": str(server.timeouts), "missed_ticks": str(missed_ticks)}
    if failure:
        return PlantHealth(Level.ERROR, f"integration failed: {failure}; the plant stopped (cleanup and configure "
                                        "start it again)", values)
    if server.holding:
        return PlantHealth(Level.WARN, f"{doing}: no command for {server.settings.command_timeout:g} s: the hold "
                                       "command acts", values)
    if server.refused and server.refused_last:
        return PlantHealth(Level.WARN, f"{doing}: command refused: {server.last_refusal}", values)
    if newly_missed:
        return PlantHealth(Level.WARN, f"{doing}: {newly_missed} periods missed (the machine is too slow for the "
                                       "control rate)", values)
    return PlantHealth(Level.OK, doing, values)


def warm_up_plant() -> WarmUp:
    """Call every kernel the plant node uses (a period under its start efforts and one under the hold command,
    on the packaged flexible crane: the kernels depend on the array types only), for ``crane-reference compile``."""
    start = time.perf_counter()
    compiled, loaded = cache_counts()
    server = PlantServer(load_config(), PlantSettings())
    server.command(server.hold_efforts(server.q)[server.order], 0.0)
    server.tick(0.0)
    now_compiled, now_loaded = cache_counts()
    return WarmUp(time.perf_counter() - start, now_compiled - compiled, now_loaded - loaded)
