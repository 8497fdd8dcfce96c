# SPDX-License-Identifier: MIT
"""The add-on's declared API (issue 37): what addon/endophoton_addon may use from the package is
listed in docs/design.md ("The add-on's API"), and the add-on uses exactly that.

The add-on's source is read (no Blender needed): every ``import endophoton...`` /
``from endophoton... import ...`` and every attribute it reaches on the package module (named
``ep``, ``self.ep``/``job.ep`` or bound by ``import endophoton as NAME``) or on a package module
it imported.  No ``importlib`` or ``__import__``: a reach the parser cannot see is refused."""

import ast
import importlib.util
import os
import re

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
ADDON = os.path.join(REPO, "addon", "endophoton_addon")
DESIGN = os.path.join(REPO, "docs", "design.md")
HEADING = "### The add-on's API"
PACKAGE = "endophoton"


def _is_module(dotted):
    try:
        return importlib.util.find_spec(dotted) is not None
    except ModuleNotFoundError:
        return False


def _package_bound(node, aliases):
    """The package path a Name/Attribute stands for (``ep``, ``self.ep``, an imported alias), or None."""
    if isinstance(node, ast.Name):
        if node.id == "ep":
            return PACKAGE
        return aliases.get(node.id)
    if isinstance(node, ast.Attribute) and node.attr == "ep":
        return PACKAGE
    return None


def used_names(path):
    """{dotted name} the file uses from the package, and its dynamic-import calls."""
    tree = ast.parse(open(path, encoding="utf-8").read(), path)
    aliases, used, dynamic = {}, set(), []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == PACKAGE or alias.name.startswith(PACKAGE + "."):
                    aliases[alias.asname or alias.name.split(".")[0]] = alias.name if alias.asname else PACKAGE
                if alias.name == "importlib" or alias.name.startswith("importlib."):
                    dynamic.append(f"{path}:{node.lineno}: import {alias.name}")
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            if node.module == "importlib":
                dynamic.append(f"{path}:{node.lineno}: from importlib import ...")
            if node.module == PACKAGE or node.module.startswith(PACKAGE + "."):
                for alias in node.names:
                    dotted = f"{node.module}.{alias.name}"
                    if _is_module(dotted):
                        aliases[alias.asname or alias.name] = dotted  # its attributes are the names used
                    else:
                        used.add(dotted)
        elif isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "__import__":
            dynamic.append(f"{path}:{node.lineno}: __import__(...)")
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and not node.attr.startswith("__"):
            owner = _package_bound(node.value, aliases)
            if owner is not None:
                used.add(f"{owner}.{node.attr}")
    return used, dynamic


def addon_usage():
    used, dynamic = set(), []
    for name in sorted(os.listdir(ADDON)):
        if name.endswith(".py"):
            u, d = used_names(os.path.join(ADDON, name))
            used |= u
            dynamic += d
    return used, dynamic


def declared_names():
    """{dotted name} of the table under HEADING in docs/design.md: | `module` | `a`, `b` |."""
    text = open(DESIGN, encoding="utf-8").read()
    assert HEADING in text, f"docs/design.md has no section '{HEADING}'"
    section = text.split(HEADING, 1)[1].split("\n#", 1)[0]
    declared = set()
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 2 or not cells[0].startswith(f"`{PACKAGE}"):
            continue
        module = cells[0].strip("`")
        declared |= {f"{module}.{name}" for name in re.findall(r"`([A-Za-z_][A-Za-z_0-9]*)`", cells[1])}
    return declared


def test_the_addon_reaches_the_package_only_through_static_imports():
    _used, dynamic = addon_usage()
    assert not dynamic, "dynamic imports in the add-on (declare the module instead):\n" + "\n".join(dynamic)


def test_the_addon_uses_exactly_its_declared_api():
    used, _dynamic = addon_usage()
    declared = declared_names()
    assert used - declared == set(), f"used but not declared in docs/design.md: {sorted(used - declared)}"
    assert declared - used == set(), f"declared in docs/design.md but not used: {sorted(declared - used)}"


def test_the_names_the_addon_checks_for_are_declared():
    """package_finder.REQUIRED_NAMES (checked with hasattr when the package is found)."""
    tree = ast.parse(open(os.path.join(ADDON, "package_finder.py"), encoding="utf-8").read())
    required = next(
        node.value
        for node in ast.walk(tree)
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "REQUIRED_NAMES" for t in node.targets)
    )
    names = {f"{PACKAGE}.{elt.value}" for elt in required.elts}
    assert names <= declared_names()


def test_every_declared_name_exists_in_the_package():
    import importlib

    missing = []
    for dotted in sorted(declared_names()):
        module, _, name = dotted.rpartition(".")
        if not hasattr(importlib.import_module(module), name):
            missing.append(dotted)
    assert not missing, missing


def test_the_parser_sees_each_kind_of_reach(tmp_path):
    """The checker itself: a module import, a name import, ep.X, self.ep.X and importlib are seen."""
    source = tmp_path / "m.py"
    source.write_text(
        "import importlib\n"
        "def f(ep, self):\n"
        "    from endophoton.sweep import driver\n"
        "    from endophoton.io import no_nan\n"
        "    import endophoton as module\n"
        "    return driver.sweep, ep.run, self.ep.Scene, module.check_run, no_nan, ep.__name__\n"
    )
    used, dynamic = used_names(str(source))
    assert used == {
        "endophoton.sweep.driver.sweep",
        "endophoton.io.no_nan",
        "endophoton.run",
        "endophoton.Scene",
        "endophoton.check_run",
    }
    assert len(dynamic) == 1
