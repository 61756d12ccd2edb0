"""Issue #9, item 5: with the default structured-light settings, parts get SL depth from 0.35 m to
1.5 m camera height, for the default rig and the original GUI's rig (tests/sl_scenes.py).

One scene (the demo preset's parts dropped into its bin, as an original-layout pickle preset makes
it) is rendered at both ends of the working distance and scanned with both rigs; the native render
per height is shared (the projector is not in it). Everything structured light is the default:
exposure "auto", fringe_mode "auto" (-> "fast" for the meshes' own materials), 320x240 (the
smallest resolution the default periods [1, 8, 64] pass validation at).

Metric, against ground truth independent of the fringes: of the part pixels the projector lights
directly and the camera sees (z-buffer point inside the projector image with a free line to the
projector: Blender ray cast, sl_scenes.direct_mask; part = instance mask > 0), the fraction whose
sl_depth.exr is within `tolerance(z)` of the native z-buffer depth.

Tolerance: the phase-shift depth noise is sigma_Z = Z^2 / (f_p b) * sigma_x (docs/CONVENTIONS.md; the standard fringe-projection error propagation),
and auto exposure keeps the signal, hence sigma_x, about constant over distance (metered 0.10 at
0.35 m, 2.4 at 1.5 m: ~Z^2), so errors grow as Z^2 / b. `tolerance` = TOL_1M at 1 m depth over a
0.12 m baseline, x z^2 / b: 0.17-0.22 mm on the parts at 0.35 m, 3.5-4.4 mm at 1.5 m, ~10x the
median error measured here at both ends (0.014-0.018 mm and 0.34-0.45 mm; sl_materials.md, render
mode: 0.023 / 0.27 mm). Noise passes; a wrong fringe order (>= one fine period, 16 mm across at
1.5 m, x Z/b in depth: > 100 mm) or a strongly multipath-biased phase does not. (The issue's 1 mm
at its 0.55 m acceptance case is this tolerance at ~0.7 m depth.)

Measured (render seeds 1234, 1, 2, 3), fraction ok:
  default 0.35 m: 0.89      (lit part px 3458)   default 1.5 m: 0.86-0.88 (615 px)
  gui     0.35 m: 0.86      (4294 px)            gui     1.5 m: 0.89-0.90 (615 px)
so MIN_OK = 0.8 (the issue's acceptance fraction) leaves 6 points under the lowest case, 4x the
seed spread (<= 1.5 points). SL depth on the part pixels (lit or not): 0.30-0.36 at 0.35 m (the
projector, toed in to cross the camera axis at 0.8-1.0 m, lights part of the near view), 0.93-0.96 at 1.5 m.

Checked to fail on the old behaviour: the same measurement with structured_light.exposure = 0.5
(the former fixed exposure, `measure(tmp, exposure=0.5)`) gives 0.001 (default) and 0.003 (gui)
at 0.35 m, where the parts saturate; at 1.5 m it passes too (0.90 / 0.91: the old exposure already
reached 1.5 m, with ~1.6x the median error).
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from sl_scenes import RIGS, direct_mask, rig_config  # noqa: E402

from datapipe import config as C  # noqa: E402
from datapipe.io.exr import read_depth  # noqa: E402

HEIGHTS = (0.35, 1.5)          # m, camera above the bin floor: the ends of the working distance
SEED = 1234
TOL_1M = 2e-3                  # m of depth error allowed at 1 m depth with a 0.12 m baseline (x z^2 / b)
MIN_OK = 0.8                   # fraction of the directly lit part pixels within the tolerance


def tolerance(z: np.ndarray, baseline: float) -> np.ndarray:
    return TOL_1M * z * z * (0.12 / baseline)


def measure(tmp: Path, exposure=None) -> dict:
    """{(rig, height): metrics} of one dropped scene; `exposure` overrides the default ("auto")."""
    from datapipe.core.structured_light import StructuredLightCamera
    from datapipe.core.world import BlenderWorld
    from datapipe.draws.seeds import scene_rng

    bpy.ops.wm.read_factory_settings(use_empty=True)
    cfg = rig_config("default", HEIGHTS[0])
    cfg.camera.poses = [C.CameraPose(location=[0.0, 0.0, h]) for h in HEIGHTS]
    cfg.render.outputs = ["depth", "mask"]   # no RGB: the native layer takes 1 sample; depth and mask are the
                                             # pixel centre's at any count (core/renderer.py), so the same truth
    if exposure is not None:
        cfg.structured_light.exposure = exposure
    world = BlenderWorld(cfg, tmp / "world")
    world.setup()
    world.start_scene(0, cfg.scene.seed, scene_rng(cfg.scene.seed, 0), 1)
    native, out = {}, {}
    for rig in RIGS:
        if rig != "default":          # the projector pose is config: rebuild the SL camera on the same scene
            cfg.projector = rig_config(rig, HEIGHTS[0]).projector
            world.sl.teardown()
            world.sl = StructuredLightCamera(cfg, world.blend.scene, world.camera, world.renderer)
            world.sl.setup()
        baseline = float(np.linalg.norm(cfg.projector.location))
        for k, h in enumerate(HEIGHTS):
            T = world.camera.set_pose(k)
            if k not in native:
                native[k] = world.renderer.render(tmp / f"native_{k}", SEED)
            z, part = native[k].depth, native[k].mask > 0
            rdir = tmp / f"{rig}_{k}"
            files, info = world.sl.process(rdir, SEED, T)
            sl_z = read_depth(files["sl_depth"])
            lit = direct_mask(world.blend.scene, cfg, T, world.camera.K, z, where=part)
            err = np.abs(sl_z - z)
            ok = np.isfinite(err) & (err <= tolerance(z, baseline))
            out[(rig, h)] = {"ok": float(ok[lit].mean()), "lit_px": int(lit.sum()),
                             "valid_parts": float(np.isfinite(sl_z[part]).mean()),
                             "tol_mm": float(np.median(tolerance(z[lit], baseline)) * 1e3),
                             "median_mm": float(np.nanmedian(err[lit]) * 1e3),
                             "p99_mm": float(np.nanpercentile(err[lit], 99) * 1e3),
                             "fringe_mode": info["fringe_mode"], "exposure": info["exposure"],
                             "exposure_mode": info["exposure_mode"]}
    world.close()
    return out


@pytest.fixture(scope="module")
def working_distance(tmp_path_factory):
    return measure(tmp_path_factory.mktemp("sl_wd"))


@pytest.mark.parametrize("rig", list(RIGS))
@pytest.mark.parametrize("height", HEIGHTS)
def test_parts_get_depth_at_both_ends_of_the_working_distance(working_distance, rig, height):
    m = working_distance[(rig, height)]
    assert m["fringe_mode"] == "fast" and m["exposure_mode"] == "auto"    # the defaults, nothing pinned
    assert m["lit_px"] > 400, m               # the parts are in view and lit: the metric means something
    assert m["ok"] >= MIN_OK, m
