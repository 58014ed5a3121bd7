"""The plant node's real-time pacing (control/pacing.py) on a clock written out here: every period runs once
when due, a wake-up more than a period past a due time (L seconds) misses floor(L / T) periods, counted, however
long the stall, and the periods run and missed add up to those due."""

from __future__ import annotations

import math

import numpy as np
import pytest

from crane_reference.control.pacing import Pacing

PERIOD = 2.0**-7  # [s] (128 Hz: sums of it are exact in binary, so "due" compares exactly)


def run(pacing: Pacing, wakes: list[float]) -> list[float]:
    """The times at which periods run when the caller wakes at ``wakes`` (a period runs at a wake if due)."""
    ran = []
    for now in wakes:
        while pacing.wait(now) <= 0.0:
            ran.append(now)
            pacing.ran()
    return ran


def test_on_time_every_period_runs_once_at_its_due_time():
    pacing = Pacing(PERIOD, 1.0)
    wakes = [1.0 + k * PERIOD for k in range(1, 101)]
    assert run(pacing, wakes) == wakes and pacing.missed == 0


@pytest.mark.parametrize("stall", [0.5, 1.0, 1.5, 2.0, 160.25])
def test_a_stall_misses_the_whole_periods_past_and_stays_on_the_grid(stall):
    """A wake-up ``stall`` periods after a due time: up to one period late the periods catch up (none missed);
    beyond, floor(stall) are missed and the latest due runs at once; the next is due on the grid."""
    pacing = Pacing(PERIOD, 0.0)
    assert run(pacing, [PERIOD]) == [PERIOD]
    late = 2 * PERIOD + stall * PERIOD  # the period due at 2 T found at 2 T + stall T
    ran = run(pacing, [late])
    assert pacing.missed == (math.floor(stall) if stall > 1.0 else 0)
    assert len(ran) == (1 if stall > 1.0 else 1 + math.floor(stall))  # a late period runs; on time, all due
    assert pacing.wait(late) == PERIOD * (1 - stall % 1)  # the next grid time after the stall


def test_every_period_due_is_run_or_missed():
    """Over irregular wake-ups (stalls of up to 40 periods among on-time ones), the periods run and those missed
    add up to the periods due: none is lost uncounted."""
    rng = np.random.default_rng(3)
    wakes = np.cumsum(np.where(rng.random(2000) < 0.05, rng.uniform(1.0, 40.0, 2000), rng.uniform(0.0, 1.0, 2000))
                      * PERIOD)
    pacing = Pacing(PERIOD, 0.0)
    ran = run(pacing, list(wakes))
    assert pacing.missed > 0 and len(ran) + pacing.missed == math.floor(wakes[-1] / PERIOD)


@pytest.mark.parametrize("period", [0.0, -1e-3, math.nan, math.inf])
def test_a_period_must_be_finite_and_positive(period):
    with pytest.raises(ValueError, match="period"):
        Pacing(period, 0.0)
