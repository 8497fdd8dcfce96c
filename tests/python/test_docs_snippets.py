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
import subprocess
import sys

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


@pytest.mark.parametrize("doc", PYTHON_DOCS)
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


BASH = [s for doc, blocks in _all() for s in blocks if s.lang == "bash" and s.marker is None]


def _addon_user_scripts(tmp_path):
    """A Blender user-scripts folder holding the source tree's add-on (as an installed add-on)."""
    addons = tmp_path / "scripts" / "addons"
    addons.mkdir(parents=True)
    os.symlink(os.path.join(ds.REPO, "addon", "endophoton_addon"), addons / "endophoton_addon")
    return str(tmp_path / "scripts")


@pytest.mark.parametrize("snippet", BASH, ids=[s.where for s in BASH])
def test_doc_bash_snippets_run(snippet, tmp_path):
    env = dict(
        os.environ,
        PATH=os.pathsep.join([os.path.dirname(sys.executable), "/usr/bin", os.environ.get("PATH", "")]),
        PYTHONPATH=os.path.join(ds.REPO, "python"),
        ENDOPHOTON_PYTHONPATH=os.path.join(ds.REPO, "python"),
        BLENDER_USER_SCRIPTS=_addon_user_scripts(tmp_path),
        HOME=str(tmp_path),  # Blender reads no user preferences from the real home
    )
    proc = subprocess.run(
        ["bash", "-e", "-c", snippet.code], cwd=ds.REPO, env=env, capture_output=True, text=True, timeout=900
    )
    assert proc.returncode == 0, f"{snippet.where}:\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}"
    # Blender exits 0 after a failing --python script unless told otherwise: look for the traceback too.
    assert "Traceback" not in proc.stdout + proc.stderr, f"{snippet.where}:\n{proc.stdout[-3000:]}"
    print(proc.stdout[-1500:])
