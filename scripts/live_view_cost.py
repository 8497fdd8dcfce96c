"""The live endoscope view's cost (issue 36): the same Run of colon_polyp.blend with Live View on
and off, alternating, through the add-on's Run operator (the blocking execute path, whose wait loop
shows each snapshot as the modal timer does); the final view render after the run is left out of
both. Prints, per run, the wall time, packets/s, the
process's CPU time and the snapshots shown, then the medians and the slowdown. No verdict.

    blender -b --factory-startup blend_scenes/colon_polyp.blend --python scripts/live_view_cost.py -- \
        [PHOTONS [REPEATS [THREADS]]]

``sweep`` first measures a β sweep instead (the Sweep β operator on flat_tissue.blend, PHOTONS = its
Store N per β, β = 0,10,20,30, no β collections kept so no per-β view render, no visibility): the
sweep's wall time (its analysis and output files included, the same in every mode) and its β runs'
own seconds.

    blender -b --factory-startup blend_scenes/flat_tissue.blend --python scripts/live_view_cost.py -- \
        sweep [STORE [REPEATS [THREADS]]]

ENDOPHOTON_PYTHONPATH names the package folder (default: this repository's python/).
"""
import os
import statistics
import sys
import tempfile
import time

import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
PACKAGE = os.environ.get("ENDOPHOTON_PYTHONPATH", os.path.join(REPO, "python"))
sys.path.insert(0, os.path.join(REPO, "addon"))
sys.path.insert(0, PACKAGE)  # before any other endophoton on the path
args = sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else []
SWEEP = bool(args) and args[0] == "sweep"
args = args[1:] if SWEEP else args
SWEEP_BETAS = "0,10,20,30"
PHOTONS = int(args[0]) if len(args) > 0 else 200_000
REPEATS = int(args[1]) if len(args) > 1 else 3
THREADS = int(args[2]) if len(args) > 2 else 2

import addon_utils  # noqa: E402

addon_utils.enable("endophoton_addon", default_set=True)
prefs = bpy.context.preferences.addons["endophoton_addon"].preferences
prefs.package_path = PACKAGE

from endophoton_addon import operators, results, simulation  # noqa: E402

# The run alone: the final endoscope-view render after it (the same with the live view on or off) is
# left out of both, so that its seconds do not dilute the difference.
simulation.endoscope_view = lambda *_args: (None, None)

s = bpy.context.scene.endophoton
s.quality, s.photons, s.threads, s.seed = "CUSTOM", PHOTONS, THREADS, 1
s.output_grids, s.output_points, s.output_views = False, False, True
s.grid_dir = tempfile.mkdtemp(prefix="ep-live-bench-")
sw = s.sweep
sw.betas, sw.store, sw.seed, sw.threads, sw.keep_runs, sw.visibility = SWEEP_BETAS, PHOTONS, 1, THREADS, "OFF", False
sw.output_dir = tempfile.mkdtemp(prefix="ep-live-bench-sweep-")


from endophoton_addon import live_view  # noqa: E402

EVERY_S = live_view.EVERY_S
# "path": Live View on without clock snapshots (ep.run_live's unit path and the first-chunk snapshot);
# "on": with them, every EVERY_S (as the share rule allows)
MODES = {"off": (False, EVERY_S), "path": (True, 1e9), "on": (True, EVERY_S)}


def one(mode):
    s.live_view, live_view.EVERY_S = MODES[mode]
    cpu0, t0 = time.process_time(), time.perf_counter()
    assert (bpy.ops.endophoton.sweep_beta() if SWEEP else bpy.ops.endophoton.run_simulation()) == {"FINISHED"}
    wall, cpu = time.perf_counter() - t0, time.process_time() - cpu0
    job = operators._running["job"]
    shown = len(job.live.shown) if getattr(job, "live", None) is not None else 0
    if SWEEP:  # packets over every β; the engine's rate over the β runs' own seconds
        packets = sum(row["packets_traced"] for row in job.result.rows)
        engine_s = sum(row["seconds"] for row in job.result.rows)
    else:
        packets, engine_s = PHOTONS, s.result_collection[results.SUMMARY_KEY]["seconds"]
        results.remove_results(bpy.context.scene)
    return dict(wall=wall, cpu=cpu, rate=packets / wall, engine_rate=packets / engine_s, shown=shown)


one("off")  # warm-up: the engine scene's build and caches
rows = {mode: [] for mode in MODES}
for i in range(REPEATS):
    for mode in list(MODES) if i % 2 == 0 else list(MODES)[::-1]:
        r = one(mode)
        rows[mode].append(r)
        print(
            f"{mode:4s} wall {r['wall']:6.2f} s  {r['rate']:8.0f} packets/s (engine "
            f"{r['engine_rate']:8.0f})  CPU {r['cpu']:6.2f} s  snapshots shown {r['shown']}",
            flush=True,
        )
med = {m: {k: statistics.median(r[k] for r in rows[m]) for k in rows[m][0]} for m in rows}
off = med["off"]
what = f"sweep β {SWEEP_BETAS}, store {PHOTONS:,} per β" if SWEEP else f"{PHOTONS:,} packets"
print(f"{bpy.path.basename(bpy.data.filepath)}, {what}, {THREADS} threads, {REPEATS} repeats (medians):", flush=True)
for mode in MODES:
    m = med[mode]
    print(
        f"  {mode:4s} {m['rate']:8.0f} packets/s (slowdown {100 * (1 - m['rate'] / off['rate']):+5.1f} %; "
        f"engine {m['engine_rate']:8.0f}, {100 * (1 - m['engine_rate'] / off['engine_rate']):+5.1f} %), "
        f"CPU {m['cpu']:6.2f} s ({100 * (m['cpu'] / off['cpu'] - 1):+5.1f} %), wall {m['wall']:6.2f} s, "
        f"snapshots shown {m['shown']:g}",
        flush=True,
    )
