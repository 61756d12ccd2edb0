"""Registration of the sidebar UI and the PropertyGroup tree `Scene.datapipe`."""
import dataclasses

import bpy
import pytest

from datapipe import config as C
import datapipe.ui as ui
from datapipe.ui import props as P
from datapipe.ui.convert import props_to_config


def _registered() -> bool:
    return hasattr(bpy.types.Scene, "datapipe")


@pytest.fixture
def ui_registered():
    was = _registered()
    if not was:
        ui.register()
    yield bpy.context.scene.datapipe
    if not was:
        ui.unregister()


def test_register_unregister_twice():
    was = _registered()
    if was:
        ui.unregister()
    try:
        for _ in range(2):
            ui.register()
            assert _registered()
            assert hasattr(bpy.types, "DATAPIPE_PT_objects")
            assert "run" in dir(bpy.ops.datapipe)
            n = len(bpy.context.scene.datapipe.objects)   # ID properties outlive re-registration
            bpy.ops.datapipe.object_add()
            assert len(bpy.context.scene.datapipe.objects) == n + 1
            ui.unregister()
            assert not _registered()
            assert not hasattr(bpy.types, "DATAPIPE_PT_objects")
            assert "run" not in dir(bpy.ops.datapipe)
    finally:
        if was:
            ui.register()


def test_one_pointer_on_scene(ui_registered):
    ours = [p.identifier for p in bpy.types.Scene.bl_rna.properties if "datapipe" in p.identifier.lower()]
    assert ours == ["datapipe"]
    assert bpy.types.Scene.bl_rna.properties["datapipe"].fixed_type.identifier == "DATAPIPE_PG_root"


def test_class_order_and_names():
    names = [c.__name__ for c in ui.CLASSES]
    assert len(names) == len(set(names))
    assert all(n.startswith("DATAPIPE_") for n in names)
    # property groups before the groups that point to them
    assert names.index("DATAPIPE_PG_pose") < names.index("DATAPIPE_PG_camera") < names.index("DATAPIPE_PG_root")
    assert names.index("DATAPIPE_PT_scene") < names.index("DATAPIPE_PT_simulation")      # parent first
    assert names.index("DATAPIPE_PT_output") < names.index("DATAPIPE_PT_render")


def test_defaults_come_from_the_config(ui_registered):
    cfg = props_to_config(ui_registered)
    expected = C.Config()
    expected.camera.poses = []          # collections start empty in a fresh scene
    # Blender stores floats as float32: -8.5 degrees comes back as -0.14835298 (not ...2986)
    assert cfg.projector.rotation == pytest.approx(expected.projector.rotation, abs=1e-7)
    cfg.projector.rotation = expected.projector.rotation
    assert cfg.to_dict() == expected.to_dict()


def _walk(pg, path=""):
    for prop in pg.bl_rna.properties:
        if prop.identifier == "rna_type":
            continue
        yield f"{path}{prop.identifier}", pg, prop
        if prop.type == "POINTER":
            yield from _walk(getattr(pg, prop.identifier), f"{path}{prop.identifier}.")
        elif prop.type == "COLLECTION":
            item = getattr(pg, prop.identifier).add()
            yield from _walk(item, f"{path}{prop.identifier}[].")


def test_every_property_has_a_tooltip(ui_registered):
    missing = [path for path, pg, prop in _walk(ui_registered)
               if not prop.is_hidden and prop.identifier != "name" and not prop.description]
    assert missing == []


def test_units_and_subtypes(ui_registered):
    def rna(group, name):
        return group.bl_rna.properties[name]
    d = ui_registered
    assert rna(d.scene, "drop_zone_loc").unit == "LENGTH"
    assert rna(d.scene, "drop_zone_scale").unit == "LENGTH"
    assert rna(d.scene, "bin_wall_thickness").unit == "LENGTH"
    item = d.objects.add()
    assert rna(item, "mass").unit == "MASS"
    assert rna(item, "filepath").subtype == "FILE_PATH"
    assert rna(d.camera, "focal_length").unit == "CAMERA"
    assert rna(d.camera, "sensor_width").unit == "CAMERA"
    assert rna(d.camera, "clip_start").unit == "LENGTH"
    assert rna(d.projector, "focal_length").unit == "CAMERA"
    assert rna(d.projector, "rotation_euler").unit == "ROTATION"
    assert rna(d.projector, "rotation_quaternion").subtype == "QUATERNION"
    assert rna(d.projector, "location").unit == "LENGTH"
    assert rna(d.simulation, "settle_speed").unit == "VELOCITY"
    assert rna(d.render, "light_power").unit == "POWER"
    assert rna(d.output, "path").subtype == "DIR_PATH"
    pose = d.camera.poses.add()
    assert rna(pose, "location").unit == "LENGTH"
    assert rna(pose, "rotation").subtype == "QUATERNION"


def test_limits_match_validation(ui_registered):
    d = ui_registered
    assert d.scene.bl_rna.properties["num_renders"].hard_min == 1
    item = d.objects.add()
    assert item.bl_rna.properties["max_instances"].hard_max == 500
    assert d.camera.bl_rna.properties["resolution"].hard_max == C.MAX_RESOLUTION
    assert d.structured_light.bl_rna.properties["steps"].hard_min == 3
    item.mass = -1.0
    assert item.mass > 0                 # clamped: impossible values are unavailable
    item.restitution = 2.0
    assert item.restitution == 1.0


def test_min_max_pairs_stay_ordered(ui_registered):
    s = ui_registered.scene
    s.min_renders_per_scene, s.max_renders_per_scene = 1, 2
    s.min_renders_per_scene = 5
    assert (s.min_renders_per_scene, s.max_renders_per_scene) == (5, 5)
    s.max_renders_per_scene = 3
    assert (s.min_renders_per_scene, s.max_renders_per_scene) == (3, 3)

    item = ui_registered.objects.add()
    item.min_instances, item.max_instances = 1, 2
    item.max_instances = 0
    assert (item.min_instances, item.max_instances) == (0, 0)
    item.min_instances = 7
    assert (item.min_instances, item.max_instances) == (7, 7)

    cam = ui_registered.camera
    cam.clip_start, cam.clip_end = 0.1, 10.0
    cam.clip_start = 20.0
    assert cam.clip_end > cam.clip_start
    cam.clip_end = 1.0
    assert cam.clip_start < cam.clip_end


def test_periods_text_accepts_only_valid_lists(ui_registered):
    sl = ui_registered.structured_light
    sl.periods = "[8; 7]"
    assert sl.periods == "8, 7"
    sl.periods = "8, zero"
    assert sl.periods == "8, 7"          # invalid text is refused, the last valid list stays
    sl.periods = "0, 4"
    assert sl.periods == "8, 7"
    assert props_to_config(ui_registered).structured_light.periods == [8, 7]


def test_formats_never_empty(ui_registered):
    out = ui_registered.output
    out.formats = set()
    assert out.formats == {"native"}


def test_projector_rotation_representations_agree(ui_registered):
    pr = ui_registered.projector
    pr.rotation_mode = "XYZ"
    pr.rotation_euler = (0.1, -0.2, 0.3)
    pr.rotation_mode = "QUATERNION"
    q = props_to_config(ui_registered).projector.rotation
    assert len(q) == 4
    pr.rotation_mode = "XYZ"
    e = props_to_config(ui_registered).projector.rotation
    assert e == pytest.approx([0.1, -0.2, 0.3], abs=1e-6)


def test_every_config_field_has_a_property(ui_registered):
    """The converter maps by name: each dataclass field must have a same-named property (or a special case)."""
    from datapipe.ui import convert
    for section in convert.SECTIONS:
        group = getattr(ui_registered, section)
        for f in dataclasses.fields(type(getattr(C.Config(), section))):
            key = (section, f.name)
            if key in convert._COLLECTIONS or key in convert._SPECIAL:
                continue
            assert f.name in group.bl_rna.properties, key
    for dc, pg in ((C.ObjectEntry, P.DATAPIPE_PG_object), (C.CameraPose, P.DATAPIPE_PG_pose),
                   (C.LightingConfig, P.DATAPIPE_PG_lighting)):
        for f in dataclasses.fields(dc):
            assert f.name in pg.bl_rna.properties, (dc.__name__, f.name)
    for (section, name), dc in convert._NESTED.items():          # sub-groups (camera.sampler, scene.textures)
        group = getattr(getattr(ui_registered, section), name)
        for f in dataclasses.fields(dc):
            assert f.name in group.bl_rna.properties, (section, name, f.name)


def test_sensor_field_suggests_presets(ui_registered):
    from datapipe.sl.sensor import PRESETS
    from datapipe.ui.props.structured_light import _sensor_search
    assert _sensor_search(None, None, "") == sorted(PRESETS)
    assert all("ind" in name for name in _sensor_search(None, None, "IND"))
    assert ui_registered.structured_light.sensor == C.StructuredLightConfig().sensor


def test_textures_and_environment_survive_the_sidebar(ui_registered, tmp_path):
    """scene.textures and the lighting's per_render / environment fields go to the properties and
    come back unchanged (ranges as float32, as every range field)."""
    from datapipe.ui.convert import config_to_props
    cfg = C.default_config()
    cfg.scene.textures = C.TexturesConfig(targets=["bin", "parts"], kinds=["wave", "image"],
                                          image_folder=str(tmp_path), feature_size=[0.01, 0.02],
                                          contrast=[0.25, 0.5], albedo=[0.5, 0.75], saturation=[0.0, 0.5])
    cfg.lighting = C.LightingConfig(per_render=True, environment=str(tmp_path / "sky.hdr"),
                                    environment_strength=[0.5, 2.0], environment_rotation_deg=[0.0, 90.0])
    config_to_props(cfg, ui_registered)
    back = props_to_config(ui_registered)
    t = back.scene.textures
    assert (t.targets, t.kinds, t.image_folder) == (["bin", "parts"], ["wave", "image"], str(tmp_path))
    assert t.feature_size == pytest.approx([0.01, 0.02], rel=1e-6)
    assert t.contrast == pytest.approx([0.25, 0.5]) and t.albedo == pytest.approx([0.5, 0.75])
    li = back.lighting
    assert li.per_render is True and li.environment == str(tmp_path / "sky.hdr")
    assert li.environment_strength == pytest.approx([0.5, 2.0])
    assert li.environment_rotation_deg == pytest.approx([0, 90])
    config_to_props(C.default_config(), ui_registered)               # off again: no targets, no lighting
    assert props_to_config(ui_registered).scene.textures.targets == []
