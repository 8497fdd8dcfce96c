#!/usr/bin/env bash
# Builds EndoPhoton and runs every test: C++ (ctest), Python (pytest) and
# the Blender add-on tests inside `blender -b`.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
echo "== C++ unit tests"
ctest --test-dir build --output-on-failure
echo "== Python tests"
/usr/bin/python3 -m pytest tests/python -q
if [ -f tests/blender/run_blender_tests.py ]; then
  echo "== Blender tests"
  blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_blender_tests.py
fi
