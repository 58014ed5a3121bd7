"""How the plant and the controller nodes run as programs: until SIGINT or SIGTERM, exit code 0.

rclpy's own signal handlers are off: a signal only ends the spin loop, in the main thread, and the node is
destroyed and the context shut down after it, so that nothing is taken from the middleware while the context
shuts down (rclpy's handler shuts it down from under an executor that may be taking a message).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from ..model.config import ConfigError
from ..stream.health import CANNOT
from .parameters import ParameterError
from .settings import StartupError

SPIN_PERIOD = 0.1  # [s] the longest a signal waits for the spin loop


def run_node(make: Callable[[], Node], name: str, args: list[str] | None = None) -> int:
    """Spin the node ``make`` returns until SIGINT or SIGTERM; 0, or 1 if it cannot start (the reason logged
    as ``name``'s).  ``args``: the command line for ``rclpy.init`` (None: sys.argv)."""
    stop = threading.Event()
    for number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(number, lambda *_: stop.set())
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    try:
        try:
            node = make()
        except (StartupError, ConfigError, ParameterError, ValueError) as error:
            rclpy.logging.get_logger(name).fatal(f"{CANNOT} start: {error}")
            return 1
        try:
            executor = SingleThreadedExecutor()
            executor.add_node(node)
            while not stop.is_set():
                executor.spin_once(timeout_sec=SPIN_PERIOD)
        finally:
            node.destroy_node()
    finally:
        rclpy.try_shutdown()
    return 0
