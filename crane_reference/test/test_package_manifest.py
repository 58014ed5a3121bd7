"""package.xml against the code: every module the package's Python files import (found by parsing them)
is the standard library, the package itself, or a dependency that package.xml names, so that rosdep
installs what `ros2 run crane_reference node` and the launch file need on a ROS machine."""

from __future__ import annotations

import ast
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
SOURCES = [*sorted((ROOT / "crane_reference").rglob("*.py")), *sorted((ROOT / "launch").glob("*.py")),
           ROOT / "scripts" / "node"]

ROSDEP_KEYS = {
    "numpy": "python3-numpy", "scipy": "python3-scipy", "yaml": "python3-yaml",
    "matplotlib": "python3-matplotlib", "numba": "python3-numba", "tqdm": "python3-tqdm",
    "pandas": "python3-pandas", "rosbags": "python3-rosbags-pip", "urdf_parser_py": "urdfdom_py",
}
"""Python modules that are not ROS packages, with their keys in ros/rosdistro's rosdep/python.yaml."""

PIP_ONLY = {"dask", "distributed", "pyarrow"}
"""Modules without a rosdep key (installed by pip with the package): only the studies may use them."""

TEST_ROSDEP_KEYS = {**ROSDEP_KEYS, "pytest": "python3-pytest"}
TEST_PIP_ONLY = {"mcap"}
"""Test modules without a rosdep key (setup.py's test extra installs them)."""
TEST_HELPERS = {path.stem for path in (ROOT / "test").glob("*.py")}


def imported_modules(path: Path) -> set[str]:
    """Top-level names of the absolute imports in a Python file."""
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names - set(sys.stdlib_module_names) - {"crane_reference"}


def exec_depends(tags: tuple[str, ...] = ("exec_depend", "depend")) -> set[str]:
    root = ET.parse(ROOT / "package.xml").getroot()
    return {e.text.strip() for tag in tags for e in root.iter(tag)}


def test_every_import_is_a_declared_dependency():
    declared = exec_depends()
    missing = {}
    for path in SOURCES:
        for module in imported_modules(path) - PIP_ONLY:
            key = ROSDEP_KEYS.get(module, module)  # anything else is a ROS package of the same name
            if key not in declared:
                missing.setdefault(key, []).append(str(path.relative_to(ROOT)))
    assert not missing, f"package.xml lacks <exec_depend> for: {missing}"


def test_modules_without_rosdep_keys_stay_in_the_studies():
    users = {str(p.relative_to(ROOT)) for p in SOURCES if imported_modules(p) & PIP_ONLY}
    assert users and all(u.startswith("crane_reference/analysis/study/") for u in users), users


def test_declared_ros_packages_are_used():
    """No stale ROS dependency: each declared ROS package (not a python3-* key) is imported somewhere, or is
    a bring-up executable the launch file starts."""
    launched = {"robot_state_publisher", "rviz2"}
    used = {ROSDEP_KEYS.get(m, m) for m in set().union(*(imported_modules(p) for p in SOURCES))} | launched
    ros_packages = {d for d in exec_depends() if not d.startswith("python3-")}
    assert ros_packages <= used, ros_packages - used


def test_every_test_import_is_a_declared_dependency():
    """What the tests import is a dependency of the package or a <test_depend> (rosdep installs it before
    colcon test), besides the tests' own helper modules."""
    declared = exec_depends(("exec_depend", "depend", "test_depend"))
    missing = {}
    for path in sorted((ROOT / "test").glob("*.py")):
        for module in imported_modules(path) - PIP_ONLY - TEST_PIP_ONLY - TEST_HELPERS:
            key = TEST_ROSDEP_KEYS.get(module, module)
            if key not in declared:
                missing.setdefault(key, []).append(path.name)
    assert not missing, f"package.xml lacks <test_depend> for: {missing}"
