# SPDX-License-Identifier: MIT
"""Operators: thin wrappers over rig.py, simulation.py, sweep_job.py and results.py.

Errors are reported with ``self.report({'ERROR'}, message)``; messages name
the object (or scene) and the field.  Validation runs before any datablock is
created, so a rejected run leaves the scene untouched.
"""

import os
import time

import bpy

from . import (
    blend_paths,
    export,
    guards,
    legend_render,
    live_view,
    package_finder,
    properties,
    result_export,
    results,
    rig,
    simulation,
    sweep_job,
)
from .package_finder import EngineMissing
from .errors import InputError

# The job being run (one at a time); "modal" is True from invoke until the
# modal operator has finished (results added) or been cancelled.
_running = {"job": None, "modal": False, "ended_at": None}
HEADER_EVERY_S = 1.0  # the viewport header's progress text: at most this often (it redraws the whole area)


def running_job():
    """The job in progress, until its results are in the scene; else None."""
    job = _running["job"]
    if job is None or (job.done and not _running["modal"]):
        return None
    return job


def _redraw_sidebars(_context=None):
    """Redraw the 3D views' sidebars (progress box, Run button) in every window:
    a finished job must re-enable the buttons without waiting for the mouse."""
    wm = bpy.context.window_manager
    for window in wm.windows if wm is not None else ():
        for area in window.screen.areas:
            if area.type == "VIEW_3D":
                for region in area.regions:
                    if region.type == "UI":
                        region.tag_redraw()


def _redraw_soon():
    """Redraw once more from a timer, after the modal handler is gone (the poll
    of Run / Sweep β reads the finished state only then)."""
    bpy.app.timers.register(lambda: _redraw_sidebars() or None, first_interval=0.05)


class ENDOPHOTON_OT_add_endoscope(bpy.types.Operator):
    """Add an endoscope rig (head empty, two spot lights, camera) aimed at the 3D cursor"""

    bl_idname = "endophoton.add_endoscope"
    bl_label = "Add Endoscope"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        rig_obj = rig.create_rig(context, target=tuple(context.scene.cursor.location))
        for obj in context.view_layer.objects:
            obj.select_set(False)
        rig_obj.select_set(True)
        context.view_layer.objects.active = rig_obj
        return {"FINISHED"}


class ENDOPHOTON_OT_fluorophore_add(bpy.types.Operator):
    """Add a fluorophore to the active object"""

    bl_idname = "endophoton.fluorophore_add"
    bl_label = "Add Fluorophore"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return context.object is not None and context.object.type == "MESH"

    def execute(self, context):
        settings = context.object.endophoton
        settings.fluorophores.add()
        settings.active_fluorophore = len(settings.fluorophores) - 1
        return {"FINISHED"}


class ENDOPHOTON_OT_fluorophore_remove(bpy.types.Operator):
    """Remove the selected fluorophore from the active object"""

    bl_idname = "endophoton.fluorophore_remove"
    bl_label = "Remove Fluorophore"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return (
            context.object is not None
            and context.object.type == "MESH"
            and len(context.object.endophoton.fluorophores) > 0
        )

    def execute(self, context):
        settings = context.object.endophoton
        index = settings.active_fluorophore
        if not 0 <= index < len(settings.fluorophores):
            self.report(
                {"ERROR"},
                f"Object '{context.object.name}': active_fluorophore = {index} " "is not a fluorophore of this object",
            )
            return {"CANCELLED"}
        settings.fluorophores.remove(index)
        settings.active_fluorophore = max(0, index - 1)
        return {"FINISHED"}


class ENDOPHOTON_OT_role_defaults(bpy.types.Operator):
    """Reload the role's default medium, priority and fluorophores"""

    bl_idname = "endophoton.role_defaults"
    bl_label = "Role Defaults"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return context.object is not None and context.object.endophoton.role != "NONE"

    def execute(self, context):
        properties.apply_role_defaults(context.object.endophoton)
        return {"FINISHED"}


class ENDOPHOTON_OT_retry_engine_import(bpy.types.Operator):
    """Look for the EndoPhoton package again"""

    bl_idname = "endophoton.retry_engine_import"
    bl_label = "Find Engine Again"

    def execute(self, context):
        package_finder.forget()
        module, message = package_finder.status()
        if module is None:
            self.report({"ERROR"}, message)
            return {"CANCELLED"}
        self.report({"INFO"}, f"EndoPhoton engine: {module.__file__}")
        return {"FINISHED"}


class ENDOPHOTON_OT_cancel_run(bpy.types.Operator):
    """Cancel the running EndoPhoton simulation or sweep (same as Esc)"""

    bl_idname = "endophoton.cancel_run"
    bl_label = "Cancel Run"

    @classmethod
    def poll(cls, context):
        return running_job() is not None

    def execute(self, context):
        job = running_job()
        if job is not None:
            job.cancel()
        return {"FINISHED"}


class ENDOPHOTON_OT_clear_results(bpy.types.Operator):
    """Delete this scene's EndoPhoton result collections and their data"""

    bl_idname = "endophoton.clear_results"
    bl_label = "Clear Results"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        results.remove_results(context.scene)
        return {"FINISHED"}


def _result_by_name(context, name):
    """The scene's result collection called ``name`` ('' = the active one), or None."""
    if not name:
        return context.scene.endophoton.result_collection
    return next((c for c in results.result_collections(context.scene) if c.name == name), None)


class _NamedResult:
    """Operators on one kept run, chosen by ``name`` ('' = the active result)."""

    name: bpy.props.StringProperty(name="Result", default="")

    def _collection(self, context):
        collection = _result_by_name(context, self.name)
        if collection is None:
            self.report({"ERROR"}, f"Scene '{context.scene.name}': no EndoPhoton result named '{self.name}'")
        return collection


class ENDOPHOTON_OT_result_activate(_NamedResult, bpy.types.Operator):
    """Make this run the active result (panel summary, legend, filters, export)"""

    bl_idname = "endophoton.result_activate"
    bl_label = "Show Result"

    def execute(self, context):
        collection = self._collection(context)
        if collection is None:
            return {"CANCELLED"}
        context.scene.endophoton.result_collection = collection
        message = results.update_display(context.scene)
        if message is not None:
            self.report({"ERROR"}, message)
            return {"CANCELLED"}
        return {"FINISHED"}


class ENDOPHOTON_OT_result_delete(_NamedResult, bpy.types.Operator):
    """Delete this run: its collection, its data and its .vdb file"""

    bl_idname = "endophoton.result_delete"
    bl_label = "Delete Result"
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        collection = self._collection(context)
        if collection is None:
            return {"CANCELLED"}
        name = collection.name
        results.remove_run(collection)
        remaining = results.result_collections(context.scene)
        settings = context.scene.endophoton
        if settings.result_collection is None and remaining:
            settings.result_collection = remaining[-1]
        self.report({"INFO"}, f"EndoPhoton: deleted result '{name}'")
        return {"FINISHED"}


class ENDOPHOTON_OT_export_result(_NamedResult, bpy.types.Operator):
    """Export the active run's photon map and summary (CSV, NPZ or JSON)"""

    bl_idname = "endophoton.export_result"
    bl_label = "Export Result"

    filepath: bpy.props.StringProperty(name="File", subtype="FILE_PATH", default="")
    format: bpy.props.EnumProperty(
        name="Format",
        items=(
            ("CSV", "CSV", "One row per record (+ <file>.json with the summary)"),
            ("NPZ", "NPZ", "numpy arrays per record column + the summary as JSON"),
            ("JSON", "JSON", "Summary, parameters and names only"),
        ),
        default="CSV",
    )

    @classmethod
    def poll(cls, context):
        return context.scene.endophoton.result_collection is not None

    def invoke(self, context, _event):
        if not self.filepath:
            collection = _result_by_name(context, self.name)
            self.filepath = bpy.path.clean_name(collection.name if collection else "result") + "." + self.format.lower()
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        collection = self._collection(context)
        if collection is None:
            return {"CANCELLED"}
        if not self.filepath:
            self.report({"ERROR"}, f"Export of '{collection.name}': filepath is empty")
            return {"CANCELLED"}
        try:
            package_finder.require()  # the package writes the files (endophoton.io)
            paths = result_export.export_result(collection, bpy.path.abspath(self.filepath), self.format)
        except (OSError, ValueError, EngineMissing) as exc:
            self.report({"ERROR"}, f"Export of '{collection.name}' to '{self.filepath}' failed: {exc}")
            return {"CANCELLED"}
        self.report({"INFO"}, f"EndoPhoton: exported '{collection.name}' -> {', '.join(paths)}")
        return {"FINISHED"}


class ENDOPHOTON_OT_check_scene(bpy.types.Operator):
    """Show each region's size and wall thickness in mm and the run's estimate; run the guards"""

    bl_idname = "endophoton.check_scene"
    bl_label = "Check Scene"

    def execute(self, context):
        settings = context.scene.endophoton
        lines = []
        try:
            regions = export.export_regions(context.scene, context.view_layer, context.evaluated_depsgraph_get())
            lines += guards.size_lines(regions)
            inputs = simulation.collect_inputs(context)
            lines.append("Run: " + guards.estimate_text(guards.estimate(inputs, simulation.last_rate(context.scene))))
        except InputError as exc:
            lines.append(f"Problem: {exc}")
            self.report({"WARNING"}, str(exc))
        else:
            self.report({"INFO"}, "; ".join(lines))
        settings.scene_report = "\n".join(lines)
        return {"FINISHED"}


class ENDOPHOTON_OT_render_legend(bpy.types.Operator):
    """Render the active result from its rig's endoscope camera (Cycles, denoising off) and save the
    picture with the colour bar of its points beside it"""

    bl_idname = "endophoton.render_legend"
    bl_label = "Render with Legend"

    filepath: bpy.props.StringProperty(
        name="File",
        subtype="FILE_PATH",
        default="",
        description="PNG to write; empty = '<result name>_legend.png' in the grid folder",
    )

    @classmethod
    def poll(cls, context):
        return context.scene.endophoton.result_collection is not None

    def execute(self, context):
        collection = context.scene.endophoton.result_collection
        try:
            if self.filepath:
                path = os.path.abspath(bpy.path.abspath(self.filepath))
                folder = os.path.dirname(path)  # checked before the render, not after it
                guards.resolve_folder(folder, "render_legend.filepath", "", value=self.filepath)
            else:
                path = os.path.join(
                    simulation.grid_folder(context.scene.endophoton),
                    bpy.path.clean_name(collection.name) + "_legend.png",
                )
            image, note = legend_render.render_with_legend(context.scene, collection, path)
        except (RuntimeError, InputError) as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, f"EndoPhoton: {note} -> '{image.filepath}' (image '{image.name}')")
        return {"FINISHED"}


PROGRESS_EVERY_S = 2.0  # background runs print a progress line this often


def _wait_printing_progress(job):
    """Wait for the job; in background mode print its progress line to stdout."""
    import time

    last = time.monotonic()
    while not job.wait(0.2):
        live_view.refresh(job)
        if bpy.app.background and time.monotonic() - last >= PROGRESS_EVERY_S:
            last = time.monotonic()
            print(job.progress().text().replace(" · Esc to cancel", " · Ctrl-C to cancel"), flush=True)


class _ctrl_c_cancels:
    """While a blocking run waits in the main thread, one Ctrl-C (SIGINT) cancels
    it cleanly: the worker stops, the partial result is discarded and the
    previous result is kept.  Blender's own handler (first Ctrl-C ignored, the
    second kills Blender) is put back afterwards when Python knows it, else
    the default (Ctrl-C ends the process)."""

    def __init__(self, job):
        self.job = job
        self.previous = None

    def _handler(self, _signum, _frame):
        print("EndoPhoton: Ctrl-C -> cancelling the run (the previous result is kept)", flush=True)
        self.job.cancel()

    def __enter__(self):
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            self.previous = signal.signal(signal.SIGINT, self._handler)
            self.installed = True
        else:
            self.installed = False
        return self

    def __exit__(self, *_exc):
        import signal

        if self.installed:
            signal.signal(signal.SIGINT, self.previous if self.previous is not None else signal.SIG_DFL)
        return False


class _JobOperator:
    """The one job operator behind Run and Sweep β.

    ``job_module`` (simulation or sweep_job) gives ``prepare_job(context,
    interactive)`` (raises InputError / EngineMissing) and ``report_finished(context,
    job)`` -> ``(level, message)``, level "INFO" when something was added.  A
    job has ``start()``, ``cancel()``, ``wait(timeout)``, ``done`` and
    ``progress()`` (with ``fraction`` and ``text()``); its worker thread never
    calls bpy.
    """

    job_module = None
    _timer = None
    _job = None
    _area = None
    _workspace = None

    @classmethod
    def poll(cls, context):
        return running_job() is None

    # Scripts and background mode: the same job, waited for in this thread.
    def execute(self, context):
        job = self._prepare(context)
        if job is None:
            return {"CANCELLED"}
        _running["job"] = job
        with _ctrl_c_cancels(job):
            job.start()
            _wait_printing_progress(job)
        return self._finish(context, job)

    # Interactive: worker thread + timer; the UI keeps running.
    def invoke(self, context, _event):
        job = self._prepare(context, interactive=not bpy.app.background)
        if job is None:
            return {"CANCELLED"}
        self._job = job
        self._area = context.area
        self._workspace = context.workspace
        _running.update(job=job, modal=True)
        job.start()
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.2, window=context.window)
        wm.progress_begin(0, 1000)
        wm.modal_handler_add(self)
        self._status(context, job.progress().text())
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        job = self._job
        esc = event.type == "ESC" and event.value == "PRESS"
        if esc or (event.type == "TIMER" and job.cancelled_at is not None and not job.done):  # Esc or Cancel
            # The operator ends now; the engine stops before its next packet and the worker skips
            # the rest of its work (grids, view), in the background: _drain discards what it leaves.
            job.cancel()
            self._cleanup(context)
            live_view.end(context, job)
            _drain(job, self.job_module)
            self.report({"WARNING"}, "EndoPhoton: cancelled; nothing was added (the previous result stays)")
            _redraw_sidebars(context)
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if not job.done:
            progress = job.progress()
            live_view.refresh(job)
            context.window_manager.progress_update(int(1000 * progress.fraction))
            self._status(context, progress.text())
            _redraw_sidebars(context)
            return {"PASS_THROUGH"}
        try:
            return self._finish(context, job)
        finally:
            self._cleanup(context)
            _redraw_sidebars(context)
            _redraw_soon()

    def cancel(self, context):
        # Blender cancels modal operators when the file is closed.
        if self._job is not None:
            self._job.cancel()
            self._job.wait(10.0)
        self._cleanup(context)

    def _prepare(self, context, interactive=False):
        try:
            return self.job_module.prepare_job(context, interactive=interactive)
        except (InputError, EngineMissing) as exc:
            self.report({"ERROR"}, str(exc))
            return None

    def _finish(self, context, job):
        try:
            level, message = self.job_module.report_finished(context, job)
        except Exception as exc:  # engine failure or result import error
            live_view.end(context, job)
            if job.error_traceback:
                print(job.error_traceback)
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        live_view.end(context, job)  # the live images give way to the run's own
        self.report({level}, message)
        return {"FINISHED"} if level == "INFO" else {"CANCELLED"}

    def _status(self, _context, text):
        if self._workspace is not None:
            self._workspace.status_text_set(text)
        # The viewport header's text redraws the whole 3D view (its point clouds and volumes):
        # at most once a HEADER_EVERY_S, and always when it is cleared.
        now = time.monotonic()
        if self._area is not None and (text is None or now - getattr(self, "_header_at", 0.0) >= HEADER_EVERY_S):
            self._area.header_text_set(text)
            self._header_at = now

    def _cleanup(self, context):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        self._status(context, None)
        self._area = self._workspace = None
        _running.update(modal=False, ended_at=time.monotonic())


def _drain(job, job_module, every_s=0.2):
    """After Esc: wait for the cancelled job's worker in a timer (the UI runs on; well under a second,
    docs/addon.md "Running") and discard what it leaves (``job_module.discard_job``: a run's partial
    grid file); Run and Sweep β stay disabled (running_job) until it has ended."""

    def poll():
        if not job.done:
            return every_s
        try:
            job_module.discard_job(job)
        except OSError as exc:  # a partial file we could not remove: say so, never raise in a timer
            print(f"EndoPhoton: after cancel: {exc}")
        if _running["job"] is job and not _running["modal"]:
            _running["job"] = None
        _redraw_sidebars()
        return None

    bpy.app.timers.register(poll, first_interval=every_s)


class ENDOPHOTON_OT_run(_JobOperator, bpy.types.Operator):
    """Run the EndoPhoton simulation for this scene (Esc cancels)"""

    bl_idname = "endophoton.run_simulation"
    bl_label = "Run Simulation"
    bl_options = {"REGISTER", "UNDO"}
    job_module = simulation


class ENDOPHOTON_OT_sweep(_JobOperator, bpy.types.Operator):
    """Sweep the endoscope tilt β about the rig's target (store N records per β), write
    CSV, JSON, plots and report, and load the plots as images (Esc cancels)"""

    bl_idname = "endophoton.sweep_beta"
    bl_label = "Sweep β"
    bl_options = {"REGISTER", "UNDO"}
    job_module = sweep_job


@bpy.app.handlers.persistent
def _forget_engine_scenes(_file_path=None):
    """load_post: the new file's scenes must not keep the old file's engine scene alive."""
    simulation.forget_engine_scenes()


# (bpy.app.handlers list name, function): added and removed by the registration loop.
HANDLERS = (("load_post", _forget_engine_scenes), ("save_post", blend_paths.relative_on_save))

CLASSES = (
    ENDOPHOTON_OT_add_endoscope,
    ENDOPHOTON_OT_fluorophore_add,
    ENDOPHOTON_OT_fluorophore_remove,
    ENDOPHOTON_OT_role_defaults,
    ENDOPHOTON_OT_retry_engine_import,
    ENDOPHOTON_OT_cancel_run,
    ENDOPHOTON_OT_clear_results,
    ENDOPHOTON_OT_render_legend,
    ENDOPHOTON_OT_check_scene,
    ENDOPHOTON_OT_result_activate,
    ENDOPHOTON_OT_result_delete,
    ENDOPHOTON_OT_export_result,
    ENDOPHOTON_OT_run,
    ENDOPHOTON_OT_sweep,
)
