#!/usr/bin/env bash
# Builds EndoPhoton and runs its tests: C++ (ctest), Python (pytest) and the
# Blender add-on tests inside `blender -b`.
#
#   bash scripts/test.sh          everything: before a commit lands (about 12 minutes on 2 idle cores)
#   bash scripts/test.sh --fast   the fast tier, while you work (under 2 minutes): ctest, the Python
#                                 tests not marked slow (`pytest -m "not slow"`) and one Blender smoke test
set -euo pipefail
cd "$(dirname "$0")/.."
fast=0
case "${1:-}" in
  --fast) fast=1 ;;
  "") ;;
  *) echo "usage: bash scripts/test.sh [--fast]" >&2; exit 2 ;;
esac
bash scripts/setup.sh
echo "== C++ unit tests"
ctest --test-dir build --output-on-failure
echo "== Python tests"
if [ "$fast" = 1 ]; then
  /usr/bin/python3 -m pytest tests/python -q -m "not slow"
else
  # tests/blender_shell: tests that start Blender from the shell (slow; not in the fast tier)
  /usr/bin/python3 -m pytest tests/python tests/blender_shell -q
fi
if [ -f tests/blender/run_blender_tests.py ]; then
  echo "== Blender tests"
  if [ "$fast" = 1 ]; then
    blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_blender_tests.py -- tests/blender/test_smoke.py
  else
    blender -b --factory-startup --python-exit-code 1 --python tests/blender/run_blender_tests.py
  fi
fi
