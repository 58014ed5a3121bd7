"""What both sides of the solver's pipe share (:mod:`.solver`, the caller's side; :mod:`.stream_solver`, the
solver's): the stream's specification, what the solver tells of it, its errors, and the memory the two processes
share (the stop flag and the heartbeat).
"""

from __future__ import annotations

import mmap
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from ..model.description import CraneDescription
from ..model.parameters import Task
from .sample import ReferenceSample

HEARTBEAT_PERIOD = 0.05
"""[s] between the solver process's beats."""
HUNG_AFTER = 1.0
"""[s] without a beat after which a solver process that owes a reply is held hung (twenty beats missed)."""
SHARED_BYTES = 16
"""The memory the caller and the solver process share: the stop flag (byte 0) and the beat counter (bytes 8-15)."""



class SolverStoppedError(RuntimeError):
    """The caller stopped waiting for the solver (shutting down), or the solver process is gone."""


class SolverHungError(SolverStoppedError):
    """The solver process gave no sign of life for :data:`HUNG_AFTER` while a reply was due: it was killed."""


@dataclass(frozen=True)
class StreamSpec:
    """Everything that makes a :class:`~.reference_stream.ReferenceStream` (picklable): the crane's
    configuration, model variant, integrator step [s], blend time [s], targets, the column drive's torque
    [N m] and duration [s] (None: the configuration's), speed scaling and its ramp time [s]; ``warm_up``:
    make every kernel ready first (and say how)."""

    config: CraneDescription
    model: str
    step: float
    blend_time: float
    targets: Task
    drive_torque: float | None = None
    drive_duration: float | None = None
    speed_scaling: float = 1.0
    ramp_time: float = 1.0
    warm_up: bool = True


@dataclass(frozen=True)
class StreamInfo:
    """What a server needs to know of the stream once: joint names and their units ("rad", or "m" for a
    prismatic joint), the URDF of the model, the sample at the start, E's static height [m], the singular-value
    margin of target checks, and how the kernels were made ready ("" without warm-up)."""

    joint_names: tuple[str, ...]
    joint_units: tuple[str, ...]
    urdf: str
    start: ReferenceSample
    z_static: float
    singular_value_margin: float
    kernels: str


@dataclass(frozen=True)
class StreamStatus:
    """The stream's state after a request: RUNNING / PAUSED / ERROR, targets, the speed scaling it is at or
    moving to, the last error, the ramp time [s] and the publish time [s] it settles at."""

    state: str
    targets: Task
    target_speed: float
    last_error: str
    ramp_time: float
    settled_at: float


class Return(NamedTuple):
    """A return to the start: q [SI units] at the stream time it happens, before, and q at the start."""

    before: np.ndarray
    start: np.ndarray


def shared_memory(fd: int) -> tuple[np.ndarray, np.ndarray]:
    """The stop flag (:func:`~crane_reference.motion.integration.stop_flag`) and the beat counter over the
    :data:`SHARED_BYTES` of the file ``fd``, mapped shared: what one process writes there, another that maps the
    same file reads."""
    memory = mmap.mmap(fd, SHARED_BYTES)
    return np.frombuffer(memory, dtype=np.uint8, count=1), np.frombuffer(memory, dtype=np.uint64, count=1, offset=8)
