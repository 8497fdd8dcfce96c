"""Issue 39: the seed tissue side by side with MCML 1.2, one core each, in interleaved pairs.

MCML's source is not in this repository. Build its transport with the driver beside this script:

    # mcmlgo.c and mcml.h of MCML 1.2 (Wang & Jacques, 1993; e.g. the bipy/MCML copy on GitHub) in $MCML
    gcc -O3 -I"$MCML" -o /tmp/mcml_seed scripts/mcml_driver.c "$MCML"/mcmlgo.c -lm
    /usr/bin/python3 scripts/mcml_side_by_side.py /tmp/mcml_seed [pairs] [photons] [--double]

Each pair runs MCML and `python3 -m endophoton run examples/seed_tissue.json --threads 1 --stats` (its order
alternating from pair to pair). CPU time is user + system time of the whole process (os.wait4), for both; the
engine's process includes Python's start-up and import, so the engine's own figure (`run_cpu_seconds`: the run,
scene build included) is printed beside it. MCML's layer is the region of examples/seed_tissue.json (its medium,
and its box's depth as the thickness; the box is 10 cm wide, MCML's layer unbounded). MCML seeds itself from the
clock, so its runs are independent; the engine's use seeds 1, 2, ... The engine takes its plain interior steps in
float32 lanes (native/lane_block.h), its default; with --double it runs the same scene with `run.lanes` off (the
double walk), from a copy of the file. Prints a line per pair and the medians as
JSON (at least 2 pairs: the MCML Rd's standard error comes from their spread).
"""
from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SCENE = os.path.join(ROOT, "examples", "seed_tissue.json")


def mcml_layer():
    """The driver's layer arguments (mua, mus in cm^-1, g, n, thickness in cm) from the engine's scene file, so
    that both programs trace the one tissue."""
    with open(SCENE, encoding="utf-8") as fh:
        doc = json.load(fh)
    (region,) = doc["regions"]
    if doc["unit"] != "cm" or doc.get("ambient_n", 1.0) != 1.0:
        raise SystemExit(f"{SCENE}: the driver takes a layer in cm between ambient media of n = 1")
    m, box = region["medium"], region["box"]
    return tuple(str(v) for v in (m["mua"], m["mus"], m["g"], m["n"], box["max"][2] - box["min"][2]))


def timed(cmd, env=None):
    """Runs ``cmd``; returns (its stdout, user + system CPU seconds of the process)."""
    with open(os.devnull, "w") as null:
        p = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=null, env=env, cwd=ROOT, text=True)
        out = p.stdout.read()
        _, status, usage = os.wait4(p.pid, 0)
        p.returncode = os.waitstatus_to_exitcode(status)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} exited {p.returncode}")
    return out, usage.ru_utime + usage.ru_stime


def mcml(binary, photons, layer):
    out, cpu = timed([binary, str(photons), *layer])
    return json.loads(out), cpu


def double_scene():
    """A copy of the seed tissue's file with ``run.lanes`` off, in the system's temporary directory."""
    import tempfile

    with open(SCENE, encoding="utf-8") as fh:
        doc = json.load(fh)
    doc["run"]["lanes"] = False
    fd, path = tempfile.mkstemp(prefix="seed_tissue_double_", suffix=".json")
    with os.fdopen(fd, "w", encoding="utf-8") as fh:
        json.dump(doc, fh)
    return path


def engine(photons, seed, scene=SCENE):
    cmd = [sys.executable, "-m", "endophoton", "run", scene, "--photons", str(photons), "--threads", "1",
           "--seed", str(seed), "--stats"]  # fmt: skip
    out, cpu = timed(cmd, dict(os.environ, PYTHONPATH=os.path.join(ROOT, "python")))
    return json.loads(out), cpu


def main(argv):
    if len(argv) < 2:
        raise SystemExit(__doc__)
    double = "--double" in argv
    argv = [a for a in argv if a != "--double"]
    binary = argv[1]
    pairs = int(argv[2]) if len(argv) > 2 else 7
    photons = int(argv[3]) if len(argv) > 3 else 1_000_000
    scene = double_scene() if double else SCENE
    if pairs < 2 or photons < 1:
        raise SystemExit(f"pairs must be >= 2 (got {pairs}) and photons >= 1 (got {photons})")
    layer = mcml_layer()
    rows = []
    for k in range(pairs):
        runs = {}
        for who in ("mcml", "engine") if k % 2 == 0 else ("engine", "mcml"):
            runs[who] = mcml(binary, photons, layer) if who == "mcml" else engine(photons, k + 1, scene)
        (m, m_cpu), (e, e_cpu) = runs["mcml"], runs["engine"]
        e_run = e["stats"]["process"]["run_cpu_seconds"]
        rows.append(dict(mcml_cpu_s=m_cpu, engine_cpu_s=e_cpu, engine_run_cpu_s=e_run, ratio=m_cpu / e_cpu,
                         ratio_run=m_cpu / e_run, mcml_rd=m["Rd"], engine_rd=e["diffuse_reflectance"],
                         engine_rd_se=e["diffuse_reflectance_stderr"], load=os.getloadavg()[0]))  # fmt: skip
        r = rows[-1]
        print(f"pair {k + 1}: MCML {photons / m_cpu:,.0f} packets per CPU-s, engine {photons / e_cpu:,.0f} "
              f"(process) / {photons / e_run:,.0f} (run); MCML/engine CPU {r['ratio']:.2f}x / "
              f"{r['ratio_run']:.2f}x; Rd {r['mcml_rd']:.5f} / {r['engine_rd']:.5f}; load {r['load']:.1f}",
              flush=True)  # fmt: skip
    rd = [r["mcml_rd"] for r in rows]
    mcml_rd, mcml_se = statistics.mean(rd), statistics.stdev(rd) / len(rd) ** 0.5
    eng_rd = statistics.mean(r["engine_rd"] for r in rows)
    eng_se = statistics.mean(r["engine_rd_se"] for r in rows) / len(rows) ** 0.5
    if double:
        os.unlink(scene)
    summary = dict(
        lanes=not double,
        photons=photons,
        pairs=pairs,
        ratio_median=statistics.median(r["ratio"] for r in rows),
        ratio_range=[min(r["ratio"] for r in rows), max(r["ratio"] for r in rows)],
        ratio_run_median=statistics.median(r["ratio_run"] for r in rows),
        mcml_packets_per_cpu_s=photons / statistics.median(r["mcml_cpu_s"] for r in rows),
        engine_packets_per_cpu_s=photons / statistics.median(r["engine_cpu_s"] for r in rows),
        engine_run_packets_per_cpu_s=photons / statistics.median(r["engine_run_cpu_s"] for r in rows),
        mcml_rd=[mcml_rd, mcml_se],
        engine_rd=[eng_rd, eng_se],
        rd_z=(eng_rd - mcml_rd) / (mcml_se**2 + eng_se**2) ** 0.5,
    )
    print(json.dumps(summary))


if __name__ == "__main__":
    main(sys.argv)
