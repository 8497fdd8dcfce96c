# SPDX-License-Identifier: MIT
"""The live endoscope view (issue 36): while a run or a sweep's β is in flight, its endoscope-view
images ("EP View white (live)", "EP View fluorescence (live)"; during a sweep named with the β, e.g.
"EP View white (live, β 20°)") and every Image Editor showing an endoscope view refresh every few
seconds from the records merged so far, so the user watches the noise fall.

The run goes through ``ep.run_live`` (the package's unit path: the final result is the bits of
``ep.run``); its snapshots are rendered with ``ep.render_view`` (kernel estimator) in the job's
worker thread, and the main thread copies the newest View into the Images (``refresh``, from the
job operator's timer and from the blocking run's wait loop). When the run ends the Image Editors
showing a live image are handed the run's own view images and the live images are removed.
Only a run with the endoscope-view images on, a camera on its rig, Live View on and no Dask
scheduler takes this path; any other run is ``ep.run`` as before. A sweep (sweep_job.py) hands the
same knobs to ``endophoton.sweep(live=...)``, which runs each β through ``ep.run_live``
(:meth:`LiveView.sweep_kwargs`).
"""

import threading

import bpy

from . import endoscope_views

#: Seconds between two refreshes (at least; ep.run_live also keeps their share of the run's time
#: under OVERHEAD_SHARE).
EVERY_S = 3.0
#: Most of a run's time its snapshots (the re-merge and the render) may take.
OVERHEAD_SHARE = 0.05
#: A snapshot after each of the first N merged chunks, whatever the clock says. One by default: the
#: first chunk is one work unit, so its render finds the kernel radius (the costly auto-radius render,
#: four times the pairs of the later ones) on a thousand packets' records. Tests raise it and set
#: WAIT_FOR_DISPLAY_S: the worker then waits until the main thread has shown each forced snapshot
#: (a deterministic mid-run refresh).
FORCE_AFTER_CHUNKS = 1
WAIT_FOR_DISPLAY_S = 0.0
#: The live images have 1/LIVE_SCALE of the camera's resolution each way (a quarter of the render's cost).
LIVE_SCALE = 2
LIVE_KEY = "endophoton_live"  # on a live Image: which image of the View it holds


def wanted(inputs, scheduler):
    """Whether a run or a sweep of ``inputs`` shows a live view: its view images are on (a camera on the
    rig), Live View is on and it runs locally (the Dask path has no snapshots), and its images come from
    the records (a next-event run's camera tally is not carried by ep.run_live's snapshots)."""
    nee = getattr(inputs, "view_estimator", "kernel") == "nee"
    return bool(inputs.endoscope_view and inputs.live_view and not scheduler and not nee)


class LiveView:
    """A job's live view: ``on_snapshot`` (worker thread, no bpy) renders a snapshot Result;
    ``refresh`` (main thread) shows the newest rendering."""

    def __init__(self, ep, threads):
        self.ep = ep
        self.threads = threads
        self.error = None  # why the live view stopped (e.g. a camera inside tissue); the run goes on
        self.shown = []  # packets of each snapshot shown, in order
        self.kernel_radius = None  # scene units: the full-resolution image's kernel (_knobs)
        self._part = 0  # a sweep's β index whose snapshots are shown (a run: 0 throughout)
        self._pending = None  # (View, label) not shown yet
        self._lock = threading.Lock()
        self._displayed = threading.Event()

    def run_kwargs(self):
        """Keyword arguments of ep.run_live besides those of ep.run."""
        return {
            "on_snapshot": self.on_snapshot,
            "every_s": EVERY_S,
            "overhead_share": OVERHEAD_SHARE,
            "snapshot_after_chunks": FORCE_AFTER_CHUNKS,
        }

    def sweep_kwargs(self):
        """``endophoton.sweep``'s ``live`` argument: the same knobs, each β's snapshots shown with its angle."""
        return {"live": {**self.run_kwargs(), "on_snapshot": self.on_beta_snapshot}}

    # --- worker thread --------------------------------------------------------
    def on_snapshot(self, result, part=0, label=""):
        """A run's snapshot (or β ``part``'s, named with ``label``): rendered, kept for ``refresh``."""
        escapes = getattr(result, "escapes", None)
        if self.error is not None or escapes is None or len(escapes.get("weight", ())) == 0:
            return  # nothing to image yet (the next snapshot will have records)
        try:
            view = self.ep.render_view(result, threads=1, **self._knobs(result))  # the run's threads keep theirs
        except ValueError as exc:
            if part == self._part:  # not a late one of an earlier β
                self.error = f"live view stopped: {exc}"
            return
        with self._lock:
            if part != self._part:
                return  # an earlier β's, ended in the background after its run (ep.run_live): not shown
            self._keep_kernel(view)
            self._pending = (view, label)
            self._displayed.clear()
        if WAIT_FOR_DISPLAY_S > 0:
            self._displayed.wait(WAIT_FOR_DISPLAY_S)

    def on_beta_snapshot(self, index, beta, result):
        """The sweep's ``on_snapshot(i_beta, beta_deg, result)``. A new β starts afresh: its camera has
        moved, so its kernel radius is found again from its own first snapshot, and a render refused at an
        earlier β (e.g. its camera inside tissue) is tried again."""
        with self._lock:
            if index < self._part:
                return  # a late snapshot of an earlier β
            if index > self._part:
                self._part, self.kernel_radius, self.error = index, None, None
        self.on_snapshot(result, part=index, label=f"β {beta:g}°")

    def _knobs(self, result):
        """render_view's knobs for a live image: half the camera's resolution with the full-resolution
        kernel (half the half-resolution one, kept from the first snapshot: the median depth it comes from
        is the camera's, not the records'), so a snapshot gathers about a quarter of the kernel pairs of
        the final image; two batches (the live image shows no standard error)."""
        width, height = (max(1, n // LIVE_SCALE) for n in result.source.camera_resolution)
        knobs = {"width": width, "height": height, "n_batches": 2, "estimator": "kernel"}  # the cheapest
        if self.kernel_radius is not None:
            knobs["kernel_radius"] = self.kernel_radius
        return knobs

    def _keep_kernel(self, view):
        if self.kernel_radius is None:
            self.kernel_radius = float(view.kernel["radius"]) / LIVE_SCALE

    # --- main thread ----------------------------------------------------------
    def refresh(self):
        """Shows the newest snapshot's View, if a new one came; returns whether one did."""
        with self._lock:
            pending, self._pending = self._pending, None
        if pending is None:
            return False
        view, label = pending
        for name in endoscope_views.VIEW_IMAGES:
            image = _live_image(name, view, label)
            image.pixels.foreach_set(endoscope_views.view_pixels(view, name).ravel())
            image["endophoton_view_info"] = dict(endoscope_views.view_info(view, name), live_label=label)
            image.update()
            _show_in_editors(image, name)
        self.shown.append(int(view.packets))
        self._displayed.set()
        return True


def _live_image(name, view, label=""):
    """The live Image of view image ``name`` at the View's size (made or remade as needed), named with
    ``label`` (a sweep's β): the same datablock from β to β, so the Image Editors showing it stay on it."""
    title = f"EP View {name} (live, {label})" if label else f"EP View {name} (live)"
    image = next((im for im in bpy.data.images if im.get(LIVE_KEY) == name), None)
    if image is not None and tuple(image.size) != (view.width, view.height):
        bpy.data.images.remove(image)
        image = None
    if image is not None and image.name != title:
        image.name = title
    if image is None:
        image = bpy.data.images.new(title, view.width, view.height, alpha=True, float_buffer=True)
        image.colorspace_settings.name = "Linear"
        image[LIVE_KEY] = name
    return image


def _editors():
    """The Image Editor spaces of every window."""
    wm = bpy.context.window_manager
    for window in wm.windows if wm is not None else ():
        for area in window.screen.areas:
            if area.type == "IMAGE_EDITOR":
                yield area, area.spaces.active


def _show_in_editors(image, name):
    """Image Editors showing an endoscope view of kind ``name`` (a run's or the live one) show ``image``."""
    for area, space in _editors():
        shown = space.image
        if shown is not None and shown != image and name in (shown.get(endoscope_views.VIEW_KEY), shown.get(LIVE_KEY)):
            space.image = image
        if space.image == image:
            area.tag_redraw()


def refresh(job):
    """The job operator's hook while ``job`` runs (main thread): a no-op for jobs without a live view."""
    live = getattr(job, "live", None)
    if live is not None:
        live.refresh()


def end(context, job):
    """After ``job`` (main thread): the Image Editors showing a live image get the finished run's
    own view image of that kind (if it made one) and the live images are removed."""
    if getattr(job, "live", None) is None:
        return
    collection = _finished_collection(context, job)
    own = endoscope_views.view_images(collection) if collection is not None else {}
    for image in [im for im in bpy.data.images if LIVE_KEY in im]:
        for area, space in _editors():
            if space.image == image:
                space.image = own.get(image[LIVE_KEY])
                area.tag_redraw()
        bpy.data.images.remove(image)


def _finished_collection(context, job):
    """The results collection whose view images take the live images' place: a finished run's; a finished
    sweep's last kept β (its ``collections``; none when it kept none); none after a failure or a cancel."""
    if job.error is not None or job.result is None or getattr(job.result, "cancelled", False):
        return None
    if hasattr(job, "collections"):  # a sweep: the scene's result collection may be an older run's
        return job.collections[-1] if job.collections else None
    return context.scene.endophoton.result_collection
