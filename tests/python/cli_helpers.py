"""The tests' one way to run the command line: ``python3 -m endophoton ARGS`` in a subprocess, on the
source tree's package (its python/ first on PYTHONPATH), from the repository's root."""
from __future__ import annotations

import json
import os
import subprocess
import sys

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
PY = os.path.join(ROOT, "python")
EXAMPLES = os.path.join(ROOT, "examples")


def cli_env(*extra_paths: str, **overrides: str) -> dict:
    """The environment of a CLI run: PYTHONPATH = the tree's python/ (then ``extra_paths``), plus ``overrides``."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([PY, *extra_paths]))
    env.update(overrides)
    return env


def cli_command(*args) -> list[str]:
    """The argv of ``python3 -m endophoton ARGS`` (the interpreter running the tests)."""
    return [sys.executable, "-m", "endophoton", *(str(a) for a in args)]


def run_cli(*args, timeout: float = 600, env: dict | None = None, cwd: str = ROOT) -> subprocess.CompletedProcess:
    """Runs ``python3 -m endophoton ARGS`` to its end; stdout and stderr captured as text."""
    return subprocess.run(
        cli_command(*args), cwd=cwd, env=env or cli_env(), capture_output=True, text=True, timeout=timeout
    )


def start_cli(*args, env: dict | None = None, cwd: str = ROOT) -> subprocess.Popen:
    """Starts ``python3 -m endophoton ARGS`` (stdout and stderr piped, text) for a test that talks to it."""
    return subprocess.Popen(
        cli_command(*args), cwd=cwd, env=env or cli_env(), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )


def run_json(*args, timeout: float = 600) -> dict:
    """``run_cli(*args)`` that must exit 0 and print one line of JSON: that JSON."""
    p = run_cli(*args, timeout=timeout)
    assert p.returncode == 0, f"exit {p.returncode}\nstdout: {p.stdout[-3000:]}\nstderr: {p.stderr[-3000:]}"
    out = p.stdout.strip()
    assert out.count("\n") == 0, f"expected a single line of JSON, got:\n{out[-3000:]}"
    return json.loads(out)


def write_scene(directory, doc: dict, name: str = "scene.json") -> str:
    """Writes the SCENE.json document ``doc`` as ``directory/name``; returns its path."""
    path = os.path.join(str(directory), name)
    with open(path, "w", encoding="utf-8") as fh:
        json.dump(doc, fh)
    return path


def scene_file(path: str):
    """(Scene, source) of a SCENE.json file, read as ``python3 -m endophoton run`` reads it."""
    import endophoton as ep

    with open(path, encoding="utf-8") as fh:
        doc = json.load(fh)
    return ep.Scene.from_dict(doc, base_dir=os.path.dirname(os.path.abspath(path))), ep.source_from_dict(doc["source"])


def bench_scene(name: str):
    """(Scene, source) of the benchmark scene bench/scenes/NAME.json (data: the tests import no bench/ code)."""
    return scene_file(os.path.join(ROOT, "bench", "scenes", name + ".json"))
