"""Compile ahead of use: run every compiled kernel once, so that numba writes its cache.

numba compiles a kernel on its first call and keeps the machine code in the cache directory keyed by the
sources of :mod:`crane_reference.dynamics` and their path (see :mod:`crane_reference`).  A first start with an empty
cache therefore waits for the compilation; ``crane-reference compile`` (run by ``scripts/setup.sh``, and
after ``colcon build`` for an installed package, whose sources live at a new path) does it beforehand.
Afterwards each process only loads the cached code.
"""

from __future__ import annotations

import time
from collections.abc import Iterable

import numpy as np

from ..dynamics.cache import WarmUp, cache_counts
from ..model.chain import VARIANTS
from ..model.config import load_config
from ..motion.simulation import Scenario, simulate
from ..motion.steps import ONLINE_STEP
from .reference_stream import ReferenceStream

WARM_UP_STEPS = 3


def warm_up(variants: Iterable[str] = VARIANTS) -> WarmUp:
    """Call every kernel the simulation, the stream and the node use for the model ``variants`` (a few steps
    offline and streamed, one evaluation, a target check and a re-target, on the packaged crane: the
    kernels depend on the array types only)."""
    start = time.perf_counter()
    compiled, loaded = cache_counts()
    params = load_config()
    for variant in variants:
        scenario = Scenario(params, variant)
        q = scenario.equilibrium.q
        simulate(scenario.motion, q, WARM_UP_STEPS * ONLINE_STEP, step=ONLINE_STEP)
        scenario.motion.solve(0.0, q, np.zeros_like(q))
        stream = ReferenceStream(params, variant)
        stream.compute(WARM_UP_STEPS * ONLINE_STEP)
        stream.sample(0.5 * ONLINE_STEP)  # between two computed steps: interpolated (E's poses from q)
        stream.check_targets(params.task)
        stream.retarget(1e-3, params.task, checked=True)
    now_compiled, now_loaded = cache_counts()
    return WarmUp(time.perf_counter() - start, now_compiled - compiled, now_loaded - loaded)
