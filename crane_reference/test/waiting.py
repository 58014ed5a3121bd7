"""Waiting in tests for a condition, never for a fixed time."""

from __future__ import annotations

import time
from collections.abc import Callable


def wait_for(condition: Callable[[], object], what: str, timeout: float = 30.0, period: float = 0.005) -> None:
    """Return once ``condition()`` is true; TimeoutError naming ``what`` after ``timeout`` seconds (generous: a busy
    machine makes a condition late, not false)."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise TimeoutError(f"timed out after {timeout:g} s waiting for {what}")
        time.sleep(period)
