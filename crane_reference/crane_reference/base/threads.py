"""Threads named for the operating system too, so that ``top -H``, ``ps -L`` and ``benchmarks/bench_node.py``
tell the node's threads apart (CPython 3.11 names a thread only for Python); Python's thread switch interval
while a thread keeps real time."""

from __future__ import annotations

import ctypes
import ctypes.util
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager

PR_SET_NAME = 15  # prctl(2) option: the calling thread's name
OS_NAME_LENGTH = 15  # [bytes] the kernel keeps of a thread's name

SWITCH_INTERVAL = 1e-4
"""[s] Python's thread switch interval while a thread keeps real time.  A thread woken at its deadline waits for
the GIL until the thread holding it gives it back: at a blocking call, or after the switch interval (5 ms by
default; a compiled call that releases the GIL gives it back at once, Python running while messages come does
not)."""

_libc = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True) if sys.platform.startswith("linux") else None


def name_this_thread(name: str) -> None:
    """Give the calling thread ``name`` (its first OS_NAME_LENGTH bytes) for the operating system (Linux only;
    elsewhere nothing)."""
    if _libc is not None:
        _libc.prctl(PR_SET_NAME, name.encode()[:OS_NAME_LENGTH], 0, 0, 0)


def start_named(target: Callable[[], None], name: str) -> threading.Thread:
    """A daemon thread called ``name`` (for Python and the operating system) running ``target``, started."""
    def run() -> None:
        name_this_thread(name)
        target()
    thread = threading.Thread(target=run, name=name, daemon=True)
    thread.start()
    return thread


@contextmanager
def real_time_switching() -> Iterator[None]:
    """Python's thread switch interval (process-wide) at most :data:`SWITCH_INTERVAL` inside, the previous one
    restored after."""
    previous = sys.getswitchinterval()
    sys.setswitchinterval(min(previous, SWITCH_INTERVAL))
    try:
        yield
    finally:
        sys.setswitchinterval(previous)
