"""The add-on renders into the user's open scene. In Blender's startup scene the default cube
(2 m, at the origin) encloses the camera and the bin and shuts out the key light, so every render
was black, and the default light lit the bin and leaked into the fringe layers. `scene.other_objects` ("auto" = hide without a blend_file)
hides such objects from the renders for the run and shows them again afterwards."""
import pytest

bpy = pytest.importorskip("bpy")

from datapipe import config as C  # noqa: E402
from datapipe.engine.pipeline import Pipeline  # noqa: E402
import cv2  # noqa: E402

from datapipe.io.exr import read_mask  # noqa: E402


def _run(tmp_path, other_objects, sl=True):
    bpy.ops.wm.read_factory_settings(use_empty=False)        # Cube, Light, Camera
    assert {"Cube", "Light"} <= set(bpy.context.scene.objects.keys())
    cfg = C.load(C.presets_dir() / "default.json")
    cfg.scene.num_renders = cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 1
    cfg.scene.other_objects = other_objects
    cfg.camera.resolution = [80, 60]
    cfg.render.samples = 4
    cfg.render.outputs = ["rgb", "depth", "mask"]
    cfg.structured_light.enabled = sl
    cfg.structured_light.periods = [1, 4, 16]                 # >= 3 camera px per fringe at 80 px
    out = tmp_path / f"{other_objects}_{sl}"
    messages = [p.message for p in Pipeline(cfg, out).run()]
    rdir = out / "scene.0001" / "render.0001"
    return messages, cv2.imread(str(rdir / "rgb.png")), read_mask(rdir / "mask.exr")


def test_startup_cube_and_light_are_hidden_for_the_run_and_restored(tmp_path):
    messages, rgb, mask = _run(tmp_path, "auto")
    assert any("hid 2 object(s)" in m and "Cube" in m and "Light" in m for m in messages)
    assert rgb.mean() > 40                                    # the lit bin (grey floor ~0.4 linear)
    assert (mask > 0).any()                        # parts in view
    assert not bpy.data.objects["Cube"].hide_render and not bpy.data.objects["Light"].hide_render


def test_keep_renders_them(tmp_path):
    """The same scene with 'keep': the cube shuts the key light out (what every add-on user got);
    with structured light on, the kept light is refused before any render, naming the fix."""
    from datapipe.errors import DataPipeError
    with pytest.raises(DataPipeError, match="Light.*other_objects"):
        _run(tmp_path, "keep")
    assert not bpy.data.objects["Light"].hide_render
    messages, rgb, mask = _run(tmp_path, "keep", sl=False)
    assert not any("hid" in m for m in messages)
    assert rgb.max() < 3 and (mask > 0).any()                 # black, though the parts are in view
    assert any("black" in m for m in messages)                # the quality gate says so
