# SPDX-License-Identifier: MIT
"""Issue 15, acceptance 5: every snippet in docs/*.md runs in a test.

The python snippets that need no Blender run here, one namespace per file, in
a temporary working folder; those that need ``bpy`` run in
tests/blender/test_docs_snippets.py; the bash snippets run here in a
subprocess from the repository root.  Snippets that cannot run are marked in
the markdown (doc_snippets.py says how) and checked to be what the marker says.

Runs are kept small without editing the code: every engine run a python
snippet starts has its packet requests (photons, store, max_photons) capped at
$EP_DOCS_MAX_PACKETS (default 1,500) through the one place they all pass,
``endophoton._core.RunConfig``.  Bash snippets run exactly as written.
"""

import os

import pytest

import doc_snippets as ds

CAP = int(os.environ.get("EP_DOCS_MAX_PACKETS", "1500"))


def _all():
    return [(doc, ds.snippets(doc, untagged=True)) for doc in ds.docs()]


def test_every_doc_snippet_runs_or_is_marked():
    problems, count = [], 0
    for doc, blocks in _all():
        known = set()
        for s in blocks:
            if s.lang == "":
                first = next((ln for ln in s.code.splitlines() if ln.strip()), "")
                if ds.COMMAND.match(first):
                    problems.append(f"{s.where}: a command line in an untagged fence: tag it ```bash")
                continue
            count += 1
            if s.marker is not None:
                problems.append(ds.check_marker(s, known))
            elif s.lang == "python":
                known |= ds.python_names([s])
    assert count >= 10
    assert not [p for p in problems if p], "\n".join(p for p in problems if p)


def test_marker_check_refuses_runnable_snippets(tmp_path):
    md = tmp_path / "x.md"
    md.write_text(
        "<!-- no-run: illustrative -- looks abstract -->\n```python\nimport math\nx = math.pi\n```\n"
        "<!-- no-run: shell contract -- usage -->\n```bash\nls -l\n```\n"
        "<!-- no-run: too slow -->\n```python\nx = 1\n```\n"
        "<!-- no-run: illustrative -- placeholders -->\n```python\nres = ep.run(scene, rig)\n```\n"
        "<!-- no-run: shell contract -- usage -->\n```sh\nprog --out DIR [--seed S]\n```\n"
        "```\npython3 -m endophoton run X\n```\n"
    )
    blocks = ds.snippets(str(md), untagged=True)
    assert [b.lang for b in blocks] == ["python", "bash", "python", "python", "bash", ""]
    assert [b.line for b in blocks] == [3, 8, 12, 16, 20, 23]  # first code line
    verdicts = [ds.check_marker(b) for b in blocks[:5]]
    assert "every name is defined" in verdicts[0]
    assert "without placeholders" in verdicts[1]
    assert "is not one of" in verdicts[2]
    assert verdicts[3] == "" and verdicts[4] == ""
    assert ds.COMMAND.match(blocks[5].code)


def _capped_run_config(monkeypatch):
    from endophoton import _core

    real = _core.RunConfig

    def capped(**opts):
        for key in ("photons", "store", "max_photons"):
            if opts.get(key):
                opts[key] = min(int(opts[key]), CAP)
        return real(**opts)

    monkeypatch.setattr(_core, "RunConfig", capped)


# Files whose python needs no Blender (a file with any bpy snippet runs whole in Blender).
PYTHON_DOCS = [
    doc
    for doc, blocks in _all()
    if any(b.lang == "python" for b in blocks) and not any(b.needs_blender for b in blocks)
]


# Docs whose snippets run sweeps and renders take seconds (the fast tier leaves them out).
SLOW_DOCS = {"docs/render.md", "docs/sweep.md"}


@pytest.mark.parametrize("doc", [pytest.param(d, marks=pytest.mark.slow) if d in SLOW_DOCS else d for d in PYTHON_DOCS])
def test_doc_python_snippets_run(doc, tmp_path, monkeypatch):
    _capped_run_config(monkeypatch)
    monkeypatch.chdir(tmp_path)
    namespace = {"__name__": "__docs__"}
    ran = 0
    for s in ds.snippets(doc):
        if s.lang != "python" or s.marker is not None:
            continue
        try:
            exec(compile(s.code, s.where, "exec"), namespace)
        except Exception as exc:
            raise AssertionError(f"{s.where} failed: {type(exc).__name__}: {exc}") from exc
        ran += 1
    print(f"{doc}: {ran} python snippet(s) ran")


# Bash snippets that start Blender run in tests/blender_shell/test_docs_bash_blender.py (slow).
BASH = [s for doc, blocks in _all() for s in blocks if s.lang == "bash" and s.marker is None and not s.starts_blender]


@pytest.mark.slow
@pytest.mark.parametrize("snippet", BASH, ids=[s.where for s in BASH])
def test_doc_bash_snippets_run(snippet, tmp_path):
    proc = ds.run_bash(snippet, tmp_path)
    assert proc.returncode == 0, f"{snippet.where}:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    print(proc.stdout[-1500:])
