"""Every panel's draw() (and header, and UI list rows) against the registered properties, with a
recording stand-in for `layout`: each property path it references must exist, each operator it
shows must be registered, and each operator property it sets must exist on that operator."""
import types

import bpy
import pytest

import datapipe.ui as ui
from datapipe.ui import panels, preview


class Problems(list):
    pass


class OpProps:
    """What layout.operator() returns: records property assignments and checks them."""

    def __init__(self, idname, problems):
        object.__setattr__(self, "_idname", idname)
        object.__setattr__(self, "_problems", problems)

    def __setattr__(self, key, value):
        mod, name = self._idname.split(".")
        props = getattr(getattr(bpy.ops, mod), name).get_rna_type().properties
        if key not in props:
            self._problems.append(f"operator {self._idname} has no property {key!r}")


class Layout:
    """Records calls; every container method returns another recorder."""

    def __init__(self, log, problems):
        object.__setattr__(self, "_log", log)
        object.__setattr__(self, "_problems", problems)

    def __setattr__(self, key, value):          # layout.enabled = ..., use_property_split = ...
        if key not in ("enabled", "active", "alert", "scale_x", "scale_y", "use_property_split",
                       "use_property_decorate", "alignment", "operator_context", "emboss"):
            self._problems.append(f"unknown layout attribute {key!r}")

    def _child(self):
        return Layout(self._log, self._problems)

    # containers
    def row(self, **kw): return self._child()
    def column(self, **kw): return self._child()
    def box(self): return self._child()
    def split(self, **kw): return self._child()
    def grid_flow(self, **kw): return self._child()
    def column_flow(self, **kw): return self._child()

    # leaves
    def label(self, *, text="", icon="NONE", **kw):
        self._check_icon(icon)
        self._log.append(("label", text))

    def separator(self, **kw):
        pass

    def prop(self, data, prop, **kw):
        self._log.append(("prop", data, prop))
        self._check_icon(kw.get("icon", "NONE"))
        if prop not in data.bl_rna.properties:
            self._problems.append(f"{data.bl_rna.identifier} has no property {prop!r}")
            return
        p = data.bl_rna.properties[prop]
        if "index" in kw and kw["index"] >= 0:
            if not getattr(p, "is_array", False) or kw["index"] >= p.array_length:
                self._problems.append(f"{prop}: index {kw['index']} out of range")
        unknown = set(kw) - {"text", "icon", "index", "expand", "slider", "toggle", "emboss", "icon_only",
                             "text_ctxt", "invert_checkbox", "full_event", "placeholder"}
        if unknown:
            self._problems.append(f"prop(): unknown keywords {unknown}")

    def operator(self, idname, **kw):
        self._log.append(("operator", idname))
        self._check_icon(kw.get("icon", "NONE"))
        mod, _, name = idname.partition(".")
        if name not in dir(getattr(bpy.ops, mod)):
            self._problems.append(f"operator {idname} is not registered")
        return OpProps(idname, self._problems)

    def template_list(self, listtype, list_id, dataptr, propname, active_dataptr, active_propname, **kw):
        self._log.append(("template_list", listtype, propname))
        if not hasattr(bpy.types, listtype):
            self._problems.append(f"UIList {listtype} is not registered")
        if propname not in dataptr.bl_rna.properties or dataptr.bl_rna.properties[propname].type != "COLLECTION":
            self._problems.append(f"{propname} is not a collection")
        if active_propname not in active_dataptr.bl_rna.properties:
            self._problems.append(f"no active index property {active_propname}")

    def menu(self, *a, **kw):
        self._problems.append("menu() not expected")

    def _check_icon(self, icon):
        icons = bpy.types.UILayout.bl_rna.functions["label"].parameters["icon"].enum_items.keys()
        if icon not in icons:
            self._problems.append(f"unknown icon {icon!r}")


@pytest.fixture(autouse=True)
def d(ui_props):
    return ui_props


PANELS = [c for c in panels.CLASSES if issubclass(c, bpy.types.Panel)]
LISTS = [c for c in panels.CLASSES if issubclass(c, bpy.types.UIList)]


def draw_all(context):
    log, problems = [], Problems()
    for cls in PANELS:
        assert cls.bl_space_type == "VIEW_3D" and cls.bl_region_type == "UI" and cls.bl_category == "DataPipe"
        assert cls.poll(context)
        for fn in ("draw_header", "draw"):
            if hasattr(cls, fn):
                getattr(cls, fn)(types.SimpleNamespace(layout=Layout(log, problems)), context)
    d = context.scene.datapipe
    for cls, data, coll in ((panels.DATAPIPE_UL_objects, d, d.objects),
                            (panels.DATAPIPE_UL_poses, d.camera, d.camera.poses)):
        for i, item in enumerate(coll):
            cls.draw_item(None, context, Layout(log, problems), data, item, 0, data, "", i)
    return log, problems


def test_panels_exist():
    labels = {c.bl_label for c in PANELS}
    assert {"Initialize", "Scene", "Objects", "Camera", "Structured Light", "Output & Run"} <= labels
    for cls in PANELS:
        assert hasattr(bpy.types, cls.__name__)


def test_draw_empty(d):
    log, problems = draw_all(bpy.context)
    assert problems == []
    assert ("template_list", "DATAPIPE_UL_objects", "objects") in log


@pytest.mark.parametrize("mode", ["XYZ", "QUATERNION"])
def test_draw_filled_with_previews_and_status(d, mode):
    bpy.ops.datapipe.initialize(preset="builtin:thesis_sensor")
    d.projector.rotation_mode = mode
    bpy.ops.datapipe.pose_jump(index=1)
    bpy.ops.datapipe.projector_preview()
    d.status = "Error: something"
    log, problems = draw_all(bpy.context)
    assert problems == []
    drawn = {(type(e[1]).__name__ if e[0] == "prop" else None, e[2]) for e in log if e[0] == "prop"}
    # every Config-facing property of each group is drawn somewhere
    # (an object entry shows the fields of its Source: a mesh file's here, test_ui_bop.py the BOP ones)
    for group, skip in ((d.scene, {"textures"}), (d.scene.textures, set()), (d.lighting, set()),
                        (d.camera, {"poses", "poses_index", "sampler"}),
                        (d.objects[0], {"bop_models", "bop_obj_ids", "shape"}),
                        (d.structured_light, {"periods_text", "hdr_text"}), (d.render, set()), (d.simulation, set()),
                        (d.output, set()),
                        (d.projector, {"rotation_quaternion"} if mode == "XYZ" else {"rotation_euler"})):
        names = {p.identifier for p in group.bl_rna.properties} - {"rna_type", "name"} - skip
        if group == d.objects[0]:
            names.add("name")
        missing = {n for n in names if (type(group).__name__, n) not in drawn}
        assert missing == set(), (type(group).__name__, missing)
    ops = {e[1] for e in log if e[0] == "operator"}
    assert {"datapipe.run", "datapipe.cancel", "datapipe.preset_save", "datapipe.preset_load",
            "datapipe.object_preview", "datapipe.camera_preview", "datapipe.projector_preview",
            "datapipe.pose_add", "datapipe.pose_jump", "datapipe.drop_zone_place", "datapipe.drop_zone_read",
            "datapipe.initialize"} <= ops
    preview.remove_all()


def test_shape_source_draws_the_shape_and_annotate(d):
    """Source Shape (a procedural distractor) shows its JSON and the Annotate switch, not a file."""
    bpy.ops.datapipe.initialize(preset="builtin:distractors")
    d.objects_index = next(k for k, o in enumerate(d.objects) if o.source == "SHAPE")
    item = d.objects[d.objects_index]
    assert not item.annotate
    log, problems = draw_all(bpy.context)
    assert problems == []
    drawn = {e[2] for e in log if e[0] == "prop" and type(e[1]).__name__ == "DATAPIPE_PG_object"}
    assert {"shape", "annotate", "mass", "min_instances", "material"} <= drawn
    assert not drawn & {"filepath", "bop_models", "symmetries", "collision_shape"}


def test_sampler_and_lighting_ranges_drawn(d):
    """bin_view shows every sampler range instead of the pose list; the Lighting sub-panel every
    lighting range and its switch."""
    bpy.ops.datapipe.initialize(preset="builtin:default")
    d.camera.sampler.kind = "bin_view"
    d.lighting.enabled = True
    log, problems = draw_all(bpy.context)
    assert problems == []
    drawn = {(type(e[1]).__name__, e[2]) for e in log if e[0] == "prop"}
    for group in (d.camera.sampler, d.lighting):
        names = {p.identifier for p in group.bl_rna.properties} - {"rna_type", "name"}
        assert {n for n in names if (type(group).__name__, n) not in drawn} == set()
    assert ("template_list", "DATAPIPE_UL_poses", "poses") not in log
    d.camera.sampler.tilt_deg = (30.0, 10.0)          # an inverted range is put in order
    assert tuple(d.camera.sampler.tilt_deg) == (10.0, 30.0)
