"""The `DataPipe` tab of the 3D viewport sidebar (N panel): Initialize, Scene, Objects, Camera,
Structured Light, Output & Run (with Simulation and Render settings as closed sub-panels).

Panels only draw `Scene.datapipe` and call `datapipe.*` operators; no logic lives here.
"""
from __future__ import annotations

from pathlib import Path

from bpy.types import Panel, UIList

from . import preview, runner


def _props(context):
    return context.scene.datapipe


class _DataPipePanel:
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "DataPipe"

    @classmethod
    def poll(cls, context):
        return context.scene is not None and hasattr(context.scene, "datapipe")


# ------------------------------------------------------------------------------------------------
# lists

class DATAPIPE_UL_objects(UIList):
    """Object entries: name (or file stem), instances min-max, scale."""

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0):
        if item.source == "BOP":
            folder = Path(item.bop_models.rstrip("/\\"))
            label = item.name or (f"BOP {folder.parent.name or folder.name} {item.bop_obj_ids or 'all'}"
                                  if item.bop_models else "(no BOP folder)")
        elif item.source == "SHAPE":
            label = item.name or "shape"
        else:
            label = item.name or (Path(item.filepath).stem if item.filepath else "(no file)")
        row = layout.row(align=True)
        row.label(text=f"{index + 1}. {label}", icon="MESH_DATA")
        row.label(text=f"{item.min_instances}-{item.max_instances}x")


class DATAPIPE_UL_poses(UIList):
    """Camera poses: index and location."""

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0):
        x, y, z = item.location
        layout.label(text=f"{index + 1}.  ({x:.3f}, {y:.3f}, {z:.3f}) m", icon="CAMERA_DATA")


def _list_buttons(col, add: str, remove: str, move: str) -> None:
    col.operator(add, icon="ADD", text="")
    col.operator(remove, icon="REMOVE", text="")
    col.separator()
    col.operator(move, icon="TRIA_UP", text="").direction = "UP"
    col.operator(move, icon="TRIA_DOWN", text="").direction = "DOWN"


# ------------------------------------------------------------------------------------------------
# panels

def _fields(layout, group, names):
    """A column of `group`'s properties `names`, labels split off (Blender's property-editor look)."""
    col = layout.column()
    col.use_property_split = True
    col.use_property_decorate = False
    for name in names:
        col.prop(group, name)
    return col


class DATAPIPE_PT_initialize(_DataPipePanel, Panel):
    bl_label = "Initialize"
    bl_idname = "DATAPIPE_PT_initialize"
    bl_order = 0

    def draw(self, context):
        layout = self.layout
        props = _props(context)
        col = layout.column(align=True)
        col.prop(props, "preset", text="Preset")
        row = col.row(align=True)
        row.operator("datapipe.initialize", icon="FILE_REFRESH")
        row.operator("datapipe.preset_load_selected", text="Load", icon="IMPORT")
        layout.operator("datapipe.preset_load", text="Load File (JSON / Pickle)...", icon="FILEBROWSER")


class DATAPIPE_PT_scene(_DataPipePanel, Panel):
    bl_label = "Scene"
    bl_idname = "DATAPIPE_PT_scene"
    bl_order = 1

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        s = _props(context).scene
        col = layout.column(align=True)
        col.prop(s, "num_renders")
        col.prop(s, "min_renders_per_scene", text="Per Scene Min")
        col.prop(s, "max_renders_per_scene", text="Max")
        layout.prop(s, "seed")
        box = layout.box()
        box.label(text="Drop Zone", icon="CUBE")
        box.prop(s, "drop_zone_loc", text="Location")
        box.prop(s, "drop_zone_scale", text="Half Size")
        row = box.row(align=True)
        row.operator("datapipe.drop_zone_place", text="Place", icon="IMPORT")
        row.operator("datapipe.drop_zone_read", text="Read Back", icon="EXPORT")
        col = layout.column()
        col.prop(s, "make_bin")
        sub = col.column()
        sub.active = s.make_bin
        sub.prop(s, "bin_wall_thickness")
        _draw_ranges(sub, s, (("bin_size_scale", "Size Scale"), ("bin_wall_scale", "Wall Scale")))
        col.prop(s, "bin_material")
        col = layout.column()
        col.prop(s, "use_fill")
        sub = col.column()
        sub.active = s.use_fill
        _draw_ranges(sub, s, (("fill", "Fill"),))
        col = layout.column()
        col.prop(s, "use_picks")
        sub = col.column(align=True)
        sub.active = s.use_picks
        sub.prop(s, "picks_per_step")
        sub.prop(s, "picks_order")
        sub.prop(s, "picks_until")
        layout.prop(s, "blend_file")
        layout.prop(s, "other_objects")


def _draw_ranges(col, grp, names) -> None:
    """[min, max] vector properties as two aligned rows each."""
    for name, label in names:
        sub = col.column(align=True)
        sub.prop(grp, name, index=0, text=f"{label} Min")
        sub.prop(grp, name, index=1, text="Max")


class DATAPIPE_PT_lighting(_DataPipePanel, Panel):
    bl_label = "Lighting"
    bl_idname = "DATAPIPE_PT_lighting"
    bl_parent_id = "DATAPIPE_PT_scene"
    bl_options = {"DEFAULT_CLOSED"}

    def draw_header(self, context):
        self.layout.prop(_props(context).lighting, "enabled", text="")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        li = _props(context).lighting
        col = layout.column()
        col.active = li.enabled
        _draw_ranges(col, li, (("key_power", "Key Power"), ("key_color_temperature", "Temperature (K)"),
                               ("key_size", "Key Size")))
        col.prop(li, "key_position_jitter")
        _draw_ranges(col, li, (("ambient", "Ambient"),))
        col.prop(li, "per_render")
        col.prop(li, "environment")
        sub = col.column()
        sub.active = bool(li.environment)
        _draw_ranges(sub, li, (("environment_strength", "Env. Strength"),
                               ("environment_rotation_deg", "Env. Rotation (deg)")))


class DATAPIPE_PT_textures(_DataPipePanel, Panel):
    bl_label = "Textures"
    bl_idname = "DATAPIPE_PT_textures"
    bl_parent_id = "DATAPIPE_PT_scene"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        tx = _props(context).scene.textures
        layout.prop(tx, "targets")
        col = layout.column()
        col.active = bool(tx.targets)
        col.prop(tx, "kinds")
        col.prop(tx, "image_folder")
        _draw_ranges(col, tx, (("feature_size", "Feature Size"), ("contrast", "Contrast"), ("albedo", "Albedo"),
                               ("saturation", "Saturation")))


class DATAPIPE_PT_simulation(_DataPipePanel, Panel):
    bl_label = "Simulation"
    bl_idname = "DATAPIPE_PT_simulation"
    bl_parent_id = "DATAPIPE_PT_scene"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        m = _props(context).simulation
        col = layout.column(align=True)
        for name in ("substeps", "max_substeps", "solver_iterations", "max_frames", "settle_speed", "settle_frames",
                     "layer_gap", "redraw_lost_share", "redraw_attempts"):
            col.prop(m, name)


class DATAPIPE_PT_objects(_DataPipePanel, Panel):
    bl_label = "Objects"
    bl_idname = "DATAPIPE_PT_objects"
    bl_order = 2

    def draw(self, context):
        layout = self.layout
        props = _props(context)
        row = layout.row()
        row.template_list("DATAPIPE_UL_objects", "", props, "objects", props, "objects_index", rows=3)
        _list_buttons(row.column(align=True), "datapipe.object_add", "datapipe.object_remove",
                      "datapipe.object_move")
        on = preview.is_on("object")
        layout.operator("datapipe.object_preview", text="Hide Preview" if on else "Preview Selected",
                        icon="HIDE_OFF" if on else "HIDE_ON", depress=on)
        if not 0 <= props.objects_index < len(props.objects):
            layout.label(text="Add an object entry (a mesh file)", icon="INFO")
            return
        item = props.objects[props.objects_index]
        layout.row().prop(item, "source", expand=True)
        if item.source == "BOP":       # mm -> m and the ids come from the folder
            col = _fields(layout, item, ("bop_models", "bop_obj_ids", "name", "mass", "collision_shape"))
        elif item.source == "SHAPE":   # a distractor: no model, exact collision (datapipe/shapes.py)
            col = _fields(layout, item, ("shape", "name", "scale", "mass"))
        else:
            col = _fields(layout, item, ("filepath", "name", "scale", "obj_id", "mass", "collision_shape"))
        sub = col.column(align=True)
        sub.prop(item, "min_instances", text="Instances Min")
        sub.prop(item, "max_instances", text="Max")
        sub = col.column(align=True)
        sub.prop(item, "friction")
        sub.prop(item, "restitution")
        col.prop(item, "material")
        col.prop(item, "annotate")
        if item.annotate and item.source != "SHAPE":
            col.prop(item, "symmetries")
        if item.source != "SHAPE":
            col.prop(item, "origin")


class DATAPIPE_PT_camera(_DataPipePanel, Panel):
    bl_label = "Camera"
    bl_idname = "DATAPIPE_PT_camera"
    bl_order = 3

    def draw(self, context):
        layout = self.layout
        cam = _props(context).camera
        col = _fields(layout, cam, ("focal_length", "sensor_width", "sensor_fit"))
        sub = col.column(align=True)
        sub.prop(cam, "resolution", index=0, text="Resolution X")
        sub.prop(cam, "resolution", index=1, text="Y")
        sub = col.column(align=True)
        sub.prop(cam, "clip_start")
        sub.prop(cam, "clip_end", text="End")
        for name in ("intrinsics", "distortion"):         # a calibrated camera (docs/CALIBRATION.md)
            col.prop(cam, f"use_{name}")
            sub = col.column()
            sub.active = getattr(cam, f"use_{name}")
            sub.prop(cam, name)

        on = preview.is_on("camera")
        layout.operator("datapipe.camera_preview", text="Hide Camera" if on else "Preview Camera",
                        icon="HIDE_OFF" if on else "OUTLINER_OB_CAMERA", depress=on)
        sm = cam.sampler
        col = layout.column()
        col.use_property_split = True
        col.use_property_decorate = False
        col.prop(sm, "kind")
        if sm.kind == "bin_view":
            _draw_ranges(col, sm, (("distance", "Distance"), ("tilt_deg", "Tilt (deg)"),
                                   ("azimuth_deg", "Azimuth (deg)"), ("roll_deg", "Roll (deg)")))
            col.prop(sm, "target_jitter")
            return
        layout.label(text=f"Poses ({len(cam.poses)})")
        row = layout.row()
        row.template_list("DATAPIPE_UL_poses", "", cam, "poses", cam, "poses_index", rows=3)
        _list_buttons(row.column(align=True), "datapipe.pose_add", "datapipe.pose_remove", "datapipe.pose_move")
        row = layout.row(align=True)
        row.operator("datapipe.pose_add", text="Add Current Pose", icon="ADD")
        row.operator("datapipe.pose_jump", text="Jump to Pose", icon="VIEW_CAMERA")
        if 0 <= cam.poses_index < len(cam.poses):
            pose = cam.poses[cam.poses_index]
            box = layout.box()
            box.use_property_split = True
            box.prop(pose, "location")
            box.prop(pose, "rotation")


class DATAPIPE_PT_structured_light(_DataPipePanel, Panel):
    bl_label = "Structured Light"
    bl_idname = "DATAPIPE_PT_structured_light"
    bl_order = 4

    def draw_header(self, context):
        self.layout.prop(_props(context).structured_light, "enabled", text="")

    def draw(self, context):
        layout = self.layout
        props = _props(context)
        sl, pr = props.structured_light, props.projector
        layout.active = sl.enabled
        row = layout.row(align=True)                   # a real scanner fills the fields below
        row.prop(props, "device")
        row.prop(props, "binning", text="Bin")
        col = _fields(layout, sl, ("periods", "steps", "unwrap", "fringe_mode", "samples", "sensor",
                                   "auto_exposure"))
        sub = col.column()
        sub.active = not sl.auto_exposure
        sub.prop(sl, "exposure")
        for name in ("hdr", "reflection_filter", "ambient", "projector_gamma", "debug"):
            col.prop(sl, name)
        box = layout.box()
        box.label(text="Projector", icon="LIGHT_SPOT")
        bcol = _fields(box, pr, ("focal_length", "sensor_width"))
        sub = bcol.column(align=True)
        sub.prop(pr, "resolution", index=0, text="Resolution X")
        sub.prop(pr, "resolution", index=1, text="Y")
        bcol.prop(pr, "use_intrinsics")
        sub = bcol.column()
        sub.active = pr.use_intrinsics
        sub.prop(pr, "intrinsics")
        bcol.prop(pr, "power")
        bcol.label(text="Pose relative to the camera")
        bcol.prop(pr, "location")
        bcol.prop(pr, "rotation_mode")
        if pr.rotation_mode == "QUATERNION":
            bcol.prop(pr, "rotation_quaternion")
        else:
            bcol.prop(pr, "rotation_euler")
        on = preview.is_on("projector")
        row = box.row()
        row.enabled = preview.is_on("camera") or on
        row.operator("datapipe.projector_preview", text="Hide Projector" if on else "Preview Projector",
                     icon="HIDE_OFF" if on else "LIGHT_SPOT", depress=on)


class DATAPIPE_PT_output(_DataPipePanel, Panel):
    bl_label = "Output & Run"
    bl_idname = "DATAPIPE_PT_output"
    bl_order = 5

    def draw(self, context):
        layout = self.layout
        props = _props(context)
        out, r = props.output, props.render
        col = _fields(layout, out, ("path",))
        col.prop(r, "outputs")
        col.prop(out, "formats")
        col.prop(out, "bop_sensor")          # names the scanner's BOP folders (BOP + structured light)
        col.prop(out, "legacy_pickle")
        col.prop(out, "overview")
        sub = col.column(align=True)
        sub.active = "bop" in out.formats          # both go into the BOP export (validate refuses them without)
        sub.prop(out, "xyz_crop")
        sub.prop(out, "amodal_coco")

        box = layout.box()
        box.label(text="Preset", icon="PRESET")
        row = box.row(align=True)
        row.prop(props, "preset_name", text="")
        row.operator("datapipe.preset_save", text="Save", icon="FILE_TICK")
        row = box.row(align=True)
        row.operator("datapipe.preset_save", text="Save As...", icon="FILEBROWSER").browse = True
        row.operator("datapipe.preset_load", text="Load...", icon="IMPORT")

        running = runner.is_running()
        row = layout.row(align=True)
        row.prop(props, "resume")
        row.prop(props, "force")
        layout.operator("datapipe.check", icon="CHECKMARK")
        row = layout.row(align=True)
        row.scale_y = 1.5
        sub = row.row(align=True)
        sub.enabled = not running
        sub.operator("datapipe.run", icon="PLAY")
        sub = row.row(align=True)
        sub.enabled = running
        sub.operator("datapipe.cancel", icon="CANCEL")
        if props.status:
            col = layout.column(align=True)
            if running:
                col.prop(props, "progress", text="Progress", slider=True)
            for line in props.status.splitlines():      # a refusal lists one problem per line
                row = col.row()
                row.alert = props.status.startswith("Error")
                row.label(text=line)
        for line in props.warnings.splitlines():
            layout.label(text=f"Warning: {line}", icon="ERROR")


class DATAPIPE_PT_render(_DataPipePanel, Panel):
    bl_label = "Render Settings"
    bl_idname = "DATAPIPE_PT_render"
    bl_parent_id = "DATAPIPE_PT_output"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        r = _props(context).render
        col = layout.column()
        for name in ("engine", "device", "samples", "sampling_pattern", "adaptive_threshold", "denoise",
                     "denoise_prefilter", "denoise_quality", "persistent_data", "threads", "max_bounces",
                     "light_power"):
            col.prop(r, name)


CLASSES = (
    DATAPIPE_UL_objects,
    DATAPIPE_UL_poses,
    DATAPIPE_PT_initialize,
    DATAPIPE_PT_scene,
    DATAPIPE_PT_lighting,
    DATAPIPE_PT_textures,
    DATAPIPE_PT_simulation,
    DATAPIPE_PT_objects,
    DATAPIPE_PT_camera,
    DATAPIPE_PT_structured_light,
    DATAPIPE_PT_output,
    DATAPIPE_PT_render,
)
