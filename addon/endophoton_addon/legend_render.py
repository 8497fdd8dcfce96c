# SPDX-License-Identifier: MIT
"""Render with Legend: a Cycles render from the endoscope camera of the run's rig with the colour
bar of the run's point cloud beside it, written as a PNG and loaded as an Image."""

import os

import bpy
import numpy as np

from . import blend_paths, colour_maps, points, rig
from .keys import PARAMS_KEY, RUN_KEY


# Cycles samples when the scene is not set up for Cycles (its own samples are used when it is).
RENDER_SAMPLES = 64


def run_camera(scene, collection):
    """The camera to render ``collection`` from and why: ``(camera object, note)``.  The endoscope
    camera of the rig the run was made with (its parameters name the rig), else the scene camera
    (the note says so), else None."""
    params = collection.get(PARAMS_KEY)
    rig_name = params.get("rig") if params is not None else None
    rig_obj = scene.objects.get(rig_name) if rig_name else None
    if rig_obj is not None and rig.has_camera(rig_obj):
        camera = rig.camera_of(rig_obj)
        return camera, f"the endoscope camera '{camera.name}' of rig '{rig_obj.name}'"
    if scene.camera is not None:
        why = f"rig '{rig_name}' is gone or has no camera" if rig_name else "the run names no rig"
        return scene.camera, f"the scene camera '{scene.camera.name}' ({why})"
    return None, ""


class _cycles_from:
    """Render settings for Render with Legend, put back afterwards: ``camera``, Cycles (the points
    are a point cloud, which EEVEE does not draw), denoising off (Blender builds without
    OpenImageDenoiser fail with it on), RENDER_SAMPLES samples unless the scene already uses Cycles,
    and the linear EXR output the figure is made from."""

    def __init__(self, scene, camera, raw_path):
        self.scene, self.camera, self.raw_path = scene, camera, raw_path
        self.saved = []

    def _set(self, owner, name, value):
        self.saved.append((owner, name, getattr(owner, name)))
        setattr(owner, name, value)

    def __enter__(self):
        scene = self.scene
        self._set(scene, "camera", self.camera)
        if scene.render.engine != "CYCLES":
            self._set(scene.render, "engine", "CYCLES")
            self._set(scene.cycles, "samples", RENDER_SAMPLES)
        self._set(scene.cycles, "use_denoising", False)
        self._set(scene.render, "filepath", self.raw_path)
        self._set(scene.render.image_settings, "file_format", "OPEN_EXR")
        return self

    def __exit__(self, *_exc):
        for owner, name, value in reversed(self.saved):
            setattr(owner, name, value)
        return False


def _render_linear(scene, camera):
    """Render ``scene`` from ``camera`` (see _cycles_from); the linear pixels (H, W, 3), rows top-down."""
    import tempfile

    with tempfile.TemporaryDirectory(prefix="endophoton_legend_") as tmp:
        raw = os.path.join(tmp, "raw.exr")  # linear scene values, no view transform; removed with tmp
        with _cycles_from(scene, camera, raw):
            bpy.ops.render.render(write_still=True, scene=scene.name)
        rendered = bpy.data.images.load(raw)
        try:
            w, h = rendered.size
            pixels = np.empty(w * h * 4, np.float32)
            rendered.pixels.foreach_get(pixels)
        finally:
            bpy.data.images.remove(rendered)
    return pixels.reshape(h, w, 4)[::-1, :, :3]  # Blender's rows run bottom-up


def render_with_legend(scene, collection, path):
    """Render ``collection`` from its rig's endoscope camera (run_camera) with Cycles and write
    ``path``: the render (linear, exposed by the endoscope-view images' rule,
    colour_maps.exposed_srgb) with the colour bar of the run's points beside it, loaded as an
    Image tagged with the run (removed with it).  Returns ``(Image, note)``, the note naming
    the camera used.  The scene's camera and render settings are put back."""
    clouds = points.points_objects(collection)
    legend = points.legend_of(clouds[0]) if clouds else None
    if legend is None:
        raise RuntimeError(f"Collection '{collection.name}' has no coloured point cloud to make a legend of")
    camera, note = run_camera(scene, collection)
    if camera is None:
        raise RuntimeError(
            f"Scene '{scene.name}' has no camera to render from: the run's rig has none and the scene "
            "has no camera (use Add Endoscope)"
        )
    images_before = set(bpy.data.images)
    try:
        picture, exposure = colour_maps.exposed_srgb(_render_linear(scene, camera))
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        title = f"{collection.name} from {camera.name} (exposure ×{exposure:.3g})"
        colour_maps.legend_figure(legend, path, image=picture, title=title)
    except BaseException:  # no image of ours left behind (Blender's own "Render Result" slot stays, as after F12)
        for image in set(bpy.data.images) - images_before:
            if image.type != "RENDER_RESULT":
                bpy.data.images.remove(image)
        raise
    image = bpy.data.images.load(path, check_existing=True)
    image.filepath = blend_paths.stored_path(image.filepath)
    image.reload()
    image[RUN_KEY] = collection.get(RUN_KEY)
    image["endophoton_camera"] = camera.name
    return image, f"rendered with Cycles (denoising off) from {note}"
