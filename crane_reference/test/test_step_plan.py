"""The step plan of :meth:`~crane_reference.motion.simulation.MotionStepper.step_plan` (what a compiled closed loop
and the plant node's periods step along) against the steps :meth:`~.MotionStepper.advance_until` takes: the same
step ends, bit for bit, with and without drive jumps on the way."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from crane_reference.control.plant import Plant, held_start
from crane_reference.model.parameters import FlexibleDrive, TorqueDrive
from crane_reference.motion.simulation import Scenario

STEP = 1e-3  # [s]
ENDS = (np.array([2e-3, 5e-3, 6e-3, 9.5e-3, 9.7e-3, 12e-3, 12e-3, 20e-3]),  # off the grid, two in one step, repeated
        np.array([25e-3, 26e-3, 26.5e-3, 26.5e-3, 26.7e-3, 30e-3, 44.2e-3, 50e-3]))  # 26.5 ms: a jump
DRIVES = {"torque jumps off the grid": TorqueDrive(torque=300.0, start=3.5e-3, end=26.5e-3),
          "torque jumps on the grid": TorqueDrive(torque=300.0, start=0.0, end=25e-3),
          "flexible": FlexibleDrive(stiffness=1e6, travel=0.01, start=0.0, duration=0.04)}


@pytest.mark.parametrize("drive", DRIVES)
def test_a_step_plan_is_the_steps_advance_until_takes(params, drive: str) -> None:
    crane = replace(params, drive=DRIVES[drive])
    start = held_start(Scenario(crane, "rigid"))
    planned, stepped = (Plant(crane, "rigid", start, STEP).stepper for _ in range(2))
    plan, last, on_jump = None, [], []
    for ends in ENDS:
        plan = planned.step_plan(ends, after=plan)
        last.append(plan.times)
        on_jump.append(plan.on_jump)
        times, counts = [], [0]
        for end in ends:
            rows = stepped.advance_until(end)
            times.append(rows.t)
            counts.append(counts[-1] + times[-1].size)
        assert np.array_equal(plan.times, np.concatenate(times))
        assert np.array_equal(plan.first, counts)
        assert plan.t == stepped.state.t and plan.k == stepped.snapshot().k
    column = DRIVES[drive]
    jumps = {b for b in (column.start, column.end) if b > 0.0} if isinstance(column, TorqueDrive) else set()
    times = np.concatenate(last)
    assert np.array_equal(np.concatenate(on_jump), np.isin(times, sorted(jumps)))  # steps ending on the jumps
