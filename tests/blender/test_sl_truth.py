"""Issue #19, items 3 and 5: no confident wrong points from bounced light, on a real render.

The cheapest real render that shows the bin wall the demo got wrong: the original GUI's rig
(legacy pickle preset, camera 0.55 m above the bin floor, 320x240, everything structured light at
its defaults: fringe_mode "auto" -> "fast" for the meshes' own material, auto exposure, local
reflection filter). The bin's inner wall on the projector's side is lit at grazing incidence
(Cycles' direct light there is ~1/6 of the floor's) and gets more light bounced off the floor than
straight from the projector; the bounce keeps the coarse fringes (1 period: 98%) and so decides
their phase and the fringe order: points 5-210 mm in front of the wall.

Ground truth independent of the fringes: the native z-buffer, depth edges from it
(sl_scenes.depth_edges: a > 5 mm second difference, +-2 px), and the pixels the projector lights
directly (Blender ray cast from the z-buffer point towards the projector, sl_scenes.direct_mask).

Asserted (the issue's acceptance): of the valid SL pixels away from depth edges at most 0.1% more
than 5 mm off and p99 <= 2 mm; >= 80% of the directly lit part pixels within 1 mm; projector-
shadowed pixels (at least 2 px from any directly lit one: the ray cast tests the pixel centre, a
neighbour of a lit pixel is partly lit) with depth: <= 0.5%.

Measured with this code (seed 1234): > 5 mm off edges 0.000%, p99 off edges 0.34 mm, part pixels
within 1 mm 0.877, deep shadow with depth 0 (benchmarks/results/sl_truth.md, gui_h0.55 fast).
On main before the global-light filter the same render gave 1.96% > 5 mm off edges and a p99 of
109 mm (835 of the 889 wrong pixels on the bounce-dominated wall); part pixels 0.885.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from sl_scenes import depth_edges, direct_mask, rig_config  # noqa: E402

from datapipe.io.exr import read_depth  # noqa: E402

SEED = 1234
HEIGHT = 0.55
MAX_OFF_SHARE = 1e-3           # of the valid pixels away from depth edges, > 5 mm off
MAX_P99 = 2e-3                 # m, away from depth edges
MIN_PART_OK = 0.8              # directly lit part pixels within 1 mm
MAX_SHADOW_VALID = 5e-3        # of the projector-shadowed pixels (>= 2 px from any lit one)


@pytest.fixture(scope="module")
def scan(tmp_path_factory):
    from scipy.ndimage import binary_dilation

    from datapipe.core.world import BlenderWorld
    from datapipe.draws.seeds import scene_rng

    tmp = tmp_path_factory.mktemp("sl_truth")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    cfg = rig_config("gui", HEIGHT)
    cfg.render.outputs = ["depth", "mask"]   # no RGB: the native layer takes 1 sample; depth and mask are the
                                             # pixel centre's at any count (core/renderer.py), so the same truth
    world = BlenderWorld(cfg, tmp / "world")
    world.setup()
    world.start_scene(0, cfg.scene.seed, scene_rng(cfg.scene.seed, 0), 1)
    T = world.camera.set_pose(0)
    native = world.renderer.render(tmp / "native", SEED)
    files, info = world.sl.process(tmp / "sl", SEED, T)
    z = native.depth
    direct = direct_mask(world.blend.scene, cfg, T, world.camera.K, z)
    world.close()
    sl_z = read_depth(files["sl_depth"])
    seen = np.isfinite(z)
    return {"z": z, "sl": sl_z, "valid": np.isfinite(sl_z) & seen, "edge": depth_edges(z), "info": info,
            "lit_part": direct & (native.mask > 0) & seen,
            "deep_shadow": seen & ~binary_dilation(direct, iterations=2)}


def test_defaults_are_what_the_user_gets(scan):
    assert scan["info"]["fringe_mode"] == "fast" and scan["info"]["exposure_mode"] == "auto"
    assert scan["lit_part"].sum() > 400 and scan["deep_shadow"].sum() > 1000   # the metrics mean something


def test_no_wrong_points_away_from_depth_edges(scan):
    err = np.abs(scan["sl"] - scan["z"])
    away = scan["valid"] & ~scan["edge"]
    assert away.sum() > 0.3 * away.size
    off = (err[away] > 5e-3).mean()
    p99 = np.percentile(err[away], 99)
    assert off <= MAX_OFF_SHARE and p99 <= MAX_P99, (off, p99)


def test_directly_lit_part_pixels_keep_their_depth(scan):
    err = np.abs(scan["sl"] - scan["z"])
    ok = scan["valid"] & (err <= 1e-3)
    assert ok[scan["lit_part"]].mean() >= MIN_PART_OK


def test_projector_shadow_has_no_depth(scan):
    assert scan["valid"][scan["deep_shadow"]].mean() <= MAX_SHADOW_VALID
