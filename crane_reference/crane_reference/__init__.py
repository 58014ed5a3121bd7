"""Programmed constrained motion of a flexible-boom crane (Jarzebowska, Urbas, Augustynek).

The subpackages follow the computation, each importing only those before it (checked by
import-linter, see ``.importlinter``):

``model`` (parameters, config, RFE, chain, drive, URDF) -> ``dynamics`` (compiled kernels) ->
``motion`` (task constraints, eqs. (7)-(8), integration, simulation) -> ``stream`` (online reference)
-> ``interface`` (ROS messages and rosbag2 without rclpy) -> ``ros`` (the rclpy node); ``analysis``
(modal, vibration, plots) sits beside ``stream``; ``cli`` on top.
"""

import hashlib
import os
from pathlib import Path

COMPILED_PACKAGE = Path(__file__).parent / "dynamics"
"""The numba-compiled modules: their sources key the compilation cache."""


def _numba_cache_dir() -> str:
    """Numba caches compiled functions per file and does not notice when a function *called* from
    another file changes; keying the cache directory on the sources of all compiled modules makes a
    stale cache impossible."""
    digest = hashlib.sha256()
    for source in sorted(COMPILED_PACKAGE.glob("*.py")):
        digest.update(source.name.encode())
        digest.update(source.read_bytes())
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
    return str(base / "crane_reference" / f"numba-{digest.hexdigest()[:16]}")


os.environ.setdefault("NUMBA_CACHE_DIR", _numba_cache_dir())
# One BLAS thread (unless the user chose otherwise; read when numpy loads OpenBLAS, so before it is imported):
# the matrices here are tens of rows, which a second thread does not speed up, and OpenBLAS's threads wait for
# work spinning, a whole core taken from the publisher and a plant beside the solver.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
