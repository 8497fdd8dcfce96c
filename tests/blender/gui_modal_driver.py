# SPDX-License-Identifier: MIT
"""Drives the modal Run and Sweep β operators in a real (windowed) Blender; run by
test_modal_gui.py under Xvfb:

    xvfb-run -a blender --factory-startup --enable-event-simulate BLEND \
        --python tests/blender/gui_modal_driver.py -- OUT.json GRID_DIR ENGINE_FOLDER

Everything happens in bpy.app.timers callbacks, i.e. in Blender's own event
loop: the operator is invoked with INVOKE_DEFAULT in the 3D viewport, its
progress is sampled from the status bar text, a real ESC key event is
injected with Window.event_simulate, and the tick times measure whether the
UI kept running.  The findings go to OUT.json; the test asserts on them.

No verdict may depend on how fast the engine or the machine is: a run or a β can
end between two ticks (a 20,000-packet β takes ~40 ms).  So the job's worker
thread is held, at the points the test looks at, until the UI has ticked a few
times (``hold_for_ticks``): after a Run's body, and before each β is counted as
finished.  The UI must tick while the worker waits, which is itself the check
that the job does not freeze it; a hold that times out is reported.
"""

import json
import os
import sys
import time

import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(HERE)), "addon"))

OUT, GRID_DIR, ENGINE_FOLDER = sys.argv[sys.argv.index("--") + 1 :][:3]
SWEEP_DIR = os.path.join(os.path.dirname(os.path.abspath(GRID_DIR)), "sweep")
TICK = 0.1
DEADLINE = 300.0  # seconds; the driver quits Blender whatever happens
START = time.monotonic()
HOLD_TIMEOUT = 120.0  # seconds a held worker waits for the UI's ticks
state = {"phase": "warmup", "t": time.monotonic(), "ticks": [], "report": {}, "texts": [], "n_ticks": 0}
held = {"timeouts": 0, "holds": 0}


def hold_for_ticks(count):
    """Worker thread: wait until the UI's timer has ticked ``count`` more times."""
    target = state["n_ticks"] + count
    deadline = time.monotonic() + HOLD_TIMEOUT
    held["holds"] += 1
    while state["n_ticks"] < target:
        if time.monotonic() > deadline:
            held["timeouts"] += 1
            return
        time.sleep(0.01)


def hold_jobs():
    """Wrap the jobs' worker-side steps so each waits for the UI (see the docstring)."""
    from endophoton_addon import simulation, sweep_job

    run_body = simulation.SimulationJob._body
    on_beta = sweep_job.SweepJob._on_beta

    def held_body(self):
        run_body(self)
        hold_for_ticks(5)  # the status text is sampled while the job still runs

    def held_on_beta(self, index, n, row):
        hold_for_ticks(2)  # the status still names this β, at fraction index / n
        on_beta(self, index, n, row)

    simulation.SimulationJob._body = held_body
    sweep_job.SweepJob._on_beta = held_on_beta


def finish(extra=None):
    state["report"].update(extra or {})
    with open(OUT, "w") as f:
        json.dump(state["report"], f, indent=1)
    bpy.ops.wm.quit_blender()


def view3d():
    window = bpy.context.window_manager.windows[0]
    area = max((a for a in window.screen.areas if a.type == "VIEW_3D"), key=lambda a: a.width * a.height)
    region = next(r for r in area.regions if r.type == "WINDOW")
    return window, area, region


def invoke(photons):
    settings = bpy.context.scene.endophoton
    settings.quality, settings.photons, settings.grid_dir = "CUSTOM", photons, GRID_DIR
    settings.allow_large_runs = photons > 5_000_000  # the run ESC cancels is "large" on purpose
    window, area, region = view3d()
    with bpy.context.temp_override(window=window, area=area, region=region):
        return sorted(bpy.ops.endophoton.run_simulation("INVOKE_DEFAULT"))


def invoke_sweep(betas, store):
    sweep = bpy.context.scene.endophoton.sweep
    sweep.betas, sweep.store, sweep.output_dir = betas, store, SWEEP_DIR
    sweep.keep_runs = "OFF"  # this test checks the modal job; per-β collections: test_sweep_operator
    sweep.visibility = False  # the energy sweep's plots; the visibility answer: test_sweep_answer
    window, area, region = view3d()
    with bpy.context.temp_override(window=window, area=area, region=region):
        return sorted(bpy.ops.endophoton.sweep_beta("INVOKE_DEFAULT"))


def status_text():
    from endophoton_addon import operators

    job = operators.running_job()
    return None if job is None else job.progress().text()


def tick():
    try:
        return _tick()
    except Exception:  # never leave a windowed Blender hanging
        import traceback

        finish({"error": traceback.format_exc()})
        return None


def _tick():
    from endophoton_addon import operators

    now = time.monotonic()
    state["n_ticks"] += 1
    if now - START > DEADLINE:
        finish({"error": f"driver deadline ({DEADLINE:.0f} s) passed in phase {state['phase']}"})
        return None
    phase = state["phase"]
    report = state["report"]
    settings = bpy.context.scene.endophoton
    if phase == "warmup":  # let the first redraws (shader compiles) pass
        if now - state["t"] > 6.0:
            report["objects_before"] = sorted(o.name for o in bpy.data.objects)
            report["invoke_1"] = invoke(150_000)
            state.update(phase="run1", t=now, ticks=[])
    elif phase == "run1":
        state["ticks"].append(now)
        text = status_text()
        if text:
            state["texts"].append(text)
        if operators.running_job() is None:
            gaps = [b - a for a, b in zip(state["ticks"], state["ticks"][1:])]
            coll = settings.result_collection
            report.update(
                run1_seconds=now - state["t"],
                run1_ticks=len(state["ticks"]),
                run1_max_gap=max(gaps) if gaps else None,
                run1_gaps=[(round(a - state["t"], 2), round(g, 2)) for a, g in zip(state["ticks"], gaps) if g > 0.5],
                run1_texts=state["texts"][-3:],
                run1_collection=coll.name if coll else None,
                run1_objects=sorted(o.name for o in coll.objects) if coll else [],
                objects_after_run1=sorted(o.name for o in bpy.data.objects),
            )
            report["invoke_2"] = invoke(50_000_000)
            state.update(phase="run2", t=now, ticks=[], texts=[])
    elif phase == "run2":
        state["ticks"].append(now)
        text = status_text()
        if text:
            state["texts"].append(text)
        if now - state["t"] > 3.0 and "esc_sent" not in report:
            window, _area, _region = view3d()
            window.event_simulate(type="ESC", value="PRESS")
            window.event_simulate(type="ESC", value="RELEASE")
            report["esc_sent"] = now - state["t"]
            state["esc_at"], state["job"] = time.monotonic(), operators.running_job()
        if "esc_sent" in report and operators.running_job() is None:
            gaps = [b - a for a, b in zip(state["ticks"], state["ticks"][1:])]
            coll = settings.result_collection
            report.update(
                run2_stopped_after=now - state["t"],
                run2_cancel_seconds=now - state["t"] - report["esc_sent"],  # a figure, never a verdict
                run2_esc_to_cancel=(state["job"].cancelled_at or now) - state["esc_at"],
                run2_esc_to_operator_end=(operators._running["ended_at"] or now) - state["esc_at"],
                run2_cancel_to_worker_end=(state["job"].finished_at or now) - (state["job"].cancelled_at or now),
                run2_max_gap=max(gaps) if gaps else None,
                run2_ticks=len(state["ticks"]),
                run2_gaps=[(round(a - state["t"], 2), round(g, 2)) for a, g in zip(state["ticks"], gaps) if g > 0.5],
                run2_texts=state["texts"][-3:],
                run2_collection=coll.name if coll else None,
                objects_after_run2=sorted(o.name for o in bpy.data.objects),
                grid_files=sorted(os.listdir(GRID_DIR)) if os.path.isdir(GRID_DIR) else [],
                status_cleared=status_text() is None,
            )
            report["invoke_sweep_1"] = invoke_sweep("0,30", 20_000)
            state.update(phase="sweep1", t=now, ticks=[], texts=[], fractions=[])
            return TICK
        if now - state["t"] > 600.0:  # a hang guard, not a speed check
            finish({"error": "run 2 did not stop after ESC"})
            return None
    elif phase == "sweep1":  # Sweep β to the end: progress, then the plots as images
        state["ticks"].append(now)
        job = operators.running_job()
        if job is not None:
            state["texts"].append(job.progress().text())
            state["fractions"].append(job.progress().fraction)
        else:
            gaps = [b - a for a, b in zip(state["ticks"], state["ticks"][1:])]
            report.update(
                sweep1_seconds=now - state["t"],
                sweep1_max_gap=max(gaps) if gaps else None,
                sweep1_ticks=len(state["ticks"]),
                sweep1_texts=state["texts"],
                sweep1_fractions=state["fractions"],
                sweep1_images=sorted(i.name for i in bpy.data.images if i.name.startswith("EndoPhoton Sweep: ")),
                sweep1_image_sizes=[tuple(i.size) for i in bpy.data.images if i.name.startswith("EndoPhoton Sweep: ")],
                sweep1_files=sorted(os.listdir(SWEEP_DIR)) if os.path.isdir(SWEEP_DIR) else [],
                sweep1_summary=bpy.context.scene.get("endophoton_sweep", {}).get("n_betas"),
                images_after_sweep1=sorted(i.name for i in bpy.data.images),
                objects_after_sweep1=sorted(o.name for o in bpy.data.objects),
            )
            report["invoke_sweep_2"] = invoke_sweep("0:60:5", 5_000_000)
            state.update(phase="sweep2", t=now, ticks=[], texts=[])
        if now - state["t"] > 90.0:
            finish({"error": "sweep 1 did not finish in 90 s"})
            return None
    elif phase == "sweep2":  # Sweep β cancelled with ESC: nothing new
        state["ticks"].append(now)
        if operators.running_job() is not None:
            state["texts"].append(status_text())
        if now - state["t"] > 3.0 and "sweep_esc_sent" not in report:
            window, _area, _region = view3d()
            window.event_simulate(type="ESC", value="PRESS")
            window.event_simulate(type="ESC", value="RELEASE")
            report["sweep_esc_sent"] = now - state["t"]
        if "sweep_esc_sent" in report and operators.running_job() is None:
            finish(
                dict(
                    sweep2_stopped_after=now - state["t"],
                    sweep2_cancel_seconds=now - state["t"] - report["sweep_esc_sent"],
                    sweep2_texts=state["texts"][-3:],
                    images_after_sweep2=sorted(i.name for i in bpy.data.images),
                    objects_after_sweep2=sorted(o.name for o in bpy.data.objects),
                    sweep2_files=sorted(os.listdir(SWEEP_DIR)) if os.path.isdir(SWEEP_DIR) else [],
                    sweep_status_cleared=status_text() is None,
                    holds=held["holds"],
                    hold_timeouts=held["timeouts"],
                )
            )
            return None
        if now - state["t"] > 600.0:  # a hang guard, not a speed check
            finish({"error": "sweep 2 did not stop after ESC"})
            return None
    return TICK


import addon_utils  # noqa: E402

addon_utils.enable("endophoton_addon", default_set=True)
bpy.context.preferences.addons["endophoton_addon"].preferences.package_path = ENGINE_FOLDER
hold_jobs()
bpy.app.timers.register(tick, first_interval=1.0)
