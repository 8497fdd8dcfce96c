# SPDX-License-Identifier: MIT
"""The endoscope camera's images of a run (``ep.View``, rendered by the package from the run's
records) as float Image datablocks tagged with the run."""

import bpy
import numpy as np

from .keys import PARAMS_KEY, RUN_KEY

VIEW_KEY = "endophoton_view"  # on an endoscope-view Image: which image of the View it holds


VIEWS_KEY = "endophoton_views"  # on the run's collection: the names of its view Images


VIEW_IMAGES = ("white", "fluorescence")


def view_pixels(view, name):
    """RGBA float32 rows bottom-up (Blender's order) of ``view.images[name]``: the linear
    sRGB radiance times the image's exposure, unclipped (NaN -> 0), so the Image shows
    what ``srgb8`` encodes and pixel / exposure is the radiance."""
    image = view.images[name]
    rgba = np.ones((view.height, view.width, 4), dtype=np.float32)
    rgba[..., :3] = np.nan_to_num(np.asarray(image["rgb"], dtype=np.float64) * float(image["exposure"]))
    return rgba[::-1]


def view_info(view, name):
    """What the view Image carries as ID properties besides its pixels."""
    return {
        "exposure": float(view.images[name]["exposure"]),
        "width": int(view.width),
        "height": int(view.height),
        "packets": int(view.packets),
        "estimator": str(view.estimator),
        "kernel_radius_m": float(view.kernel["radius"]),
        "kernel_angle_deg": float(view.kernel["angle_deg"]),
        "emission_filter": str(view.emission_filter),
        "white_balance": str(view.white_balance),
    }


def create_view_images(collection, view, label):
    """The rig camera's images (``ep.View``) as float Images tagged with the run:
    packed and kept with a fake user (saved with the .blend), removed by results.remove_run."""
    names = []
    for name in VIEW_IMAGES:
        image = bpy.data.images.new(f"EP View {name} {label}", view.width, view.height, alpha=True, float_buffer=True)
        image.colorspace_settings.name = "Linear"
        image.pixels.foreach_set(view_pixels(view, name).ravel())
        image.pack()
        image.use_fake_user = True
        image[RUN_KEY] = collection[RUN_KEY]
        image[VIEW_KEY] = name
        image["endophoton_collection"] = collection.name
        image[PARAMS_KEY] = collection[PARAMS_KEY]
        image["endophoton_view_info"] = view_info(view, name)
        names.append(image.name)
    collection[VIEWS_KEY] = names
    return [bpy.data.images[n] for n in names]


def view_images(collection):
    """The run's endoscope-view Images, by VIEW_KEY."""
    run_id = collection.get(RUN_KEY)
    return {
        im[VIEW_KEY]: im
        for im in bpy.data.images
        if run_id is not None and im.get(RUN_KEY) == run_id and VIEW_KEY in im
    }
