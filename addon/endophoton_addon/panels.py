# SPDX-License-Identifier: MIT
"""The "EndoPhoton" sidebar tab of the 3D viewport."""

import re

import bpy

from . import endoscope_views, operators, package_finder, presets, results, rig, run_summary, sweep_answer, sweep_job
from .utils import wrap_text


# Characters a label shows at the default sidebar width (measured on the
# screenshots of tests/blender/test_screenshots.py); longer lines are wrapped.
SIDEBAR_CHARS = 28


EEVEE_NOTE = (
    "The points render in Cycles only (EEVEE draws no point clouds); Render with Legend uses Cycles, " "denoising off"
)


def run_label(name):
    """A run's name short enough for a list row beside its eye and X at the default width:
    'EP β=+20.0° 20250105-071536' -> 'β=+20.0° 07:15:36' (β digits and time kept whole)."""
    short = name[3:] if name.startswith("EP ") else name
    return re.sub(r"\b\d{8}-(\d\d)(\d\d)(\d\d)\b", r"\1:\2:\3", short)


def draw_rows(col, rows, width=SIDEBAR_CHARS):
    """(label, value) rows as wrapped lines, readable at the default sidebar width: the label on
    its own line when "label: value" does not fit, the value wrapped below it, never cut."""
    for label, value in rows:
        lines = wrap_text(f"{label}: {value}", width)
        if len(lines) > 1:
            col.label(text=f"{label}:")
            lines = wrap_text(value, width - 2)
            for line in lines:
                row = col.row()
                row.separator(factor=1.0)
                row.label(text=line)
        else:
            col.label(text=lines[0] if lines else f"{label}:")


class _EndoPhotonPanel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "EndoPhoton"


class ENDOPHOTON_UL_fluorophores(bpy.types.UIList):
    def draw_item(self, _context, layout, _data, item, _icon, _active_data, _active_prop, _index=0):
        # Read-only summary that fits the default sidebar width; the active
        # item is edited with full-width fields below the list.
        layout.label(text=f"{item.species.capitalize()}  d {item.d:.2f}  c {item.c:.2f}")


class ENDOPHOTON_PT_main(_EndoPhotonPanel, bpy.types.Panel):
    bl_label = "EndoPhoton"

    def draw(self, context):
        layout = self.layout
        module, message = package_finder.status()
        if module is None:
            box = layout.box()
            box.label(text="Engine package not found", icon="ERROR")
            col = box.column(align=True)
            for line in wrap_text(message, 40):
                col.label(text=line)
            box.operator("endophoton.retry_engine_import", icon="FILE_REFRESH")
        else:
            version = getattr(module, "__version__", "")
            layout.label(text=f"Engine ready {version}".strip(), icon="CHECKMARK")
        job = operators.running_job()
        if job is not None:
            box = layout.box()
            col = box.column(align=True)
            lines = job.panel_lines() if job.cancelled_at is None else ["Cancelling: the engine ends its unit"]
            for i, line in enumerate(lines):
                for j, part in enumerate(wrap_text(line, SIDEBAR_CHARS)):
                    col.label(text=part, icon="TIME" if i == j == 0 else "NONE")
            box.operator("endophoton.cancel_run", icon="CANCEL")


class ENDOPHOTON_PT_object(_EndoPhotonPanel, bpy.types.Panel):
    bl_label = "Object"
    bl_parent_id = "ENDOPHOTON_PT_main"

    def draw(self, context):
        layout = self.layout
        obj = context.object
        if obj is None or obj.type != "MESH":
            layout.label(text="Select a mesh to give it a role")
            return
        s = obj.endophoton
        layout.label(text=obj.name, icon="OBJECT_DATA")
        layout.prop(s, "role")
        if s.role == "NONE":
            return
        layout.prop(s, "tissue_preset", text="Preset")
        preset = presets.TISSUE_PRESETS.get(s.tissue_preset)
        if preset is not None:
            box = layout.box()
            for line in wrap_text(preset.source, SIDEBAR_CHARS):
                box.label(text=line)
        col = layout.column(align=True)
        col.label(text="Medium (μa, μs in cm⁻¹)")
        col.prop(s.medium, "mua")
        col.prop(s.medium, "mus")
        col.prop(s.medium, "g")
        col.prop(s.medium, "n")
        layout.prop(s, "priority")
        layout.label(text="Fluorophores (d, c)")
        row = layout.row()
        row.template_list("ENDOPHOTON_UL_fluorophores", "", s, "fluorophores", s, "active_fluorophore", rows=2)
        col = row.column(align=True)
        col.operator("endophoton.fluorophore_add", icon="ADD", text="")
        col.operator("endophoton.fluorophore_remove", icon="REMOVE", text="")
        if 0 <= s.active_fluorophore < len(s.fluorophores):
            item = s.fluorophores[s.active_fluorophore]
            col = layout.column(align=True)
            col.prop(item, "species", text="Species")
            col.prop(item, "d", text="d (excitation)")
            col.prop(item, "c", text="c (emission)")

        layout.operator("endophoton.role_defaults", icon="LOOP_BACK")


class ENDOPHOTON_PT_endoscope(_EndoPhotonPanel, bpy.types.Panel):
    bl_label = "Endoscope"
    bl_parent_id = "ENDOPHOTON_PT_main"

    def draw(self, context):
        layout = self.layout
        layout.operator("endophoton.add_endoscope", icon="OUTLINER_OB_CAMERA")
        settings = context.scene.endophoton
        layout.prop(settings, "rig")
        layout.prop(settings, "show_rig_overlay")
        rig_obj = context.object if rig.is_rig(context.object) else settings.rig
        if rig_obj is None:
            return
        s = rig_obj.endophoton_rig
        layout.label(text=rig_obj.name, icon="EMPTY_AXIS")
        col = layout.column(align=True)
        col.prop(s, "beta")
        col.prop(s, "distance")
        col = layout.column(align=True)
        col.prop(s, "target")
        col = layout.column(align=True)
        col.prop(s, "normal")
        col = layout.column(align=True)
        col.prop(s, "tilt_axis")
        col = layout.column(align=True)
        col.label(text="Tip")
        col.prop(s, "head_diameter")
        col.prop(s, "light_diameter")
        col.prop(s, "light_offset")
        col.prop(s, "cone_angle")
        col.prop(s, "camera_fov")


class ENDOPHOTON_PT_simulation(_EndoPhotonPanel, bpy.types.Panel):
    bl_label = "Simulation"
    bl_parent_id = "ENDOPHOTON_PT_main"

    def draw(self, context):
        layout = self.layout
        s = context.scene.endophoton
        layout.prop(s, "quality")
        layout.prop(s, "mode", expand=True)
        if s.quality == "CUSTOM":
            layout.prop(s, "store" if s.mode == "STORE" else "photons")
        layout.prop(s, "fluorescent_only")
        layout.prop(s, "fluorescence_rule", text="Rule")
        row = layout.row(align=True)
        row.prop(s, "seed")
        row.prop(s, "threads")
        col = layout.column(heading="Outputs")
        col.prop(s, "output_points")
        col.prop(s, "output_grids")
        col.prop(s, "output_views")
        est = col.row()
        est.active = s.output_views
        est.prop(s, "view_estimator", text="Estimator")
        live = col.row()
        # live images only when the view images are on and come from the records (not the camera tally)
        live.active = s.output_views and s.view_estimator != "NEE"
        live.prop(s, "live_view")
        sub = col.column()
        sub.active = s.output_grids
        sub.prop(s, "voxel_size")
        quantities = sub.column(heading="Tally", align=True)
        quantities.prop(s, "grid_absorbed")
        quantities.prop(s, "grid_fluorescent_light")
        quantities.prop(s, "grid_emission")
        per = sub.row()
        per.active = s.grid_fluorescent_light
        per.prop(s, "grid_per_fluorophore")
        sub.prop(s, "grid_dir", text="Folder")
        col = layout.column(heading="Guards")
        col.prop(s, "allow_unusual_scale")
        col.prop(s, "allow_large_runs")
        layout.operator("endophoton.check_scene", icon="VIEWZOOM")
        if s.scene_report:
            box = layout.box()
            col = box.column(align=True)
            for paragraph in s.scene_report.split("\n"):
                for line in wrap_text(paragraph, SIDEBAR_CHARS):
                    col.label(text=line)
        row = layout.row()
        row.scale_y = 1.5
        row.enabled = package_finder.get() is not None
        row.operator("endophoton.run_simulation", icon="PLAY")


class ENDOPHOTON_PT_sweep(_EndoPhotonPanel, bpy.types.Panel):
    bl_label = "Sweep β"
    bl_parent_id = "ENDOPHOTON_PT_main"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        s = context.scene.endophoton.sweep
        layout.label(text="Tilts the chosen rig about its target")
        layout.prop(s, "betas", text="β")
        layout.prop(s, "store")
        row = layout.row(align=True)
        row.prop(s, "seed")
        row.prop(s, "threads")
        layout.prop(s, "seed_per_beta")
        layout.prop(s, "batches")
        layout.prop(s, "fluorescent_only")
        layout.prop(s, "fluorescence_rule", text="Rule")
        layout.prop(s, "output_dir", text="Output")
        layout.prop(s, "keep_runs", text="Per β")
        box = layout.box()
        box.prop(s, "visibility")
        col = box.column()
        col.active = s.visibility
        for name in sweep_answer.VISIBILITY_FIELDS:
            col.prop(s, name, text=sweep_answer.SHORT_LABELS.get(name, ""))
        row = layout.row()
        row.scale_y = 1.5
        row.enabled = package_finder.get() is not None
        row.operator("endophoton.sweep_beta", icon="GRAPH")
        rows = sweep_job.summary_rows(context.scene)
        if not rows:
            return
        box = layout.box()
        box.label(text="Last sweep", icon="IMAGE_DATA")
        plot = bpy.data.images.get(sweep_job.image_name("visibility.png"))
        if plot is not None and plot.get(sweep_job.IMAGE_KEY):
            plot.preview_ensure()
            box.template_icon(icon_value=plot.preview.icon_id, scale=8.0)
        draw_rows(box.column(align=True), rows)


class ENDOPHOTON_PT_results(_EndoPhotonPanel, bpy.types.Panel):
    bl_label = "Results"
    bl_parent_id = "ENDOPHOTON_PT_main"

    def draw(self, context):
        layout = self.layout
        s = context.scene.endophoton
        layout.prop(s, "color_by", text="Colour")
        col = layout.column(heading="Show")
        col.prop(s, "filter_fluorescent")
        col.prop(s, "filter_fluorophore")
        col.prop(s, "filter_region")
        col.prop(s, "filter_toward_camera")
        if s.filter_toward_camera:
            col.prop(s, "camera_cone_deg")
        if s.legend_header:
            box = layout.box()
            col = box.column(align=True)
            for line in wrap_text(s.legend_header, SIDEBAR_CHARS):
                col.label(text=line, icon="NONE")
            grid = box.grid_flow(columns=2, even_columns=True, align=True)
            for entry in s.legend:
                row = grid.row(align=True)
                split = row.split(factor=0.25, align=True)
                split.prop(entry, "colour", text="")
                split.label(text=entry.name)
            box.operator("endophoton.render_legend", icon="RENDER_STILL")
            if context.scene.render.engine != "CYCLES":  # EEVEE draws no point clouds (Blender 3.4)
                for line in wrap_text(EEVEE_NOTE, SIDEBAR_CHARS):
                    box.label(text=line)
        layout.prop(s, "point_radius")
        layout.prop(s, "volume_density")
        row = layout.row(align=True)
        row.prop(s, "volume_scale", expand=True)
        if s.volume_scale == "LOG":
            layout.prop(s, "volume_decades")
        collection = s.result_collection
        if collection is None:
            layout.label(text="No results yet")
            return
        runs = results.result_collections(context.scene)
        if len(runs) > 1:
            col = layout.column(align=True)
            col.label(text=f"{len(runs)} runs kept", icon="OUTLINER_COLLECTION")
            for run in runs:
                row = col.row(align=True)
                row.prop(run, "hide_viewport", text="", emboss=False)  # compare runs / β side by side
                op = row.operator(
                    "endophoton.result_activate", text=run_label(run.name), depress=run == collection, emboss=True
                )
                op.name = run.name
                row.operator("endophoton.result_delete", text="", icon="X").name = run.name
        box = layout.box()
        for i, line in enumerate(wrap_text(run_label(collection.name), SIDEBAR_CHARS)):
            box.label(text=line, icon="OUTLINER_COLLECTION" if i == 0 else "NONE")
        col = box.column(align=True)
        for label, value in run_summary.summary_rows(collection):
            row = col.split(factor=0.34, align=True)
            row.label(text=label)
            row.label(text=value)
        for name, image in sorted(endoscope_views.view_images(collection).items()):  # Image Editor: "EP View ..."
            col.label(text=f"{name.capitalize()} view {image.size[0]}×{image.size[1]}", icon="IMAGE_DATA")
        for line in wrap_text(collection.get("endophoton_view_error", ""), SIDEBAR_CHARS):
            col.label(text=line, icon="ERROR")
        row = layout.row(align=True)
        row.operator("endophoton.export_result", icon="EXPORT").name = collection.name
        row.operator("endophoton.result_delete", icon="X").name = collection.name
        layout.operator("endophoton.clear_results", icon="TRASH")


CLASSES = (
    ENDOPHOTON_UL_fluorophores,
    ENDOPHOTON_PT_main,
    ENDOPHOTON_PT_object,
    ENDOPHOTON_PT_endoscope,
    ENDOPHOTON_PT_simulation,
    ENDOPHOTON_PT_results,
    ENDOPHOTON_PT_sweep,
)
