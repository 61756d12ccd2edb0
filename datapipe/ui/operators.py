"""Sidebar operators. Thin: read the properties through `convert.props_to_config`, call core (or the
small viewport helpers in `preview`), and turn `ConfigError` / `DataPipeError` into
`self.report({'ERROR'}, ...)` - never a traceback for a user mistake. (Under `bpy.ops` an ERROR
report raises `RuntimeError("Error: ...")` to the caller, which the tests rely on.)
"""

import functools
from pathlib import Path

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty
from bpy.types import Operator

from .. import config as C
from ..errors import ConfigError, DataPipeError
from . import presets, preview, runner
from .convert import config_to_props, props_to_config


def _props(context):
    return context.scene.datapipe


def user_errors(fn):
    """Report ConfigError/DataPipeError as one ERROR (every problem, each naming its field)."""
    @functools.wraps(fn)
    def wrapper(self, context, *args):
        try:
            return fn(self, context, *args)
        except ConfigError as e:
            self.report({"ERROR"}, str(e))
        except DataPipeError as e:
            self.report({"ERROR"}, str(e))
        return {"CANCELLED"}
    return wrapper


def _check_bounds(collection, index: int, what: str) -> None:
    if not 0 <= index < len(collection):
        raise DataPipeError(f"{what}: nothing selected (fix: select an entry in the list)")


# ------------------------------------------------------------------------------------------------
# Initialize / presets

_PRESET_FILTER = "*.json;*.pickle;*.pkl"


def _load_into(context, path) -> C.Config:
    """Load a preset (JSON or original pickle) and fill the panels. Problems that make the preset
    unusable (min > max, unknown choices) are refused; missing mesh files only warn, so a preset
    from another machine can be loaded and its paths fixed."""
    cfg = presets.load(path)
    cfg.validate(check_files=False)
    props = _props(context)
    config_to_props(cfg, props)
    if not presets.is_builtin(path):
        props.preset_name = Path(path).stem       # Save then writes back to the same preset
    preview.remove("object")
    if preview.is_on("camera"):
        preview.show_camera(context, _props(context))
    return cfg


def _missing_files_warning(op, cfg: C.Config) -> None:
    problems = [p for p in cfg.problems(check_files=True) if "not found" in p.message]
    if problems:
        op.report({"WARNING"}, "; ".join(str(p) for p in problems))


class DATAPIPE_OT_initialize(Operator):
    """Set up the scene for DataPipe (metric units, Cycles) and fill the panels from the chosen preset"""
    bl_idname = "datapipe.initialize"
    bl_label = "Initialize"
    bl_options = {"REGISTER", "UNDO"}

    preset: StringProperty(name="Preset", description="Preset to start from ('builtin:default', 'user:NAME' or a "
                           "name); empty: the one selected in the panel", default="")

    @user_errors
    def execute(self, context):
        props = _props(context)
        ident = self.preset or props.preset or "builtin:default"
        if ident == "NONE":
            ident = "builtin:default"
        path = presets.resolve(ident)
        scene = context.scene
        us = scene.unit_settings
        us.system, us.scale_length, us.length_unit = "METRIC", 1.0, "METERS"
        scene.render.engine = "CYCLES"
        cfg = _load_into(context, path)
        _missing_files_warning(self, cfg)
        self.report({"INFO"}, f"DataPipe initialized from preset {path.stem}")
        return {"FINISHED"}


class DATAPIPE_OT_preset_load(Operator):
    """Load a preset (JSON, or an original DataPipe inputs pickle) into the panels"""
    bl_idname = "datapipe.preset_load"
    bl_label = "Load Preset"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(name="File", subtype="FILE_PATH", default="",
                             description="Preset file; empty: the preset selected in the panel")
    filter_glob: StringProperty(default=_PRESET_FILTER, options={"HIDDEN"})

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    @user_errors
    def execute(self, context):
        if self.filepath:
            path = Path(bpy.path.abspath(self.filepath))
        else:
            path = presets.resolve(_props(context).preset)
        cfg = _load_into(context, path)
        _missing_files_warning(self, cfg)
        self.report({"INFO"}, f"Loaded preset {path}")
        return {"FINISHED"}


class DATAPIPE_OT_preset_load_selected(Operator):
    """Load the preset selected in the list into the panels"""
    bl_idname = "datapipe.preset_load_selected"
    bl_label = "Load Selected Preset"
    bl_options = {"REGISTER", "UNDO"}

    @user_errors
    def execute(self, context):
        path = presets.resolve(_props(context).preset)
        cfg = _load_into(context, path)
        _missing_files_warning(self, cfg)
        self.report({"INFO"}, f"Loaded preset {path.stem}")
        return {"FINISHED"}


class DATAPIPE_OT_preset_save(Operator):
    """Save the panels as a JSON preset (exactly what `python -m datapipe run PRESET.json` reads)"""
    bl_idname = "datapipe.preset_save"
    bl_label = "Save Preset"

    filepath: StringProperty(name="File", subtype="FILE_PATH", default="", options={"SKIP_SAVE"},
                             description="Where to save; empty: <user presets>/<name>.json")
    name: StringProperty(name="Name", default="", options={"SKIP_SAVE"},
                         description="Preset name (user presets folder); empty: the Preset Name field")
    browse: BoolProperty(name="Choose File", default=False, options={"SKIP_SAVE", "HIDDEN"},
                         description="Pick the file in the file browser")
    filter_glob: StringProperty(default="*.json", options={"HIDDEN"})

    def invoke(self, context, event):
        if not self.browse:
            return self.execute(context)
        if not self.filepath:
            try:
                self.filepath = str(presets.user_dir() / f"{_props(context).preset_name}.json")
            except OSError:
                self.filepath = f"{_props(context).preset_name}.json"
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    @user_errors
    def execute(self, context):
        props = _props(context)
        path = presets.save_path_for(self.name or props.preset_name, self.filepath)
        cfg = props_to_config(props)
        presets.save(cfg, path)
        problems = cfg.problems(check_files=True)
        if problems:
            self.report({"WARNING"}, f"Saved {path}, but a run would refuse it: " + "; ".join(map(str, problems)))
        else:
            self.report({"INFO"}, f"Saved preset {path}")
        ident = f"user:{path.stem}"
        if path.parent == presets.user_dir(create=False) and any(i[0] == ident for i in presets.enum_items()):
            props.preset = ident
        return {"FINISHED"}


# ------------------------------------------------------------------------------------------------
# Scene: drop zone

class DATAPIPE_OT_drop_zone_place(Operator):
    """Create (or move) the wire cube 'drop_zone' from the drop zone location and half size"""
    bl_idname = "datapipe.drop_zone_place"
    bl_label = "Place Drop Zone"
    bl_options = {"REGISTER", "UNDO"}

    @user_errors
    def execute(self, context):
        preview.place_drop_zone(context, _props(context))
        return {"FINISHED"}


class DATAPIPE_OT_drop_zone_read(Operator):
    """Read the drop zone location and half size back from the object 'drop_zone' (its world bounds)"""
    bl_idname = "datapipe.drop_zone_read"
    bl_label = "Read Drop Zone"
    bl_options = {"REGISTER", "UNDO"}

    @user_errors
    def execute(self, context):
        centre, half, rotated = preview.read_drop_zone(_props(context))
        if rotated:
            self.report({"WARNING"}, "drop_zone is rotated: its axis-aligned world bounds were used")
        return {"FINISHED"}


# ------------------------------------------------------------------------------------------------
# Objects

class DATAPIPE_OT_object_add(Operator):
    """Add an object entry (a mesh file)"""
    bl_idname = "datapipe.object_add"
    bl_label = "Add Object"
    bl_options = {"REGISTER", "UNDO"}

    filepath: StringProperty(name="File", subtype="FILE_PATH", default="",
                             description="Mesh file of the new entry (may be set later)")
    filter_glob: StringProperty(default=";".join(f"*{s}" for s in C.MESH_SUFFIXES), options={"HIDDEN"})

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        props = _props(context)
        entry = props.objects.add()           # every field starts at the ObjectEntry default
        if self.filepath:
            entry.filepath = self.filepath
        props.objects_index = len(props.objects) - 1
        return {"FINISHED"}


class DATAPIPE_OT_object_remove(Operator):
    """Remove the selected object entry"""
    bl_idname = "datapipe.object_remove"
    bl_label = "Remove Object"
    bl_options = {"REGISTER", "UNDO"}

    @user_errors
    def execute(self, context):
        props = _props(context)
        _check_bounds(props.objects, props.objects_index, "objects")
        preview.remove("object")
        props.objects.remove(props.objects_index)
        props.objects_index = max(0, min(props.objects_index, len(props.objects) - 1))
        return {"FINISHED"}


_DIRECTIONS = [("UP", "Up", "Move up"), ("DOWN", "Down", "Move down")]


def _move(collection, index: int, direction: str) -> int:
    new = index - 1 if direction == "UP" else index + 1
    if 0 <= new < len(collection):
        collection.move(index, new)
        return new
    return index


class DATAPIPE_OT_object_move(Operator):
    """Move the selected object entry up or down (the order is the object id in the dataset)"""
    bl_idname = "datapipe.object_move"
    bl_label = "Move Object"
    bl_options = {"REGISTER", "UNDO"}

    direction: EnumProperty(items=_DIRECTIONS, name="Direction")

    @user_errors
    def execute(self, context):
        props = _props(context)
        _check_bounds(props.objects, props.objects_index, "objects")
        old = props.objects_index
        props.objects_index = _move(props.objects, old, self.direction)
        for o in preview.tagged("object"):     # the preview follows its entry
            if o.get("datapipe_entry") == old:
                o["datapipe_entry"] = props.objects_index
            elif o.get("datapipe_entry") == props.objects_index:
                o["datapipe_entry"] = old
        return {"FINISHED"}


class DATAPIPE_OT_object_preview(Operator):
    """Show or hide the selected object entry in the viewport at its scale (collection 'datapipe_preview')"""
    bl_idname = "datapipe.object_preview"
    bl_label = "Preview Object"
    bl_options = {"REGISTER", "UNDO"}

    @user_errors
    def execute(self, context):
        if preview.is_on("object"):
            preview.remove("object")
        else:
            props = _props(context)
            preview.show_object(context, props, props.objects_index)
        return {"FINISHED"}


# ------------------------------------------------------------------------------------------------
# Camera

class DATAPIPE_OT_camera_preview(Operator):
    """Show or hide a preview camera with the camera intrinsics, at the selected pose"""
    bl_idname = "datapipe.camera_preview"
    bl_label = "Preview Camera"
    bl_options = {"REGISTER", "UNDO"}

    @user_errors
    def execute(self, context):
        if preview.is_on("camera"):
            preview.remove("camera")
        else:
            preview.show_camera(context, _props(context))
        return {"FINISHED"}


class DATAPIPE_OT_pose_add(Operator):
    """Append the preview camera's current pose (world location + quaternion w, x, y, z) to the pose list"""
    bl_idname = "datapipe.pose_add"
    bl_label = "Add Pose"
    bl_options = {"REGISTER", "UNDO"}

    @user_errors
    def execute(self, context):
        cam = preview.camera_object()
        if cam is None:
            raise DataPipeError("camera.poses: the camera preview is off (fix: turn on Preview Camera, move it "
                                "where a render should be taken, then click Add Pose)")
        context.view_layer.update()
        pose = preview.camera_pose(cam)
        props = _props(context)
        item = props.camera.poses.add()
        item.location = pose.location
        item.rotation = pose.rotation
        props.camera.poses_index = len(props.camera.poses) - 1
        return {"FINISHED"}


class DATAPIPE_OT_pose_remove(Operator):
    """Remove the selected camera pose"""
    bl_idname = "datapipe.pose_remove"
    bl_label = "Remove Pose"
    bl_options = {"REGISTER", "UNDO"}

    @user_errors
    def execute(self, context):
        cam = _props(context).camera
        _check_bounds(cam.poses, cam.poses_index, "camera.poses")
        cam.poses.remove(cam.poses_index)
        cam.poses_index = max(0, min(cam.poses_index, len(cam.poses) - 1))
        return {"FINISHED"}


class DATAPIPE_OT_pose_move(Operator):
    """Move the selected camera pose up or down"""
    bl_idname = "datapipe.pose_move"
    bl_label = "Move Pose"
    bl_options = {"REGISTER", "UNDO"}

    direction: EnumProperty(items=_DIRECTIONS, name="Direction")

    @user_errors
    def execute(self, context):
        cam = _props(context).camera
        _check_bounds(cam.poses, cam.poses_index, "camera.poses")
        cam.poses_index = _move(cam.poses, cam.poses_index, self.direction)
        return {"FINISHED"}


class DATAPIPE_OT_pose_jump(Operator):
    """Move the preview camera to the selected pose (turns the camera preview on)"""
    bl_idname = "datapipe.pose_jump"
    bl_label = "Jump to Pose"
    bl_options = {"REGISTER", "UNDO"}

    index: IntProperty(name="Pose", default=-1, min=-1, description="Pose to jump to; -1: the selected one")

    @user_errors
    def execute(self, context):
        props = _props(context)
        cam = props.camera
        if self.index >= 0:
            _check_bounds(cam.poses, self.index, "camera.poses")
            cam.poses_index = self.index
        _check_bounds(cam.poses, cam.poses_index, "camera.poses")
        pose = props_to_config(props).camera.poses[cam.poses_index]
        preview.show_camera(context, props, pose)
        return {"FINISHED"}


# ------------------------------------------------------------------------------------------------
# Structured light

class DATAPIPE_OT_projector_preview(Operator):
    """Show or hide the projector (a spot light parented to the preview camera, at the projector pose)"""
    bl_idname = "datapipe.projector_preview"
    bl_label = "Preview Projector"
    bl_options = {"REGISTER", "UNDO"}

    @user_errors
    def execute(self, context):
        if preview.is_on("projector"):
            preview.remove("projector")
        else:
            preview.show_projector(context, _props(context))
        return {"FINISHED"}


# ------------------------------------------------------------------------------------------------
# Output & Run

def _output_dir(cfg: C.Config) -> Path:
    """The output folder: '//' is relative to the .blend; other relative paths too when the file is saved
    (else to the working directory, as on the command line)."""
    path = cfg.output.path
    if path.startswith("//"):
        path = bpy.path.abspath(path)
    p = Path(path).expanduser()
    if not p.is_absolute() and bpy.data.filepath:
        p = Path(bpy.data.filepath).parent / p
    return p


def _gate(op, context, pipeline) -> None:
    """The pipeline's check (datapipe/engine/gate.py, what `datapipe run` goes through), its outcome
    shown in the panel with the CLI's text: the refusal as the status, each warning as a line and
    as a WARNING report."""
    props = _props(context)
    props.warnings = ""
    try:
        report = pipeline.check()
    except DataPipeError as e:
        props.status = f"Error: {e}"
        raise
    props.warnings = "\n".join(report.warnings)
    for w in report.warnings:
        op.report({"WARNING"}, w)


class DATAPIPE_OT_check(Operator):
    """Check the settings as a run would (every problem at once, each naming its field)"""
    bl_idname = "datapipe.check"
    bl_label = "Check Settings"

    @user_errors
    def execute(self, context):
        from ..engine.pipeline import Pipeline
        props = _props(context)
        cfg = props_to_config(props)
        _gate(self, context, Pipeline(cfg, _output_dir(cfg), resume=props.resume, force=props.force))
        props.status = "Settings OK: ready to run"
        self.report({"INFO"}, props.status)
        return {"FINISHED"}


class DATAPIPE_OT_run(Operator):
    """Run the pipeline with these settings. In the UI it runs step by step (Cancel stops after the current
    render, keeping everything written); in background mode it runs to the end before returning"""
    bl_idname = "datapipe.run"
    bl_label = "Run"

    blocking: BoolProperty(name="Blocking", default=False, options={"SKIP_SAVE"},
                           description="Run to the end before returning (always so in background mode, "
                           "where timers never tick)")
    output: StringProperty(name="Output Folder", default="", subtype="DIR_PATH", options={"SKIP_SAVE"},
                           description="Override the output folder (empty: the Output panel's folder)")

    @user_errors
    def execute(self, context):
        from ..engine.pipeline import Pipeline
        props = _props(context)
        if runner.is_running():
            raise DataPipeError("run: a run is already in progress (fix: wait for it or click Cancel)")
        cfg = props_to_config(props)
        blocking = self.blocking or bpy.app.background
        if cfg.scene.blend_file and not bpy.app.background and bpy.data.is_dirty:
            raise DataPipeError("scene.blend_file: a run opens that file in place of the open one, which has "
                                "unsaved changes (fix: save your file first, or run headless)")
        out = Path(bpy.path.abspath(self.output)) if self.output else _output_dir(cfg)
        pipeline = Pipeline(cfg, out, resume=props.resume, force=props.force)
        _gate(self, context, pipeline)      # as `datapipe run`: before the run writes anything
        run = runner.start(pipeline, context.scene.name, blocking=blocking)
        if not blocking:
            self.report({"INFO"}, f"DataPipe run started: {pipeline.total} renders into {pipeline.out}")
            return {"FINISHED"}
        if run.error:
            raise DataPipeError(run.error)
        last = run.last
        if last is not None and last.stage == "cancelled":
            self.report({"WARNING"}, last.line())
        else:
            self.report({"INFO"}, f"DataPipe run finished: {last.done if last else 0}/{pipeline.total} renders "
                        f"in {pipeline.out}")
        return {"FINISHED"}


class DATAPIPE_OT_cancel(Operator):
    """Stop the run after the render in progress; everything written so far is kept (Resume continues)"""
    bl_idname = "datapipe.cancel"
    bl_label = "Cancel"

    @classmethod
    def poll(cls, context):
        return runner.is_running()

    def execute(self, context):
        runner.cancel()
        self.report({"INFO"}, "DataPipe: cancelling after the current render")
        return {"FINISHED"}


CLASSES = (
    DATAPIPE_OT_initialize,
    DATAPIPE_OT_preset_load,
    DATAPIPE_OT_preset_load_selected,
    DATAPIPE_OT_preset_save,
    DATAPIPE_OT_drop_zone_place,
    DATAPIPE_OT_drop_zone_read,
    DATAPIPE_OT_object_add,
    DATAPIPE_OT_object_remove,
    DATAPIPE_OT_object_move,
    DATAPIPE_OT_object_preview,
    DATAPIPE_OT_camera_preview,
    DATAPIPE_OT_pose_add,
    DATAPIPE_OT_pose_remove,
    DATAPIPE_OT_pose_move,
    DATAPIPE_OT_pose_jump,
    DATAPIPE_OT_projector_preview,
    DATAPIPE_OT_check,
    DATAPIPE_OT_run,
    DATAPIPE_OT_cancel,
)
