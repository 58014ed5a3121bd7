"""How the plant and the controller nodes run as programs: until SIGINT or SIGTERM, exit code 0.

rclpy's own signal handlers are off: a signal only ends the spin loop, in the main thread, and the node is
destroyed and the context shut down after it, so that nothing is taken from the middleware while the context
shuts down (rclpy's handler shuts it down from under an executor that may be taking a message).

The executor is rclpy's EventsExecutor where rclpy has it (``rclpy.experimental``, Jazzy's rclpy from 7.1.4;
the SingleThreadedExecutor before): it takes a message at a fraction of the SingleThreadedExecutor's cost, a
large part of what these nodes spend at a 1 kHz control rate (``benchmarks/bench_loop.py``, docs/performance.md).
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable

import rclpy
from rclpy.executors import Executor, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from ..base.health import CANNOT, StartupError
from ..model.config import ConfigError
from ..motion.simulation import SOLVER_FAILURES
from .parameter_spec import ParameterError

try:
    from rclpy.experimental import EventsExecutor as NodeExecutor
except ImportError:  # rclpy before 7.1.4
    NodeExecutor = SingleThreadedExecutor

SPIN_PERIOD = 0.1  # [s] the longest a signal waits for the spin loop
LOST_MESSAGE = "Unable to convert call argument"
"""The start of rclpy's error when a message it took from the middleware cannot be made into its Python object
(pybind11's; seen here under load about once in six runs of the lock-step loop, on /clock, and in other
packages' nodes, e.g. ros/joint_state_publisher#117): that message is lost."""


def spin_once(executor: Executor, node: Node, timeout_sec: float | None = None) -> None:
    """``executor.spin_once``, where a message that rclpy cannot convert (:data:`LOST_MESSAGE`) is lost with a
    WARN instead of ending the node; every other error propagates."""
    try:
        executor.spin_once(timeout_sec=timeout_sec)
    except RuntimeError as error:
        if not str(error).startswith(LOST_MESSAGE):
            raise
        node.get_logger().warning(f"a message taken from the middleware could not be converted by rclpy and is "
                                  f"lost: {error}", throttle_duration_sec=10.0)


def run_node(make: Callable[[], Node], name: str, args: list[str] | None = None) -> int:
    """Spin the node ``make`` returns until SIGINT or SIGTERM; 0, or 1 if it cannot start (its parameters, its
    crane file, or a crane without a start, such as no static equilibrium: the reason logged as ``name``'s).
    ``args``: the command line for ``rclpy.init`` (None: sys.argv)."""
    stop = threading.Event()
    for number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(number, lambda *_: stop.set())
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    try:
        try:
            node = make()
        except (StartupError, ConfigError, ParameterError, ValueError, *SOLVER_FAILURES) as error:
            rclpy.logging.get_logger(name).fatal(f"{CANNOT} start: {error}")
            return 1
        executor = NodeExecutor()
        executor.add_node(node)
        try:
            while not stop.is_set():
                spin_once(executor, node, SPIN_PERIOD)
        finally:
            executor.shutdown()  # before the node goes: nothing of it is served while it is destroyed
            node.destroy_node()
    finally:
        rclpy.try_shutdown()
    return 0
