"""Drawn textures (scene.textures) and environment maps (lighting.environment): the pure draws, the
texture-set file names, and the refusals before any work. No bpy (tests/blender/test_textures_blender.py
renders them)."""
import cv2
import numpy as np
import pytest

from datapipe import config as C
from datapipe.config.plan import grey_materials
from datapipe.draws import environment, textures
from datapipe.draws.lighting import draw_lighting
from datapipe.draws.seeds import TEXTURE_PARTS, TEXTURE_STATIC, lighting_render_rng, lighting_rng, texture_rng
from datapipe.io.exr import write_exr


def _cfg(**tex) -> C.Config:
    cfg = C.default_config()
    for k, v in tex.items():
        setattr(cfg.scene.textures, k, v)
    return cfg


def _fields(cfg) -> dict:
    return {p.path: p for p in cfg.problems()}


# ------------------------------------------------------------------------------------------------
# texture sets by file name

def test_texture_sets_recognise_the_cc0_names(tmp_path):
    """Names as CC0 PBR sets commonly spell them: colour, roughness and normal grouped by set; OpenGL's
    normal preferred over DirectX's; a set without a colour map and non-images are no set."""
    for f in ("Wood051_1K_Color.jpg", "Wood051_1K_Roughness.jpg", "Wood051_1K_NormalDX.jpg",
              "Wood051_1K_NormalGL.jpg", "Wood051_1K_Displacement.jpg",
              "metal_plate_diff_1k.png", "metal_plate_rough_1k.png", "metal_plate_nor_dx_1k.png",
              "lonely_Roughness.png", "notes_color.txt",
              "rough_concrete_diff_1k.png", "rough_concrete_rough_1k.png"):
        (tmp_path / f).write_bytes(b"")
    sets = {s["name"].split("/")[1]: s for s in textures.texture_sets(tmp_path)}
    assert set(sets) == {"Wood051_1K", "metal_plate", "rough_concrete"}
    assert sets["rough_concrete"]["roughness"].endswith("rough_concrete_rough_1k.png")
    w, m = sets["Wood051_1K"], sets["metal_plate"]
    assert w["color"].endswith("Wood051_1K_Color.jpg") and w["roughness"].endswith("_Roughness.jpg")
    assert w["normal"].endswith("NormalGL.jpg") and "normal_dx_green" not in w
    assert m["color"].endswith("_diff_1k.png") and m["roughness"].endswith("_rough_1k.png")
    assert m["normal"].endswith("_nor_dx_1k.png") and m["normal_dx_green"] is True   # flipped when built


# ------------------------------------------------------------------------------------------------
# draws

def test_draws_are_per_scene_deterministic_and_on_their_own_streams():
    tex = _cfg(targets=["bin", "floor", "parts"]).scene.textures
    a = textures.draw_static(tex, texture_rng(3, 5, TEXTURE_STATIC))
    b = textures.draw_static(tex, texture_rng(3, 5, TEXTURE_STATIC))
    assert a == b and set(a) == {"bin", "floor"}
    assert a != textures.draw_static(tex, texture_rng(3, 6, TEXTURE_STATIC))
    parts = textures.draw_parts(tex, texture_rng(3, 5, TEXTURE_PARTS), 7)
    assert len(parts) == 7 and parts[:3] == textures.draw_parts(tex, texture_rng(3, 5, TEXTURE_PARTS), 3)
    # a scene of many draws shows several kinds (5 kinds, 2 + 7 draws: P(one kind) ~ 5 * 0.2^9)
    assert len({d["kind"] for d in [*a.values(), *parts]}) > 1


def test_drawn_colours_hold_the_drawn_contrast_and_ranges():
    """dark = bright * (1 - contrast) channel by channel: the albedo ratio the fringe modulation sees."""
    tex = _cfg(targets=["parts"], contrast=[0.3, 0.6], albedo=[0.4, 0.7], saturation=[0.0, 0.5]).scene.textures
    for d in textures.draw_parts(tex, np.random.default_rng(1), 200):
        bright, dark = np.array(d["colors"][0]), np.array(d["colors"][1])
        assert 0.3 <= d["contrast"] <= 0.6
        assert np.allclose(dark, bright * (1 - d["contrast"]), rtol=0, atol=1e-12)
        assert 0.4 - 1e-12 <= bright.max() <= 0.7 + 1e-12                     # HSV value = the albedo
        assert (bright.max() - bright.min()) / bright.max() <= 0.5 + 1e-12     # HSV saturation
        assert 0.005 <= d["feature_size"] <= 0.05


def test_targets_off_draw_nothing():
    tex = _cfg().scene.textures
    assert tex.targets == [] and textures.draw_static(tex, np.random.default_rng(0)) == {}
    assert textures.draw_parts(tex, np.random.default_rng(0), 5) == []
    only_floor = _cfg(targets=["floor"]).scene.textures
    assert set(textures.draw_static(only_floor, np.random.default_rng(0))) == {"floor"}


def test_image_draw_takes_a_set_and_records_its_name(tmp_path):
    (tmp_path / "brick_albedo.png").write_bytes(b"")
    tex = _cfg(targets=["bin"], kinds=["image"], image_folder=str(tmp_path)).scene.textures
    d = textures.draw_static(tex, np.random.default_rng(0), textures.texture_sets(tmp_path))["bin"]
    assert d["kind"] == "image" and d["set"]["color"].endswith("brick_albedo.png")
    assert textures.record(d)["set"] == f"{tmp_path.name}/brick"


def test_saturated_or_image_textures_are_not_grey():
    """Quadrature packing takes frames back by colour ratios: coloured textures must turn it off."""
    def grey(**tex):
        cfg = _cfg(**tex)
        for o in cfg.objects:
            o.material = "matte_plastic"
        return grey_materials(cfg)
    assert grey(targets=[]) and grey(targets=["parts"], saturation=[0.0, 0.0])
    assert not grey(targets=["parts"], saturation=[0.0, 0.3])
    assert not grey(targets=["bin"], saturation=[0.0, 0.0], kinds=["image"])


# ------------------------------------------------------------------------------------------------
# refusals

def test_texture_folder_without_images_is_refused_naming_the_field(tmp_path):
    (tmp_path / "readme.txt").write_text("no maps here")
    (tmp_path / "wood_Roughness.png").write_bytes(b"")        # a map, but no colour map
    p = _fields(_cfg(targets=["bin"], kinds=["image"], image_folder=str(tmp_path)))["scene.textures.image_folder"]
    assert "no texture image with a colour map" in p.message and "color/albedo" in p.fix
    assert "scene.textures.image_folder" in _fields(_cfg(targets=["bin"], kinds=["noise", "image"]))
    assert "scene.textures.image_folder" in _fields(_cfg(targets=["bin"], kinds=["noise"],
                                                        image_folder=str(tmp_path)))   # never drawn
    p = _fields(_cfg(targets=["bin"], kinds=["image"], image_folder=str(tmp_path / "nope")))
    assert "is not a folder" in p["scene.textures.image_folder"].message
    (tmp_path / "wood_Color.png").write_text("not a PNG")          # named like a map, not an image
    p = _fields(_cfg(targets=["bin"], kinds=["image"], image_folder=str(tmp_path)))["scene.textures.image_folder"]
    assert "wood_Color.png is named like a texture map but is not an image" in p.message
    import os
    (tmp_path / "wood_Color.png").unlink()
    os.mkfifo(tmp_path / "wood_Color.png")                        # would block a read: refused unread
    assert "scene.textures.image_folder" in _fields(_cfg(targets=["bin"], kinds=["image"], image_folder=str(tmp_path)))
    (tmp_path / "wood_Color.png").unlink()
    assert cv2.imwrite(str(tmp_path / "wood_Color.png"), np.zeros((4, 4, 3), np.uint8))
    assert "scene.textures.image_folder" in _fields(_cfg(targets=["bin"], kinds=["image"],
                                                        image_folder=str(tmp_path)))   # the empty roughness map
    assert cv2.imwrite(str(tmp_path / "wood_Roughness.png"), np.zeros((4, 4), np.uint8))
    assert "scene.textures.image_folder" not in _fields(_cfg(targets=["bin"], kinds=["image"],
                                                            image_folder=str(tmp_path)))


def test_unknown_targets_kinds_and_ranges_are_refused():
    f = _fields(_cfg(targets=["lid"]))
    assert "unknown value(s) ['lid']" in f["scene.textures.targets"].message
    f = _fields(_cfg(targets=["bin"], kinds=["marble"], contrast=[0.5, 1.5], feature_size=[0.0, 0.1]))
    assert {"scene.textures.kinds", "scene.textures.contrast", "scene.textures.feature_size"} <= set(f)
    assert "scene.textures.kinds" in _fields(_cfg(targets=["bin"], kinds=[]))
    assert "scene.textures.contrast" in _fields(_cfg(contrast=[0.0, 2.0]))       # off, still what the sidebar holds
    assert not [p for p in _cfg(targets=["bin", "floor", "parts"]).problems() if p.path.startswith("scene.textures")]


def _env_cfg(path) -> C.Config:
    cfg = C.default_config()
    cfg.lighting = C.LightingConfig(environment=str(path))
    return cfg


def test_readable_hdr_and_exr_maps_are_taken(tmp_path):
    sky = np.ones((8, 16, 3), np.float32) * np.float32(2.5)      # above 1: what an HDR holds
    assert cv2.imwrite(str(tmp_path / "sky.hdr"), sky)
    write_exr(tmp_path / "sky.exr", {"R": sky[..., 0], "G": sky[..., 1], "B": sky[..., 2]})
    for name in ("sky.hdr", "sky.exr"):
        assert environment.header_problem(tmp_path / name) is None
        assert not [p for p in _env_cfg(tmp_path / name).problems() if p.path.startswith("lighting")]
    assert environment.find_maps(tmp_path) == [str(tmp_path / "sky.exr"), str(tmp_path / "sky.hdr")]
    assert not [p for p in _env_cfg(tmp_path).problems() if p.path.startswith("lighting")]


def test_unreadable_environment_maps_are_refused_before_any_work(tmp_path):
    (tmp_path / "fake.hdr").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 64)
    (tmp_path / "cut.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n")     # header never ends
    (tmp_path / "nores.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\nrubbish\n")
    (tmp_path / "fake.exr").write_bytes(b"v/1\x01" + b"\0" * 40)                    # magic, then no header
    (tmp_path / "sky.png").write_bytes(b"")
    for name, why in (("fake.hdr", "#?RADIANCE"), ("cut.hdr", "no end of its Radiance header"),
                      ("nores.hdr", "no resolution line"), ("fake.exr", "OpenEXR cannot read"),
                      ("sky.png", "not an .hdr or .exr")):
        p = _fields(_env_cfg(tmp_path / name))["lighting.environment"]
        assert why in p.message and "not a readable HDR/EXR" in p.message and ".exr" in p.fix, name
    import os
    os.mkfifo(tmp_path / "pipe.hdr")                              # would block a read: refused unread
    assert "not a regular file" in _fields(_env_cfg(tmp_path / "pipe.hdr"))["lighting.environment"].message
    (tmp_path / "empty").mkdir()
    p = _fields(_env_cfg(tmp_path / "empty"))["lighting.environment"]
    assert "holds no .hdr or .exr" in p.message
    assert "does not exist" in _fields(_env_cfg(tmp_path / "gone.hdr"))["lighting.environment"].message
    bad = _env_cfg(tmp_path / "fake.hdr")                        # a folder is refused by its first bad map
    bad.lighting.environment = str(tmp_path)
    assert "lighting.environment" in _fields(bad)


def test_environment_draw_leaves_the_lighting_draws_alone(tmp_path):
    """The map, rotation and strength are drawn after the key light and ambient: adding a map
    changes none of them; per_render draws come from a stream of each render."""
    li = C.LightingConfig(environment_strength=[0.5, 1.5], environment_rotation_deg=[0.0, 360.0])
    rng = lighting_rng(0, 4)
    with_env = draw_lighting(li, rng)
    env = environment.draw_environment(li, ["a.hdr", "b.hdr"], rng)
    assert with_env == draw_lighting(li, lighting_rng(0, 4))
    assert env["map"] in ("a.hdr", "b.hdr") and 0.5 <= env["strength"] <= 1.5 and 0 <= env["rotation_deg"] <= 360
    r0, r1 = (draw_lighting(li, lighting_render_rng(0, 4, r)) for r in (0, 1))
    assert r0 != r1 and r0 == draw_lighting(li, lighting_render_rng(0, 4, 0))
    assert r0 != with_env


def test_ranges_of_the_environment_are_checked(tmp_path):
    assert cv2.imwrite(str(tmp_path / "sky.hdr"), np.ones((4, 8, 3), np.float32))
    cfg = _env_cfg(tmp_path / "sky.hdr")
    cfg.lighting.environment_strength = [2.0, 1.0]
    assert "lighting.environment_strength" in _fields(cfg)
    cfg.lighting.environment = ""                                 # no map: the range is still checked
    assert "lighting.environment_strength" in _fields(cfg)
    assert pytest.approx(environment.rotation_rad({"rotation_deg": 180.0})) == np.pi
