"""Drawn textures and environment maps in Blender (real Cycles, 64x48, floor only, fast fringe mode).

- An environment map lights the RGB and the projector-off layer of structured_light.ambient "scene";
  the fringe frames stay the projector's alone (the black world override).
- A textured floor is the same material for the RGB and the fringes: the fringe offset's ratio to
  the untextured floor's is the checker's albedo ratio, and the RGB shows the same squares.
"""
from pathlib import Path

import cv2
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from datapipe import config as C  # noqa: E402
from datapipe.core import structured_light as SLM  # noqa: E402
from datapipe.core.camera import BlendCamera  # noqa: E402
from datapipe.core.projector import fringe_layer_leaks  # noqa: E402
from datapipe.core.renderer import Renderer  # noqa: E402
from datapipe.core.scene import BlendScene  # noqa: E402
from cli_runs import maps_only, small_config  # noqa: E402

SEED = 5
STEPS = 4


def _build(ambient: str):
    cfg = C.default_config()
    cfg.camera.resolution = [64, 48]
    cfg.scene.make_bin = False            # the floor alone: a plane 0.8 m under the camera
    cfg.render.samples = 8
    cfg.render.threads = 2
    cfg.render.denoise = False
    s = cfg.structured_light
    s.enabled, s.periods, s.ambient, s.fringe_mode = True, [1, 4, 16], ambient, "fast"
    blend = BlendScene(cfg).setup()
    cam = BlendCamera(cfg, blend.scene).setup()
    ren = Renderer(cfg, blend.scene, cam).setup()
    slc = SLM.StructuredLightCamera(cfg, blend.scene, cam, ren)
    slc.setup()
    return blend, ren, slc, cam.set_pose(0)


def _no_light(env=None) -> dict:
    d = {"key_power": 0.0, "key_color_temperature": 6500.0, "key_color": [1.0, 1.0, 1.0], "key_size": 1.0,
         "key_offset": [0.0, 0.0, 0.0], "ambient": 0.0}
    if env is not None:
        d["environment"] = env
    return d


def test_environment_lights_the_rgb_and_the_ambient_layer_never_the_fringes(tmp_path):
    """A uniform sky of radiance L = 0.5 (strength 1), key light and ambient off: the floor (the
    built-in grey, diffuse albedo 0.5, roughness 0.6) under it has radiance ~ albedo x L = 0.25
    (a Lambertian surface under a uniform hemisphere: irradiance pi L, radiance albedo L), plus the
    ~4% specular layer of IOR 1.5: the projector-off layer's median within 0.2..0.32. The fringe
    frames do not change (the projector's light alone: below 1e-4 of the frame's peak), no leak is
    found, and the RGB gets brighter."""
    sky = np.full((16, 32, 3), 0.5, np.float32)
    assert cv2.imwrite(str(tmp_path / "sky.hdr"), sky)
    blend, ren, slc, T = _build("scene")
    blend.apply_lighting(_no_light())
    dark_rgb = ren.render(tmp_path / "r0", SEED).rgb.astype(np.float64)
    stack0, _ = slc.render_fringes(tmp_path / "f0", SEED, T)
    assert float(np.max(slc.ambient_image)) < 1e-6            # nothing but the projector lights it yet
    blend.apply_lighting(_no_light({"map": str(tmp_path / "sky.hdr"), "rotation_deg": 30.0, "strength": 1.0}))
    proj = slc.strategy.flat.projector                                 # the fast mode's flat-lit projector
    layers = [blend.scene.view_layers[n] for n in proj.layer_names]
    assert layers and fringe_layer_leaks(blend.scene, layers, proj.collections) == {}
    lit_rgb = ren.render(tmp_path / "r1", SEED).rgb.astype(np.float64)
    stack1, _ = slc.render_fringes(tmp_path / "f1", SEED, T)
    amb = slc.ambient_image
    assert 0.2 < float(np.median(amb)) < 0.32, float(np.median(amb))
    assert float(np.max(np.abs(stack1 - stack0))) < 1e-4 * float(stack0.max())
    assert lit_rgb.mean() > dark_rgb.mean() + 30                # 8-bit sRGB: the sky lifts the floor


def test_textured_floor_is_one_material_for_rgb_and_fringes(tmp_path):
    """A grey checker (bright albedo 0.8, contrast 0.75: dark 0.2, 5 cm squares) on the floor. The
    fast mode's fringe offset A (the mean of the 4 steps of the one-period fringe) scales with the
    albedo: textured / untextured (0.5 grey) is 1.6 on bright and 0.4 on dark squares (within 20%:
    the 4% specular layer adds alike to both, the squares' edges mix), on most pixels; the RGB's
    brighter half is the fringes' bright squares."""
    blend, ren, slc, T = _build("off")
    plain, _ = slc.render_fringes(tmp_path / "plain", SEED, T)
    draw = {"kind": "checker", "colors": [[0.8, 0.8, 0.8], [0.2, 0.2, 0.2]], "contrast": 0.75,
            "feature_size": 0.05, "param": 0.0}
    blend.set_textures({"floor": draw})
    assert blend.floor.data.materials[0].name.startswith("datapipe_tex_floor")
    tex, _ = slc.render_fringes(tmp_path / "tex", SEED, T)
    rgb = ren.render(tmp_path / "rgb", SEED).rgb.astype(np.float64).mean(axis=2)
    a_plain, a_tex = plain[:STEPS].mean(axis=0), tex[:STEPS].mean(axis=0)
    lit = a_plain > 0.2 * np.median(a_plain)                   # inside the projector's image
    ratio = a_tex[lit] / a_plain[lit]
    bright = np.abs(ratio / 1.6 - 1) < 0.2
    dark = np.abs(ratio / 0.4 - 1) < 0.2
    print(f"bright {bright.mean():.2f}, dark {dark.mean():.2f} of {lit.sum()} lit pixels")
    assert bright.mean() > 0.25 and dark.mean() > 0.25 and (bright | dark).mean() > 0.75
    r = rgb[lit]
    assert np.median(r[bright]) > 1.5 * np.median(r[dark])     # sRGB of 4x the albedo
    thr = 0.5 * (np.median(r[bright]) + np.median(r[dark]))
    agree = np.mean((r[bright | dark] > thr) == bright[bright | dark])
    assert agree > 0.9, agree


def _run_config(tmp_path) -> C.Config:
    """1 scene x 2 renders at 48x36, every look option on: textures on all targets from all kinds
    (one image set: a pure red colour map), lighting per render from a folder of two skies."""
    sets = tmp_path / "sets" / "paint"
    sets.mkdir(parents=True, exist_ok=True)
    red = np.zeros((8, 8, 3), np.uint8)
    red[..., 2] = 255                                          # BGR: pure red
    assert cv2.imwrite(str(sets / "paint_Color.png"), red)
    assert cv2.imwrite(str(sets / "paint_Roughness.png"), np.full((8, 8), 128, np.uint8))
    skies = tmp_path / "skies"
    skies.mkdir(exist_ok=True)
    for name, v in (("blue.hdr", (1.0, 0.5, 0.2)), ("warm.exr", None)):
        if v is not None:
            assert cv2.imwrite(str(skies / name), np.tile(np.float32(v), (8, 16, 1)))
    from datapipe.io.exr import write_exr
    write_exr(skies / "warm.exr", {c: np.full((8, 16), x, np.float32) for c, x in zip("RGB", (1.0, 0.6, 0.3))})
    cfg = maps_only(small_config(2, (48, 36), samples=2, per_scene=2, instances=2, threads=2))
    cfg.scene.textures = C.TexturesConfig(targets=["bin", "floor", "parts"], kinds=[*C.TEXTURE_KINDS],
                                          image_folder=str(tmp_path / "sets"))
    cfg.lighting = C.LightingConfig(per_render=True, environment=str(skies))
    return cfg.validate()


def test_a_run_records_its_textures_and_light_per_render_and_is_made_again_alike(tmp_path):
    """scene.json: per scene the bin, floor and one texture per part (every kind of the list, the
    image set by name), no scene lighting; per render its own lighting draw with a map of the
    folder. Made again from the seed (a second run), every record and image is the same."""
    import json
    from datapipe.engine.pipeline import Pipeline

    def run(out):
        events = list(Pipeline(_run_config(tmp_path), out).run())
        assert events[-1].stage == "done", events[-1]
        return [json.loads(p.read_text()) for p in sorted(out.glob("scene.*/scene.json"))]

    scenes = run(tmp_path / "a")
    assert len(scenes) == 1
    kinds, maps = set(), set()
    for s in scenes:
        t = s["textures"]
        assert set(t) == {"bin", "floor", "parts"} and len(t["parts"]) == len(s["objects"])
        kinds |= {d["kind"] for d in [t["bin"], t["floor"], *t["parts"]]}
        assert all(d["set"] == "paint/paint" for d in [t["bin"], t["floor"], *t["parts"]] if d["kind"] == "image")
        assert "lighting" not in s
        lights = [r["lighting"] for r in s["renders"]]
        assert lights[0]["key_power"] != lights[1]["key_power"]
        maps |= {Path(li["environment"]["map"]).name for li in lights}
    assert len(kinds) >= 3 and maps <= {"blue.hdr", "warm.exr"}
    bpy.ops.wm.read_factory_settings(use_empty=True)
    again = run(tmp_path / "b")
    for s, t in zip(scenes, again):
        assert s["textures"] == t["textures"] and [r["lighting"] for r in s["renders"]] == \
            [r["lighting"] for r in t["renders"]]
    for f in sorted((tmp_path / "a").glob("scene.*/render.*/rgb.png")):
        same = tmp_path / "b" / f.relative_to(tmp_path / "a")
        assert np.array_equal(cv2.imread(str(f)), cv2.imread(str(same))), f


def test_an_image_set_colours_the_floor(tmp_path):
    """A set whose colour map is pure red on the floor: the floor's RGB turns red (red channel
    well above green and blue), where the untextured grey floor is grey."""
    cfg = _run_config(tmp_path)
    blend, ren, slc, T = _build("off")
    grey = ren.render(tmp_path / "g", SEED).rgb.astype(np.float64)
    from datapipe.draws.textures import texture_sets
    s = texture_sets(tmp_path / "sets")[0]
    assert s["roughness"].endswith("paint_Roughness.png")
    blend.set_textures({"floor": {"kind": "image", "colors": [[1, 1, 1], [0, 0, 0]], "contrast": 0.0,
                                  "feature_size": 0.1, "param": 0.0, "set": s}})
    red = ren.render(tmp_path / "r", SEED).rgb.astype(np.float64)
    g = np.median(grey.reshape(-1, 3), axis=0)
    r = np.median(red.reshape(-1, 3), axis=0)
    assert abs(g[0] - g[1]) < 10 and abs(g[1] - g[2]) < 10                 # grey: R = G = B
    assert r[0] > 3 * max(r[1], r[2]) + 10, r                              # red
    assert cfg.scene.textures.targets
    # the open file's own unused image (a file's, no user) stays; ours goes once no material uses it
    assert cv2.imwrite(str(tmp_path / "user.png"), np.zeros((4, 4, 3), np.uint8))
    own = bpy.data.images.load(str(tmp_path / "user.png"))
    ours = [i.name for i in bpy.data.images if i.get("datapipe_loaded")]
    assert ours and own.users == 0 and own.name not in ours
    blend.set_textures({})
    assert own.name in bpy.data.images and not [n for n in ours if n in bpy.data.images]
