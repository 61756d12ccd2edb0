"""`render.persistent_data` keeps Cycles' scene (BVH, shaders, images) between renders; it must not
change a byte of what a run writes.

Ground truth is the same run without it: with equal seeds Cycles traces the same paths, so every
file of every render (RGB after the denoiser, depth, normals, mask, the structured-light depth and
validity) is expected byte-identical, not merely within Monte-Carlo noise. Two scenes of two views
each: the second scene's parts replace the first's (deleted objects, new ones), the views of one
pile move only the camera, and each view's fringe call switches view layers, resolution, pixel
filter and (render.sampling_pattern, as the bin presets) the sampling pattern, so a stale Cycles
scene in any of these would show."""
import json
import sys
from pathlib import Path

import pytest

pytest.importorskip("bpy")
sys.path.insert(0, str(Path(__file__).parent))

from test_pipeline import run, tiny_config  # noqa: E402

MAPS = ("rgb.png", "depth.exr", "normals.exr", "mask.exr", "sl_depth.exr", "sl_valid.png")


def _run(out, persistent):
    cfg = tiny_config(num_renders=4, res=(64, 48), samples=4)
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 2
    cfg.structured_light.fringe_mode = "quadrature"          # what bin_picking.json's steel parts use
    cfg.render.sampling_pattern = "BLUE_NOISE"               # as bin_picking.json: set around the native call
                                                             # only, so every render switches the pattern
    cfg.render.persistent_data = persistent
    cfg.output.overview = False
    run(cfg, out)
    return out


def test_persistent_data_writes_the_same_files(tmp_path):
    off, on = _run(tmp_path / "off", False), _run(tmp_path / "on", True)
    renders = sorted(p.relative_to(off) for p in off.glob("scene.*/render.*"))
    assert len(renders) == 4
    for r in renders:
        for name in MAPS:
            assert (off / r / name).read_bytes() == (on / r / name).read_bytes(), f"{r}/{name}"
    for s in sorted(off.glob("scene.*/scene.json")):
        a, b = json.loads(s.read_text()), json.loads((on / s.relative_to(off)).read_text())
        assert [x["objects"] for x in a["renders"]] == [x["objects"] for x in b["renders"]]
