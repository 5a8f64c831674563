#!/usr/bin/env bash
# Build the cito_msgs interface package (msg_defs/) with plain CMake against the
# ROS 2 Jazzy wheels in a venv, and install it into the venv prefix (typesupport
# libraries in <venv>/lib, the Python package in site-packages). No colcon; in a
# ROS workspace colcon builds msg_defs/ as any ament_cmake package.
set -euo pipefail
root="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
venv="${1:?usage: build_msgs.sh VENV}"
python="$venv/bin/python"
build="$root/build/cito_msgs"

py_include="$("$python" -c 'import sysconfig; print(sysconfig.get_paths()["include"])')"
np_include="$("$python" -c 'import numpy; print(numpy.get_include())')"
# The wheels' exported *__rosidl_generator_py targets name the include directories of the
# machine that built them (/opt/python/cp311-cp311/...); point them at this interpreter's.
for export in "$venv"/share/*/cmake/*__rosidl_generator_pyExport.cmake; do
  if grep -q '/opt/python/' "$export"; then
    sed -i -E "s#INTERFACE_INCLUDE_DIRECTORIES \"/opt/python/[^\"]*\"#INTERFACE_INCLUDE_DIRECTORIES \"$py_include;$np_include\"#" "$export"
  fi
done

export AMENT_PREFIX_PATH="$venv" CMAKE_PREFIX_PATH="$venv" PATH="$venv/bin:$PATH"
cmake -S "$root/msg_defs" -B "$build" -DCMAKE_INSTALL_PREFIX="$venv" -DCMAKE_BUILD_TYPE=Release \
  -DBUILD_TESTING=OFF -DPython3_EXECUTABLE="$python" -DPYTHON_EXECUTABLE="$python" \
  -DPython3_FIND_STRATEGY=LOCATION -DPython3_FIND_VIRTUALENV=ONLY
cmake --build "$build" -j "$(nproc)"
cmake --install "$build"
