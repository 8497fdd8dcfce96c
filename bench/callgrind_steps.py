"""Instructions per packet and per step of the transport loop, from callgrind (load-independent).

    /usr/bin/python3 bench/callgrind_steps.py [--py PYTHON_PKG_DIR] [scene:packets ...]

Runs each scene in a child under `valgrind --tool=callgrind --toggle-collect=ep::Tracer::trace(*`
(one thread) and prints Ir per packet, steps per packet (interactions + boundary events from the
tallies) and Ir per step, split into geometry (Embree ray / point queries, the local triangle
cache), libm and the rest of the loop.
"""
from __future__ import annotations

import argparse
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
    "point query": "ep::Scene::distance_to_surface",
    "triangle cache gather": "ep::Scene::gather_triangles",
    "triangle cache test": "ep::TriangleCache::intersect",
    "libm log": "log@@",
    "libm sincos": "sincos",
    "source emit": "ep::Source::emit",
}


def child(scene_name, n, py, safe_distance=True):
    sys.path.insert(0, py)
    import endophoton as ep
    import colon_scene as cs

    scene, src = {"seed_tissue": cs.seed_tissue_box, "mcml_slab": cs.mcml_slab, "colon": cs.colon_scene}[scene_name]()
    r = ep.run(scene, src, photons=n, threads=1, seed=1, record_escapes=False, safe_distance=safe_distance)
    print(
        "RESULT "
        + json.dumps(
            dict(
                rd=r.diffuse_reflectance,
                rd_se=r.diffuse_reflectance_stderr,
                interactions=float(r.interactions) * r.photons,
            )
        )
    )


def profile(scene_name, n, py, safe_distance=True):
    from callgrind_summary import parse

    out = os.path.join(tempfile.gettempdir(), f"ep-cg-steps-{os.getpid()}-{scene_name}.out")
    cmd = [
        "valgrind",
        "--tool=callgrind",
        f"--callgrind-out-file={out}",
        "--toggle-collect=ep::Tracer::trace(*",
        sys.executable,
        os.path.abspath(__file__),
        "--child",
        scene_name,
        str(n),
        "--py",
        py,
    ] + ([] if safe_distance else ["--no-safe-distance"])
    p = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    if p.returncode:
        raise RuntimeError(p.stderr[-2000:])
    res = json.loads([l for l in p.stdout.splitlines() if l.startswith("RESULT ")][-1][7:])
    prof = parse(out)
    os.remove(out)
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


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--child", nargs=2)
    ap.add_argument("--py", default=os.path.join(ROOT, "python"))
    ap.add_argument("--no-safe-distance", action="store_true", help="run with safe_distance=False")
    ap.add_argument("runs", nargs="*", default=["seed_tissue:5000", "mcml_slab:20000", "colon:2000"])
    a = ap.parse_args()
    if a.child:
        return child(a.child[0], int(a.child[1]), a.py, not a.no_safe_distance)
    rows = []
    for spec in a.runs:
        name, n = spec.split(":")
        row = profile(name, int(n), a.py, not a.no_safe_distance)
        rows.append(row)
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
