"""Run from the sidebar (bpy.ops.datapipe.run, blocking as in background mode) on a tiny preset gives
the same dataset as the CLI (`python -m datapipe run PRESET --out DIR`) with the same seed; Cancel
keeps what was written; the timer path steps the same generator."""
import json
import os
import subprocess
import sys
from pathlib import Path

import bpy
import numpy as np
import pytest

from datapipe import config as C
import datapipe.ui as ui
from datapipe.ui import runner

pipeline = pytest.importorskip("datapipe.engine.pipeline")
ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(autouse=True)
def d(ui_props):
    return ui_props


def tiny_preset(d, tmp_path, num_renders=2):
    """Panels filled as a user would: the default preset, made tiny."""
    bpy.ops.datapipe.initialize(preset="builtin:default")
    d.scene.num_renders = num_renders
    d.scene.min_renders_per_scene, d.scene.max_renders_per_scene = 1, 1
    d.scene.seed = 7
    while len(d.objects) > 1:
        d.objects_index = len(d.objects) - 1
        bpy.ops.datapipe.object_remove()
    d.objects[0].min_instances, d.objects[0].max_instances = 1, 2
    d.camera.resolution = (40, 30)
    d.structured_light.periods = "1, 8"      # finest fringe >= 3 camera px at 40 px (validation refuses finer)
    d.render.samples = 1
    d.render.threads = 2
    d.simulation.max_frames = 40
    d.output.legacy_pickle = False
    d.output.overview = False
    path = tmp_path / "tiny.json"
    bpy.ops.datapipe.preset_save(filepath=str(path))
    return path


def _load_scene_json(p: Path) -> dict:
    return json.loads(p.read_text())


def _files(out: Path) -> list[str]:
    return sorted(str(p.relative_to(out)) for p in out.rglob("*") if p.is_file() and p.name != "run.json"
                  and "sheets" not in p.parts)


def test_run_matches_cli(d, tmp_path, capfd):
    preset = tiny_preset(d, tmp_path)
    out_ui, out_cli = tmp_path / "ui", tmp_path / "cli"
    d.output.path = str(out_ui)
    capfd.readouterr()
    assert bpy.ops.datapipe.run(blocking=True) == {"FINISHED"}
    assert d.status.startswith("Done: 2/2")
    console = capfd.readouterr()                # Blender's own output: in the run's log, not the console
    assert "| Saved: '" not in console.out + console.err
    assert (out_ui / "blender.log").read_text().count("| Saved: '") >= 2

    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    r = subprocess.run([sys.executable, "-m", "datapipe", "run", str(preset), "--out", str(out_cli), "--quiet"],
                       cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-3000:]

    assert _files(out_ui) == _files(out_cli)
    assert {"scene.0002/render.0001/rgb.png", "scene.0002/render.0001/depth.exr"} <= set(_files(out_cli))
    run_ui, run_cli = (json.loads((o / "run.json").read_text()) for o in (out_ui, out_cli))
    assert run_ui["plan"] == run_cli["plan"] and run_ui["seed"] == run_cli["seed"] == 7
    assert run_ui["config_identity"] == run_cli["config_identity"]
    for sj in sorted(out_cli.glob("scene.*/scene.json")):
        a = _load_scene_json(out_ui / sj.relative_to(out_cli))
        b = _load_scene_json(sj)
        assert a == b
    from datapipe.io.exr import read_depth, read_mask
    for f in _files(out_cli):
        if f.endswith("depth.exr"):
            np.testing.assert_array_equal(read_depth(out_ui / f), read_depth(out_cli / f))
        elif f.endswith("mask.exr"):
            np.testing.assert_array_equal(read_mask(out_ui / f), read_mask(out_cli / f))
        elif f.endswith(".png"):
            import cv2
            np.testing.assert_array_equal(cv2.imread(str(out_ui / f), cv2.IMREAD_UNCHANGED),
                                          cv2.imread(str(out_cli / f), cv2.IMREAD_UNCHANGED))


def test_cancel_keeps_what_was_written(d, tmp_path):
    tiny_preset(d, tmp_path, num_renders=3)
    out = tmp_path / "out"
    cfg = C.load(tmp_path / "tiny.json")
    pipe = pipeline.Pipeline(cfg, out)
    run = runner.Run(pipe, bpy.context.scene.name)
    runner._ACTIVE = run
    while run.step():                     # the timer path: one event per tick
        if run.last.stage == "render":
            assert bpy.ops.datapipe.cancel() == {"FINISHED"}
    assert run.last.stage == "cancelled" and run.error is None
    assert not runner.is_running()
    assert d.status.startswith("Cancelled at 1/3")
    assert (out / "scene.0001" / "scene.json").is_file()
    assert not (out / "scene.0002").exists()
    # Resume continues the run to the end
    d.output.path = str(out)
    d.resume = True
    bpy.ops.datapipe.run(blocking=True)
    assert json.loads((out / "run.json").read_text())["status"] == "complete"


def test_timer_path_registers_and_ticks(d, tmp_path, monkeypatch):
    """In the UI (not background) Run registers a timer; each tick advances one event."""
    tiny_preset(d, tmp_path, num_renders=1)
    d.output.path = str(tmp_path / "out")
    registered = []
    monkeypatch.setattr(bpy.app.timers, "register", lambda fn, **kw: registered.append((fn, kw)))
    cfg = C.load(tmp_path / "tiny.json")
    run = runner.start(pipeline.Pipeline(cfg, tmp_path / "out"), bpy.context.scene.name, blocking=False)
    assert registered and registered[0][0] is runner._tick and registered[0][1]["persistent"]
    assert runner.is_running()
    ticks = 0
    while runner._tick() is not None:
        ticks += 1
    assert ticks >= 2 and run.finished and run.last.stage == "done"
    assert not runner.is_running()
    with pytest.raises(RuntimeError, match="not empty"):
        bpy.ops.datapipe.run(blocking=True)


def test_opening_another_file_stops_the_run(d, tmp_path, monkeypatch):
    tiny_preset(d, tmp_path, num_renders=2)
    monkeypatch.setattr(bpy.app.timers, "register", lambda fn, **kw: None)
    cfg = C.load(tmp_path / "tiny.json")
    run = runner.start(pipeline.Pipeline(cfg, tmp_path / "out"), bpy.context.scene.name, blocking=False)
    runner._tick()
    assert runner.is_running() and runner._on_load_pre in bpy.app.handlers.load_pre
    bpy.ops.wm.read_factory_settings(use_empty=True)         # the user opens another file
    assert not runner.is_running() and run.finished
    assert runner._on_load_pre not in bpy.app.handlers.load_pre


def test_previews_are_hidden_from_renders(d, tmp_path, assets_dir):
    from datapipe.ui import preview
    bpy.ops.datapipe.object_add(filepath=str(assets_dir / "peg.obj"))
    bpy.ops.datapipe.object_preview()
    bpy.ops.datapipe.camera_preview()
    bpy.ops.datapipe.projector_preview()
    objs = [o for o in bpy.data.objects if o.get(preview.TAG)]
    assert len(objs) >= 3 and all(o.hide_render for o in objs)
    assert bpy.data.collections[preview.COLLECTION].hide_render
    preview.remove_all()
