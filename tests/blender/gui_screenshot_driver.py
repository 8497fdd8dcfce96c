# SPDX-License-Identifier: MIT
"""Screenshots of each EndoPhoton panel in a real (windowed) Blender; run by
test_screenshots.py under Xvfb:

    xvfb-run -a blender --factory-startup BLEND --python tests/blender/gui_screenshot_driver.py \
        -- OUT_DIR GRID_DIR ENGINE_FOLDER

After a small run (so Results has a legend), the sidebar is opened on the
EndoPhoton tab and, for each sub-panel, only the main panel and that one are
registered; the 3D view is captured with screen.screenshot_area and cropped to
the sidebar.  Everything runs in bpy.app.timers callbacks (Blender's own event
loop) so the UI has drawn before each capture.  OUT_DIR/screenshots.json lists
the files."""

import json
import os
import sys

import bpy

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(HERE)), "addon"))
OUT_DIR, GRID_DIR, ENGINE_FOLDER = sys.argv[sys.argv.index("--") + 1 :][:3]
if ENGINE_FOLDER:
    sys.path.insert(0, ENGINE_FOLDER)  # before any other endophoton installed on this machine
PANELS = (
    "ENDOPHOTON_PT_object",
    "ENDOPHOTON_PT_endoscope",
    "ENDOPHOTON_PT_simulation",
    "ENDOPHOTON_PT_results",
    "ENDOPHOTON_PT_sweep",
)
state = {"step": 0, "shots": [], "ticks": 0, "shot_classes": []}


def view3d():
    window = bpy.context.window_manager.windows[0]
    area = max((a for a in window.screen.areas if a.type == "VIEW_3D"), key=lambda a: a.width * a.height)
    return window, area


def drop_shot_classes():
    """Unregister the open copies of closed-by-default panels that only_panel made."""
    while state["shot_classes"]:
        cls = state["shot_classes"].pop()
        if cls.is_registered:
            bpy.utils.unregister_class(cls)


def only_panel(name):
    from endophoton_addon import panels

    drop_shot_classes()

    for cls in panels.CLASSES:
        if cls.__name__.startswith("ENDOPHOTON_PT_") and cls.__name__ != "ENDOPHOTON_PT_main" and cls.is_registered:
            bpy.utils.unregister_class(cls)
    cls = next(c for c in panels.CLASSES if c.__name__ == name)
    if "DEFAULT_CLOSED" in getattr(cls, "bl_options", set()):
        # The region remembers a panel's closed state by its id, so clearing bl_options
        # on the same class is not enough: draw it open under an id the region never saw.
        cls = type(name + "_shot", (cls,), {"bl_idname": name + "_shot", "bl_options": set()})
    bpy.utils.register_class(cls)
    state["shot_classes"].append(cls)


def hide_other_sidebar_tabs():
    """Unregister the 3D view's other Python sidebar panels (this Blender process
    only): "Item" (native) and "EndoPhoton" are the only tabs left, so the
    EndoPhoton tab sits at a known place.  Blender's own modules complain when
    they unregister these at quit; that noise is expected."""

    def subclasses(cls):
        for sub in cls.__subclasses__():
            yield sub
            yield from subclasses(sub)

    for cls in list(subclasses(bpy.types.Panel)):
        if (
            getattr(cls, "bl_space_type", "") == "VIEW_3D"
            and getattr(cls, "bl_region_type", "") == "UI"
            and getattr(cls, "bl_category", "") != "EndoPhoton"
            and cls.is_registered
        ):
            bpy.utils.unregister_class(cls)


def restore_panels():
    from endophoton_addon import panels

    drop_shot_classes()

    for cls in panels.CLASSES:
        if cls.__name__.startswith("ENDOPHOTON_PT_") and cls.__name__ != "ENDOPHOTON_PT_main" and cls.is_registered:
            bpy.utils.unregister_class(cls)
    for cls in panels.CLASSES:
        if not cls.is_registered:
            bpy.utils.register_class(cls)


def capture(name, file_name=None):
    import numpy as np

    window, area = view3d()
    path = os.path.join(OUT_DIR, file_name or f"panel_{name}.png")
    with bpy.context.temp_override(window=window, area=area):
        bpy.ops.screen.screenshot_area(filepath=path)
    ui = next(r for r in area.regions if r.type == "UI")
    image = bpy.data.images.load(path)
    w, h = image.size
    px = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(px)
    bpy.data.images.remove(image)
    px = px.reshape(h, w, 4)
    x0 = max(0, ui.x - area.x)
    crop = px[:, x0 : x0 + ui.width]
    out = bpy.data.images.new(f"crop {name}", crop.shape[1], crop.shape[0], alpha=True)
    out.pixels.foreach_set(np.ascontiguousarray(crop).ravel())
    out.filepath_raw = path
    out.file_format = "PNG"
    out.save()
    note_shot(name, path, crop)


def note_shot(name, path, pixels=None):
    """List ``path`` in screenshots.json with its size and spread (read back from the file if not given)."""
    import numpy as np

    if pixels is None:
        image = bpy.data.images.load(path)
        w, h = image.size
        pixels = np.empty(w * h * 4, np.float32)
        image.pixels.foreach_get(pixels)
        bpy.data.images.remove(image)
        pixels = pixels.reshape(h, w, 4)
    state["shots"].append(
        {
            "panel": name,
            "file": path,
            "size": [int(pixels.shape[1]), int(pixels.shape[0])],
            "std": float(pixels[..., :3].std()),
        }
    )


# ---- Issue 36's acceptance pictures, after the panels: the Sweep β panel with its answer, Render with
# Legend from the endoscope camera, and the live view mid-run (an Image Editor and the status bar).
SWEEP = dict(betas="0,10,20,30,40", store=1_500, seed=3, threads=1, keep_runs="OFF", view_size=32)
LIVE_PHOTONS = 5_000_000  # cancelled once captured: long enough to be mid-run whatever the machine's speed
LIVE_HOLD_SHOWN = (2, 50_000)  # the merge waits once the live image has been refreshed twice, the last >= 50k packets
live = {"release": None, "job": None, "held_at": None}


def sweep_answer():
    """A small visibility sweep (target Polyp, background Colon), then the Sweep β panel alone."""
    sweep = bpy.context.scene.endophoton.sweep
    for name, value in SWEEP.items():
        setattr(sweep, name, value)
    sweep.output_dir = os.path.join(GRID_DIR, "sweep")
    sweep.visibility, sweep.target_region, sweep.background_region = True, "Polyp", "Colon"
    bpy.ops.endophoton.sweep_beta()
    only_panel("ENDOPHOTON_PT_sweep")
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            area.tag_redraw()


def render_legend():
    restore_panels()
    path = os.path.join(OUT_DIR, "render_with_legend.png")
    bpy.ops.endophoton.render_legend(filepath=path)
    note_shot("render_with_legend", path)


def start_live_run():
    """The 3D view becomes an Image Editor showing the first run's white view image; a modal run starts
    whose merge waits at LIVE_HOLD_AT of its packets until the capture (live["release"])."""
    import threading

    from endophoton_addon import endoscope_views, live_view, simulation

    live["release"] = threading.Event()
    original = simulation.SimulationJob._on_progress

    def held(self, done, total):
        original(self, done, total)
        shown = self.live.shown if self.live is not None else []
        if live["held_at"] is None and len(shown) >= LIVE_HOLD_SHOWN[0] and shown[-1] >= LIVE_HOLD_SHOWN[1]:
            live["held_at"] = done
            live["release"].wait(120.0)

    simulation.SimulationJob._on_progress = held
    live_view.EVERY_S = 1.0
    window, area = view3d()
    first = endoscope_views.view_images(bpy.context.scene.endophoton.result_collection)["white"]
    area.type = "IMAGE_EDITOR"
    area.spaces.active.image = first
    s = bpy.context.scene.endophoton
    s.photons, s.live_view, s.threads = LIVE_PHOTONS, True, 1
    region = next(r for r in area.regions if r.type == "WINDOW")
    with bpy.context.temp_override(window=window, area=area, region=region):
        bpy.ops.endophoton.run_simulation("INVOKE_DEFAULT")
    from endophoton_addon import operators

    live["job"] = operators.running_job()


def live_shown_enough():
    """The run's merge waits (the live image shows its last refresh), or the run is over."""
    job = live["job"]
    return job is None or job.done or job.live is None or live["held_at"] is not None


def fit_live_image():
    """The Image Editor zooms the live image to its size (it shows it at 1:1, small, by default)."""
    window = bpy.context.window_manager.windows[0]
    area = max(window.screen.areas, key=lambda a: a.width * a.height)
    if area.type == "IMAGE_EDITOR":
        region = next(r for r in area.regions if r.type == "WINDOW")
        with bpy.context.temp_override(window=window, area=area, region=region):
            bpy.ops.image.view_all(fit_view=True)


def capture_live():
    window = bpy.context.window_manager.windows[0]
    area = max(window.screen.areas, key=lambda a: a.width * a.height)
    path = os.path.join(OUT_DIR, "live_view_mid_run.png")
    with bpy.context.temp_override(window=window, area=area):
        bpy.ops.screen.screenshot(filepath=path)
    job = live["job"]
    note_shot("live_view_mid_run", path)
    state["shots"][-1]["live_packets"] = list(job.live.shown) if job is not None and job.live else []
    state["shots"][-1]["run_packets"] = LIVE_PHOTONS
    state["shots"][-1]["merged_packets"] = live["held_at"]
    state["shots"][-1]["image"] = area.spaces.active.image.name if area.type == "IMAGE_EDITOR" else ""
    if job is not None:
        job.cancel()  # captured: the rest of the run is not needed (nothing is added)
    live["release"].set()


def extra_step(index):
    """The acceptance pictures after the panels: returns seconds to the next tick, or None when done."""
    from endophoton_addon import operators

    if index == 0:
        sweep_answer()
    elif index == 1:
        capture("ENDOPHOTON_PT_sweep_answer", "sweep_answer.png")
    elif index == 2:
        render_legend()
    elif index == 3:
        start_live_run()
    elif index == 4:
        if not live_shown_enough():
            return 0.5  # this step again
        fit_live_image()
    elif index == 5:
        capture_live()
    elif operators.running_job() is not None:
        return 0.5  # the live run finishes (its results are added) before Blender quits
    else:
        return None
    state["extra"] += 1
    return 1.0


def tick():
    try:
        return _tick()
    except Exception:  # never leave a windowed Blender hanging: the listing says what failed
        import traceback

        state["shots"].append({"panel": "error", "error": traceback.format_exc()})
        with open(os.path.join(OUT_DIR, "screenshots.json"), "w") as f:
            json.dump(state["shots"], f, indent=1)
        bpy.ops.wm.quit_blender()
        return None


def _tick():
    state["ticks"] += 1
    step = state["step"]
    if step == 0:
        s = bpy.context.scene.endophoton
        s.quality, s.photons, s.grid_dir, s.output_grids = "CUSTOM", 5_000, GRID_DIR, False
        bpy.ops.endophoton.run_simulation()
        s.color_by, s.filter_fluorescent = "WAVELENGTH", True
        bpy.ops.endophoton.check_scene()
        polyp = bpy.data.objects["Polyp"]
        bpy.context.view_layer.objects.active = polyp
        window, area = view3d()
        space = area.spaces.active
        space.show_region_ui = True
        hide_other_sidebar_tabs()
        state["step"] = -1
        return 1.0
    if step in (-1, -2):
        # Blender 3.4 has no API for the sidebar's tab: click the EndoPhoton tab
        # (below "Item", the one native tab left) on the region's right edge;
        # move first, click on the next tick.
        window, area = view3d()
        ui = next(r for r in area.regions if r.type == "UI")
        x, y = area.x + area.width - 9, area.y + area.height - 140
        if step == -1:
            window.event_simulate(type="MOUSEMOVE", value="NOTHING", x=x, y=y)
            state["step"] = -2
            return 0.5
        window.event_simulate(type="LEFTMOUSE", value="PRESS", x=x, y=y)
        window.event_simulate(type="LEFTMOUSE", value="RELEASE", x=x, y=y)
        state["step"] = 1
        return 1.0
    index = (step - 1) // 2
    if index >= len(PANELS) and extra_step_due():
        return extra_tick()
    if index >= len(PANELS):
        with open(os.path.join(OUT_DIR, "screenshots.json"), "w") as f:
            json.dump(state["shots"], f, indent=1)
        restore_panels()  # the add-on unregisters cleanly on quit
        bpy.ops.wm.quit_blender()
        return None
    if (step - 1) % 2 == 0:
        only_panel(PANELS[index])
        for window in bpy.context.window_manager.windows:
            for area in window.screen.areas:
                area.tag_redraw()
    else:
        capture(PANELS[index])
    state["step"] += 1
    return 0.7


def extra_step_due():
    return state.setdefault("extra", 0) >= 0


def extra_tick():
    try:
        wait = extra_step(state["extra"])
    except Exception:  # never leave a windowed Blender hanging: the listing says what failed
        import traceback

        state["shots"].append({"panel": "error", "error": traceback.format_exc()})
        if live["release"] is not None:
            live["release"].set()
        wait = None
    if wait is None:
        state["extra"] = -1  # done: the next tick writes screenshots.json and quits
        return 0.1
    return wait


import addon_utils  # noqa: E402

addon_utils.enable("endophoton_addon", default_set=True)
bpy.context.preferences.addons["endophoton_addon"].preferences.package_path = ENGINE_FOLDER
os.makedirs(OUT_DIR, exist_ok=True)
bpy.app.timers.register(tick, first_interval=1.0)
