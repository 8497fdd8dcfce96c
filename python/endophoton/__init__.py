"""EndoPhoton: Monte Carlo light transport for endoscopy of colon tissue.

Units: lengths in the scene unit ("m", "cm", "mm"); mua and mus in cm^-1;
wavelengths in nm; depths reported in cm.
"""
from .medium import Medium
from .mesh_io import box_mesh, load_mesh
from .run import CancelToken, GridRequest, Result, Target, check_run, run, FRACTIONS, TARGET_TALLIES
from .scene import Region, Scene, forget_native_scenes, layered_slab
from .sources import ConeSource, DiskSource, EndoscopeRig, PencilSource, source_from_dict
from .spectra import EEM, FLUOROPHORE_DEFAULTS, Fluorophore, Spectrum
from .units import UNIT_CM, unit_cm
from . import _core
from . import analysis, media, meshes, paper
from .live import run_live
from .sweep.driver import SweepResult, default_flat_scene, sweep
from .report import write_report
from .quality import QUALITY_PRESETS, Quality, quality_preset
from .view.camera import Camera
from .view.render import View, excitation_spectrum, render_view

__version__ = _core.__version__

__all__ = [
    "Medium",
    "Scene",
    "Region",
    "layered_slab",
    "forget_native_scenes",
    "box_mesh",
    "load_mesh",
    "PencilSource",
    "DiskSource",
    "ConeSource",
    "EndoscopeRig",
    "source_from_dict",
    "run",
    "run_live",
    "check_run",
    "Result",
    "GridRequest",
    "Target",
    "CancelToken",
    "EEM",
    "Fluorophore",
    "Spectrum",
    "FLUOROPHORE_DEFAULTS",
    "FRACTIONS",
    "TARGET_TALLIES",
    "UNIT_CM",
    "unit_cm",
    "analysis",
    "media",
    "meshes",
    "paper",
    "sweep",
    "SweepResult",
    "default_flat_scene",
    "write_report",
    "QUALITY_PRESETS",
    "Quality",
    "quality_preset",
    "Camera",
    "View",
    "render_view",
    "excitation_spectrum",
]
