"""Programmed constrained motion of a flexible-boom crane (Jarzebowska, Urbas, Augustynek).

Layout, following the computation: parameters/config -> model (+ rfe) -> kinematics -> inertia ->
dynamics -> constraints -> programmed_motion (eqs. (7)-(8)) -> kernels (compiled) -> integration ->
simulation / reference_stream -> node (ROS 2 adapter).
"""

import hashlib
import os
from pathlib import Path

_COMPILED_MODULES = ("kinematics.py", "inertia.py", "dynamics.py", "kernels.py")


def _numba_cache_dir() -> str:
    """Numba caches compiled functions per file and does not notice when a function *called* from
    another file changes; keying the cache directory on the sources of all compiled modules makes a
    stale cache impossible."""
    digest = hashlib.sha256()
    for name in _COMPILED_MODULES:
        digest.update((Path(__file__).parent / name).read_bytes())
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return str(base / "crane_reference" / f"numba-{digest.hexdigest()[:16]}")


os.environ.setdefault("NUMBA_CACHE_DIR", _numba_cache_dir())
