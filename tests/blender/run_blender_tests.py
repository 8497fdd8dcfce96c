# SPDX-License-Identifier: MIT
"""Run the Blender tests inside Blender:

    blender -b --factory-startup --python tests/blender/run_blender_tests.py [-- PYTEST ARGS]

Runs pytest on tests/blender inside Blender's Python, prints a final line
'N passed, M failed' and exits non-zero on any failure or error (or when no
test ran).  Arguments after '--' go to pytest (e.g. '-- -k rig -x'); a test file among them
('-- tests/blender/test_smoke.py') runs instead of the whole folder.

The engine package is taken from a normal ``import endophoton`` if that works,
else from the repository's python/ folder (the in-tree build), passed to the
add-on through its "Package Folder" preference.  $ENDOPHOTON_PYTHONPATH
overrides both.
"""

import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(os.path.dirname(HERE))


def main():
    import pytest

    argv = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
    sys.path.insert(0, os.path.join(REPO, "addon"))
    sys.path.insert(0, HERE)

    class Tally:
        def __init__(self):
            self.passed = self.failed = self.skipped = 0

        def pytest_runtest_logreport(self, report):
            if report.when == "call":
                if report.passed:
                    self.passed += 1
                elif report.failed:
                    self.failed += 1
                elif report.skipped:
                    self.skipped += 1
            elif report.failed:  # setup/teardown error
                self.failed += 1
            elif report.skipped and report.when == "setup":
                self.skipped += 1

        def pytest_collectreport(self, report):
            if report.failed:
                self.failed += 1

    tally = Tally()
    # Test files or folders among the arguments replace the default (the whole folder).
    targets = [] if any(os.path.exists(a.split("::")[0]) for a in argv) else [HERE]
    code = pytest.main(
        ["-p", "no:cacheprovider", "-q", "-rfEs", "--rootdir", HERE, *targets, *argv],
        plugins=[tally],
    )
    line = f"{tally.passed} passed, {tally.failed} failed"
    if tally.skipped:
        line += f", {tally.skipped} skipped"
    sys.stdout.flush()
    print(line, flush=True)
    ok = int(code) == 0 and tally.failed == 0 and tally.passed > 0
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
