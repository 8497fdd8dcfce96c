# SPDX-License-Identifier: MIT
"""Issue 15, acceptance 5: the code in the documentation runs as written.

The ```python snippets of docs/*.md that use ``bpy`` or the add-on run here,
inside Blender, from the repository root, in order, one namespace per file (a
later block may use names from an earlier one).  The snippets that need no
Blender, the bash snippets and the check of the no-run markers are in
tests/python/test_docs_snippets.py; tests/python/doc_snippets.py finds them
all.  The example script of a β sweep also runs in its own `blender -b`.
"""

import os
import re
import subprocess
import sys

import bpy
import pytest

from conftest import ENGINE_FOLDER, REPO, ensure_addon

sys.path.insert(0, os.path.join(REPO, "tests", "python"))
import doc_snippets  # noqa: E402

DOCS = [doc for doc in doc_snippets.docs() if any(s.needs_blender for s in doc_snippets.snippets(doc))]


def test_blender_docs_found():
    assert "docs/addon.md" in DOCS


@pytest.mark.parametrize("doc", DOCS)
def test_doc_snippets_run(ep, doc, monkeypatch):
    blocks = [s for s in doc_snippets.snippets(doc) if s.lang == "python" and s.marker is None]
    assert blocks, f"{doc} has no python snippet"
    monkeypatch.chdir(REPO)
    namespace = {"__name__": "__docs__"}
    for s in blocks:
        ensure_addon()
        try:
            exec(compile(s.code, s.where, "exec"), namespace)
        except Exception as exc:
            raise AssertionError(f"{s.where} failed: {type(exc).__name__}: {exc}") from exc


def test_beta_sweep_example_runs(ep):
    env = dict(os.environ, ENDOPHOTON_PYTHONPATH=ENGINE_FOLDER or os.path.dirname(os.path.dirname(ep.__file__)))
    cmd = [
        bpy.app.binary_path,
        "-b",
        "--factory-startup",
        os.path.join(REPO, "blend_scenes", "colon_polyp.blend"),
        "--python-exit-code",
        "1",
        "--python-expr",
        f"import sys; sys.path.insert(0, {os.path.join(REPO, 'addon')!r})",
        "--python",
        os.path.join(REPO, "examples", "beta_sweep_compare.py"),
        "--",
        "3000",
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    rows = [ln.split() for ln in proc.stdout.splitlines() if re.match(r"^\s+\d+\.\d\s+0\.\d+", ln)]
    assert [float(r[0]) for r in rows] == [0.0, 20.0, 40.0]
    for r in rows:  # Rd ± se and the photofrin share ± se are finite fractions
        assert 0 < float(r[1]) < 1 and 0 < float(r[2]) < 0.1 and 0 <= float(r[3]) <= 1
