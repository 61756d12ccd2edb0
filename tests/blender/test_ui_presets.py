"""Config <-> properties conversion and JSON presets (built-in read-only, user folder, legacy pickle)."""
import copy
import json
import math
import pickle

import bpy
import pytest

from datapipe import config as C
from datapipe.errors import ConfigError
import datapipe.ui as ui
from datapipe.ui import presets
from datapipe.ui.convert import config_to_props, f32, props_to_config


@pytest.fixture(autouse=True)
def registered(ui_props):
    return ui_props


def dump(pg, skip=("preset", "status", "progress")):
    """Every property value of a PropertyGroup tree, recursively (the UI's complete state)."""
    out = {}
    for prop in pg.bl_rna.properties:
        k = prop.identifier
        if k == "rna_type" or k in skip:
            continue
        v = getattr(pg, k)
        if prop.type == "POINTER":
            out[k] = dump(v, skip)
        elif prop.type == "COLLECTION":
            out[k] = [dump(item, skip) for item in v]
        elif prop.type == "ENUM" and prop.is_enum_flag:
            out[k] = sorted(v)
        elif getattr(prop, "is_array", False):
            out[k] = list(v)
        else:
            out[k] = v
    return out


def test_f32_shortest_decimal():
    assert f32(0.06) == 0.06
    assert f32(0.1) == 0.1
    assert f32(1 / 3) == float("0.33333334")
    assert f32(f32(0.123456789)) == f32(0.123456789)


@pytest.mark.parametrize("name", ["default", "thesis_sensor", "bin_picking", "bin_picking_25views", "distractors"])
def test_builtin_preset_round_trip(registered, name):
    cfg = C.load(presets.builtin_dir() / f"{name}.json")
    config_to_props(cfg, registered)
    back = props_to_config(registered)
    a, b = cfg.to_dict(), back.to_dict()
    if name != "thesis_sensor":   # math.radians(-8.5), 0.22131444 are not float32s; everything else is exact
        assert b["projector"]["rotation"] == pytest.approx(a["projector"]["rotation"], abs=1e-7)
        b["projector"]["rotation"] = a["projector"]["rotation"]
    assert a == b


def test_sampler_and_lighting_round_trip(registered, tmp_path):
    """bin_view ranges and a lighting section survive config -> sidebar -> config exactly; a config
    without lighting comes back without it (the switch is off)."""
    cfg = C.default_config()
    cfg.projector.rotation = [0.0, -0.15, 0.0]        # radians(-8.5) is not a float32 (see above)
    cfg.scene.bin_size_scale, cfg.scene.bin_wall_scale = [0.75, 1.25], [0.5, 1.5]
    cfg.camera.sampler = C.CameraSamplerConfig(kind="bin_view", distance=[0.55, 0.8], tilt_deg=[5.0, 35.0],
                                               azimuth_deg=[-90.0, 90.0], roll_deg=[-15.0, 15.0],
                                               target_jitter=0.03)
    cfg.lighting = C.LightingConfig(key_power=[30.0, 90.0], key_color_temperature=[2800.0, 7000.0],
                                    key_size=[0.4, 1.25], key_position_jitter=0.25, ambient=[0.05, 0.3])
    config_to_props(cfg, registered)
    assert registered.lighting.enabled and registered.camera.sampler.kind == "bin_view"
    assert props_to_config(registered).to_dict() == cfg.to_dict()
    cfg.lighting = None
    cfg.camera.sampler.kind = "pool"
    config_to_props(cfg, registered)
    back = props_to_config(registered)
    assert not registered.lighting.enabled and back.lighting is None and back.to_dict() == cfg.to_dict()
    bad = C.default_config()
    bad.camera.sampler.tilt_deg = [0.0, 120.0]
    with pytest.raises(ConfigError) as e:
        config_to_props(bad, registered)
    assert e.value.paths() == ["camera.sampler.tilt_deg"]


def test_thesis_sensor_preset():
    cfg = C.load(presets.builtin_dir() / "thesis_sensor.json")
    default = C.load(presets.builtin_dir() / "default.json")
    assert cfg.problems() == []
    assert (cfg.camera.focal_length, cfg.camera.sensor_width, cfg.camera.resolution) == (50.0, 36.0, [720, 480])
    pr = cfg.projector
    assert (pr.focal_length, pr.sensor_width, pr.resolution) == (50.0, 36.0, [720, 480])
    assert pr.location == [-0.15, 0.0, 0.0]
    assert pr.rotation == pytest.approx([0.0, math.radians(-8.5), 0.0], abs=1e-7)
    sl = cfg.structured_light
    assert sl.enabled and sl.periods == [8, 7] and sl.steps == 3 and sl.unwrap == "heterodyne"
    assert cfg.objects == default.objects


def test_config_to_props_refuses_values_the_sidebar_cannot_hold(registered):
    before = dump(registered)
    cfg = C.default_config()
    cfg.scene.seed = 2**31                       # beyond Blender's int property (validate refuses it too)
    cfg.objects[0].collision_shape = "BLOB"
    with pytest.raises(ConfigError) as e:
        config_to_props(cfg, registered)
    assert set(e.value.paths()) == {"scene.seed", "objects[0].collision_shape"}
    assert dump(registered) == before            # nothing changed


def test_quaternion_projector_round_trip(registered):
    cfg = C.default_config()
    cfg.projector.rotation = [0.5, 0.5, 0.5, 0.5]
    config_to_props(cfg, registered)
    assert registered.projector.rotation_mode == "QUATERNION"
    assert props_to_config(registered).projector.rotation == [0.5, 0.5, 0.5, 0.5]


def test_calibrated_camera_and_projector_round_trip(registered):
    """camera.intrinsics / distortion and projector.intrinsics (docs/CALIBRATION.md) through the
    sidebar: the values (float32, as every sidebar float) and their null (the switch off)."""
    cfg = C.default_config()
    cfg.camera.intrinsics = [300.25, 302.5, 163.3, 116.2]
    cfg.camera.distortion = [-0.25, 0.08, 0.0012, -0.0009, -0.01]
    cfg.projector.intrinsics = [1290.0, 1291.5, 455.5, 300.25]
    config_to_props(cfg, registered)
    back = props_to_config(registered)
    assert back.camera.intrinsics == [f32(v) for v in cfg.camera.intrinsics]
    assert back.camera.distortion == [f32(v) for v in cfg.camera.distortion]
    assert back.projector.intrinsics == [f32(v) for v in cfg.projector.intrinsics]
    config_to_props(C.default_config(), registered)
    back = props_to_config(registered)
    assert back.camera.intrinsics is None and back.camera.distortion is None and back.projector.intrinsics is None


@pytest.mark.parametrize("exposure, hdr", [("auto", []), (0.7, [1.0, 4.0, 16.0]), ("auto", "auto")])
def test_exposure_and_hdr_round_trip(registered, exposure, hdr):
    cfg = C.default_config()
    cfg.structured_light.exposure, cfg.structured_light.hdr = exposure, hdr
    config_to_props(cfg, registered)
    assert registered.structured_light.auto_exposure == (exposure == "auto")
    back = props_to_config(registered).structured_light
    assert (back.exposure, back.hdr) == (exposure, hdr)


@pytest.mark.parametrize("mode", C.REFLECTION_FILTERS)
def test_reflection_filter_round_trip(registered, mode):
    cfg = C.default_config()
    cfg.structured_light.reflection_filter = mode
    config_to_props(cfg, registered)
    assert registered.structured_light.reflection_filter == mode
    assert props_to_config(registered).structured_light.reflection_filter == mode


def test_materials_round_trip_through_the_sidebar(registered):
    cfg = C.default_config()
    cfg.objects[0].material = "steel"
    cfg.objects[1].material = ["steel", "aluminium"]
    cfg.objects[2].material = {"name": "blue", "base_color": [0.1, 0.2, 0.6], "roughness": 0.3}
    cfg.scene.bin_material = {"base_color": [0.5, 0.5, 0.5], "roughness": 0.1}
    config_to_props(cfg, registered)
    assert registered.objects[1].material == "steel, aluminium"
    back = props_to_config(registered)
    assert [o.material for o in back.objects] == [o.material for o in cfg.objects]
    assert back.scene.bin_material == cfg.scene.bin_material
    registered.objects[0].material = "{not json"
    assert "objects[0].material" in {p.path for p in props_to_config(registered).problems(check_files=False)}


def test_save_then_load_into_fresh_scene_is_identical(registered, tmp_path):
    bpy.ops.datapipe.initialize(preset="builtin:thesis_sensor")
    d = bpy.context.scene.datapipe
    # edit a bit of everything, as a user would
    d.scene.seed = 1234
    d.scene.other_objects = "keep"
    d.structured_light.reflection_filter = "global"
    d.scene.drop_zone_scale = (0.2, 0.12, 0.08)
    d.objects[1].scale = 0.001
    d.objects[1].mass = 0.123
    d.camera.focal_length = 35.5
    d.projector.rotation_mode = "QUATERNION"
    d.projector.rotation_quaternion = (0.99, 0.0, -0.1, 0.0)
    d.structured_light.periods = "1, 4, 20"
    d.structured_light.unwrap = "multi-frequency"
    d.structured_light.auto_exposure = False
    d.structured_light.exposure = 0.7
    d.structured_light.hdr = "1, 4, 16"
    d.objects[0].material = "steel, rubber"
    d.scene.bin_material = "matte_plastic"
    d.render.outputs = {"rgb", "depth"}
    d.output.formats = {"native", "bop"}
    d.render.outputs = {"rgb", "depth", "mask"}
    d.preset_name = "round_trip"
    state = dump(d)
    cfg = props_to_config(d)
    bpy.ops.datapipe.preset_save()
    path = presets.user_dir() / "round_trip.json"
    assert path.is_file()
    # the file is exactly what the headless runner reads
    assert C.load(path).to_dict() == cfg.to_dict()
    assert json.loads(path.read_text()) == cfg.to_dict()

    bpy.ops.wm.read_factory_settings(use_empty=True)
    fresh = bpy.context.scene.datapipe
    assert len(fresh.objects) == 0
    bpy.ops.datapipe.preset_load(filepath=str(path))
    assert dump(bpy.context.scene.datapipe) == state
    assert props_to_config(bpy.context.scene.datapipe).to_dict() == cfg.to_dict()


def test_builtin_presets_are_read_only(registered):
    src = presets.builtin_dir() / "default.json"
    text = src.read_text()
    with pytest.raises(RuntimeError, match="read-only"):
        bpy.ops.datapipe.preset_save(name="default")
    with pytest.raises(RuntimeError, match="read-only"):
        bpy.ops.datapipe.preset_save(filepath=str(src))
    assert src.read_text() == text


def test_bad_preset_name(registered):
    with pytest.raises(RuntimeError, match="preset name"):
        bpy.ops.datapipe.preset_save(name="../evil")


def test_preset_enum_lists_builtin_and_user(registered):
    bpy.ops.datapipe.preset_save(name="mine")
    ids = [item[0] for item in presets.enum_items()]
    assert "builtin:default" in ids and "builtin:thesis_sensor" in ids and "user:mine" in ids
    assert registered.preset == "user:mine"
    registered.preset = "builtin:thesis_sensor"
    bpy.ops.datapipe.preset_load_selected()
    assert registered.camera.focal_length == 50.0


def test_initialize_sets_up_scene_and_fills_panels(registered):
    bpy.ops.datapipe.initialize(preset="builtin:default")
    sc = bpy.context.scene
    assert sc.unit_settings.system == "METRIC" and sc.render.engine == "CYCLES"
    assert len(registered.objects) == 3 and len(registered.camera.poses) == 6
    with pytest.raises(RuntimeError, match="no preset named"):
        bpy.ops.datapipe.initialize(preset="builtin:nope")


def test_load_refuses_invalid_preset_naming_the_field(registered, tmp_path):
    data = C.default_config().to_dict()
    data["objects"][0]["min_instances"] = 5
    data["objects"][0]["max_instances"] = 2
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(data))
    before = dump(registered)
    with pytest.raises(RuntimeError, match=r"objects\[0\]\.min_instances"):
        bpy.ops.datapipe.preset_load(filepath=str(path))
    assert dump(registered) == before
    path.write_text("{not json")
    with pytest.raises(RuntimeError, match="not valid JSON"):
        bpy.ops.datapipe.preset_load(filepath=str(path))


def test_load_legacy_pickle(registered, tmp_path, assets_dir):
    legacy = {
        "camera": {"world2cam_pose_list": [{"rotation": [1, 0, 0, 0], "location": [0, 0, 0.8]}],
                   "focal_length": 50, "sensor_width": 36, "resolution": [480, 720], "is_structured_light": True},
        "projector": {"proj2cam_pose": {"rotation": [0, -0.148353, 0], "location": [-0.15, 0, 0]},
                      "focal_length": 50, "sensor_width": 36, "resolution": [480, 720]},
        "scene": {"num_renders": 2, "max_renders_per_scene": 1, "min_renders_per_scene": 1,
                  "drop_zone_loc": [0, 0, 0.1], "drop_zone_scale": [0.1, 0.1, 0.1]},
        "objects": {"objects_list": [{"filepath": str(assets_dir / "peg.obj"), "scale": 1.0, "mass": 0.5,
                                      "collision_shape": "MESH", "max": 2, "min": 0}]},
        "output": {"path": str(tmp_path / "out")},
    }
    path = tmp_path / "inputs.pickle"
    path.write_bytes(pickle.dumps(legacy))
    bpy.ops.datapipe.preset_load(filepath=str(path))
    assert tuple(registered.camera.resolution) == (720, 480)
    assert registered.structured_light.enabled
    assert registered.objects[0].collision_shape == "MESH"
    assert len(registered.camera.poses) == 1


def test_user_dir_fallback_without_extension(monkeypatch):
    monkeypatch.delenv("DATAPIPE_USER_PRESETS", raising=False)
    path = presets.user_dir(create=False)       # plain `import datapipe`: not an extension
    assert path.parts[-2:] == ("datapipe", "presets")


def _numeric_fields(props):
    """(field path, Config getter, property) of every INT / FLOAT property of the sidebar that holds a
    Config field of the same name."""
    groups = [(section, getattr(props, section).bl_rna, lambda c, s=section: getattr(c, s))
              for section in ("scene", "camera", "projector", "structured_light", "render", "simulation", "output")]
    groups += [("objects[0]", props.bl_rna.properties["objects"].fixed_type, lambda c: c.objects[0]),
               ("camera.poses[0]", props.camera.bl_rna.properties["poses"].fixed_type, lambda c: c.camera.poses[0]),
               ("camera.sampler", props.camera.sampler.bl_rna, lambda c: c.camera.sampler),
               ("lighting", props.lighting.bl_rna, lambda c: c.lighting)]
    for path, rna, get in groups:
        for prop in rna.properties:
            if prop.type in ("INT", "FLOAT"):
                yield path, get, prop


def test_validate_refuses_every_value_the_sidebar_cannot_hold(registered):
    """Issue 33: the sidebar refused what the CLI accepted (seed 3,000,000,000; mass 1e-40). Each
    numeric property's hard limit (an IntProperty is a signed 32-bit integer; a float's min) is now
    one validate() also enforces (config/limits.py MAX_INT32, MIN_POSITIVE): a value just beyond it is
    refused at that field, so every preset validate accepts can be shown in the sidebar."""
    base = C.default_config()
    base.lighting = C.LightingConfig()
    base.camera.sampler.kind = "bin_view"
    checked = []
    for path, get, prop in _numeric_fields(registered):
        value = getattr(get(base), prop.identifier, None)
        if not isinstance(value, (int, float, list)) or isinstance(value, bool):
            continue                                      # no Config field of that name and kind
        lo, hi = prop.hard_min, prop.hard_max
        if prop.type == "INT":
            lo, hi = max(lo, -2**31), min(hi, 2**31 - 1)
        for beyond in ([lo - 1 if prop.type == "INT" else (lo / 10 if lo > 0 else lo - 1e-3)] if lo > -3e38 else []) + \
                      ([hi + 1 if prop.type == "INT" else hi * 1.01 + 1e-3] if hi < 3e38 else []):
            cfg = copy.deepcopy(base)
            if isinstance(value, list):                   # a vector or a [min, max] range: one end beyond
                new = list(value)
                new[0 if beyond < lo else -1] = beyond
                beyond = new
            setattr(get(cfg), prop.identifier, beyond)
            paths = [p.path for p in cfg.problems(check_files=False)]
            assert any(p.startswith(f"{path}.{prop.identifier}") for p in paths), (path, prop.identifier, beyond, paths)
            checked.append(f"{path}.{prop.identifier}")
    assert {"scene.seed", "objects[0].mass", "objects[0].obj_id", "camera.clip_start"} <= set(checked)


@pytest.mark.parametrize("field,value", [("seed", 3_000_000_000), ("mass", 1e-40)])
def test_sidebar_and_cli_refuse_with_the_same_message(registered, tmp_path, field, value):
    import subprocess
    import sys
    data = C.default_config().to_dict()
    target = data["scene"] if field == "seed" else data["objects"][0]
    target[field] = value
    path = tmp_path / "p.json"
    path.write_text(json.dumps(data))
    r = subprocess.run([sys.executable, "-m", "datapipe", "validate", str(path)], capture_output=True, text=True)
    problem = [line.strip()[2:] for line in r.stderr.splitlines() if line.strip().startswith("- ")]
    assert r.returncode == 2 and len(problem) == 1 and "(fix:" in problem[0], r.stderr[-1500:]
    before = dump(registered)
    with pytest.raises(RuntimeError) as e:
        bpy.ops.datapipe.preset_load(filepath=str(path))
    assert problem[0] in str(e.value) and dump(registered) == before
