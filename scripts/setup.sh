#!/usr/bin/env bash
# Creates .venv with crane_reference (editable) and, from PyPI, ROS 2 Jazzy's rclpy and messages and
# the test tools, then compiles the kernels.  Idempotent: a second run only checks what is there.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q 'setuptools<80' -e '.[ros,test]' colcon-common-extensions
# Compile the numba kernels now (fills the cache), so that the first simulate or node start does not wait.
.venv/bin/crane-reference compile
