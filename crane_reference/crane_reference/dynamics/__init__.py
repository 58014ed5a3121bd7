"""The numba-compiled layer.  Its modules' sources key the compilation cache (see :mod:`crane_reference`);
the cache directory is set here too, before any kernel is decorated, in case numba was imported before
crane_reference (numba reads ``NUMBA_CACHE_DIR`` only when it is first imported)."""

import os

from numba.core import config as _numba_config

_numba_config.CACHE_DIR = os.environ["NUMBA_CACHE_DIR"]
