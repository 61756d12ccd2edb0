"""Rendered structured-light test scenes for the benchmarks, cached as npz (bpy only while rendering).

A *case* is (rig, camera height, material): the demo preset's parts dropped into its bin (seed 0,
scene 0), the camera straight down from `height` m above the bin floor, and the projector of
`rig`: 'default' (the preset: 0.15 m baseline, 8.5 deg toe-in) or 'gui' (where the original
DataPipe GUI puts it: 0.12 m, 8.5 deg). The preset is made the way a user of the original add-on
makes it: an original-layout pickle (camera pose, projector pose, is_structured_light) loaded with
`config.load_legacy_pickle`, everything else default (tests/sl_scenes.py, shared with
tests/blender/test_sl_working_distance.py, which checks the working distance with the default
fringe mode; the cases here pin the path-traced one).

Per case the cache holds the linear fringe stack (`rad`: the F*N fringe images, then the global
reflection filter's row code, rendered for every case so its residual can be measured on diffuse
scenes too; `renders.json` says whether the product would render it), the z-buffer depth, the instance mask,
the camera pose/intrinsics and `direct`: the pixels the projector lights directly and the camera
sees (z-buffer point inside the projector image, nothing between it and the projector: a Blender
ray cast, independent of the fringe render), plus render times.
"""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from harness import clocked, on_path

on_path("tests")
from datapipe import config as C  # noqa: E402
from datapipe.sl.scanner import ROW_PERIODS     # the row code the cache holds (renders again when it changes)  # noqa: E402
from sl_scenes import RIGS, direct_mask, rig_config  # noqa: E402,F401  (RIGS: part of this module's API)

SEED = 1234


def case_config(rig: str, height: float, material=None, res=(320, 240)) -> C.Config:
    """The original-layout pickle preset of a case (tests/sl_scenes.rig_config), with the fringes
    path-traced (the reference, as cached) and the parts' material ("NAME+bin": the bin's too)."""
    cfg = rig_config(rig, height, res)
    cfg.structured_light.fringe_mode = "render"   # the reference path (sharp glossy bounces), as cached
    if material is not None:
        name = material.removesuffix("+bin")
        for o in cfg.objects:
            o.material = name
        if name != material:
            cfg.scene.bin_material = name
    return cfg


def case_key(rig: str, height: float, material=None) -> str:
    return f"{rig}_h{height:.2f}_{material or 'file'}"


def render_cases(cases, cache: Path, log=print) -> dict:
    """Render every (rig, height, material) case missing from `cache`; returns the meta dict."""
    import bpy

    from datapipe.core.world import BlenderWorld
    from datapipe.draws.seeds import scene_rng
    from datapipe.core.structured_light import has_shiny_surface

    cache.mkdir(parents=True, exist_ok=True)
    meta_path = cache / "renders.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    groups: dict = {}
    for rig, h, mat in cases:
        if meta.get(case_key(rig, h, mat), {}).get("row_periods") != list(ROW_PERIODS):   # another row code: again
            groups.setdefault((rig, mat), []).append(h)
    for (rig, mat), heights in groups.items():
        bpy.ops.wm.read_factory_settings(use_empty=True)
        cfg = case_config(rig, heights[0], mat)
        cfg.camera.poses = [C.CameraPose(location=[0.0, 0.0, float(h)]) for h in heights]
        tmp = Path(tempfile.mkdtemp(prefix="slmat_"))
        world = BlenderWorld(cfg, tmp / "world")
        world.setup()
        world.start_scene(0, cfg.scene.seed, scene_rng(cfg.scene.seed, 0), 1)   # drops the parts, applies their material
        for k, h in enumerate(heights):
            T = world.camera.set_pose(k)
            out, native_s, _ = clocked(lambda: world.renderer.render(tmp / "native", SEED))
            world.sl.set_sharp_glossy(has_shiny_surface(world.blend.scene))   # as process() does
            rows = world.sl.wants_rows()                                       # what the product renders
            # every case: the row code's residual on diffuse bins too
            (rad, _), fringe_s, _ = clocked(lambda: world.sl.render_fringes(tmp / "fringes", SEED, rows=True))
            direct = direct_mask(world.blend.scene, cfg, T, world.camera.K, out.depth)
            key = case_key(rig, h, mat)
            np.savez_compressed(cache / f"{key}.npz", rad=rad, depth=out.depth, mask=out.mask, T=T,
                                K=world.camera.K, direct=direct, rgb=out.rgb)
            meta[key] = {"rig": rig, "height": h, "material": mat or "file", "native_s": native_s,
                         "fringe_s": fringe_s, "images": int(rad.shape[0]), "sharp_glossy": world.sl.sharp_glossy,
                         "row_periods": list(ROW_PERIODS), "product_rows": rows}
            meta_path.write_text(json.dumps(meta, indent=1))
            log(f"  {key}: native {native_s:.1f} s, fringes {fringe_s:.1f} s")
    return meta


def load_case(cache: Path, rig, height, material=None):
    return dict(np.load(cache / f"{case_key(rig, height, material)}.npz"))


# -- the adversarial synthetic stack: a dark patch beside a depth step (no bpy) -----------------------
DARK_PERIODS, DARK_STEPS = (1, 8, 64), 4
DARK_PEAK_DN = 255.0            # a white surface's brightest sample (8 bit)
DARK_READ_DN, DARK_GAIN_DN = 1.0, 40.0   # noise sigma^2 = read^2 + signal / gain (DN^2)


def dark_step_stack(cam_size=(640, 480), seed: int = 0):
    """Issue #19's adversarial stack (tests/sl/synth.py ray caster, no bpy): a floor tilted 5 deg,
    boxes with 0.13 m and 0.25 m steps, two spheres, projector shadows, a floor patch of albedo
    0.015 beside the tall box and that box (top) of albedo 0.04; periods (1, 8, 64) x 4; read +
    shot noise, 8-bit. Returns (images, render truth, camera, projector); `images` uint8."""
    on_path("tests/sl")
    import synth

    cam, proj = synth.make_rig(cam_size=cam_size, proj_size=(912, 570), baseline=0.15, distance=1.0)
    a = np.radians(5.0)
    scene = synth.Scene([synth.Plane((0, 0, 0), (np.sin(a), 0.0, np.cos(a)), 0.6),
                         synth.Box((-0.25, -0.05, -0.05), (-0.1, 0.1, 0.13), 0.5),
                         synth.Box((0.02, -0.12, -0.05), (0.16, 0.02, 0.25), 0.04),
                         synth.Box((0.17, -0.12, -0.05), (0.27, 0.02, -0.0225 * np.sin(a) + 0.002 - 0.0), 0.015),
                         synth.Sphere((-0.1, -0.2, 0.06), 0.06, 0.7), synth.Sphere((0.05, 0.2, 0.08), 0.08, 0.7)])
    r = synth.render(scene, cam, proj, DARK_PERIODS, DARK_STEPS)
    rng = np.random.default_rng(seed)
    sig = DARK_PEAK_DN * r.images
    sig = sig + rng.normal(0.0, 1.0, sig.shape) * np.sqrt(DARK_READ_DN ** 2 + np.maximum(sig, 0) / DARK_GAIN_DN)
    return np.clip(np.rint(sig), 0, 255).astype(np.uint8), r, cam, proj
