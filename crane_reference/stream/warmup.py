"""Compile ahead of use: run every compiled kernel once, so that numba writes its cache.

numba compiles a kernel on its first call and keeps the machine code in the cache directory keyed by the
sources of :mod:`crane_reference.dynamics` and their path (see :mod:`crane_reference`).  A first start with an empty
cache therefore waits for the compilation; ``crane-reference compile`` (run by ``scripts/setup.sh``, and
after ``colcon build`` for an installed package, whose sources live at a new path) does it beforehand.
Afterwards each process only loads the cached code.
"""

from __future__ import annotations

import time

import numpy as np

from ..model.chain import VARIANTS
from ..model.config import load_config
from ..motion.simulation import Scenario, simulate
from .reference_stream import ReferenceStream

WARM_UP_STEPS = 3


def compile_kernels() -> float:
    """Call every kernel the simulation, the stream and the node use (both model variants: a few steps
    offline and streamed, one evaluation, a target check and a re-target); returns the wall time [s]
    (compiling with an empty cache, loading with a filled one)."""
    start = time.perf_counter()
    params = load_config()
    for variant in VARIANTS:
        scenario = Scenario(params, variant)
        q = scenario.equilibrium.q
        simulate(scenario.motion, q, WARM_UP_STEPS * 1e-3, step=1e-3)
        scenario.motion.solve(0.0, q, np.zeros_like(q))
        stream = ReferenceStream(params, variant)
        stream.compute(WARM_UP_STEPS * 1e-3)
        stream.sample(0.5e-3)
        stream.check_targets(params.task)
        stream.retarget(1e-3, params.task, checked=True)
    return time.perf_counter() - start
