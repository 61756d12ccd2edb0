"""Config: JSON and legacy-pickle round trips, the restricted unpickler, and every validation error."""
import json
import math
import os
import pickle

import pytest

from datapipe import config as C
from datapipe.errors import ConfigError


@pytest.fixture
def cfg():
    return C.default_config()


def test_default_preset_is_valid(cfg):
    assert cfg.validate() is cfg
    assert all(os.path.isabs(o.filepath) and os.path.isfile(o.filepath) for o in cfg.objects)


def test_json_round_trip(cfg, tmp_path):
    cfg.structured_light.enabled = True
    cfg.projector.rotation = [1.0, 0.0, 0.0, 0.0]
    C.save(cfg, tmp_path / "p.json")
    back = C.load(tmp_path / "p.json")
    assert back.to_dict() == cfg.to_dict()
    assert json.loads((tmp_path / "p.json").read_text())["schema_version"] == C.SCHEMA_VERSION


def test_relative_paths_resolve_against_preset_folder(tmp_path, assets_dir):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "p.obj").write_bytes((assets_dir / "peg.obj").read_bytes())
    d = C.Config().to_dict()
    d["objects"] = [{"filepath": "meshes/p.obj"}]
    (tmp_path / "x.json").write_text(json.dumps(d))
    cfg = C.load(tmp_path / "x.json")
    assert cfg.objects[0].filepath == str(tmp_path / "meshes" / "p.obj")
    cfg.validate()


def _legacy(objfile, key="world2cam_pose_list", rot=(0.0, -0.148, 0.0)):
    return {
        "camera": {key: [{"rotation": [1, 0, 0, 0], "location": [0, 0, 1.2]},
                         {"rotation": [0.9659, 0.2588, 0, 0], "location": [0, -0.3, 1.1]}],
                   "focal_length": 50, "sensor_width": 36, "resolution": [480, 720], "is_structured_light": True},
        "projector": {"proj2cam_pose": {"rotation": list(rot), "location": [-0.15, 0, 0]},
                      "focal_length": 50, "sensor_width": 36, "resolution": [480, 720]},
        "scene": {"num_renders": 3, "max_renders_per_scene": 2, "min_renders_per_scene": 1,
                  "drop_zone_loc": [0, 0, 2], "drop_zone_scale": [0.5, 0.5, 0.5]},
        "objects": {"objects_list": [{"filepath": str(objfile), "scale": 1.0, "mass": 0.5,
                                      "collision_shape": "MESH", "max": 2, "min": 0}]},
        "output": {"path": "/tmp/out"},
    }


@pytest.mark.parametrize("key", ["world2cam_pose_list", "wrlld2cam_pose_list", "wrl2cam_pose_list"])
def test_legacy_pickle_all_spellings(tmp_path, assets_dir, key):
    p = tmp_path / "inputs.pickle"
    p.write_bytes(pickle.dumps(_legacy(assets_dir / "peg.obj", key)))
    cfg = C.load(p)
    assert [pose.location for pose in cfg.camera.poses] == [[0, 0, 1.2], [0, -0.3, 1.1]]
    assert cfg.camera.resolution == [720, 480]          # [h, w] in the original -> [w, h]
    assert cfg.projector.resolution == [720, 480]
    assert cfg.structured_light.enabled
    assert cfg.objects[0].min_instances == 0 and cfg.objects[0].max_instances == 2
    assert cfg.objects[0].collision_shape == "MESH"
    assert cfg.scene.drop_zone_loc == [0, 0, 2]
    assert cfg.projector.rotation == [0.0, -0.148, 0.0]
    cfg.validate()


def test_legacy_round_trip(tmp_path, assets_dir):
    cfg = C.load_legacy_pickle(pickle.dumps(_legacy(assets_dir / "peg.obj", rot=(1, 0, 0, 0))))
    again = C.from_legacy_dict(C.to_legacy_dict(cfg))
    assert again.to_dict() == cfg.to_dict()


class _Evil:
    def __reduce__(self):
        return (os.system, ("touch /tmp/datapipe_pwned_marker",))


def test_malicious_pickle_is_refused_without_running(tmp_path):
    marker = "/tmp/datapipe_pwned_marker"
    if os.path.exists(marker):
        os.remove(marker)
    p = tmp_path / "evil.pickle"
    p.write_bytes(pickle.dumps({"camera": _Evil()}))
    with pytest.raises(ConfigError, match="refused to load"):
        C.load(p)
    assert not os.path.exists(marker)


def test_corrupt_pickle_and_bad_json(tmp_path):
    (tmp_path / "x.pickle").write_bytes(pickle.dumps({"a": 1})[:5])
    with pytest.raises(ConfigError, match="cannot read the pickle"):
        C.load(tmp_path / "x.pickle")
    (tmp_path / "x.json").write_text("{ nope")
    with pytest.raises(ConfigError, match="not valid JSON"):
        C.load(tmp_path / "x.json")
    with pytest.raises(ConfigError, match="preset not found"):
        C.load(tmp_path / "missing.json")


def _problems(cfg, **kw):
    return {p.path: p for p in cfg.problems(**kw)}


def _sl(**fields):
    """A CASES mutation: structured light on, then its `fields` set (in the order given)."""
    def mutate(c):
        c.structured_light.enabled = True
        for k, v in fields.items():
            setattr(c.structured_light, k, v)
    return mutate


# (mutation, field path expected, fragment of the message)
CASES = [
    (lambda c: setattr(c.scene, "num_renders", 0), "scene.num_renders", ">= 1"),
    (lambda c: (setattr(c.scene, "min_renders_per_scene", 3), setattr(c.scene, "max_renders_per_scene", 2)),
     "scene.min_renders_per_scene", "> max_renders_per_scene"),
    (lambda c: setattr(c.scene, "drop_zone_scale", [0.1, 0, 0.1]), "scene.drop_zone_scale", "> 0"),
    (lambda c: setattr(c.scene, "drop_zone_loc", [0, 0]), "scene.drop_zone_loc", "needs 3"),
    (lambda c: setattr(c.scene, "drop_zone_loc", [0, math.nan, 0]), "scene.drop_zone_loc", "NaN"),
    (lambda c: setattr(c.scene, "blend_file", "/nonexistent/x.blend"), "scene.blend_file", "not found"),
    (lambda c: setattr(c, "objects", []), "objects", "no objects"),
    (lambda c: setattr(c.objects[0], "filepath", "/nonexistent/part.obj"), "objects[0].filepath", "not found"),
    (lambda c: setattr(c.objects[0], "filepath", __file__), "objects[0].filepath", "not a mesh file"),
    (lambda c: setattr(c.objects[1], "scale", 0.0), "objects[1].scale", "> 0"),
    (lambda c: setattr(c.objects[1], "mass", -1.0), "objects[1].mass", "> 0"),
    (lambda c: setattr(c.objects[0], "collision_shape", "BLOB"), "objects[0].collision_shape", "unknown value"),
    (lambda c: (setattr(c.objects[2], "min_instances", 5), setattr(c.objects[2], "max_instances", 1)),
     "objects[2].min_instances", "> max_instances"),
    (lambda c: setattr(c.objects[1], "name", "peg"), "objects[1].name", "already used"),
    (lambda c: setattr(c.camera, "focal_length", 0), "camera.focal_length", "> 0"),
    (lambda c: setattr(c.camera, "resolution", [0, 240]), "camera.resolution", "width 0"),
    (lambda c: setattr(c.camera, "resolution", [320, 100000]), "camera.resolution", "height 100000"),
    (lambda c: setattr(c.camera, "poses", []), "camera.poses", "no camera poses"),
    (lambda c: setattr(c.camera.poses[0], "rotation", [0, 0, 0, 0]), "camera.poses[0].rotation", "zero quaternion"),
    (lambda c: setattr(c.scene, "max_renders_per_scene", 99), "scene.max_renders_per_scene", "only 6 camera poses"),
    (lambda c: setattr(c.camera, "clip_end", 0.01), "camera.clip_end", "clip_start"),
    (_sl(steps=2), "structured_light.steps", ">= 3"),
    (_sl(periods=[1, 400]), "structured_light.periods", "fewer than 3 px"),
    (lambda c: (setattr(c.structured_light, "enabled", True), setattr(c.projector, "rotation", [0, 0])),
     "projector.rotation", "needs 3"),
    (_sl(unwrap="magic"), "structured_light.unwrap", "unknown value"),
    (_sl(projector_gamma=0), "structured_light.projector_gamma", "[0.2, 5]"),
    (_sl(periods=[16, 64]), "structured_light.periods", "share the factor 16"),
    (_sl(exposure="bright"), "structured_light.exposure", "unknown mode"),
    (_sl(exposure=0.0), "structured_light.exposure", "> 0"),
    (_sl(hdr=[1, -4]), "structured_light.hdr", "factor 1"),
    (_sl(hdr=[1, 1]), "structured_light.hdr", "repeats"),
    (_sl(hdr="bright"), "structured_light.hdr", "unknown mode"),
    (lambda c: setattr(c.objects[0], "material", "chrome"), "objects[0].material", "unknown material"),
    (lambda c: setattr(c.objects[1], "material", {"roughnes": 0.2}), "objects[1].material", "unknown key"),
    (lambda c: setattr(c.objects[1], "material", {"base_color": [2, 0, 0]}), "objects[1].material", "base_color"),
    (lambda c: setattr(c.objects[2], "material", ["steel", 3]), "objects[2].material", "item 1"),
    (lambda c: setattr(c.scene, "bin_material", ["steel", "gold"]), "scene.bin_material", "item 1: unknown material"),
    (lambda c: setattr(c.scene, "bin_material", []), "scene.bin_material", "empty list"),
    (_sl(fringe_mode="quick"), "structured_light.fringe_mode", "unknown value"),
    (lambda c: setattr(c.scene, "other_objects", "delete"), "scene.other_objects", "unknown value"),
    (_sl(reflection_filter="on"), "structured_light.reflection_filter", "unknown value"),
    (_sl(ambient="hall"), "structured_light.ambient", "unknown value"),
    (_sl(fringe_mode="fast", reflection_filter="global"), "structured_light.reflection_filter", "fast mode"),
    (_sl(fringe_mode="quadrature", projector_gamma=2.2), "structured_light.fringe_mode", "projector gamma"),
    (lambda c: setattr(c.render, "adaptive_threshold", -0.01), "render.adaptive_threshold", "must be in [0, 1)"),
    (lambda c: setattr(c.render, "samples", 0), "render.samples", ">= 1"),
    (lambda c: setattr(c.render, "outputs", ["rgb", "thermal"]), "render.outputs[1]", "unknown value"),
    (lambda c: setattr(c.render, "engine", "BLENDER_EEVEE"), "render.engine", "unknown value"),
    (lambda c: setattr(c.render, "denoise_prefilter", "SLOW"), "render.denoise_prefilter", "unknown value"),
    (lambda c: setattr(c.render, "denoise_quality", "balanced"), "render.denoise_quality", "unknown value"),
    (lambda c: setattr(c.render, "sampling_pattern", "SOBOL_BURLEY"), "render.sampling_pattern", "unknown value"),
    (lambda c: (setattr(c.output, "formats", ["bop"]), setattr(c.render, "outputs", ["rgb", "depth"])),
     "render.outputs", "BOP format needs"),
    (lambda c: setattr(c.simulation, "max_frames", 0), "simulation.max_frames", ">= 1"),
    (lambda c: setattr(c.output, "path", ""), "output.path", "empty"),
    # issue #12: limits, finiteness and useless-dataset checks
    (lambda c: (setattr(c.scene, "min_renders_per_scene", 0), setattr(c.scene, "max_renders_per_scene", 0)),
     "scene.min_renders_per_scene", ">= 1"),
    (lambda c: setattr(c.scene, "num_renders", 10**9), "scene.num_renders", "more than 1000000"),
    (lambda c: setattr(c.render, "samples", 10**7), "render.samples", "more than 4096"),
    (lambda c: setattr(c.camera, "resolution", [10**12, 240]), "camera.resolution", "outside"),
    (lambda c: setattr(c.render, "outputs", []), "render.outputs", "no outputs"),
    (lambda c: setattr(c.render, "light_power", math.inf), "render.light_power", "finite"),
    (lambda c: setattr(c.objects[0], "scale", math.nan), "objects[0].scale", "finite"),
    (lambda c: setattr(c.camera, "focal_length", 1e-9), "camera.focal_length", "deg across"),
    (lambda c: setattr(c.camera.poses[0], "location", [0, math.inf, 1]), "camera.poses[0].location", "NaN"),
    (lambda c: (setattr(c.structured_light, "enabled", True), setattr(c.projector, "rotation", [0, math.nan, 0])),
     "projector.rotation", "NaN"),
    (lambda c: (setattr(c.structured_light, "enabled", True), setattr(c.projector, "power", math.inf)),
     "projector.power", "finite"),
    (_sl(steps=100000), "structured_light.steps", "more than 32"),
    (lambda c: (setattr(c.structured_light, "enabled", True), setattr(c.structured_light, "steps", 32),
                setattr(c.structured_light, "periods", [1, 4, 16, 64]), setattr(c.camera, "resolution", [4096, 3072]),
                setattr(c.projector, "resolution", [3840, 2160])), "structured_light.steps", "GiB"),
    (lambda c: (setattr(c.structured_light, "enabled", True), setattr(c.structured_light, "periods", [1, 300]),
                setattr(c.camera, "resolution", [64, 48])), "structured_light.periods", "camera pixels"),
    (_sl(samples=0), "structured_light.samples", ">= 1"),
    (lambda c: setattr(c.objects[0], "filepath", os.path.dirname(__file__)), "objects[0].filepath", "is a folder"),
]


@pytest.mark.parametrize("mutate,path,fragment", CASES, ids=[c[1] + ":" + c[2] for c in CASES])
def test_each_validation_error_names_field_and_fix(cfg, mutate, path, fragment):
    mutate(cfg)
    probs = _problems(cfg)
    assert path in probs, f"expected a problem at {path}, got {list(probs)}"
    assert fragment in probs[path].message
    assert probs[path].fix
    with pytest.raises(ConfigError) as ei:
        cfg.validate()
    assert path in str(ei.value) and "fix:" in str(ei.value)


def test_all_problems_reported_at_once(cfg):
    cfg.scene.num_renders = 0
    cfg.objects[0].scale = -1
    cfg.camera.poses = []
    assert {"scene.num_renders", "objects[0].scale", "camera.poses"} <= set(_problems(cfg))


def test_unknown_keys_and_wrong_types_in_json():
    d = C.Config().to_dict()
    d["scene"]["colour"] = "red"
    d["camera"]["focal_length"] = "fifty"
    d["render"]["samples"] = 3.5
    d["objects"] = [{"filepath": 3}]
    with pytest.raises(ConfigError) as ei:
        C.Config.from_dict(d)
    paths = ei.value.paths()
    assert "scene.colour" in paths and "camera.focal_length" in paths
    assert "render.samples" in paths and "objects[0].filepath" in paths
    assert "unknown key" in str(ei.value) and "expected a number" in str(ei.value)


def test_schema_version_checked():
    d = C.Config().to_dict()
    d["schema_version"] = 99
    with pytest.raises(ConfigError, match="schema version"):
        C.Config.from_dict(d)


@pytest.mark.parametrize("periods", [[13, 7], [9, 10, 11], [70, 64, 59], [1, 8, 64], [16, 15]])
def test_period_sets_that_decode_are_accepted(periods):
    """Every set the decoder unwraps (datapipe.sl.plan_unwrap) passes validation."""
    c = C.Config()
    c.structured_light.enabled = True
    c.structured_light.periods = periods
    c.structured_light.projector_gamma = 2.2
    assert not [p for p in c.problems(check_files=False) if p.path.startswith("structured_light")]


def test_wrapped_decoder_message_says_fix_once(cfg):
    """Defect #10: the [1, 1] periods message printed "(fix:" twice."""
    cfg.structured_light.enabled = True
    cfg.structured_light.periods = [1, 1]
    with pytest.raises(ConfigError) as ei:
        cfg.validate()
    line = next(x for x in str(ei.value).splitlines() if "structured_light.periods" in x)
    assert line.count("(fix:") == 1, line


def test_predicted_fringe_period_matches_the_default_comment(cfg):
    """320 px wide camera, f 16 / 11.3 mm both, 912 px projector, 64 periods: 912/64 * 320/912 = 5 px."""
    cfg.structured_light.enabled = True
    cfg.projector.location = [-0.15, 0.0, 0.0]
    assert C.fringe_period_camera_px(cfg) == pytest.approx(320 / 64, rel=1e-9)
    cfg.projector.location = [-0.15, 0.0, 0.35]      # projector 0.35 m behind the camera: wider fringes
    d = max(math.dist(p.location, cfg.scene.drop_zone_loc) for p in cfg.camera.poses)   # worst: farthest
    assert C.fringe_period_camera_px(cfg) == pytest.approx(5 * (d + 0.35) / d, rel=1e-9)


@pytest.mark.parametrize("exposure, hdr", [("auto", []), (0.7, [1.0, 4.0, 16.0]), (2, []), ("auto", "auto")])
def test_exposure_modes_round_trip(cfg, tmp_path, exposure, hdr):
    """structured_light.exposure is a number or "auto" (the default), hdr a list of factors or
    "auto" (the default): both survive a JSON round trip with their types."""
    assert C.StructuredLightConfig().exposure == "auto" and C.StructuredLightConfig().hdr == "auto"
    cfg.structured_light.enabled = True
    cfg.structured_light.exposure = exposure
    cfg.structured_light.hdr = hdr
    cfg.validate()
    C.save(cfg, tmp_path / "p.json")
    back = C.load(tmp_path / "p.json")
    assert back.structured_light.exposure == exposure
    assert type(back.structured_light.exposure) is (str if exposure == "auto" else float)
    assert back.structured_light.hdr == hdr
    d = cfg.to_dict()
    d["structured_light"]["exposure"] = [1]
    with pytest.raises(ConfigError, match="structured_light.exposure"):
        C.Config.from_dict(d)


def test_materials_round_trip(cfg, tmp_path):
    """objects[i].material / scene.bin_material: 'file' by default; names, dicts and lists survive
    a JSON round trip unchanged."""
    assert C.ObjectEntry().material == "file" and C.SceneConfig().bin_material == "file"
    cfg.objects[0].material = "steel"
    cfg.objects[1].material = {"name": "blue", "base_color": [0.1, 0.2, 0.6], "roughness": 0.3, "ior": 1.49,
                               "variation": 0.2}
    cfg.objects[2].material = ["steel", "aluminium", {"metallic": 1.0, "roughness": 0.1}]
    cfg.scene.bin_material = "matte_plastic"
    cfg.validate()
    C.save(cfg, tmp_path / "m.json")
    back = C.load(tmp_path / "m.json")
    assert [o.material for o in back.objects] == [o.material for o in cfg.objects]
    assert back.scene.bin_material == "matte_plastic"


def test_fringe_memory_counts_the_row_code_and_hdr():
    """The memory check sees what a render holds: F*N fringe images, the row code's N more where the
    global reflection filter may run (render mode), and with `hdr` the fused stack besides."""
    cfg = C.default_config()
    s = cfg.structured_light
    s.enabled, s.fringe_mode = True, "fast"
    fast = C.fringe_memory_bytes(cfg)
    s.fringe_mode = "render"
    rows = C.fringe_memory_bytes(cfg)
    assert rows == fast * (len(s.periods) + 1) // len(s.periods)
    s.reflection_filter = "local"
    assert C.fringe_memory_bytes(cfg) == fast
    s.hdr = [1.0, 4.0, 16.0]
    assert C.fringe_memory_bytes(cfg) > fast


def test_only_grey_materials_pack_three_images_per_layer():
    """config/plan.py grey_materials: quadrature packs three images per layer only when every
    configured material is grey (steel's tint passes); the bin's "file" is the built-in grey."""
    from datapipe.config.plan import grey_materials

    cfg = C.default_config()
    cfg.structured_light.fringe_mode = "quadrature"
    cfg.scene.bin_material = "file"                            # the built-in grey bin
    for entry in cfg.objects:
        entry.material = ["steel", "matte_plastic", "aluminium"]
    assert grey_materials(cfg)
    cfg.objects[0].material = {"name": "copper", "base_color": [0.95, 0.64, 0.54], "metallic": 1.0, "roughness": 0.3}
    assert not grey_materials(cfg)
    cfg.objects[0].material = "file"                           # a mesh file's own materials: any colour
    assert not grey_materials(cfg)
    cfg.objects[0].material = "steel"
    cfg.scene.bin_material = [{"name": "blue_bin", "base_color": [0.1, 0.2, 0.6], "roughness": 0.6}]
    assert not grey_materials(cfg)


def test_denoiser_settings_default_to_the_former_fixed_ones_and_are_checked():
    """render.denoise_prefilter / denoise_quality: the defaults are the values the renderer hard-coded
    before they were fields (ACCURATE, HIGH), and render.sampling_pattern's SCENE leaves the scene's
    as the renderer did, so a preset that does not set them renders as before; a JSON value is
    Cycles' name, checked before any work with the choices in the fix."""
    r = C.RenderConfig()
    assert (r.denoise_prefilter, r.denoise_quality, r.sampling_pattern) == ("ACCURATE", "HIGH", "SCENE")
    cfg = C.loads(json.dumps({"render": {"denoise_prefilter": "FAST", "denoise_quality": "BALANCED"}}))
    assert (cfg.render.denoise_prefilter, cfg.render.denoise_quality) == ("FAST", "BALANCED")
    assert "render.denoise_prefilter" not in _problems(cfg) and "render.denoise_quality" not in _problems(cfg)
    with pytest.raises(ConfigError) as e:
        C.loads(json.dumps({"render": {"denoise_prefilter": "ACCURATEST", "denoise_quality": 2}}))
    paths = e.value.paths()
    assert "render.denoise_prefilter" in paths and "render.denoise_quality" in paths
    p = _problems(C.loads(json.dumps({"render": {"denoise_prefilter": "fast"}})))["render.denoise_prefilter"]
    assert "ACCURATE, FAST, NONE" in p.fix
    cfg = C.loads(json.dumps({"render": {"sampling_pattern": "BLUE_NOISE"}}))
    assert cfg.render.sampling_pattern == "BLUE_NOISE" and "render.sampling_pattern" not in _problems(cfg)
    p = _problems(C.loads(json.dumps({"render": {"sampling_pattern": "blue"}})))["render.sampling_pattern"]
    assert "SCENE, TABULATED_SOBOL, BLUE_NOISE, AUTOMATIC" in p.fix
