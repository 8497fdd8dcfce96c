"""docs/design.md matches the code: the names it lists exist."""
import glob
import os
import re

import endophoton as ep
from endophoton import _core

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
with open(os.path.join(ROOT, "docs", "design.md"), encoding="utf-8") as fh:
    DOC = fh.read()
CODE_SPANS = re.findall(r"`([^`]+)`", DOC)


def _section(title):
    return DOC.split(title, 1)[1].split("\n## ", 1)[0]


def test_package_names_exist():
    names = set(re.findall(r"\bep\.([A-Za-z_]\w*)", DOC))  # code spans and code blocks
    assert len(names) >= 10
    assert sorted(n for n in names if not hasattr(ep, n)) == []


def test_paths_exist():
    paths = {
        m.rstrip(".,")
        for span in CODE_SPANS
        for m in re.findall(r"(?:native|python|addon|tests|docs|data|bench|blend_scenes)/[\w./*-]+", span)
    }
    assert len(paths) > 10
    assert sorted(p for p in paths if not glob.glob(os.path.join(ROOT, p))) == []


def _listed_modules(first_cell):
    """The modules a table row names: `a`, `b` at the top, or `sub/`: `a`, `b` inside subpackage sub."""
    sub = re.match(r"\s*`([a-z_]+)/`:", first_cell)
    names = re.findall(r"`([a-z_]+)`", first_cell)
    return {f"{sub.group(1)}/{m}" for m in names} if sub else set(names)


def test_listed_package_modules_exist():
    table = _section("### Package modules")
    modules = set()
    for row in table.splitlines():
        if row.startswith("| `"):
            modules |= _listed_modules(row.split("|")[1])
    assert len(modules) > 15
    pkg = os.path.join(ROOT, "python", "endophoton")
    assert sorted(m for m in modules if not os.path.isfile(os.path.join(pkg, m + ".py"))) == []
    # ... and every module of the package is listed, but for the deprecated shims of moved modules
    on_disk = set()
    for sub in ("", "view", "sweep", "analysis"):
        for f in os.listdir(os.path.join(pkg, sub)):
            text = open(os.path.join(pkg, sub, f)).read() if f.endswith(".py") else ""
            if f.endswith(".py") and f != "__init__.py" and "from ._moved import alias" not in text:
                on_disk.add(f"{sub}/{f[:-3]}" if sub else f[:-3])
    assert sorted(on_disk - modules) == []


def test_binding_names_exist():
    section = _section("## Native binding `endophoton._core`")
    names = set(re.findall(r"^- `([A-Za-z_]\w*)\(", section, re.M)) | {"CancelToken", "check_mesh"}
    assert {"Scene", "Source", "RunConfig", "run"} <= names
    assert sorted(n for n in names if not hasattr(_core, n)) == []
    testing = re.search(r"`_testing`: (.*?) —", section, re.S).group(1)
    hooks = re.findall(r"`(\w+)`", testing)
    assert len(hooks) == 5 and sorted(h for h in hooks if not hasattr(_core._testing, h)) == []
    for method in ("add_region", "add_fluorophore", "set_region_fluorophores", "commit"):
        assert method in section and hasattr(_core.Scene, method)
