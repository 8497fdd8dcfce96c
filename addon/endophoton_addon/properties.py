# SPDX-License-Identifier: MIT
"""Property groups: per-object (role, medium, fluorophores), per-rig, per-scene."""

import bpy
from bpy.props import (
    BoolProperty,
    CollectionProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)

from . import colour_maps, presets, sweep_answer

ROLE_ITEMS = (
    ("NONE", "None", "Not part of the simulation"),
    ("TISSUE", "Tissue", "Closed mesh of tissue (e.g. the colon wall)"),
    ("POLYP", "Polyp", "Closed mesh of a polyp; give it a higher priority than the tissue it overlaps"),
)

FLUORESCENCE_RULE_ITEMS = (
    ("paper", "Paper", "ξ1 < d and ξ2 < c"),
    ("eem", "EEM", "ξ1 < d·η(λ) and ξ2 < c, with the EEM's excitation efficiency η"),
)

FLUOROPHORE_ITEMS = tuple(
    (name, name.capitalize(), f"Default {name} excitation-emission matrix") for name in presets.FLUOROPHORE_NAMES
)


# --- per object --------------------------------------------------------------
class EndoPhotonFluorophore(bpy.types.PropertyGroup):
    species: EnumProperty(
        name="Fluorophore",
        description="Excitation-emission matrix of the fluorophore (the package data/eem/)",
        items=FLUOROPHORE_ITEMS,
        default="collagen",
    )
    d: FloatProperty(
        name="d",
        description="Probability (0-1, unitless) that an interaction can excite this fluorophore",
        default=0.2,
        min=0.0,
        max=1.0,
        precision=3,
    )
    c: FloatProperty(
        name="c",
        description="Probability (0-1, unitless) that an excitation emits a fluorescence photon",
        default=0.4,
        min=0.0,
        max=1.0,
        precision=3,
    )


_loading_preset = False  # True while _tissue_preset_chosen writes the medium fields


def _medium_edited(self, _context):
    """A hand edit of a medium field ends a spectral preset: the engine then gets the constant medium shown."""
    settings = getattr(self.id_data, "endophoton", None)
    if _loading_preset or settings is None:
        return
    preset = presets.TISSUE_PRESETS.get(settings.tissue_preset)
    if preset is not None and preset.spectral:
        settings.tissue_preset = "CUSTOM"


class EndoPhotonMedium(bpy.types.PropertyGroup):
    # Hard limits are left open on purpose: validation reports bad values
    # (naming object and field) instead of Blender silently clamping them.
    mua: FloatProperty(
        name="μa [cm⁻¹]",
        description="Absorption coefficient in cm⁻¹",
        default=20.0,
        soft_min=0.0,
        soft_max=1000.0,
        precision=3,
        update=_medium_edited,
    )
    mus: FloatProperty(
        name="μs [cm⁻¹]",
        description="Scattering coefficient in cm⁻¹",
        default=200.0,
        soft_min=0.0,
        soft_max=10000.0,
        precision=3,
        update=_medium_edited,
    )
    g: FloatProperty(
        name="g",
        description="Scattering anisotropy g (Henyey-Greenstein mean cosine, -1..1, unitless)",
        default=0.9,
        soft_min=-1.0,
        soft_max=1.0,
        precision=3,
        update=_medium_edited,
    )
    n: FloatProperty(
        name="n",
        description="Refractive index n (>= 1, unitless)",
        default=1.1,
        soft_min=1.0,
        soft_max=3.0,
        precision=3,
        update=_medium_edited,
    )


def _role_changed(self, _context):
    apply_role_defaults(self)


def apply_role_defaults(settings):
    """Load the role's default medium, priority and fluorophores into ``settings``."""
    defaults = presets.ROLE_DEFAULTS.get(settings.role)
    if defaults is None:
        return
    for key, value in defaults["medium"].items():
        setattr(settings.medium, key, value)
    settings.priority = defaults["priority"]
    settings.fluorophores.clear()
    for species, d, c in defaults["fluorophores"]:
        item = settings.fluorophores.add()
        item.species, item.d, item.c = species, d, c
    settings.active_fluorophore = 0


def _tissue_preset_chosen(self, _context):
    """Load the chosen published medium into the object's medium. A spectral preset stays chosen (the export
    sends its name, the engine its spectra) until a medium field is edited by hand."""
    global _loading_preset
    preset = presets.TISSUE_PRESETS.get(self.tissue_preset)
    if preset is None:
        return
    _loading_preset = True
    try:
        for key, value in preset.medium.items():
            setattr(self.medium, key, value)
    finally:
        _loading_preset = False


class EndoPhotonObjectSettings(bpy.types.PropertyGroup):
    role: EnumProperty(
        name="Role",
        description="What the mesh is in the simulation: tissue, a polyp, or not part of it (choosing a role "
        "loads its default medium, priority and fluorophores)",
        items=ROLE_ITEMS,
        default="NONE",
        update=_role_changed,
    )
    tissue_preset: EnumProperty(
        name="Tissue Preset",
        description="Load published optical properties into the medium",
        items=(("CUSTOM", "Custom", "The medium as edited"),)
        + tuple((key, p.label, p.source) for key, p in presets.TISSUE_PRESETS.items()),
        default="CUSTOM",
        update=_tissue_preset_chosen,
    )
    medium: PointerProperty(type=EndoPhotonMedium)
    priority: IntProperty(
        name="Priority",
        default=0,
        description="Where regions overlap, the higher priority owns the space (an integer rank)",
    )
    fluorophores: CollectionProperty(type=EndoPhotonFluorophore)
    active_fluorophore: IntProperty(default=0, min=0)


# --- endoscope rig (on the rig's empty) --------------------------------------
def _rig_changed(self, _context):
    from . import rig

    rig.update_rig(self.id_data)


# fmt: off
_LENGTH = dict(subtype="DISTANCE", unit="LENGTH", min=0.0)
_VECTOR = dict(subtype="XYZ", size=3)
_ANGLE = dict(subtype="ANGLE")
# The rig's geometry, one table: field -> (property type, label, description, default, keywords).
# Every field moves or resizes the rig when edited (update=_rig_changed).
RIG_FIELDS = {
    "beta": (FloatProperty, "β", "Tilt of the viewing axis from the surface normal at the target (degrees)", 0.0,
             dict(_ANGLE, min=-1.5707963, max=1.5707963)),
    "distance": (FloatProperty, "Distance", "Distance from the target point to the tip along the viewing axis "
                 "(scene length units)",
                 0.01, _LENGTH),
    "target": (FloatVectorProperty, "Target", "Point on the tissue surface the endoscope orbits around (scene length units)",
               (0.0, 0.0, 0.0), dict(subtype="TRANSLATION", unit="LENGTH", size=3)),
    "normal": (FloatVectorProperty, "Surface Normal", "Outward surface normal at the target (β = 0 looks along "
               "−normal); a direction, unitless", (0.0, 0.0, 1.0), _VECTOR),
    "tilt_axis": (FloatVectorProperty, "Tilt Axis", "Axis β rotates about (made perpendicular to the normal); a direction, unitless",
                  (0.0, 1.0, 0.0), _VECTOR),
    "head_diameter": (FloatProperty, "Head Diameter", "Diameter of the endoscope head (scene length units; "
                      "12 mm by default)", 0.012, _LENGTH),
    "light_diameter": (FloatProperty, "Light Guide Diameter", "Diameter of each light guide (scene length "
                       "units; 3 mm by default)", 0.003, _LENGTH),
    "light_offset": (FloatProperty, "Light Offset", "Distance of each light guide from the head's axis (scene length units)", 0.0035,
                     _LENGTH),
    "cone_angle": (FloatProperty, "Cone Angle", "Full apex angle of each light's emission cone (degrees)", 0.2617994,
                   dict(_ANGLE, min=0.0, max=3.1415926)),
    "camera_fov": (FloatProperty, "Camera FOV", "Full field of view of the endoscope camera (degrees)", 2.0943951, dict(_ANGLE, min=0.0174533, max=3.0)),
}
# fmt: on


class EndoPhotonRigSettings(bpy.types.PropertyGroup):
    is_rig: BoolProperty(default=False, options={"HIDDEN"})
    __annotations__.update(
        {
            name: kind(name=label, description=text, default=default, update=_rig_changed, **kw)
            for name, (kind, label, text, default, kw) in RIG_FIELDS.items()
        }
    )


# --- scene: simulation settings and result display ---------------------------
def _is_rig(_self, obj):
    return obj.type == "EMPTY" and obj.endophoton_rig.is_rig


_NAME_ITEMS = {}  # Blender needs the dynamic enum's strings kept alive


def _name_items(settings, kind):
    """ "Any" plus the names of the active result's fluorophores / regions."""
    from . import points

    names = []
    collection = settings.result_collection
    if collection is not None:
        for obj in points.points_objects(collection):
            names = points.point_names(obj).get(kind, [])
    items = [("ANY", "Any", f"Records of every {kind}")] + [(n, n, f"Only the {kind} '{n}'") for n in names]
    return _NAME_ITEMS.setdefault((kind, tuple(names)), items)


def _display_changed(self, _context):
    from . import results

    results.update_display(self.id_data)


class EndoPhotonSweepSettings(bpy.types.PropertyGroup):
    """Options of the Sweep β operator: those of ``python3 -m endophoton sweep``
    (the scene and the rig's target, normal, tilt axis, distance and tip come
    from the .blend).  Limits are left open: the operator reports bad values."""

    betas: StringProperty(
        name="β Values",
        description="Tilt angles in degrees: a list '0,10,20' or 'start:stop:step' (stop excluded, "
        "like --betas of the command line)",
        default="0:60:5",
    )
    store: IntProperty(
        name="Store N",
        description="Records stored per β (store-N mode), a count of records",
        default=500_000,
        soft_min=1,
    )
    seed: IntProperty(name="Seed", description="Engine seed (an integer), the same for every β", default=1, min=0)
    seed_per_beta: BoolProperty(
        name="Seed per β",
        description="β k runs with seed + k × 0x9E3779B97F4A7C15 (mod 2^64) instead of the same seed: "
        "independent runs, so the report's test of whether a contrast depends on β holds its level",
        default=True,
    )
    threads: IntProperty(
        name="Threads",
        description="Engine threads, a count; 0 = all cores (all but one while the UI runs)",
        default=0,
        min=0,
        max=1024,
    )
    batches: IntProperty(
        name="Batches",
        description="Batches (a count, >= 2) for the batch-means standard errors",
        default=20,
        soft_min=2,
    )
    fluorescent_only: BoolProperty(
        name="Fluorescent Only",
        description="Store only fluorescence records (the paper's photon map)",
        default=True,
    )
    fluorescence_rule: EnumProperty(
        name="Fluorescence Rule",
        description="When an interaction fluoresces: the paper rule, or the EEM excitation efficiency",
        items=FLUORESCENCE_RULE_ITEMS,
        default="paper",
    )
    output_dir: StringProperty(
        name="Output Folder",
        description="Where sweep.csv, sweep.json, the plots and report.md are written; empty = "
        "'//endophoton_sweep' next to the .blend, or the temporary folder for an unsaved file",
        subtype="DIR_PATH",
        default="",
    )
    visibility: BoolProperty(
        name="Visibility",
        description="Render the endoscope's view at every β and measure the contrast of the Target region "
        "against the Background (the command line's --target/--background): the sweep then answers at which "
        "β the target is most visible (plot, β ± error, verdict against the paper's 34°)",
        default=True,
    )
    target_region: EnumProperty(
        name="Target",
        description="Region whose visibility the sweep measures (e.g. the polyp)",
        items=lambda self, context: sweep_answer.region_items(self.id_data, "target"),
    )
    background_region: EnumProperty(
        name="Background",
        description="Region the target is seen against (e.g. the colon wall)",
        items=lambda self, context: sweep_answer.region_items(self.id_data, "background"),
    )
    view_size: IntProperty(
        name="View Size [px]",
        description="Width = height of the endoscope view rendered at every β, in pixels (--view-size)",
        default=128,
        min=8,
        max=1024,
    )
    view_estimator: EnumProperty(
        name="View Estimator",
        description="How the endoscope view of every β is estimated (the command line's --estimator, docs/sweep.md)",
        items=[
            (
                "KERNEL",
                "Kernel",
                "From each β's records: the records that leave within 15° of the camera direction and two pixel "
                "footprints of the point (fast; the kernel's size biases small bright features)",
            ),
            (
                "EXITANCE",
                "Exitance",
                "From each β's records: every record that leaves near the point, times its region's angular "
                "share toward the camera, calibrated by the records that go there: no more packets, 4–6× "
                "the kernel's efficiency on the colour contrast, agrees with the unbiased estimates within noise",
            ),
            (
                "NEE",
                "Next Event",
                "From runs of each β's own that score every scattering event into the camera (the look-back "
                "next event): unbiased, as many packets as the store run, about 6× their time",
            ),
        ],
        default="EXITANCE",
    )
    keep_runs: EnumProperty(
        name="Per-β Results",
        description="Make every β a results collection (its point cloud and, with a rig camera, its "
        "endoscope-view images); the worker keeps every β's records until the sweep ends, "
        "about 100 bytes per record",
        items=(
            ("AUTO", "Auto", "Keep them when β values × Store N is at most 2,000,000 records (about 200 MB)"),
            ("ON", "On", "Always keep every β's records and make its collection"),
            ("OFF", "Off", "Plots and summary only (no per-β collections)"),
        ),
        default="AUTO",
    )


class EndoPhotonLegendEntry(bpy.types.PropertyGroup):
    """One row of the active result's colour bar (the panel draws the swatch)."""

    colour: FloatVectorProperty(
        name="Colour",
        description="The legend entry colour (linear RGB, 0-1)",
        subtype="COLOR",
        size=3,
        min=0.0,
        max=1.0,
    )


class EndoPhotonSceneSettings(bpy.types.PropertyGroup):
    show_rig_overlay: BoolProperty(
        name="Show Aim Lines",
        description="Draw each rig's light axes and cones, the camera's frustum to the rig's distance and the "
        "target point in the 3D viewport (they follow the rig's properties)",
        default=True,
    )
    rig: PointerProperty(
        name="Endoscope",
        description="The endoscope rig to simulate (needed when the scene has several)",
        type=bpy.types.Object,
        poll=_is_rig,
    )
    sweep: PointerProperty(type=EndoPhotonSweepSettings)

    quality: EnumProperty(
        name="Quality",
        items=tuple(
            (key, p.label, f"run to {100 * p.target_error:g} % relative error of the diffuse reflectance")
            for key, p in presets.QUALITY_PRESETS.items()
        )
        + (("CUSTOM", "Custom", "Use the packet / record count below"),),
        description="How long to run: a preset runs until the diffuse reflectance relative standard error "
        "(%) reaches its goal; Custom uses the packet or record count below",
        default="PREVIEW",
    )
    mode: EnumProperty(
        name="Budget",
        items=(
            ("PHOTONS", "Packets", "Launch a fixed number of packets"),
            ("STORE", "Store N", "Run until N surface records are stored"),
        ),
        description="What the count counts: packets launched, or surface records stored",
        default="PHOTONS",
    )
    photons: IntProperty(
        name="Packets", description="Packets to launch (a count of packets)", default=100_000, min=0, soft_min=1
    )
    store: IntProperty(
        name="Store N",
        description="Surface records to store before the run stops (a count of records)",
        default=100_000,
        min=0,
        soft_min=1,
    )
    fluorescent_only: BoolProperty(
        name="Fluorescent Only",
        description="Keep only fluorescence records in the surface map",
        default=False,
    )
    fluorescence_rule: EnumProperty(
        name="Fluorescence Rule",
        description="When an interaction fluoresces: the paper rule, or the EEM excitation efficiency",
        items=FLUORESCENCE_RULE_ITEMS,
        default="paper",
    )
    seed: IntProperty(
        name="Seed", description="Engine seed (an integer): the same seed gives the same result", default=1, min=0
    )
    threads: IntProperty(
        name="Threads",
        description="Engine threads, a count; 0 = all cores (all but one while the UI runs, to keep it responsive)",
        default=0,
        min=0,
        max=1024,
    )

    allow_unusual_scale: BoolProperty(
        name="Allow Unusual Scale",
        description="Run even when a region is thinner than one transport mean free path, thicker than "
        "1000 or larger than 1 m across (usually a wrong Unit Scale)",
        default=False,
    )
    allow_large_runs: BoolProperty(
        name="Allow Large Runs",
        description="Run even above 5 million records or 100 million packets (memory and time estimate "
        "in the panel's Check Scene)",
        default=False,
    )
    scene_report: StringProperty(name="Scene Check", default="", options={"SKIP_SAVE"})

    output_points: BoolProperty(
        name="Surface Point Cloud",
        description="Bring the run's escape records back as a point cloud (one point per record)",
        default=True,
    )
    output_grids: BoolProperty(
        name="Volume Grids",
        description="Tally absorbed energy and fluorescence in voxel grids (.vdb) shown as Volume objects",
        default=True,
    )
    output_views: BoolProperty(
        name="Endoscope View Images",
        description="After a run, render the endoscope camera's white-light and fluorescence images from the "
        "run's records (ep.render_view) as Image datablocks tagged with the run; needs the rig's camera",
        default=True,
    )
    view_estimator: EnumProperty(
        name="View Estimator",
        description="How a run's endoscope-view images are estimated (ep.render_view's estimator, "
        "docs/render.md); a sweep has its own (Sweep β > Visibility)",
        items=[
            (
                "KERNEL",
                "Kernel",
                "The records that leave within 15° of the camera direction and two pixel "
                "footprints of the point: the fastest; pixels without such a record stay black, and the kernel's "
                "size biases small bright features (the seed paper's method)",
            ),
            (
                "KNN",
                "k-Nearest",
                "Each pixel's kernel grows until it holds 32 records: no tissue pixel is left "
                "black; biased where the light changes within the kernel (docs/performance.md §14)",
            ),
            (
                "EXITANCE",
                "Exitance",
                "Every record that leaves near the point, times its region's angular share toward the camera, "
                "calibrated by the records that go there: no tissue pixel left black, most pixels within 20 %; "
                "agrees with the unbiased estimates within noise (docs/render.md, docs/performance.md §20)",
            ),
            (
                "NEE",
                "Next Event",
                "The run scores every scattering event into the camera (next-event estimation): "
                "unbiased (the look-back next event), about 6× the run's time; needs a Photons count, a local run (no Dask scheduler) and "
                "shows no live images",
            ),
        ],
        default="EXITANCE",
    )
    live_view: BoolProperty(
        name="Live View",
        description="While a run is in flight, refresh its endoscope-view images ('EP View white (live)', shown "
        "in any Image Editor showing an endoscope view) from the records merged so far, at most every 3 s and "
        "at most 5 % of the run's time; needs Endoscope View Images on and a local run (no Dask scheduler)",
        default=True,
    )
    voxel_size: FloatProperty(
        name="Voxel Size",
        description="Edge of one grid voxel (scene length units; at most 256³ voxels over the scene)",
        subtype="DISTANCE",
        unit="LENGTH",
        default=0.0005,
        min=0.0,
        precision=5,
    )
    grid_absorbed: BoolProperty(
        name="Absorbed",
        description="Tally the absorbed energy grid ('absorbed': where light is absorbed)",
        default=True,
    )
    grid_fluorescent_light: BoolProperty(
        name="Fluorescent Light",
        description="Tally the fluorescent-light grid ('fluorescent_light': where fluorescence light travels)",
        default=True,
    )
    grid_emission: BoolProperty(
        name="Emission",
        description="Tally one emission grid per fluorophore ('emission_<name>': where it converts light into "
        "fluorescence). Alone, the run deposits nothing at its interactions and runs at the speed of a run "
        "without grids",
        default=True,
    )
    grid_per_fluorophore: BoolProperty(
        name="Grid per Fluorophore",
        description="Also one fluorescent-light grid per fluorophore (needs Fluorescent Light)",
        default=False,
    )
    grid_dir: StringProperty(
        name="Grid Folder",
        description="Where .vdb files are written; empty = '//endophoton_cache' next to the "
        ".blend, or the temporary folder for an unsaved file",
        subtype="DIR_PATH",
        default="",
    )

    point_radius: FloatProperty(
        name="Point Radius",
        description="Radius each photon record is drawn with (scene length units)",
        subtype="DISTANCE",
        unit="LENGTH",
        default=0.0001,
        min=0.0,
        precision=5,
        update=_display_changed,
    )
    color_by: EnumProperty(
        name="Colour By",
        description="Record attribute the points are coloured by (its unit is in the legend)",
        items=tuple(
            (
                m.key,
                m.label,
                f"Colour each record by its {m.label.lower()}"
                + (f" [{m.unit}]" if m.unit else "")
                + (" (wavelength -> CIE 1931 -> sRGB)" if m.kind == "wavelength" else ""),
            )
            for m in colour_maps.COLOUR_MAPS.values()
        ),
        default="WAVELENGTH",
        update=_display_changed,
    )
    filter_fluorescent: BoolProperty(
        name="Fluorescent Only",
        description="Show only fluorescence records",
        default=False,
        update=_display_changed,
    )
    filter_fluorophore: EnumProperty(
        name="Fluorophore",
        description="Show only records of this fluorophore",
        items=lambda self, context: _name_items(self, "fluorophore"),
        update=_display_changed,
    )
    filter_region: EnumProperty(
        name="Region",
        description="Show only records that left this region",
        items=lambda self, context: _name_items(self, "region"),
        update=_display_changed,
    )
    filter_toward_camera: BoolProperty(
        name="Toward Camera",
        description="Show only records leaving toward the scene's camera (exit direction within the "
        "cone below around the direction to the camera): the light the camera records",
        default=False,
        update=_display_changed,
    )
    camera_cone_deg: FloatProperty(
        name="Camera Cone",
        description="Half angle of the cone around the direction to the camera, degrees "
        "(ep.render_view's kernel angle)",
        default=15.0,
        min=0.1,
        max=90.0,
        update=_display_changed,
    )
    volume_scale: EnumProperty(
        name="Volume Scale",
        description="How grid values map to colour and density (own maximum, a shared maximum, or log)",
        items=(
            ("OWN", "Own Max", "Each grid from 0 to its own maximum"),
            ("SHARED", "Shared", "Every grid of a run on one scale: the largest maximum of its grids"),
            ("LOG", "Log", "Each grid on a log scale: its maximum and the decades below it"),
        ),
        default="OWN",
        update=_display_changed,
    )
    volume_decades: FloatProperty(
        name="Decades",
        description="Decades (powers of ten) below the maximum the log scale shows",
        default=3.0,
        min=0.1,
        soft_max=8.0,
        update=_display_changed,
    )
    volume_density: FloatProperty(
        name="Volume Density",
        description="Optical depth (unitless) of one voxel at the grid's maximum (density and glow of the grids)",
        default=0.2,
        min=0.0,
        soft_max=10.0,
        update=_display_changed,
    )
    result_collection: PointerProperty(name="Result", type=bpy.types.Collection)
    legend: CollectionProperty(type=EndoPhotonLegendEntry)
    legend_header: StringProperty(name="Legend", default="")


CLASSES = (
    EndoPhotonFluorophore,
    EndoPhotonMedium,
    EndoPhotonObjectSettings,
    EndoPhotonRigSettings,
    EndoPhotonSweepSettings,
    EndoPhotonLegendEntry,
    EndoPhotonSceneSettings,
)


# (owner type, attribute, group): attached by the add-on's registration loop.
POINTERS = (
    (bpy.types.Object, "endophoton", EndoPhotonObjectSettings),
    (bpy.types.Object, "endophoton_rig", EndoPhotonRigSettings),
    (bpy.types.Scene, "endophoton", EndoPhotonSceneSettings),
)
