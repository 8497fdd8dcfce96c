# SPDX-License-Identifier: MIT
"""The fenced code of docs/*.md, for the tests that run it (issue 15, acceptance 5).

Every ```python, ```bash and ```sh block of every docs/*.md file is a snippet.
A snippet runs as written unless the line just above its fence is a marker

    <!-- no-run: shell contract -- why -->     (a command line with placeholders: FILE, [--opt], a|b)
    <!-- no-run: illustrative -- why -->       (an API summary with names defined nowhere)

and :func:`check_marker` verifies that a marked snippet really is one of those
two kinds, so a runnable snippet cannot hide behind a marker.  Python snippets
of one file share a namespace, in order; a file whose python imports ``bpy``
runs inside Blender (tests/blender/test_docs_snippets.py), the others in
tests/python/test_docs_snippets.py.
"""

import ast
import builtins
import glob
import os
import re
import subprocess
import sys

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
LANGS = {"python": "python", "bash": "bash", "sh": "bash"}
KINDS = ("shell contract", "illustrative")
FENCE = re.compile(r"^```([A-Za-z]*)[^\n]*\n(.*?)^```[ \t]*$", re.S | re.M)
MARKER = re.compile(r"<!--\s*no-run:\s*(.*?)\s*-->\s*$")
# A shell command line in an untagged fence (it must be tagged bash/sh).
COMMAND = re.compile(r"^\s*(\$ )?(python3?|/usr/bin/python3|blender|dask-\w+|cmake|ctest|pip|bash|sh)\b")
PLACEHOLDER = re.compile(r"\[[^\]]*\]|\b[A-Z][A-Z_]+\b|\w\|\w")


class Snippet:
    def __init__(self, doc, line, lang, code, marker):
        self.doc, self.line, self.lang, self.code, self.marker = doc, line, lang, code, marker

    @property
    def where(self):
        return f"{self.doc}:{self.line}"

    @property
    def kind(self):
        """'shell contract' / 'illustrative' for marked snippets, else None."""
        if self.marker is None:
            return None
        return next((k for k in KINDS if self.marker.startswith(k)), self.marker)

    @property
    def starts_blender(self):
        """A bash snippet that runs ``blender`` (tests/blender_shell runs those)."""
        return self.lang == "bash" and re.search(r"^\s*blender\b", self.code, re.M) is not None

    @property
    def needs_blender(self):
        return self.lang == "python" and re.search(r"^\s*(import bpy|from endophoton_addon)", self.code, re.M)

    def __repr__(self):
        return f"Snippet({self.where}, {self.lang}, marker={self.marker!r})"


def docs():
    return sorted(os.path.relpath(p, REPO) for p in glob.glob(os.path.join(REPO, "docs", "*.md")))


def snippets(path, untagged=False):
    """The snippets of a markdown file (``untagged``: also the fences without a language, lang '')."""
    full = path if os.path.isabs(path) else os.path.join(REPO, path)
    with open(full, encoding="utf-8") as f:
        text = f.read()
    out = []
    for m in FENCE.finditer(text):
        tag = m.group(1).lower()
        if tag not in LANGS and not (untagged and tag == ""):
            continue
        line = text.count("\n", 0, m.start()) + 1
        above = text[: m.start()].rstrip("\n").rsplit("\n", 1)[-1]
        marker = MARKER.search(above)
        out.append(Snippet(path, line + 1, LANGS.get(tag, ""), m.group(2), marker.group(1) if marker else None))
    return out


def defined_nowhere(code, known=()):
    """Names the python ``code`` reads but neither it, ``known`` nor builtins define (None: not python)."""
    try:
        tree = ast.parse(code)
    except SyntaxError:
        return None
    bound, read = set(known), set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Name):
            (read if isinstance(node.ctx, ast.Load) else bound).add(node.id)
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            bound.update((a.asname or a.name).split(".")[0] for a in node.names)
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            bound.add(node.name)
        elif isinstance(node, ast.arg):
            bound.add(node.arg)
    return read - bound - set(dir(builtins))


def check_marker(snippet, known=()):
    """'' if the marked snippet is what its marker says, else the reason it is not."""
    if snippet.kind == "shell contract":
        if snippet.lang != "bash":
            return f"{snippet.where}: 'shell contract' marks a {snippet.lang or 'untagged'} block"
        if not PLACEHOLDER.search(snippet.code):
            return f"{snippet.where}: a shell contract without placeholders (FILE, [--opt], a|b) can run: run it"
        return ""
    if snippet.kind == "illustrative":
        if snippet.lang != "python":
            return f"{snippet.where}: 'illustrative' marks a {snippet.lang} block"
        missing = defined_nowhere(snippet.code, known)
        if missing == set():
            return f"{snippet.where}: marked illustrative but every name is defined: run it"
        return ""
    return f"{snippet.where}: no-run reason '{snippet.marker}' is not one of {KINDS}"


def python_names(blocks):
    """Names bound by earlier python blocks of a file (they share a namespace)."""
    names = set()
    for s in blocks:
        if s.lang == "python":
            try:
                tree = ast.parse(s.code)
            except SyntaxError:
                continue
            for node in ast.walk(tree):
                if isinstance(node, ast.Name) and not isinstance(node.ctx, ast.Load):
                    names.add(node.id)
                elif isinstance(node, (ast.Import, ast.ImportFrom)):
                    names.update((a.asname or a.name).split(".")[0] for a in node.names)
    return names


def _addon_user_scripts(tmp_path):
    """A Blender user-scripts folder holding the source tree's add-on (as an installed add-on)."""
    addons = tmp_path / "scripts" / "addons"
    addons.mkdir(parents=True)
    os.symlink(os.path.join(REPO, "addon", "endophoton_addon"), addons / "endophoton_addon")
    return str(tmp_path / "scripts")


def run_bash(snippet, tmp_path):
    """Runs a bash snippet as written from the repository root (the tree's package first; Blender, if it
    starts, with the tree's add-on and no user preferences). A traceback on its output fails it as an exit
    status would (Blender exits 0 after a failing --python script unless told otherwise)."""
    env = dict(
        os.environ,
        PATH=os.pathsep.join([os.path.dirname(sys.executable), "/usr/bin", os.environ.get("PATH", "")]),
        PYTHONPATH=os.path.join(REPO, "python"),
        ENDOPHOTON_PYTHONPATH=os.path.join(REPO, "python"),
        BLENDER_USER_SCRIPTS=_addon_user_scripts(tmp_path),
        HOME=str(tmp_path),
    )
    proc = subprocess.run(
        ["bash", "-e", "-c", snippet.code], cwd=REPO, env=env, capture_output=True, text=True, timeout=900
    )
    if proc.returncode == 0 and "Traceback" in proc.stdout + proc.stderr:
        proc.returncode = 1
    return proc
