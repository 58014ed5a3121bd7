"""Helpers the benchmark scripts share: timing, CPU of processes, Pinocchio's ABA as the unit of cost, the
integrator's compiled runs and Newton evaluations, and the tables they print."""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from crane_reference.model.urdf import model_to_urdf
from crane_reference.motion.integration import (
    EVALUATIONS,
    ONLINE_TOLERANCE,
    ExactFrequencyTrapezoidal,
)
from crane_reference.motion.simulation import MotionStepper, Scenario

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")


def call_seconds(function: Callable[[], object], repeats: int, median: bool = False) -> float:
    """Wall time [s] of one call of ``function()``: the mean of ``repeats`` calls back to back after one
    untimed call, or with ``median`` the median of ``repeats`` timed calls."""
    if median:
        times = []
        for _ in range(repeats):
            start = time.perf_counter()
            function()
            times.append(time.perf_counter() - start)
        return float(np.median(times))
    function()
    start = time.perf_counter()
    for _ in range(repeats):
        function()
    return (time.perf_counter() - start) / repeats


def process_cpu_seconds(pid: int) -> float:
    """User + system CPU time [s] of the process ``pid`` (all its threads)."""
    with open(f"/proc/{pid}/stat", encoding="ascii") as stat:
        fields = stat.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / CLOCK_TICKS


class PinocchioTimes(NamedTuple):
    """Best per-call times [s] of Pinocchio's algorithms, each called from Python at one random state: forward
    dynamics (ABA, the unit of cost), inverse dynamics (RNEA), the joint-space mass matrix (CRBA) and the joints'
    placements (forward kinematics)."""

    aba: float
    rnea: float
    crba: float
    forward_kinematics: float


def _best_call(function: Callable, arguments: tuple, repeat: int) -> float:
    """The best of 5 loops of ``repeat`` calls of ``function(*arguments)``, per call [s]."""
    fastest = math.inf
    for _ in range(5):
        start = time.perf_counter()
        for _ in range(repeat):
            function(*arguments)
        fastest = min(fastest, (time.perf_counter() - start) / repeat)
    return fastest


def _pinocchio_model(scenario: Scenario) -> tuple:
    """Pinocchio's model and data of the URDF that crane-reference exports for the scenario's chain, and a random
    state of it (continuous joints as cos/sin): q, v, tau."""
    import pinocchio as pin  # here: the other benchmarks need no Pinocchio
    model = pin.buildModelFromXML(model_to_urdf(scenario.model))
    rng = np.random.default_rng(0)
    return model, model.createData(), pin.randomConfiguration(model), rng.normal(size=model.nv), \
        rng.normal(size=model.nv)


def aba_time(scenario: Scenario, repeat: int = 20000) -> float:
    """Best per-call time [s] of Pinocchio's forward dynamics (ABA, called from Python) on the URDF that
    crane-reference exports for the scenario's chain, at a random state."""
    import pinocchio as pin
    return _best_call(pin.aba, _pinocchio_model(scenario), repeat)


def pinocchio_times(scenario: Scenario, repeat: int = 20000) -> PinocchioTimes:
    """:class:`PinocchioTimes` as :func:`aba_time` measures ABA, on the same model and state; RNEA and CRBA compute
    their own kinematics."""
    import pinocchio as pin
    model, data, q, v, tau = _pinocchio_model(scenario)
    return PinocchioTimes(_best_call(pin.aba, (model, data, q, v, tau), repeat),
                          _best_call(pin.rnea, (model, data, q, v, tau), repeat),
                          _best_call(pin.crba, (model, data, q), repeat),
                          _best_call(pin.forwardKinematics, (model, data, q), repeat))


def run_times(scenario: Scenario, step: float, duration: float, every_row: bool, chunk: float = 0.25,
              paced: bool = False, articulated: bool | None = None) -> float:
    """Wall time [s] of ``duration`` seconds of motion from rest in compiled runs of ``chunk`` seconds: the
    steps alone (only each run's last row evaluated, what a caller that reads the motion needs) or with
    every row's full evaluation (reactions, residuals, energy accounts: what ``simulate`` records); ``paced``:
    each run waits until its motion's end is reached in wall time (as a real-time solver runs them);
    ``articulated``: the iteration matrix solved by the articulated-body recursion or densely (None: as the
    integrator chooses by size)."""
    integrator = ExactFrequencyTrapezoidal(scenario.motion)
    if articulated is not None:
        integrator.articulated = articulated
    state = integrator.start(0.0, scenario.equilibrium.q, np.zeros_like(scenario.equilibrium.q))
    per_run = round(chunk / step)
    start = time.perf_counter()
    for first in range(0, round(duration / step), per_run):
        times = step * np.arange(first + 1, first + per_run + 1)
        state, _ = integrator.run(state, times, every_row=every_row)
        if paced:
            time.sleep(max(0.0, start + times[-1] - time.perf_counter()))
    return time.perf_counter() - start


def newton_iterations(scenario: Scenario, step: float, duration: float = 1.0, tolerance: float = ONLINE_TOLERANCE,
                      evaluations: int = EVALUATIONS) -> float:
    """Mean Newton evaluations per step over the first ``duration`` seconds (one step at a time)."""
    q0 = scenario.equilibrium.q
    stepper = MotionStepper(scenario.motion, 0.0, q0, np.zeros_like(q0), step, tolerance=tolerance,
                            evaluations=evaluations)
    counts = []
    while stepper.state.t < duration:
        stepper.advance()
        counts.append(stepper.integrator.last_iterations)
    return float(np.mean(counts))


def print_table(title: str, rows: list[dict[str, object]]) -> None:
    """``title``, then one line per key of ``rows`` with one column per row (floats to 3 decimals)."""
    print(title)
    for key in rows[0]:
        cells = "".join(f"{row[key]:>12.3f}" if isinstance(row[key], float) else f"{row[key]!s:>12}" for row in rows)
        print(f"{key:<22}{cells}")
