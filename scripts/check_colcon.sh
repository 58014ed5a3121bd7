#!/usr/bin/env bash
# Proves the ROS packaging: `colcon build` of this repository's two packages (crane_reference_interfaces, then
# crane_reference; the build compiles the kernels of the installed package) in a temporary workspace, then the
# installed executables install/crane_reference/lib/crane_reference/node and plant (what `ros2 run crane_reference
# node` and `plant` start) must be executable, publish their first joint_states within 10 s of their start (no
# compile at the first start), and exit with code 0 and no traceback on SIGINT.
#
# Usage: scripts/check_colcon.sh            (colcon and rclpy from .venv, see scripts/setup.sh)
# Environment: VENV (default <repo>/.venv), TMPDIR (where the workspace is made), KEEP=1 keeps it.
set -euo pipefail

REPO=$(cd "$(dirname "$0")/.." && pwd)
VENV=${VENV:-$REPO/.venv}
WORKSPACE=$(mktemp -d "${TMPDIR:-/tmp}/crane_reference_colcon.XXXXXX")
NODE_PID=""

fail() {
  echo "check_colcon: FAILED: $*" >&2
  exit 1
}

cleanup() {
  if [ -n "$NODE_PID" ] && kill -0 "$NODE_PID" 2>/dev/null; then
    kill -KILL "$NODE_PID" 2>/dev/null || true
  fi
  if [ "${KEEP:-0}" != 1 ]; then
    rm -rf "$WORKSPACE"
  else
    echo "check_colcon: workspace kept in $WORKSPACE"
  fi
}
trap cleanup EXIT

[ -x "$VENV/bin/colcon" ] || fail "no colcon in $VENV (run scripts/setup.sh)"
export PATH="$VENV/bin:$PATH"  # colcon, and the python3 of the executable's shebang (with rclpy)
export ROS_DOMAIN_ID=$(( $$ % 100 + 1 ))
export ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST

echo "check_colcon: colcon build in $WORKSPACE"
cd "$WORKSPACE"
BUILD_START=$(date +%s)
# The PyPI ROS wheels in .venv stand for a ROS distribution: CMake finds them through AMENT_PREFIX_PATH and
# scripts/pypi_ros.cmake (as scripts/setup.sh builds the interface package).
if ! AMENT_PREFIX_PATH="$VENV" colcon build --base-paths "$REPO" --event-handlers console_cohesion- \
    --cmake-args -DCMAKE_PREFIX_PATH="$VENV" -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF \
    -DCMAKE_PROJECT_INCLUDE="$REPO/scripts/pypi_ros.cmake" >colcon.log 2>&1; then
  cat colcon.log >&2
  fail "colcon build failed"
fi

echo "check_colcon: colcon build took $(( $(date +%s) - BUILD_START )) s"
BUILD_LOG=log/latest_build/crane_reference/stdout_stderr.log
grep -q "crane_reference: compiling the kernels" "$BUILD_LOG" || fail "colcon build did not compile the kernels"
if grep -q "WARNING: the kernels were not compiled" "$BUILD_LOG"; then
  cat "$BUILD_LOG" >&2
  fail "the kernels were not compiled"
fi

EXECUTABLE=install/crane_reference/lib/crane_reference/node
[ -f "$EXECUTABLE" ] || fail "$EXECUTABLE was not installed"
[ -x "$EXECUTABLE" ] || fail "$EXECUTABLE is not executable"
for executable in plant controller; do
  [ -x "install/crane_reference/lib/crane_reference/$executable" ] || fail "the $executable executable was not installed"
done
[ -f install/crane_reference_interfaces/share/crane_reference_interfaces/action/Retarget.action ] \
  || fail "the interface package's action was not installed"
[ -f install/crane_reference/share/crane_reference/config/crane.yaml ] || fail "config/crane.yaml not installed"
[ -f install/crane_reference/share/crane_reference/launch/crane_reference.launch.py ] || fail "the launch file was not installed"
[ -f install/crane_reference/share/crane_reference/rviz/crane_reference.rviz ] || fail "the RViz config was not installed"

# The installed package, not the source tree: colcon's environment puts it first on PYTHONPATH and
# makes its share directory (config/crane.yaml) findable through the ament index.
set +u
# shellcheck disable=SC1091
source install/setup.bash
set -u
for package in crane_reference crane_reference_interfaces; do
  PACKAGE_DIR=$(cd /tmp && python3 -c "import $package, os; print(os.path.dirname($package.__file__))")
  case "$PACKAGE_DIR" in
    "$WORKSPACE"/install/*) ;;
    *) fail "python imports $package from $PACKAGE_DIR, not from the colcon install space" ;;
  esac
done

# Each installed executable in turn: its first joint_states within FIRST_SAMPLE s of its start (the kernels were
# compiled by the build), then SIGINT: exit code 0, no traceback.
FIRST_SAMPLE=10
check_executable() {  # name, topic, ROS arguments...
  local name=$1 topic=$2
  shift 2
  echo "check_colcon: starting install/crane_reference/lib/crane_reference/$name (ROS_DOMAIN_ID=$ROS_DOMAIN_ID)"
  STARTED=$(python3 -c "import time; print(time.time())")
  "install/crane_reference/lib/crane_reference/$name" --ros-args "$@" >"$name.out" 2>"$name.err" &
  NODE_PID=$!
  if ! STARTED=$STARTED TOPIC=$topic FIRST_SAMPLE=$FIRST_SAMPLE python3 - <<'EOF'
import os, sys, time
import rclpy
from rclpy.node import Node
from sensor_msgs.msg import JointState

started, limit = float(os.environ["STARTED"]), float(os.environ["FIRST_SAMPLE"])
rclpy.init()
node = Node("check_colcon_listener")
received = []
node.create_subscription(JointState, os.environ["TOPIC"], lambda msg: received.append((time.time(), msg)), 10)
deadline = time.monotonic() + 300.0
while len(received) < 5 and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.1)
node.destroy_node()
rclpy.try_shutdown()
if len(received) < 5:
    sys.exit(f"no joint_states on {os.environ['TOPIC']} within 300 s")
first = received[0][0] - started
print(f"check_colcon: first of {len(received)} joint_states on {os.environ['TOPIC']} {first:.2f} s after the start "
      f"({len(received[-1][1].name)} joints)")
if first > limit:
    sys.exit(f"the first joint_states came {first:.2f} s after the start, more than {limit:g} s")
EOF
  then
    cat "$name.err" >&2
    fail "$name did not publish joint_states in time"
  fi
  kill -INT "$NODE_PID"
  set +e
  wait "$NODE_PID"
  CODE=$?
  set -e
  NODE_PID=""
  if [ "$CODE" -ne 0 ]; then
    cat "$name.err" >&2
    fail "$name exited with code $CODE after SIGINT (expected 0)"
  fi
  if grep -q Traceback "$name.out" "$name.err"; then
    cat "$name.err" >&2
    fail "traceback in the output of $name"
  fi
}
check_executable node /crane_reference/joint_states -p publish_rate:=50
check_executable plant /crane_plant/joint_states -p control_rate:=100 -p integrator.step:=0.001
echo "check_colcon: OK (colcon build compiled the kernels; the installed node and plant published within" \
  "$FIRST_SAMPLE s of their start and exited with code 0 on SIGINT, without a traceback)"
