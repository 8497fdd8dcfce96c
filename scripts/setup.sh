#!/usr/bin/env bash
# Installs everything EndoPhoton needs on a fresh Debian 12 machine, builds the
# engine in build/ (module placed in python/endophoton) and installs the
# package into the system dist-packages that Debian's Blender sees.
set -euo pipefail
cd "$(dirname "$0")/.."
SUDO=""
if [ "$(id -u)" != "0" ]; then SUDO="sudo"; fi
PKGS="blender pybind11-dev python3-dev python3-pip python3-setuptools python3-wheel libembree-dev libopenvdb-dev
libboost-iostreams-dev libtbb-dev libnanoflann-dev libsleef-dev python3-numpy python3-pytest python3-openvdb python3-matplotlib
libgtest-dev python3-tqdm python3-scipy python3-hypothesis python3-jsonschema python3-distributed xvfb xauth cmake g++ make black clang-format"
missing=""
for p in $PKGS; do dpkg -s "$p" >/dev/null 2>&1 || missing="$missing $p"; done
if [ -n "$missing" ]; then
  echo "== installing:$missing"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends $missing >/dev/null
fi
PY=/usr/bin/python3
echo "== building (build/)"
cmake -S . -B build -DCMAKE_BUILD_TYPE=Release -DPython3_EXECUTABLE=$PY >/dev/null
cmake --build build -j "$(nproc)"
echo "== installing the endophoton package for $PY and Blender"
$SUDO $PY -m pip install --no-build-isolation --no-deps --break-system-packages --quiet . 2>&1 | grep -v "WARNING: Running pip as" || true
