"""No function of the package is longer than 120 lines (issue 37: functions under ~120 lines).

The package's source is parsed with ``ast``; a function's length runs from its ``def`` (or its
first decorator) to its last line, nested functions counted in their parent too.
"""

import ast
import os

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PKG_DIR = os.path.join(ROOT, "python", "endophoton")
MAX_LINES = 120
EXEMPT: set = set()


def _functions():
    """(path relative to the package, qualified name, lines) of every function in python/endophoton."""
    out = []
    for folder, _, files in os.walk(PKG_DIR):
        for name in sorted(files):
            if not name.endswith(".py"):
                continue
            path = os.path.join(folder, name)
            rel = os.path.relpath(path, PKG_DIR).replace(os.sep, "/")
            with open(path, encoding="utf-8") as fh:
                tree = ast.parse(fh.read(), filename=path)

            def walk(node, prefix):
                for child in ast.iter_child_nodes(node):
                    if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                        first = min([child.lineno] + [d.lineno for d in child.decorator_list])
                        out.append((rel, prefix + child.name, child.end_lineno - first + 1))
                        walk(child, prefix + child.name + ".")
                    elif isinstance(child, ast.ClassDef):
                        walk(child, prefix + child.name + ".")
                    else:
                        walk(child, prefix)

            walk(tree, "")
    return out


def test_the_walk_finds_the_package_functions():
    found = {(rel, name) for rel, name, _ in _functions()}
    assert ("run.py", "run") in found and ("view/camera.py", "Camera.frame") in found
    assert len(found) > 300


def test_no_function_over_120_lines():
    long = sorted((n, f"{rel}:{name}") for rel, name, n in _functions() if n > MAX_LINES and (rel, name) not in EXEMPT)
    assert long == [], long
