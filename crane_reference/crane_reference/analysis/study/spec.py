"""A constraint-design study: which programmed constraints and crane settings to compare.

A study spec (YAML) names the crane, the run and the parameters to vary::

    config: ""              # crane description YAML ('' = the packaged config/crane.yaml)
    variant: both           # flexible | rigid | both (both: the flexible-minus-rigid difference too)
    duration: 3.0           # [s] simulated per case
    step: 0.00025           # [s] integrator step (default: the offline step, 0.25 ms)
    vary:                   # grids (values) and/or random ranges (low, high); random ranges draw `samples`
      ellipse_a: {values: [2.8, 3.0, 3.2]}
      path_speed: {values: [0.4, 0.8]}
    samples: 0              # random cases when some parameter has a range
    seed: 0
    limits:                 # design limits answered in summary.md: the largest value of each varied
      tip_deflection_m: 0.05    # parameter for which every case up to it stays below them
    realisation: ideal
    tracking:               # optional: a closed loop follows each case's reference (crane-reference track)
      controller: pd        # pd | pid; feedforward none | rigid; rate [Hz]; bandwidth [Hz];
      feedforward: rigid    # damping_ratio; torque_limit [N m] (all actuated joints; omitted: none)

Parameters that can vary (:data:`PARAMETERS`): the ellipse semi-axes, E's height rise and rise time, the
drive's torque and its duration, the payload mass, the number of rigid finite elements of every flexible link,
their stiffness-proportional damping (``damping_boom``: every flexible link's, the paper's boom's) and the path
speed (E's parametric-angle rate along the ellipse, rising
along a quintic over :data:`PATH_SPEED_RISE`, imposed by the first-order areal-rate constraint); and of the
closed loop (:data:`TRACKING_PARAMETERS`, which switch the tracking on): the bandwidth of every actuated
joint or of one (``bandwidth_<joint>``, a joint of the crane's ``actuated``), the damping ratio, the torque
limit and the feedforward (0 none, 1 rigid inverse dynamics).
With tracking, the metrics of :class:`~crane_reference.analysis.tracking.closed_loop.TrackingRun` become
columns ``track_*``.
Grids combine as a full factorial; random ranges are sampled uniformly with the seed (integers for
``n_rfe``).  Every error names the field and what is allowed.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from ...model.chain import VARIANTS
from ...model.config import load_config
from ...model.parameters import TorqueDrive
from ...motion.programmed_motion import REALISATIONS
from ...motion.steps import ANALYSIS_STEP

PATH_SPEED_RISE = 1.0  # [s], quintic rise of the path speed from rest
PARAMETERS: dict[str, tuple[str, float, float, bool]] = {
    # name: (unit, smallest, largest, integer)
    "ellipse_a": ("m", 0.1, 20.0, False),
    "ellipse_b": ("m", 0.1, 20.0, False),
    "z_increment": ("m", -10.0, 10.0, False),
    "rise_time": ("s", 0.01, 3600.0, False),
    "drive_torque": ("N m", -1e6, 1e6, False),
    "drive_duration": ("s", 1e-3, 3600.0, False),
    "payload_mass": ("kg", 0.0, 1e6, False),
    "n_rfe": ("", 1, 48, True),
    "damping_boom": ("s", 0.0, 1.0, False),
    "path_speed": ("rad/s", 0.0, 10.0, False),
    "bandwidth": ("Hz", 0.05, 50.0, False),
    "damping_ratio": ("", 0.05, 5.0, False),
    "torque_limit": ("N m", 1.0, 1e8, False),
    "feedforward": ("", 0, 1, True),
}
JOINT_BANDWIDTH = ("Hz", 0.05, 50.0, False)
"""The range of ``bandwidth_<joint>``, one parameter per actuated joint of the crane."""
TRACKING_PARAMETERS = ("bandwidth", "damping_ratio", "torque_limit", "feedforward")
"""The closed loop's parameters (and every ``bandwidth_<joint>``)."""
TRACKING_DEFAULTS = {"controller": "pd", "feedforward": "rigid", "rate": 1000.0, "bandwidth": 2.0,
                     "damping_ratio": 0.7, "torque_limit": math.inf}
CHOICES = (*VARIANTS, "both")


def parameters(joints: tuple[str, ...]) -> dict[str, tuple[str, float, float, bool]]:
    """The parameters a study of a crane with the actuated ``joints`` can vary (:data:`PARAMETERS` and a
    ``bandwidth_<joint>`` per joint)."""
    return {**PARAMETERS, **{f"bandwidth_{joint}": JOINT_BANDWIDTH for joint in joints}}


def limits_allowed(joints: tuple[str, ...]) -> tuple[str, ...]:
    """The metrics a design limit can be set on, for a crane with the actuated ``joints``."""
    return ("tip_deflection_m", "vibration_rms_m", "constraint_force_n", "drive_power_w", "ee_speed_m_s",
            "track_ellipse_distance_max_m", "track_height_error_max_m", "track_tip_vibration_rms_m",
            *(f"track_{joint}_torque_peak_nm" for joint in joints))


class StudyError(ValueError):
    """A study spec that cannot be run (the message names the field and what is allowed)."""


@dataclass(frozen=True)
class Case:
    """One setting of the varied parameters; ``key`` identifies it (a hash of the study's fixed fields
    and these values), so a re-run of the same spec finds the cases already done."""

    index: int
    values: dict[str, float]
    key: str


@dataclass(frozen=True)
class StudySpec:
    config: str
    variant: str
    duration: float
    step: float
    grid: dict[str, tuple[float, ...]]
    ranges: dict[str, tuple[float, float]]
    samples: int
    seed: int
    limits: dict[str, float] = field(default_factory=dict)
    realisation: str = "ideal"
    tracking: dict[str, Any] | None = None
    joints: tuple[str, ...] = ()
    """The crane's actuated joints (read from ``config`` when the spec is parsed)."""

    @property
    def varied(self) -> list[str]:
        return [*self.grid, *self.ranges]

    def cases(self) -> list[Case]:
        """The full factorial of the grids, each with ``samples`` random draws of the ranges (or once)."""
        rng = np.random.default_rng(self.seed)
        grid = [dict(zip(self.grid, values, strict=True)) for values in itertools.product(*self.grid.values())]
        cases = []
        for point in grid:
            for _ in range(self.samples if self.ranges else 1):
                values = dict(point)
                for name, (low, high) in self.ranges.items():
                    values[name] = (float(rng.integers(int(low), int(high) + 1)) if parameters(self.joints)[name][3]
                                    else float(rng.uniform(low, high)))
                cases.append(Case(len(cases), values, self._key(values)))
        return cases

    def _key(self, values: dict[str, float]) -> str:
        fixed = {"config": self.config, "variant": self.variant, "duration": self.duration, "step": self.step,
                 "realisation": self.realisation, **({"tracking": self.tracking} if self.tracking else {})}
        text = json.dumps({"fixed": fixed, "values": values}, sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:16]


def _number(value: Any, where: str, low: float, high: float, integer: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise StudyError(f"{where} = {value!r}: must be a finite number in [{low:g}, {high:g}]")
    if not low <= value <= high or (integer and value != int(value)):
        kind = "an integer" if integer else "a number"
        raise StudyError(f"{where} = {value!r}: must be {kind} in [{low:g}, {high:g}]")
    return float(value)


def parse_spec(data: Any, source: str = "study spec") -> StudySpec:
    """Validate a study spec (the parsed YAML); :class:`StudyError` names the field and what is allowed."""
    if not isinstance(data, dict):
        raise StudyError(f"{source}: must be a mapping with the fields config, variant, duration, step, vary")
    known = {"config", "variant", "duration", "step", "vary", "samples", "seed", "limits", "realisation", "tracking"}
    unknown = sorted(set(data) - known)
    if unknown:
        raise StudyError(f"{source}: unknown field(s) {', '.join(unknown)}; allowed: {', '.join(sorted(known))}")
    config = data.get("config", "") or ""
    if not isinstance(config, str):
        raise StudyError(f"config = {config!r}: must be a path to a crane YAML, or '' for the packaged default")
    variant = data.get("variant", "flexible")
    if variant not in CHOICES:
        raise StudyError(f"variant = {variant!r}: must be one of {', '.join(CHOICES)}")
    duration = _number(data.get("duration", 3.0), "duration", 1e-3, 600.0)
    step = _number(data.get("step", ANALYSIS_STEP), "step", 1e-5, 1e-2)
    realisation = data.get("realisation", "ideal")
    if realisation not in REALISATIONS:
        raise StudyError(f"realisation = {realisation!r}: must be one of {', '.join(map(repr, REALISATIONS))}")
    base = load_config(config or None)  # a ConfigError names the file and the field
    allowed = parameters(base.actuated)
    vary = data.get("vary")
    if not isinstance(vary, dict) or not vary:
        raise StudyError(f"vary = {vary!r}: must map parameters ({', '.join(allowed)}) to "
                         "{values: [...]} or {low: ..., high: ...}")
    grid, ranges = {}, {}
    for name, how in vary.items():
        if name not in allowed:
            raise StudyError(f"vary.{name}: unknown parameter; allowed: {', '.join(allowed)}")
        unit, low, high, integer = allowed[name]
        if isinstance(how, dict) and set(how) == {"values"} and isinstance(how["values"], list) and how["values"]:
            grid[name] = tuple(_number(v, f"vary.{name}.values[{i}]", low, high, integer)
                               for i, v in enumerate(how["values"]))
        elif isinstance(how, dict) and set(how) == {"low", "high"}:
            lo = _number(how["low"], f"vary.{name}.low", low, high, integer)
            hi = _number(how["high"], f"vary.{name}.high", low, high, integer)
            if not lo < hi:
                raise StudyError(f"vary.{name}: low = {lo:g} must be below high = {hi:g}")
            ranges[name] = (lo, hi)
        else:
            raise StudyError(f"vary.{name} = {how!r}: must be {{values: [a non-empty list]}} or {{low: x, high: y}} "
                             f"(in {unit or 'units'}, within [{low:g}, {high:g}])")
    samples = data.get("samples", 0)
    if ranges and (isinstance(samples, bool) or not isinstance(samples, int) or not 1 <= samples <= 100000):
        raise StudyError(f"samples = {samples!r}: must be an integer in [1, 100000] when a parameter has a range")
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise StudyError(f"seed = {seed!r}: must be a non-negative integer")
    limits = data.get("limits", {}) or {}
    if not isinstance(limits, dict) or any(name not in limits_allowed(base.actuated) for name in limits):
        raise StudyError(f"limits = {limits!r}: must map some of {', '.join(limits_allowed(base.actuated))} to "
                         "positive numbers")
    limits = {name: _number(value, f"limits.{name}", 0.0, math.inf) for name, value in limits.items()}
    drive_varied = sorted({"drive_torque", "drive_duration"} & set(vary))
    if drive_varied and not isinstance(base.drive, TorqueDrive):
        raise StudyError(f"vary.{drive_varied[0]}: the crane of config = {config or 'the packaged default'!r} has a "
                         "flexible drive; drive_torque and drive_duration apply to a torque drive only")
    tracking = _tracking(data.get("tracking"), set(vary))
    if tracking and not abs(round(1.0 / (tracking["rate"] * step)) * tracking["rate"] * step - 1.0) <= 1e-9:
        raise StudyError(f"tracking.rate = {tracking['rate']:g} Hz: its period must be a whole number of steps "
                         f"(step = {step:g} s)")
    return StudySpec(config, variant, duration, step, grid, ranges, samples if ranges else 0, seed, limits,
                     realisation, tracking, tuple(base.actuated))


def _tracking(block: Any, varied: set[str]) -> dict[str, Any] | None:
    """The closed loop's fixed settings (:data:`TRACKING_DEFAULTS` for those not given), or None without a
    ``tracking`` block and with no tracking parameter varied."""
    if block is None and not (varied & set(TRACKING_PARAMETERS) or any(v.startswith("bandwidth_") for v in varied)):
        return None
    block = {} if block is None else block
    if not isinstance(block, dict) or set(block) - set(TRACKING_DEFAULTS):
        raise StudyError(f"tracking = {block!r}: must map some of {', '.join(TRACKING_DEFAULTS)} to values")
    settings = {**TRACKING_DEFAULTS, **block}
    for name, allowed in (("controller", ("pd", "pid")), ("feedforward", ("none", "rigid"))):
        if settings[name] not in allowed:
            raise StudyError(f"tracking.{name} = {settings[name]!r}: must be one of {', '.join(allowed)}")
    for name, low, high in (("rate", 1.0, 1e5), ("bandwidth", 0.05, 50.0), ("damping_ratio", 0.05, 5.0),
                            ("torque_limit", 1.0, 1e8)):
        if not (name == "torque_limit" and settings[name] == math.inf):  # the default: no limit
            settings[name] = _number(settings[name], f"tracking.{name}", low, high)
    return settings


def load_spec(path: str | Path) -> StudySpec:
    """Read and validate a study spec file."""
    try:
        data = yaml.safe_load(Path(path).read_text())
    except (OSError, yaml.YAMLError) as error:
        raise StudyError(f"{path}: cannot read the study spec: {error}") from error
    return parse_spec(data, str(path))
