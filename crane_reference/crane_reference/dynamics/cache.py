"""The compiled kernels' cache, as a warm-up reports it: what was compiled and what was loaded.

numba compiles a kernel on its first call and keeps the machine code in the cache directory keyed by the
sources of this subpackage and their path (see :mod:`crane_reference`); ``crane-reference compile`` calls
every kernel once (:mod:`crane_reference.stream.warmup`, :func:`crane_reference.control.plant_server.warm_up_plant`).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass


@dataclass(frozen=True)
class WarmUp:
    """What making the kernels ready took: wall time [s], kernel versions compiled (absent from the cache)
    and loaded from the cache."""

    seconds: float
    compiled: int
    loaded: int

    def describe(self) -> str:
        how = (f"compiled {self.compiled} and loaded {self.loaded} from the cache" if self.compiled
               else f"loaded {self.loaded} from the cache")
        return f"kernels ready in {self.seconds:.1f} s ({how})"


def cache_counts() -> tuple[int, int]:
    """Kernel versions compiled (cache misses) and loaded (cache hits) so far in this process, over the
    package's compiled functions."""
    compiled = loaded = 0
    for name, module in list(sys.modules.items()):
        if name.startswith("crane_reference."):
            for value in vars(module).values():
                stats = getattr(value, "stats", None)  # a compiled kernel (numba dispatcher) defined here
                if hasattr(stats, "cache_misses") and getattr(value, "__module__", None) == name:
                    compiled += sum(stats.cache_misses.values())
                    loaded += sum(stats.cache_hits.values())
    return compiled, loaded
