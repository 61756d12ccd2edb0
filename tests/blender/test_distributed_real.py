"""Ray with the real runner (bpy + pipeline): two shards, one killed and retried, give the
one-process run (moved here from tests/test_distributed.py: it runs the real Blender pipeline)."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from datapipe import config as config_mod
from datapipe.engine.distributed import run_distributed

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from distributed_helpers import assert_recorded_as_written, killing, legacy, local_ray  # noqa: E402,F401

REAL_RUNNER = [sys.executable, "-m", "datapipe", "run"]


def tiny_real_preset(path: Path) -> Path:
    cfg = config_mod.default_config()
    cfg.scene.num_renders = 4
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 1     # 4 scenes
    cfg.camera.resolution = [96, 72]
    cfg.structured_light.periods = [1, 4, 16]      # finest fringe 6 camera px (>= 3, or validate refuses)
    cfg.render.samples = 2
    cfg.simulation.max_frames = 60
    for o in cfg.objects:
        o.min_instances, o.max_instances = 1, 2
    config_mod.save(cfg, path)
    return path


def real_annotations(run: Path) -> dict:
    out = {}
    for sj in sorted(run.glob("scene.*/scene.json")):
        doc = json.loads(sj.read_text())
        out[sj.parent.name] = [
            (rd["image_id"], rd["pose_index"], [(o["name"], o["obj_id"], o["mask_index"],
                                                 np.round(np.asarray(o["T_cam_obj"]), 6).tolist(), o["px_count_visib"])
                                                for o in rd["objects"]]) for rd in doc["renders"]]
    return out


@pytest.mark.slow
def test_ray_real_pipeline_two_shards_with_a_kill_match_one_process(tmp_path, local_ray, monkeypatch):
    preset = tiny_real_preset(tmp_path / "preset.json")
    r = subprocess.run([sys.executable, "-m", "datapipe", "run", str(preset), "--out", str(tmp_path / "single"),
                        "--quiet"], capture_output=True, text=True, timeout=1200)
    assert r.returncode == 0, r.stderr[-3000:]
    summary = run_distributed(preset, tmp_path / "out", num_shards=2, retries=2, extra_args=["--quiet"],
                              runner=killing(REAL_RUNNER, 1))     # shard 1 is killed after its first scene
    assert summary["scenes"] == 4 and summary["attempts"][1] == 2
    assert real_annotations(tmp_path / "out") == real_annotations(tmp_path / "single")
    assert legacy(tmp_path / "out") == legacy(tmp_path / "single")
    logs = tmp_path / "out" / "logs"           # Blender's own output: in each shard's blender.log, kept
    for i in range(2):                         # with the runner's log, which has none of it
        assert "render           | Saved: '" in (logs / f"shard_000{i}_of_0002.blender.log").read_text()
        assert "Saved: '" not in (logs / f"shard_000{i}_of_0002.log").read_text()
    assert_recorded_as_written(tmp_path / "out")     # the merged run's manifest, as a one-process run's
