"""Shared fixtures and markers of the test suite.

Markers (``setup.cfg``): ``ros`` for tests that need rclpy and the ROS message packages (every test in a
``test_ros_*.py`` module gets it), ``slow`` for tests that integrate seconds of motion or start
processes, ``wall_clock`` for tests that wait on the wall clock for processes or threads (every test in a
``test_ros_*.py`` module or in :data:`WALL_CLOCK_MODULES`).  ``pytest -m "not ros"`` runs the rest on a machine
without ROS: the ``test_ros_*`` modules are then not even imported.  CI runs everything: the tests without
``wall_clock`` on a worker per core (pytest-xdist), then those with it alone, so that no deadline shares the
cores with a computation of another test (``scripts/test.sh``).

Every ROS test of one pytest run uses its own ROS domain (from the process id of the pytest process that
loads this file first: with pytest-xdist its workers inherit the controller's), discovery on localhost only.
"""

from __future__ import annotations

import importlib
import os
import pkgutil
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from cranes import PAPER_LAYOUT
from numba.core.registry import CPUDispatcher

import crane_reference.dynamics as dynamics_package
from crane_reference.model.config import load_config, read_yaml
from crane_reference.model.description import CraneDescription
from crane_reference.model.paper_layout import parse_parameters
from crane_reference.model.parameters import CraneParameters
from crane_reference.motion.simulation import Scenario

ROS_MODULE_PREFIX = "test_ros_"
WALL_CLOCK_MODULES = frozenset({"test_server.py", "test_retarget_goal.py"})
"""Modules without ROS whose tests wait on the wall clock (the reference server's worker thread, the solver
process's heartbeats, their deadlines)."""
os.environ.setdefault("ROS_DOMAIN_ID", str(os.getpid() % 100 + 1))
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"


def _deselects_ros(config: pytest.Config) -> bool:
    return "not ros" in (config.getoption("markexpr") or "")


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    """Do not import the ROS test modules when the ``ros`` tests are deselected."""
    if collection_path.name.startswith(ROS_MODULE_PREFIX) and _deselects_ros(config):
        return True
    return None


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.path.name.startswith(ROS_MODULE_PREFIX):
            item.add_marker(pytest.mark.ros)
            item.add_marker(pytest.mark.wall_clock)
        elif item.path.name in WALL_CLOCK_MODULES:
            item.add_marker(pytest.mark.wall_clock)


@pytest.fixture(scope="session")
def params() -> CraneDescription:
    """The packaged default crane (config/crane.yaml), the paper's."""
    return load_config()


@pytest.fixture(scope="session")
def paper_params() -> CraneParameters:
    """The packaged crane's numbers in the paper's layout (:data:`PAPER_LAYOUT`)."""
    return parse_parameters(read_yaml(PAPER_LAYOUT))


@pytest.fixture(scope="session")
def flexible(params: CraneDescription) -> Scenario:
    """The paper's scenario on the flexible (RFE) crane."""
    return Scenario(params, "flexible")


@pytest.fixture(scope="session")
def rigid(params: CraneDescription) -> Scenario:
    """The paper's scenario on the rigid-boom crane."""
    return Scenario(params, "rigid")


@pytest.fixture
def kernel_signatures() -> Callable[[], int]:
    """How many compiled versions the package's kernels have in this process (numba's own registry): a
    warm-up test checks that using what it warmed adds none."""
    def count() -> int:
        total = 0
        for module_info in pkgutil.iter_modules(dynamics_package.__path__):
            module = importlib.import_module(f"crane_reference.dynamics.{module_info.name}")
            total += sum(len(f.signatures) for f in vars(module).values() if isinstance(f, CPUDispatcher))
        return total
    return count


@pytest.fixture(scope="session")
def loaded_kernels() -> None:
    """Every kernel the stream and the node use, loaded into this process once (``crane-reference compile``'s
    warm-up on the cached code): loading one takes the GIL for a while, which the first test to compute a stream
    beside a publishing node of the same process would otherwise do while the node must publish (the ROS tests
    run in a fresh process of their own, see ``scripts/test.sh``)."""
    from crane_reference.stream.warmup import warm_up

    warm_up()


@pytest.fixture
def ros(loaded_kernels: None) -> Iterator:
    """test_ros_node's Harness: the node under test and a probe node in one rclpy Context (ROS tests only)."""
    from test_ros_node import Harness

    harness = Harness()
    try:
        yield harness
    finally:
        harness.close()
