#!/usr/bin/env bash
# The project's test command (README, CI): sets up .venv, lints (ruff, the import contracts of .importlinter),
# runs the test suite of crane_reference and checks that colcon builds both packages (crane_reference_interfaces,
# ament_cmake; crane_reference, ament_python) and that `ros2 run crane_reference node` would start.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
.venv/bin/ruff check .
.venv/bin/lint-imports
.venv/bin/python -m pytest -q crane_reference
bash scripts/check_colcon.sh
