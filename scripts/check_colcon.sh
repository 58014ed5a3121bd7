#!/usr/bin/env bash
# Proves the ROS packaging: `colcon build` of this repository's two packages (crane_reference_interfaces, then
# crane_reference) in a temporary workspace, then the
# installed executable install/crane_reference/lib/crane_reference/node (what `ros2 run crane_reference
# node` starts) must be executable, publish joint_states, and exit with code 0 and no traceback on SIGINT.
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
# The PyPI ROS wheels in .venv stand for a ROS distribution: CMake finds them through AMENT_PREFIX_PATH and
# scripts/pypi_ros.cmake (as scripts/setup.sh builds the interface package).
if ! AMENT_PREFIX_PATH="$VENV" colcon build --base-paths "$REPO" --event-handlers console_cohesion- \
    --cmake-args -DCMAKE_PREFIX_PATH="$VENV" -DPython3_EXECUTABLE="$VENV/bin/python" -DBUILD_TESTING=OFF \
    -DCMAKE_PROJECT_INCLUDE="$REPO/scripts/pypi_ros.cmake" >colcon.log 2>&1; then
  cat colcon.log >&2
  fail "colcon build failed"
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
# The README's step after colcon build: compile the kernels of the installed package (a new source path).
install/crane_reference/lib/crane_reference/crane-reference compile || fail "crane-reference compile failed in the install space"
for package in crane_reference crane_reference_interfaces; do
  PACKAGE_DIR=$(cd /tmp && python3 -c "import $package, os; print(os.path.dirname($package.__file__))")
  case "$PACKAGE_DIR" in
    "$WORKSPACE"/install/*) ;;
    *) fail "python imports $package from $PACKAGE_DIR, not from the colcon install space" ;;
  esac
done

echo "check_colcon: starting $EXECUTABLE (ROS_DOMAIN_ID=$ROS_DOMAIN_ID)"
"$EXECUTABLE" --ros-args -p publish_rate:=50 >node.out 2>node.err &
NODE_PID=$!

if ! python3 - <<'EOF'
import sys, time
import rclpy
from rclpy.node import Node
from sensor_msgs.msg import JointState

rclpy.init()
node = Node("check_colcon_listener")
received = []
node.create_subscription(JointState, "/crane_reference/joint_states", received.append, 10)
deadline = time.monotonic() + 300.0  # a fresh install compiles the numba kernels first (about a minute)
while len(received) < 5 and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.1)
node.destroy_node()
rclpy.try_shutdown()
if len(received) < 5:
    sys.exit("no joint_states within 300 s")
print(f"check_colcon: received {len(received)} joint_states with {len(received[-1].name)} joints")
EOF
then
  cat node.err >&2
  fail "the node did not publish joint_states"
fi

kill -INT "$NODE_PID"
set +e
wait "$NODE_PID"
CODE=$?
set -e
NODE_PID=""
if [ "$CODE" -ne 0 ]; then
  cat node.err >&2
  fail "the node exited with code $CODE after SIGINT (expected 0)"
fi
if grep -q Traceback node.out node.err; then
  cat node.err >&2
  fail "traceback in the node's output"
fi
echo "check_colcon: OK (colcon build, installed executable published, exit code 0 on SIGINT, no traceback)"
