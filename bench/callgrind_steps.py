"""Instructions per packet and per step of the transport loop, from callgrind (load-independent).

    /usr/bin/python3 bench/callgrind_steps.py [--py PYTHON_PKG_DIR] [scene:packets ...]

Runs each scene in a child under `valgrind --tool=callgrind --toggle-collect=ep::Tracer::trace(*`
(one thread) and prints Ir per packet, steps per packet (interactions + boundary events from the
tallies) and Ir per step, split into geometry (Embree ray / point queries, the local triangle
cache), libm and the rest of the loop.
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)

GROUPS = {
    "ray query (Embree all-hits)": "ep::Scene::intersect_all",
    "closest-hit query": "ep::Scene::intersect_first",
    "any-hit query (mirror ray)": "ep::Scene::intersect_any",
    "point query": "ep::Scene::distance_to_surface",
    "triangle cache gather": "ep::Scene::gather_triangles",
    "per-cube cache (lookup, build)": "ep::Scene::cell_cache",
    "triangle cache test": "ep::TriangleCache::intersect",
    "libm log": "log@@",
    "libm sincos": "sincos",
    "source emit": "ep::Source::emit",
}


def child(specs, py):
    """Run each (scene, packets, safe_distance) of ``specs`` once, one thread, and print their results."""
    sys.path.insert(0, py)
    import endophoton as ep
    import colon_scene as cs

    scenes = {"seed_tissue": cs.seed_tissue_box, "mcml_slab": cs.mcml_slab, "colon": cs.colon_scene}
    out, built = [], {}
    for name, n, safe_distance in specs:
        if name not in built:  # each scene is built once (slow under valgrind)
            built[name] = scenes[name]()
        scene, src = built[name]
        r = ep.run(scene, src, photons=n, threads=1, seed=1, record_escapes=False, safe_distance=safe_distance)
        out.append(dict(rd=r.diffuse_reflectance, rd_se=r.diffuse_reflectance_stderr, interactions=r.interactions * n))
    print("RESULT " + json.dumps(out))


def _row(prof, scene_name, res):
    """Ir per packet and per interaction, split by GROUPS, of one run's callgrind profile."""
    packets = prof.calls("ep::Tracer::trace(")
    total = prof.inclusive("ep::Tracer::trace(")
    steps = res["interactions"] or prof.calls("log@@")
    row = dict(
        scene=scene_name,
        packets=packets,
        ir_packet=total / packets,
        steps_packet=steps / packets,
        ir_step=total / steps,
        rd=res["rd"],
        rd_se=res["rd_se"],
        parts={},
        calls={},
    )
    rest = total
    for label, pat in GROUPS.items():
        v = prof.inclusive(pat)
        if v:
            row["parts"][label] = v / steps
            row["calls"][label] = prof.calls(pat) / packets
            rest -= v
    row["parts"]["loop (rest)"] = rest / steps
    return row


def profile_many(specs, py):
    """One row per (scene, packets, safe_distance) of ``specs``, all traced in one process under callgrind
    (Python's start-up under valgrind is paid once): a dump after each engine run (``ep::run``) holds
    that run's instructions."""
    from callgrind_summary import parse

    out = os.path.join(tempfile.gettempdir(), f"ep-cg-steps-{os.getpid()}.out")
    cmd = ["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", "--toggle-collect=ep::Tracer::trace(*"]
    cmd += ["--dump-after=ep::run(*", sys.executable, os.path.abspath(__file__), "--child", json.dumps(specs)]
    p = subprocess.run(cmd + ["--py", py], capture_output=True, text=True, cwd=ROOT)
    dumps = sorted(glob.glob(out + ".*"), key=lambda f: int(f.rsplit(".", 1)[1]))
    try:
        if p.returncode:
            raise RuntimeError(p.stderr[-2000:])
        results = json.loads([l for l in p.stdout.splitlines() if l.startswith("RESULT ")][-1][7:])
        if len(dumps) < len(specs):
            raise RuntimeError(f"callgrind wrote {len(dumps)} dumps for {len(specs)} runs")
        return [_row(parse(f), spec[0], res) for f, spec, res in zip(dumps, specs, results)]
    finally:
        for f in dumps + [out]:
            if os.path.exists(f):
                os.remove(f)


def profile(scene_name, n, py, safe_distance=True):
    return profile_many([(scene_name, n, safe_distance)], py)[0]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--py", default=os.path.join(ROOT, "python"))
    ap.add_argument("--no-safe-distance", action="store_true", help="run with safe_distance=False")
    ap.add_argument("runs", nargs="*", default=["seed_tissue:5000", "mcml_slab:20000", "colon:2000"])
    a = ap.parse_args()
    if a.child:
        return child(json.loads(a.child), a.py)
    specs = [(spec.split(":")[0], int(spec.split(":")[1]), not a.no_safe_distance) for spec in a.runs]
    rows = profile_many(specs, a.py)
    for (name, _, _), row in zip(specs, rows):
        print(
            f"{name}: {row['ir_packet']:.0f} Ir/packet, {row['steps_packet']:.1f} interactions/packet, "
            f"{row['ir_step']:.0f} Ir per interaction; Rd {row['rd']:.5f} ± {row['rd_se']:.5f}"
        )
        for k, v in row["parts"].items():
            c = row["calls"].get(k)
            print(f"    {k:32s} {v:8.1f} Ir/interaction" + (f"   {c:8.2f} calls/packet" if c is not None else ""))
    print("JSON " + json.dumps(rows))


if __name__ == "__main__":
    main()
