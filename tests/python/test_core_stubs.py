"""python/endophoton/_core.pyi describes the binding as it is: every public name of
endophoton._core (and of its classes) has a stub, every stub names something _core has, and
the stubs ship with the package (pyproject.toml's package data)."""

import ast
import os
import tomllib

from endophoton import _core

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
STUBS = os.path.join(ROOT, "python", "endophoton", "_core.pyi")


def _public(names):
    return {n for n in names if not n.startswith("_")} | ({"__version__"} & set(names))


def _stubbed():
    """{top-level name: set of member names (classes) or None}."""
    with open(STUBS, encoding="utf-8") as fh:
        tree = ast.parse(fh.read(), filename=STUBS)
    out = {}
    for node in tree.body:
        if isinstance(node, ast.ClassDef):
            members = set()
            for item in node.body:
                if isinstance(item, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    members.add(item.name)
                elif isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name):
                    members.add(item.target.id)
            out[node.name] = _public(members)
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            out[node.name] = None
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            out[node.target.id] = None
    return out


def test_every_public_name_has_a_stub_and_every_stub_a_name():
    stubbed = _stubbed()
    public = _public(dir(_core))
    assert sorted(public - set(stubbed)) == [], "names without a stub"
    assert sorted(set(stubbed) - public) == [], "stubs of names _core does not have"
    assert {"run", "check_run", "check_spectrum", "check_eem", "Scene", "RunConfig"} <= public


def test_every_public_member_of_a_class_has_a_stub():
    for name, members in _stubbed().items():
        cls = getattr(_core, name)
        if members is None or issubclass(cls, BaseException):
            continue
        own = _public(n for n in dir(cls) if n not in dir(object) and n not in ("__init__",))
        assert sorted(own - members) == [], f"{name}: members without a stub"
        assert sorted(members - own - {"__init__"}) == [], f"{name}: stubs of members it does not have"


def test_the_stubs_ship_with_the_package():
    with open(os.path.join(ROOT, "pyproject.toml"), "rb") as fh:
        setuptools = tomllib.load(fh)["tool"]["setuptools"]
    assert "_core.pyi" in setuptools["package-data"]["endophoton"]
    # and every subpackage of python/endophoton is a package setuptools installs
    on_disk = {
        "endophoton" + folder[len(os.path.join(ROOT, "python", "endophoton")) :].replace(os.sep, ".")
        for folder, _, files in os.walk(os.path.join(ROOT, "python", "endophoton"))
        if "__init__.py" in files
    }
    assert sorted(on_disk - set(setuptools["packages"])) == []
