"""The bash snippets of docs/*.md that start Blender (tests/python/test_docs_snippets.py runs the others):
each runs as written, from the repository root, with the tree's package and add-on."""
import os
import shutil
import sys

import pytest

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
sys.path[:0] = [os.path.join(ROOT, "python"), os.path.join(ROOT, "tests", "python")]

import doc_snippets as ds  # noqa: E402

BLENDER_BASH = [
    s for doc in ds.docs() for s in ds.snippets(doc) if s.lang == "bash" and s.marker is None and s.starts_blender
]
pytestmark = [
    pytest.mark.slow,
    pytest.mark.blender,
    pytest.mark.skipif(shutil.which("blender") is None, reason="blender missing"),
]


def test_some_doc_snippet_starts_blender():
    assert BLENDER_BASH, "no bash snippet of docs/*.md starts Blender: this file has nothing left to run"


@pytest.mark.parametrize("snippet", BLENDER_BASH, ids=[s.where for s in BLENDER_BASH])
def test_doc_bash_snippet_with_blender_runs(snippet, tmp_path):
    proc = ds.run_bash(snippet, tmp_path)
    assert proc.returncode == 0, f"{snippet.where}:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
