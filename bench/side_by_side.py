"""Packets/s before and after, side by side: one engine build against another, in fresh processes,
interleaved (wall clock and CPU time; best of --repeats). Not a test, and on a shared machine only
"measured under load" figures: the load-independent measure is bench/callgrind_steps.py.

    /usr/bin/python3 bench/side_by_side.py --before /tmp/base --after python [--repeats 2]
    /usr/bin/python3 bench/side_by_side.py --build-before 37f845d --after python
    /usr/bin/python3 bench/side_by_side.py --mcml-binary /tmp/mcml-src/mcml [--repeats 3]

Each --before / --after is a directory holding an `endophoton` package (with its _core module);
--after defaults to this checkout's python/. --build-before COMMIT builds that commit's package first
(bench/baseline.json's commit is the issue-11 baseline), from `git archive` into
/tmp/ep-baseline-COMMIT (the repository is not touched). bench/run_all.py --baseline-py DIR calls
compare() for docs/performance.md §9.

--mcml-binary PATH runs an MCML executable (Wang, Jacques & Zheng's original C code, or any program
reading the same .mci input and writing the same .mco output) against this engine on MCML_PLAN:
this script writes the .mci input, runs the binary in a temporary directory, reads Rd from the
.mco's RAT block and the process's CPU time, and puts it beside the engine's packets per CPU-second
on one thread (compare_mcml(); bench/run_all.py --mcml-binary PATH passes it on to §9). MCML is
neither built nor contained here: build it yourself, outside the repository.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
import run_all  # noqa: E402  (run_child: one measured run in a fresh process)

PLAN = [
    ("seed_tissue", dict(scene="seed_tissue"), 200_000),
    ("mcml_slab", dict(scene="mcml_slab"), 1_000_000),
    ("colon", dict(scene="colon"), 60_000),
    # Like for like: the baseline had no lumen rule (every packet ended at its first exit); run_all's
    # child passes lumen=False to an engine that has the rule, so both trace the same physics.
    ("colon_lumen_off", dict(scene="colon", lumen=False), 60_000),
    ("colon+grids", dict(scene="colon", voxel=2e-4, grid_path="/tmp/ep-sbs-grid.vdb"), 60_000),
]


#: The fractions (and their standard-error keys) of run_all's child that compare() keeps per engine.
PHYSICS = ("rd", "rd_se", "absorbed", "absorbed_se", "fluorescent", "fluorescent_se")


def build_package(commit: str, dest: str | None = None) -> str:
    """Build ``commit``'s engine (Release, no tests) and return the directory that holds its package."""
    dest = dest or f"/tmp/ep-baseline-{commit}"
    src = os.path.join(dest, "src")
    if not os.path.isdir(src):
        os.makedirs(src)
        archive = subprocess.run(["git", "-C", ROOT, "archive", commit], check=True, capture_output=True).stdout
        subprocess.run(["tar", "-x", "-C", src], input=archive, check=True)
    build = os.path.join(dest, "build")
    cfg = ["cmake", "-S", src, "-B", build, "-DCMAKE_BUILD_TYPE=Release", "-DENDOPHOTON_BUILD_TESTS=OFF"]
    subprocess.run(cfg + [f"-DPython3_EXECUTABLE={sys.executable}"], check=True, capture_output=True)
    subprocess.run(["cmake", "--build", build, "-j2"], check=True, capture_output=True)
    return os.path.join(src, "python")


def compare(before: str, after: str, repeats: int = 2, plan=PLAN, report=print) -> list[dict]:
    """Best of ``repeats`` interleaved runs of each configuration with each package, 1 and 2 threads."""
    rows = []
    for key, cfg, n in plan:
        for threads in (1, 2):
            row = dict(config=key, threads=threads, packets=n)
            for rep in range(repeats):
                for tag, py in (("before", before), ("after", after)):
                    r = run_all.run_child(
                        dict(cfg, key=key, photons=n, threads=threads, py=os.path.abspath(py), warmup=2000)
                    )
                    row[tag] = max(row.get(tag, 0), r["pps"])
                    row[tag + "_cpu"] = max(row.get(tag + "_cpu", 0), r["pp_cpu_s"])
                    # The answers (seed 1; the same at every repeat and thread count), for the page's
                    # check that both engines compute the same physics within their standard errors.
                    row[tag + "_physics"] = {k: r.get(k) for k in PHYSICS}
            rows.append(row)
            report(
                f"{key:12s} {threads} thr: before {row['before']:9.0f}/s ({row['before_cpu']:9.0f}/CPU-s)  "
                f"after {row['after']:9.0f}/s ({row['after_cpu']:9.0f}/CPU-s)  x{row['after'] / row['before']:.2f}"
            )
    return rows


#: MCML's side: (bench scene of run_all.scene_by_name, its layers as (n, mua [1/cm], mus [1/cm], g,
#: thickness [cm]) from the top, packets). Ambient n = 1 above and below (MCML_AMBIENT_N). The seed
#: tissue is the engine's 10 cm deep box (semi-infinite for mut' = 40 /cm); the slab is oracles §1.
#: tests/python/test_bench_mcml.py holds these against bench/colon_scene.py.
MCML_PLAN = [
    ("seed_tissue", [(1.1, 20.0, 200.0, 0.9, 10.0)], 1_000_000),
    ("mcml_slab", [(1.0, 10.0, 90.0, 0.75, 0.02)], 1_000_000),
]
MCML_AMBIENT_N = (1.0, 1.0)
#: MCML's scoring grid (dz, dr [cm]; nz, nr, na bins): coarse, so that its arrays stay in cache. MCML
#: scores every interaction (absorption into A[r][z]) at a cost that does not depend on the grid.
MCML_GRID = (0.1, 0.1, 10, 10, 1)
MCML_OUT = "ep-bench.mco"


def mci_text(layers, photons: int, grid=MCML_GRID, ambient_n=MCML_AMBIENT_N, out=MCML_OUT) -> str:
    """An MCML input (.mci) of one run: ``layers`` as in MCML_PLAN (lengths in cm, coefficients in 1/cm),
    ``photons`` packets, scoring ``grid`` (dz, dr [cm], nz, nr, na), ASCII output file ``out``."""
    dz, dr, nz, nr, na = grid
    lines = ["1.0 # file version", "1 # number of runs", f"{out} A # output file, ASCII", f"{int(photons)} # photons"]
    lines += [f"{dz:g} {dr:g} # dz, dr [cm]", f"{nz:d} {nr:d} {na:d} # nz, nr, na", f"{len(layers)} # layers"]
    lines.append(f"{ambient_n[0]:g} # n above")
    lines += [f"{n:g} {mua:g} {mus:g} {g:g} {d:g} # n mua mus g d" for n, mua, mus, g, d in layers]
    lines.append(f"{ambient_n[1]:g} # n below")
    return "\n".join(lines) + "\n"


def parse_mco(text: str) -> dict:
    """The RAT block of an MCML output (.mco): specular reflectance rsp, diffuse reflectance rd,
    absorbed fraction a and transmittance tt (fractions of the launched weight)."""
    lines = text.splitlines()
    i = next((k for k, line in enumerate(lines) if line.startswith("RAT")), None)
    if i is None or len(lines) < i + 5:
        raise ValueError("MCML output: no RAT block (Rsp, Rd, A, Tt) found")
    return {key: float(lines[i + 1 + k].split()[0]) for k, key in enumerate(("rsp", "rd", "a", "tt"))}


def mcml_version(stdout: str) -> str:
    """The version line MCML prints at start-up ('Version 1.2, 1993'), or '' if none."""
    return next((line.strip() for line in stdout.splitlines() if line.strip().startswith("Version")), "")


def _new_second(last: int) -> int:
    """Wait until the wall-clock second differs from ``last`` and return it: MCML seeds its generator
    with time(NULL), so runs started within one second would repeat the same packets."""
    while int(time.time()) == last:
        time.sleep(0.05)
    return int(time.time())


def run_mcml(binary: str, layers, photons: int, last_second: int = 0) -> dict:
    """One MCML run in a fresh temporary directory. Returns its RAT (rsp, rd, a, tt), the process's
    user_s, sys_s and cpu_s (CPU seconds, from getrusage of the waited child), wall_s, version and
    the second it started in (its seed)."""
    with tempfile.TemporaryDirectory(prefix="ep-mcml-") as tmp:
        with open(os.path.join(tmp, "in.mci"), "w", encoding="ascii") as fh:
            fh.write(mci_text(layers, photons))
        second = _new_second(last_second)
        ru0, t0 = resource.getrusage(resource.RUSAGE_CHILDREN), time.perf_counter()
        cmd = [os.path.abspath(binary), "in.mci"]  # stdin closed: MCML asks for a file name it cannot open
        p = subprocess.run(cmd, cwd=tmp, stdin=subprocess.DEVNULL, capture_output=True, text=True, timeout=3600)
        wall, ru1 = time.perf_counter() - t0, resource.getrusage(resource.RUSAGE_CHILDREN)
        if p.returncode != 0 or not os.path.exists(os.path.join(tmp, MCML_OUT)):
            raise RuntimeError(f"MCML {binary} failed (exit {p.returncode}):\n{p.stdout[-1500:]}\n{p.stderr[-1500:]}")
        with open(os.path.join(tmp, MCML_OUT), encoding="ascii", errors="replace") as fh:
            rat = parse_mco(fh.read())
    user, sys_ = ru1.ru_utime - ru0.ru_utime, ru1.ru_stime - ru0.ru_stime
    return dict(
        rat, user_s=user, sys_s=sys_, cpu_s=user + sys_, wall_s=wall, version=mcml_version(p.stdout), second=second
    )


def _mean_se(xs) -> tuple[float, float]:
    """Mean of ``xs`` and its standard error from their spread (nan for fewer than 2 values)."""
    m = sum(xs) / len(xs)
    if len(xs) < 2:
        return m, float("nan")
    var = sum((x - m) ** 2 for x in xs) / (len(xs) - 1)
    return m, (var / len(xs)) ** 0.5


def mcml_row(key: str, packets: int, mcml_runs: list, engine_runs: list) -> dict:
    """One row of compare_mcml(): best (least) MCML CPU time and best engine packets per CPU-second,
    their ratio (engine / MCML, per core), and both Rd estimates."""
    best = min(mcml_runs, key=lambda r: r["cpu_s"])
    rd, rd_se = _mean_se([r["rd"] for r in mcml_runs])
    eng = max(engine_runs, key=lambda r: r["pp_cpu_s"])
    return dict(
        config=key,
        packets=packets,
        repeats=len(mcml_runs),
        mcml_cpu_s=best["cpu_s"],
        mcml_user_s=best["user_s"],
        mcml_pp_cpu_s=packets / best["cpu_s"],
        mcml_rd_runs=[r["rd"] for r in mcml_runs],
        mcml_rd=rd,
        mcml_rd_se=rd_se,
        mcml_tt=best["tt"],
        engine_pp_cpu_s=eng["pp_cpu_s"],
        engine_pps=max(r["pps"] for r in engine_runs),
        engine_rd=eng["rd"],
        engine_rd_se=eng["rd_se"],
        ratio=eng["pp_cpu_s"] / (packets / best["cpu_s"]),
    )


def compare_mcml(binary: str, after: str, repeats: int = 3, plan=MCML_PLAN, report=print) -> dict:
    """MCML (``binary``) and the engine package in ``after`` on ``plan``, one core each: ``repeats``
    interleaved runs (a fresh process each; the engine on 1 thread with a 2000-packet warm-up, as
    compare()). Returns the binary, its version line, the grid and one mcml_row() per configuration."""
    rows, version, last = [], "", 0
    for key, layers, n in plan:
        mc, en = [], []
        for _ in range(repeats):
            mc.append(run_mcml(binary, layers, n, last))
            last, version = mc[-1]["second"], mc[-1]["version"] or version
            cfg = dict(scene=key, key=key, photons=n, threads=1, py=os.path.abspath(after), warmup=2000)
            en.append(run_all.run_child(cfg))
        rows.append(mcml_row(key, n, mc, en))
        r = rows[-1]
        report(
            f"{key:12s} {n} packets: MCML {r['mcml_pp_cpu_s']:9.0f}/CPU-s (Rd {r['mcml_rd']:.5f} ± {r['mcml_rd_se']:.5f})"
            f"  engine {r['engine_pp_cpu_s']:9.0f}/CPU-s (Rd {r['engine_rd']:.5f} ± {r['engine_rd_se']:.5f})"
            f"  engine/MCML x{r['ratio']:.2f}"
        )
    return dict(binary=os.path.abspath(binary), version=version, grid=list(MCML_GRID), repeats=repeats, rows=rows)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    who = ap.add_mutually_exclusive_group()
    who.add_argument("--before", help="directory holding the 'before' endophoton package")
    who.add_argument("--build-before", metavar="COMMIT", help="build this commit's package and use it")
    ap.add_argument("--after", default=os.path.join(ROOT, "python"), help="default: this checkout's python/")
    ap.add_argument("--mcml-binary", metavar="PATH", help="an MCML executable (built outside the repository)")
    ap.add_argument("--mcml-build", default="", metavar="TEXT", help="how it was built (recorded with its figures)")
    ap.add_argument("--repeats", type=int, default=None, help="best of N (default 2; 3 with --mcml-binary alone)")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    if not (a.before or a.build_before or a.mcml_binary):
        ap.error("give --before DIR, --build-before COMMIT and/or --mcml-binary PATH")
    say = lambda s: print(s, flush=True)  # noqa: E731
    out = {}
    if a.before or a.build_before:
        before = a.before or build_package(a.build_before)
        out["engines"] = compare(before, a.after, a.repeats or 2, report=say)
    if a.mcml_binary:
        out["mcml"] = dict(compare_mcml(a.mcml_binary, a.after, a.repeats or 3, report=say), build=a.mcml_build)
    if a.json:
        run_all.atomic_write_text(os.path.abspath(a.json), json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
