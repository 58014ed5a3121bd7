#!/usr/bin/env bash
# The project's test command (README, CI): sets up .venv, lints (ruff, the import contracts of .importlinter),
# checks that colcon builds both packages (crane_reference_interfaces, ament_cmake; crane_reference, ament_python)
# and that `ros2 run crane_reference node` would start, and runs the test suite of crane_reference.  The kernels of
# .venv compile beside the colcon build (each mostly on one core of the two), and both are done before the tests.
# The tests run in two parts: those that compute (most of the CPU time) on a worker per core (pytest-xdist, a
# module's tests on one worker, which computes its fixtures once), then those that wait on the wall clock for
# processes or threads (the `wall_clock` marker: ROS discovery, deadlines, heartbeats) alone, as on a quiet machine.
set -euo pipefail
cd "$(dirname "$0")/.."
CRANE_REFERENCE_SETUP_COMPILE=0 bash scripts/setup.sh
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST
.venv/bin/ruff check .
.venv/bin/lint-imports
.venv/bin/crane-reference compile &
COMPILE_PID=$!
bash scripts/check_colcon.sh
wait "$COMPILE_PID"
STATUS=0  # both parts run whatever the first's outcome
.venv/bin/python -m pytest -q --durations=15 -n auto --dist loadscope -m "not wall_clock" crane_reference || STATUS=$?
.venv/bin/python -m pytest -q --durations=15 -m wall_clock crane_reference || STATUS=$?
exit "$STATUS"
