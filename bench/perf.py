#!/usr/bin/env python3
"""EndoPhoton's benchmark (not a test): measures what docs/performance.md reports.

Every engine figure comes from the command line users run, ``python3 -m endophoton run SCENE.json
--stats``, one fresh process per run, on the scenes of examples/ and bench/scenes/ (data; a variant
changes the file's ``run`` defaults only). ``--stats`` adds the engine's counters (native/stats.h) and
the process's peak memory and CPU time of the run. The render, lumen, Dask and mesh-size sections run
their own scripts (bench/render_speed.py, lumen_colon.py, dask_cluster.py, mesh_size.py) in a
subprocess. Results go to docs/perf/results.json; bench/page.py writes the page from them.

    /usr/bin/python3 bench/perf.py [--quick] [--only throughput,accuracy,...]
"""
from __future__ import annotations

import argparse
import datetime as _dt
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time

from page import RENDER_FULL

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
PYTHON = sys.executable
RESULTS = os.path.join(ROOT, "docs", "perf", "results.json")
SCENES = {
    "seed_tissue": os.path.join(ROOT, "examples", "seed_tissue.json"),
    "mcml_slab": os.path.join(ROOT, "examples", "mcml_slab.json"),
    "semi_infinite_n15": os.path.join(ROOT, "examples", "semi_infinite_n15.json"),
    "colon": os.path.join(HERE, "scenes", "colon.json"),
}
#: Oracles (docs/oracles.md): van de Hulst's slab Rd, Tt (rounding 5e-6); Giovanelli's Rsp + Rd (spread 1e-3).
VDH_RD, VDH_TT, VDH_UNC, SEMI_R, SEMI_UNC = 0.09739, 0.66096, 5e-6, 0.2600, 1e-3
REFERENCE = {"mcml_slab": (VDH_RD, VDH_UNC), "semi_infinite_n15": (SEMI_R, SEMI_UNC)}
TMP = tempfile.mkdtemp(prefix="ep-bench-")


def log(msg):
    print(f"[{time.strftime('%H:%M:%S')}] {msg}", file=sys.stderr, flush=True)


def scene_file(name, run=None):
    """SCENE.json of bench scene ``name`` with ``run`` merged into its run defaults (a copy in TMP,
    mesh paths made absolute)."""
    path = SCENES[name]
    if not run:
        return path
    with open(path, encoding="utf-8") as fh:
        doc = json.load(fh)
    for region in doc["regions"]:
        if isinstance(region.get("mesh"), str):
            region["mesh"] = os.path.join(os.path.dirname(path), region["mesh"])
    doc["run"] = dict(doc.get("run", {}), **run)
    out = os.path.join(TMP, f"{name}-{abs(hash(json.dumps(run, sort_keys=True)))}.json")
    with open(out, "w", encoding="utf-8") as fh:
        json.dump(doc, fh)
    return out


def cli(name, *args, run=None, photons=None, threads=2, seed=1, stats=True):
    """One ``python3 -m endophoton run`` process on scene ``name``: its JSON result."""
    cmd = [PYTHON, "-m", "endophoton", "run", scene_file(name, run), "--threads", str(threads), "--seed", str(seed)]
    cmd += (["--photons", str(photons)] if photons else []) + (["--stats"] if stats else []) + list(args)
    env = dict(os.environ, PYTHONPATH=os.path.join(ROOT, "python"))
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT)
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {p.returncode}: {p.stderr[-2000:]}")
    return json.loads(p.stdout)


def pps(r):
    return r["photons"] / r["seconds"]


def machine():
    def out(*cmd):
        return subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT).stdout.strip()

    cpu = next((line.split(":", 1)[1].strip() for line in open("/proc/cpuinfo") if line.startswith("model name")), "?")
    mem = next(int(line.split()[1]) for line in open("/proc/meminfo") if line.startswith("MemTotal"))
    import numpy

    return dict(
        date=_dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC"),
        cpu=cpu,
        nproc=out("nproc"),
        memory_gib=round(mem / 2**20, 1),
        kernel=platform.release(),
        python=platform.python_version(),
        numpy=numpy.__version__,
        commit=out("git", "rev-parse", "--short", "HEAD")
        + (" (modified)" if out("git", "status", "--porcelain") else ""),
        load_start=os.getloadavg(),
    )


THROUGHPUT = [  # (config, scene, run defaults, packets, quick packets)
    ("seed_tissue", "seed_tissue", None, 1_500_000, 500_000),
    ("seed_tissue_double", "seed_tissue", {"lanes": False}, 600_000, 200_000),
    ("mcml_slab", "mcml_slab", None, 3_000_000, 1_000_000),
    ("colon", "colon", None, 150_000, 50_000),
    ("colon_double", "colon", {"lanes": False}, 150_000, 50_000),
    ("colon+grids", "colon", {"grids": {"voxel_size": 0.0002, "path": os.path.join(TMP, "g.vdb")}}, 150_000, 50_000),
    (
        "colon+emission",
        "colon",
        {
            "grids": {
                "voxel_size": 0.0002,
                "path": os.path.join(TMP, "e.vdb"),
                "absorbed": False,
                "fluorescent_light": False,
            }
        },
        150_000,
        50_000,
    ),
    ("colon_lumen_off", "colon", {"lumen": False}, 150_000, 50_000),
]


def bench_throughput(q):
    """Packets/s, packets per CPU-second and peak memory at 1 and 2 threads; the scaling is the median
    over the repeats of the ratio of a 2-thread run to the 1-thread run beside it (alternating which
    runs first)."""
    rows = []
    for config, name, run, n, nq in THROUGHPUT:
        runs = {1: [], 2: []}
        for rep in range(2 if q else 5):
            for t in (1, 2) if rep % 2 == 0 else (2, 1):
                runs[t].append(cli(name, run=run, photons=nq if q else n, threads=t, seed=rep + 1))
        best = {t: max(runs[t], key=pps) for t in (1, 2)}
        pairs = [pps(b) / pps(a) for a, b in zip(runs[1], runs[2])]
        rows.append(
            dict(config=config, photons=best[1]["photons"], pps={t: pps(best[t]) for t in (1, 2)},
                 per_cpu_s={t: best[t]["photons"] / best[t]["stats"]["process"]["run_cpu_seconds"] for t in (1, 2)},
                 peak_rss_mb={t: max(r["stats"]["process"]["peak_rss_mb"] for r in runs[t]) for t in (1, 2)},
                 scaling=statistics.median(pairs), pairs=pairs, stats=best[1]["stats"]["per_packet"],
                 rd=[best[1]["diffuse_reflectance"], best[1]["diffuse_reflectance_stderr"]])  # fmt: skip
        )
        log(f"throughput {config}: {rows[-1]['pps'][1]:.0f} / {rows[-1]['pps'][2]:.0f} packets/s")
    return rows


def bench_stats_cost(q):
    """The counters' cost: packets/s of the same run with and without ``--stats``, best of the repeats."""
    rows = []
    for name, n in (("seed_tissue", 300_000), ("colon", 50_000)):
        best = {True: 0.0, False: 0.0}
        for rep in range(2 if q else 4):
            for on in (True, False) if rep % 2 == 0 else (False, True):
                best[on] = max(best[on], pps(cli(name, photons=n // (2 if q else 1), threads=1, stats=on)))
        rows.append(dict(scene=name, pps_on=best[True], pps_off=best[False]))
    return rows


def bench_accuracy(q):
    """Independent runs of the MCML slab (2 threads, distinct seeds) against van de Hulst."""
    plan = [(1000, 16), (3000, 16), (10_000, 16), (30_000, 16), (100_000, 16), (300_000, 8), (1_000_000, 4)]
    plan = [(n, max(1, k // 4)) for n, k in plan] if q else plan + [(3_000_000, 2), (10_000_000, 1)]
    runs, seed = [], 100
    for n, k in plan:
        for _ in range(k):
            seed += 1
            r = cli("mcml_slab", photons=n, seed=seed, stats=False)
            runs.append({key: r[key] for key in ("photons", "seconds", "diffuse_reflectance", "transmittance")})
            runs[-1].update(rd_se=r["diffuse_reflectance_stderr"], tt_se=r["transmittance_stderr"])
    return runs


def _scan(name, n, values, knob, q, extra=()):
    rows = []
    for v in values:
        r = cli(name, *extra, run={knob: v} if knob else None, photons=n // (3 if q else 1), seed=7)
        ref, unc = REFERENCE[name]
        est = r["diffuse_reflectance"] + (r["specular_reflectance"] if name == "semi_infinite_n15" else 0.0)
        se = r["diffuse_reflectance_stderr"]
        rows.append(dict(scene=name, value=v, photons=r["photons"], seconds=r["seconds"], estimate=est, stderr=se,
                         z=(est - ref) / se, ok=abs(est - ref) <= 3 * se + unc, cut=r["cut"],
                         roulette=[r["roulette"], r["roulette_stderr"]]))  # fmt: skip
    return rows


def bench_roulette(q):
    vals = [1e-2, 1e-3, 1e-4, 1e-5, 1e-6]
    return _scan("mcml_slab", 1_000_000, vals, "roulette_threshold", q) + _scan(
        "semi_infinite_n15", 300_000, vals, "roulette_threshold", q
    )


def bench_max_steps(q):
    vals = [3, 10, 30, 100, 300, 1000, 0]
    return _scan("mcml_slab", 400_000, vals, "max_steps", q) + _scan("semi_infinite_n15", 200_000, vals, "max_steps", q)


def bench_safe_distance(q):
    """safe_distance on / off, 1 thread, best of two interleaved; the counters say what each step took."""
    rows = []
    for name, n in (
        ("seed_tissue", 150_000),
        ("mcml_slab", 600_000),
        ("semi_infinite_n15", 150_000),
        ("colon", 80_000),
    ):
        best = {}
        for rep in range(2):
            for on in (True, False) if rep == 0 else (False, True):
                r = cli(name, run={"safe_distance": on}, photons=n // (3 if q else 1), threads=1)
                if on not in best or pps(r) > pps(best[on]):
                    best[on] = r
        rows.append(dict(scene=name, photons=best[True]["photons"], pps_on=pps(best[True]), pps_off=pps(best[False]),
                         same=best[True]["diffuse_reflectance"] == best[False]["diffuse_reflectance"],
                         on=best[True]["stats"]["per_packet"], off=best[False]["stats"]["per_packet"]))  # fmt: skip
    return rows


def bench_voxel_colon(q):
    """Grids on the colon: packets/s, peak memory, file size and the grid's sum against the absorbed weight."""
    rows = []
    for mm in [None, 1.0, 0.5, 0.2] + ([] if q else [0.1]):
        path = os.path.join(TMP, f"v{mm}.vdb")
        run = {"grids": {"voxel_size": mm / 1000, "path": path}} if mm else None
        r = cli("colon", run=run, photons=30_000 if q else 100_000)
        rows.append(dict(voxel_mm=mm, pps=pps(r), peak_rss_mb=r["stats"]["process"]["peak_rss_mb"],
                         vdb_mb=os.path.getsize(path) / 2**20 if mm else None,
                         sum_diff=abs(r["grid_absorbed_sum"] / r["absorbed_energy"] - 1) if mm else None))  # fmt: skip
    return rows


def bench_targets(q):
    """Target-accuracy runs (--target-rel-error, capped) and the presets they stand for."""
    rows = []
    for name, tally in (("mcml_slab", "diffuse_reflectance"), ("seed_tissue", "diffuse_reflectance"),
                        ("semi_infinite_n15", "diffuse_reflectance"), ("colon", "fluorescent_escaped")):  # fmt: skip
        for target in (0.05, 0.01, 0.002):
            cap = 200_000 if q else 2_000_000
            args = ("--target-rel-error", str(target), "--target-tally", tally, "--max-photons", str(cap))
            r = cli(name, *args, stats=False)
            rows.append(dict(scene=name, tally=tally, target=target, photons=r["photons"], seconds=r["seconds"],
                             value=r[tally], stderr=r[tally + "_stderr"], stop=r["stop_reason"]))  # fmt: skip
    return rows


def bench_stop_rule(q):
    """Target mode against a fixed count of the same packets, for several unit sizes (impossible target)."""
    rows, n = [], 200_000 // (4 if q else 1)
    for size in (1024, 64, 8, 2) if q else (1024, 64, 8, 4, 2, 1):
        best = {}
        for rep in range(2 if q else 3):
            fixed = cli("mcml_slab", run={"unit_size": size}, photons=n, stats=False)["seconds"]
            aimed = cli("mcml_slab", "--target-rel-error", "1e-9", "--max-photons", str(n), run={"unit_size": size},
                        stats=False)["seconds"]  # fmt: skip
            best = dict(fixed=min(best.get("fixed", fixed), fixed), target=min(best.get("target", aimed), aimed))
        rows.append(dict(unit_size=size, units=-(-n // size), **best))
    return rows


def script(name, *args, parse_json=True):
    """bench/NAME.py ARGS in a subprocess: its JSON output (or its text)."""
    env = dict(os.environ, PYTHONPATH=os.path.join(ROOT, "python"))
    p = subprocess.run([PYTHON, os.path.join(HERE, name), *args], capture_output=True, text=True, env=env, cwd=ROOT)
    if p.returncode != 0:
        raise RuntimeError(f"bench/{name} exited {p.returncode}: {p.stderr[-2000:]}")
    return json.loads(p.stdout) if parse_json else p.stdout


SECTIONS = {
    "throughput": bench_throughput,
    "stats_cost": bench_stats_cost,
    "accuracy": bench_accuracy,
    "roulette": bench_roulette,
    "safe_distance": bench_safe_distance,
    "voxel_colon": bench_voxel_colon,
    "max_steps": bench_max_steps,
    "targets": bench_targets,
    "stop_rule": bench_stop_rule,
    "lumen": lambda q: script("lumen_colon.py", "--photons", "20000" if q else "100000"),
    # The full preset: page.RENDER_FULL (image sides up to 1024², issue 38); the quick one: the kernel
    # radii at small images.
    "render": lambda q: script("render_speed.py", *(["--photons", "20000"] if q else RENDER_FULL), parse_json=False),
    "dask": lambda q: script("dask_cluster.py", *(["--quick"] if q else []), parse_json=False),
    "mesh_size": lambda q: script("mesh_size.py", *(["--quick", "--photons", "5000"] if q else [])),
}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="fewer packets and repeats (minutes, not tens of minutes)")
    ap.add_argument("--only", default="", help="comma-separated sections to rerun; the others keep their results")
    a = ap.parse_args(argv)
    only = [s for s in a.only.split(",") if s] or list(SECTIONS)
    unknown = [s for s in only if s not in SECTIONS]
    if unknown:
        ap.error(f"--only {unknown[0]!r} is not a section ({', '.join(SECTIONS)})")
    results = {}
    if a.only and os.path.exists(RESULTS):
        with open(RESULTS, encoding="utf-8") as fh:
            results = json.load(fh)
        results = results if results.get("format") == 2 else {}  # the former bench's results: start anew
    earlier = results.get("machine", {})
    results.update(format=2, machine=machine())
    if a.only and earlier:  # a partial rerun: the page's load at start and wall time cover every section
        results["machine"].update(load_start=earlier["load_start"], wall_s_before=earlier.get("wall_s", 0))
    results["preset"] = "quick" if a.quick else "full"
    t0 = time.time()
    for name in only:
        log(f"section {name}")
        results[name] = SECTIONS[name](a.quick)
    m = results["machine"]
    m.update(load_end=os.getloadavg(), wall_s=m.pop("wall_s_before", 0) + round(time.time() - t0))
    os.makedirs(os.path.dirname(RESULTS), exist_ok=True)
    with open(RESULTS + ".tmp", "w", encoding="utf-8") as fh:
        json.dump(results, fh, indent=1, allow_nan=False)
    os.replace(RESULTS + ".tmp", RESULTS)
    import page

    with open(RESULTS, encoding="utf-8") as fh:
        page.write(json.load(fh))
    return 0


if __name__ == "__main__":
    sys.exit(main())
