"""The plant node's control periods: efforts held over each period, one compiled call per period.

A period of :class:`HeldPeriods` is a tick of :meth:`.plant.Plant.follow` with no feedback (the controller
commands the efforts u; the actuator torques are u - kd qd), stepped by
:func:`~crane_reference.dynamics.closed_loop.held_period`, which carries the plant's state from one period to
the next in arrays (:class:`~crane_reference.dynamics.structures.PlantCarry`).  The steps and the column drive's
parameters on them are planned for :data:`PLANNED_PERIODS` periods at a time
(:meth:`~crane_reference.motion.simulation.MotionStepper.step_plan`), so that a period costs its compiled steps
and little else.
"""

from __future__ import annotations

import numpy as np

from ..dynamics.closed_loop import held_period_of_fields, plant_carry
from ..dynamics.deflection import link_tip
from ..dynamics.structures import CONVERGED
from ..motion.integration import IntegrationError
from ..motion.simulation import StepPlan
from .plant import Plant

PLANNED_PERIODS = 1000
"""Periods whose steps are planned at a time."""


class HeldPeriods:
    """Control periods of ``period`` [s] of ``plant`` from its state now (the plant itself stays there, under the
    actuator ``torques`` [N m or N], order of its actuated joints), each under efforts held over it; the carry
    holds the tip deflection of the first flexible link (:func:`~crane_reference.dynamics.deflection.link_tip`)."""

    def __init__(self, plant: Plant, period: float, torques: np.ndarray):
        stepper = plant.stepper
        state = stepper.state
        self.period = period
        self.count = 0
        """Periods done."""
        tip = link_tip(plant.model)
        self.carry = plant_carry(state.t, state.q, state.qd, stepper.snapshot().work, state.correction,
                                 plant.terms(), torques, tip, plant.dynamics.chain)
        """The plant's state after the periods done (:class:`~crane_reference.dynamics.structures.PlantCarry`)."""
        self._t0 = state.t
        self._stepper = stepper
        self._drive = plant.drive.drive
        model = plant.compiled_model()  # as held_period_of_fields takes it: plain tuples of the fields
        self._model = (*(tuple(part) for part in model[:4]), *model[4:])
        self._carry, self._tip = tuple(self.carry), tuple(tip)
        self._steps: tuple = ()  # the plan's steps
        self._plan: StepPlan | None = None
        self._planned = 0  # the first period of the plan

    @property
    def t(self) -> float:
        """[s] the plant's time."""
        return float(self.carry.clock[0])

    def advance(self, efforts: np.ndarray) -> None:
        """Hold the efforts u [N m or N] (order of the actuated joints) over the next
        period; an :class:`~crane_reference.motion.integration.IntegrationError` (or ProjectionError) if a step
        fails or meets a linear system it cannot solve, the plant then staying where it was."""
        i = self.count - self._planned
        if self._plan is None or i + 1 >= self._plan.first.size:
            self._make_plan()
            i = 0
        first = self._plan.first
        end = self._t0 + (self.count + 1) * self.period
        try:
            status, t, failed_at = held_period_of_fields(self._carry, end, first[i], first[i + 1], self._steps,
                                                         self._model, self._tip, np.asarray(efforts, dtype=float))
        except np.linalg.LinAlgError as error:  # the carry is updated only after every step converged
            raise IntegrationError(f"the period from t = {self.t:.6g} s to {end:.6g} s met a linear system it "
                                   f"cannot solve: {error}") from error
        if status != CONVERGED:
            raise self._stepper.integrator.failure(status, t, failed_at)
        self.count += 1

    def _make_plan(self) -> None:
        """The steps of the next :data:`PLANNED_PERIODS` periods and the column drive's parameters at their ends
        (left limits) and at their starts (right limits, where the integrator restarts)."""
        ends = self._t0 + np.arange(self.count + 1, self.count + PLANNED_PERIODS + 1) * self.period
        plan = self._stepper.step_plan(ends, after=self._plan)
        left = self._drive.kernel_parameters(plan.times, left_limit=True)
        right = self._drive.kernel_parameters(np.concatenate(([self.t], plan.times)))
        self._plan, self._planned = plan, self.count
        self._steps = (plan.times, plan.on_jump, left, right)
