"""The package's place in the house: traffic runs one way (core -> binding ->
package -> add-on), and the package's own modules import each other without
cycles.

Both checks read the source with ``ast``, so imports hidden inside functions
count as much as those at the top of a module.
"""

import ast
import os
import shutil
import subprocess
import sys
import textwrap

import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
PKG_DIR = os.path.join(ROOT, "python", "endophoton")
PKG = "endophoton"
FORBIDDEN = ("bpy", "bmesh", "mathutils", "addon_utils", "endophoton_addon")


SUBPACKAGES = ("view", "sweep", "analysis")


def _module_files():
    """{module name: path} for every .py file of the package and of its subpackages."""
    out = {}
    for sub in ("",) + SUBPACKAGES:
        prefix = f"{PKG}.{sub}" if sub else PKG
        for name in sorted(os.listdir(os.path.join(PKG_DIR, sub))):
            if name.endswith(".py"):
                out[prefix if name == "__init__.py" else f"{prefix}.{name[:-3]}"] = os.path.join(PKG_DIR, sub, name)
    return out


def _modules():
    """{module name: parsed AST} for every .py file of the package."""
    out = {}
    for mod, path in _module_files().items():
        with open(path, encoding="utf-8") as fh:
            out[mod] = ast.parse(fh.read(), filename=path)
    return out


def _imported(mod, tree, known):
    """Every module of the package that ``mod`` imports (anywhere in its body), and every
    top-level name of a module it imports from outside the package."""
    inside, outside = set(), set()
    is_package = mod == PKG or mod.split(".")[-1] in SUBPACKAGES
    here = mod if is_package else mod.rpartition(".")[0]  # the package a relative import starts from
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                (inside if a.name.split(".")[0] == PKG else outside).add(
                    a.name if a.name.split(".")[0] == PKG else a.name.split(".")[0]
                )
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                top = (node.module or "").split(".")[0]
                if top != PKG:
                    outside.add(top)
                    continue
                target = node.module
            else:
                base = here.rsplit(".", node.level - 1)[0] if node.level > 1 else here
                target = base + ("." + node.module if node.module else "")
            if target in (PKG,) + tuple(f"{PKG}.{s}" for s in SUBPACKAGES):  # "from . import x": a module or a name
                for a in node.names:
                    sub = f"{target}.{a.name}"
                    inside.add(sub if sub in known else target)
            else:
                inside.add(target)
    inside = {m if m in known else PKG for m in inside}  # e.g. endophoton._core (native) -> root
    inside.discard(mod)
    return inside, outside


def _graph():
    trees = _modules()
    known = set(trees) | {f"{PKG}._core"}
    graph = {}
    for mod, tree in trees.items():
        inside, _ = _imported(mod, tree, known)
        graph[mod] = inside - {f"{PKG}._core"}
    return graph


def _find_cycle(graph):
    """A list of modules forming a cycle, or None (depth-first search, three colours)."""
    colour, stack = {}, []

    def visit(m):
        colour[m] = "grey"
        stack.append(m)
        for n in sorted(graph.get(m, ())):
            if colour.get(n) == "grey":
                return stack[stack.index(n) :] + [n]
            if n not in colour:
                found = visit(n)
                if found:
                    return found
        stack.pop()
        colour[m] = "black"
        return None

    for m in sorted(graph):
        if m not in colour:
            found = visit(m)
            if found:
                return found
    return None


def test_cycle_finder_finds_a_planted_cycle():
    """The checker itself: a graph with a cycle hidden behind a leaf is reported as that cycle."""
    g = {"a": {"b", "leaf"}, "b": {"c"}, "c": {"a"}, "leaf": set()}
    assert _find_cycle(g) == ["a", "b", "c", "a"]
    assert _find_cycle({"a": {"b"}, "b": set()}) is None


def test_package_has_no_import_cycles():
    graph = _graph()
    assert len(graph) >= 15 and "endophoton.sweep.driver" in graph
    # the root imports the public modules; no module may import the root back
    importers_of_root = sorted(m for m, deps in graph.items() if PKG in deps and m != PKG)
    assert importers_of_root == [], importers_of_root
    assert _find_cycle(graph) is None, " -> ".join(_find_cycle(graph))


def test_no_module_imports_blender_or_the_addon():
    trees = _modules()
    known = set(trees)
    offenders = {}
    for mod, tree in trees.items():
        _, outside = _imported(mod, tree, known)
        bad = sorted(outside & set(FORBIDDEN))
        if bad:
            offenders[mod] = bad
    assert offenders == {}


BLOCKER = textwrap.dedent(
    '''
    import importlib.abc, sys
    BLOCKED = {blocked!r}

    class Block(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"{{name}} is blocked by the layering test")
            return None

    sys.meta_path.insert(0, Block())
    sys.path.insert(0, {pkg!r})
    import pkgutil, importlib
    import endophoton
    names = [m.name for m in pkgutil.walk_packages(endophoton.__path__, "endophoton.")
             if m.name != "endophoton.__main__"]   # __main__ runs the CLI
    for name in names:
        importlib.import_module(name)
    for b in BLOCKED:
        try:
            __import__(b)
        except ImportError:
            pass
        else:
            raise SystemExit(f"{{b}} was importable")
    from endophoton import cli
    try:
        cli.main(["sweep", "--help"])
    except SystemExit as e:
        assert e.code == 0, e.code
    print("IMPORTED", len(names))
'''
)


@pytest.mark.slow
def test_package_imports_with_bpy_and_addon_unimportable():
    """Import the package and every module in it, and parse the sweep CLI, in a
    fresh interpreter where bpy and the add-on cannot be imported."""
    code = BLOCKER.format(blocked=list(FORBIDDEN), pkg=os.path.join(ROOT, "python"))
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    n = int(proc.stdout.split("IMPORTED")[-1].split()[0])
    # every .py module (the subpackages' __init__ count as their package) but __init__ and __main__,
    # plus the native _core
    assert n == len(_module_files()) - 2 + 1


BENCH_DIR = os.path.join(ROOT, "bench")
TEST_DIRS = [os.path.join(ROOT, "tests", d) for d in ("python", "blender", "blender_shell")]


def _top_imports(tree):
    """The top-level names of every module ``tree`` imports (absolute imports; anywhere in its body)."""
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def _parse(path):
    with open(path, encoding="utf-8") as fh:
        return ast.parse(fh.read(), filename=path)


def _bench_graph():
    """{bench script: the bench scripts it imports} (bench/ is a folder of scripts, each importing the
    others by their bare names, as ``python3 bench/X.py`` puts bench/ first on sys.path)."""
    files = {n[:-3]: os.path.join(BENCH_DIR, n) for n in os.listdir(BENCH_DIR) if n.endswith(".py")}
    return {m: _top_imports(_parse(p)) & set(files) - {m} for m, p in files.items()}


def test_bench_has_no_import_cycles():
    graph = _bench_graph()
    assert {"perf", "page", "colon_scene"} <= set(graph)
    assert "perf" not in graph["page"], "page.py renders results; it must not import the bench driver"
    assert _find_cycle(graph) is None, " -> ".join(_find_cycle(graph))


def _test_files():
    for d in TEST_DIRS:
        for dirpath, _, names in os.walk(d):
            yield from (os.path.join(dirpath, n) for n in sorted(names) if n.endswith(".py"))


def _puts_bench_on_path(tree):
    """Whether ``tree`` calls sys.path.insert/append with an argument that mentions bench."""
    for node in ast.walk(tree):
        if (
            isinstance(node, ast.Call)
            and isinstance(node.func, ast.Attribute)
            and node.func.attr in ("insert", "append")
        ):
            if ast.unparse(node.func.value) == "sys.path" and "bench" in ast.unparse(node).lower():
                return True
    return False


def test_no_test_imports_bench():
    """Tests check the package, the CLI and the add-on; the benchmark's code is none of them (tests may read
    bench/scenes/*.json, which is data)."""
    bench_modules = set(_bench_graph())
    offenders = {}
    for path in _test_files():
        tree = _parse(path)
        bad = sorted(_top_imports(tree) & bench_modules) + (["sys.path + bench/"] if _puts_bench_on_path(tree) else [])
        if bad:
            offenders[os.path.relpath(path, ROOT)] = bad
    assert offenders == {}


def test_bench_checks_see_a_planted_offender():
    """The two checks above on planted code: a test importing a bench script, and bench/ put on sys.path."""
    planted = ast.parse("import sys, os\nsys.path.insert(0, os.path.join(ROOT, 'bench'))\nfrom perf import cli\n")
    assert _puts_bench_on_path(planted) and "perf" in _top_imports(planted) & set(_bench_graph())
    assert not _puts_bench_on_path(ast.parse("import sys\nsys.path.insert(0, PY)\n"))


def test_performance_page_is_what_page_py_writes_from_the_stored_results(tmp_path):
    """docs/performance.md is generated (bench/page.py from docs/perf/results.json and bench/frozen/):
    a hand edit of the page is lost at the next regeneration, so the page must equal page.py's output.
    page.py runs on a copy of bench/ and docs/perf/ (it writes the page beside them), as a subprocess."""
    shutil.copytree(os.path.join(ROOT, "bench"), tmp_path / "bench")
    shutil.copytree(os.path.join(ROOT, "docs", "perf"), tmp_path / "docs" / "perf")
    subprocess.run([sys.executable, str(tmp_path / "bench" / "page.py")], check=True, capture_output=True)
    with open(os.path.join(ROOT, "docs", "performance.md"), encoding="utf-8") as fh:
        committed = fh.read()
    assert (tmp_path / "docs" / "performance.md").read_text(encoding="utf-8") == committed
