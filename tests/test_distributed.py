"""Shard merging and Ray fan-out.

Merging is tested on synthetic shard folders (tests/fixtures_native.py makes the very scenes the
pipeline's `--shard i/n` would). The Ray tests run the fan-out with the fixture's stand-in runner
(same command line as `python -m datapipe run`); the Ray test with the real Blender runner is in
tests/blender/test_distributed_real.py."""
from __future__ import annotations

import hashlib
import json
import shutil
import sys
from pathlib import Path

import pytest

from datapipe import config as config_mod
from datapipe.engine.distributed import merge_shards, run_distributed
from datapipe.errors import DataPipeError
from datapipe.io.exr import read_exr

import fixtures_native as fx
from distributed_helpers import killing, legacy, local_ray  # noqa: F401  (local_ray: a fixture)

TESTS = Path(__file__).resolve().parent
FAKE_RUNNER = [sys.executable, str(TESTS / "fixtures_native.py"), "run"]


def small_cfg(**kw):
    kw.setdefault("num_renders", 6)
    kw.setdefault("min_per_scene", 1)
    kw.setdefault("max_per_scene", 2)
    kw.setdefault("resolution", (96, 72))
    return fx.default_config(**kw)


def annotations(run: Path) -> dict:
    """Everything a user trains on, per scene: scene.json less paths, plus pixel digests of the files."""
    out = {}
    for sj in sorted(run.glob("scene.*/scene.json")):
        doc = json.loads(sj.read_text())
        for rd in doc["renders"]:
            rdir = sj.parent / rd["name"]
            for name in ("depth.exr", "mask.exr", "normals.exr"):
                rd["_" + name] = {k: hashlib.md5(v.tobytes()).hexdigest() for k, v in read_exr(rdir / name).items()}
            rd["_rgb"] = hashlib.md5((rdir / "rgb.png").read_bytes()).hexdigest()
        out[sj.parent.name] = doc
    return out


def make_shards(root: Path, cfg, n: int, **kw) -> list[Path]:
    return [fx.make_native_run(root / f"shard{i}", cfg=cfg, shard=(i, n), **kw) for i in range(n)]


# ------------------------------------------------------------------------------------------------
# merge_shards

def test_merge_equals_one_process(tmp_path):
    cfg = small_cfg()
    single = fx.make_native_run(tmp_path / "single", cfg=cfg)
    shards = make_shards(tmp_path, cfg, 3)
    summary = merge_shards(shards, tmp_path / "merged")
    merged = tmp_path / "merged"
    n_scenes = len(list(single.glob("scene.*")))
    assert summary["scenes"] == n_scenes >= 3 and summary["images"] == 6
    assert annotations(merged) == annotations(single)
    assert legacy(merged) == legacy(single)
    for s in single.glob("scene.*/render.*/rgb.png"):
        assert (merged / s.relative_to(single)).read_bytes() == s.read_bytes()
    run = json.loads((merged / "run.json").read_text())
    assert run["status"] == "complete" and run["shard"] == [0, 1]
    assert run["scenes_done"] == sorted(p.name for p in single.glob("scene.*"))
    assert (merged / "models" / "models_info.json").read_text() == (single / "models" / "models_info.json").read_text()
    assert not list(shards[0].glob("scene.*"))                  # moved, not copied


def test_merge_copy_mode_keeps_shards(tmp_path):
    cfg = small_cfg()
    shards = make_shards(tmp_path, cfg, 2)
    merge_shards(shards, tmp_path / "merged", move=False)
    assert list(shards[0].glob("scene.*")) and len(list((tmp_path / "merged").glob("scene.*"))) >= 3


def test_merge_refuses_duplicates_and_moves_nothing(tmp_path):
    cfg = small_cfg()
    shards = make_shards(tmp_path, cfg, 2)
    shutil.copytree(shards[0] / "scene.0001", shards[1] / "scene.0001")
    before = sorted(p.name for p in shards[0].glob("scene.*"))
    with pytest.raises(DataPipeError, match=r"duplicate scenes.*scene\.0001"):
        merge_shards(shards, tmp_path / "merged")
    assert sorted(p.name for p in shards[0].glob("scene.*")) == before
    assert not (tmp_path / "merged").exists() or not list((tmp_path / "merged").glob("scene.*"))


def test_merge_reports_missing_scenes_and_the_shard_to_rerun(tmp_path):
    cfg = small_cfg()
    shards = make_shards(tmp_path, cfg, 3)
    with pytest.raises(DataPipeError, match=r"missing: scene\.\d{4} \(shard 2/3, .*--shard 2/3 --resume"):
        merge_shards(shards[:2], tmp_path / "merged")
    # a scene killed mid-way (no scene.json) counts as missing, not as merged
    last = sorted(shards[1].glob("scene.*"))[-1]
    (last / "scene.json").unlink()
    with pytest.raises(DataPipeError, match=f"missing: {last.name}"):
        merge_shards(shards, tmp_path / "merged2")


def test_merge_refuses_shards_of_different_runs(tmp_path):
    a = fx.make_native_run(tmp_path / "a", cfg=small_cfg(), shard=(0, 2))
    b = fx.make_native_run(tmp_path / "b", cfg=small_cfg(seed=5), shard=(1, 2))
    with pytest.raises(DataPipeError, match="different (plan|seed)"):
        merge_shards([a, b], tmp_path / "merged")
    with pytest.raises(DataPipeError, match="not a DataPipe run"):
        merge_shards([tmp_path], tmp_path / "merged")


# ------------------------------------------------------------------------------------------------
# Ray (local instance, stand-in runner)

def write_preset(path: Path, cfg) -> Path:
    cfg.objects = fx.default_config(mesh_dir=path.parent / "meshes").objects    # real files: the preset validates
    config_mod.save(cfg, path)
    return path


def ray_run(preset, out, **kw):
    """The Ray driver with the stand-in runner: nothing renders with Blender, so the driver's gate
    leaves out the Blender mesh preflight (Blender-free tests never import bpy)."""
    return run_distributed(preset, out, blender_checks=False, **kw)


def test_ray_two_shards_match_one_process(tmp_path, local_ray):
    cfg = small_cfg(num_renders=4, min_per_scene=1, max_per_scene=1)      # 4 scenes
    preset = write_preset(tmp_path / "preset.json", cfg)
    single = fx.make_native_run(tmp_path / "single", cfg=cfg)
    logs = []
    summary = ray_run(preset, tmp_path / "out", num_shards=2, runner=FAKE_RUNNER, log=logs.append)
    out = tmp_path / "out"
    assert summary["scenes"] == 4 and summary["images"] == 4 and summary["attempts"] == {0: 1, 1: 1}
    assert annotations(out) == annotations(single)
    assert legacy(out) == legacy(single)
    assert not (out / "_shards").exists()
    assert sorted(p.name for p in (out / "logs").iterdir()) == ["shard_0000_of_0002.log", "shard_0001_of_0002.log"]
    assert (out / "sheets" / "overview.png").is_file()                     # output.overview
    assert any("shard 1/2 done" in m for m in logs)


def test_ray_killed_shard_is_retried_and_resumes(tmp_path, local_ray, monkeypatch):
    cfg = small_cfg(num_renders=4, min_per_scene=1, max_per_scene=1, formats=("native", "bop"))
    preset = write_preset(tmp_path / "preset.json", cfg)
    single = fx.make_native_run(tmp_path / "single", cfg=cfg)
    summary = ray_run(preset, tmp_path / "out", num_shards=2, runner=killing(FAKE_RUNNER, 0), retries=2,
                              env={"FIXTURE_SCENE_DELAY": "1.0"})   # shard 0 killed once its first scene is done
    out = tmp_path / "out"
    assert summary["attempts"] == {0: 2, 1: 1}
    log = (out / "logs" / "shard_0000_of_0002.log").read_text()
    assert "kill_runner: killed after 1 scene" in log and "=== attempt 2" in log
    assert annotations(out) == annotations(single)          # complete, nothing twice
    assert sorted(p.name for p in out.glob("scene.*")) == ["scene.0001", "scene.0002", "scene.0003", "scene.0004"]
    # the preset asks for BOP: exported once, on the merged run, with the global image ids
    gt = json.loads((out / "bop" / "train_pbr" / "000000" / "scene_gt.json").read_text())
    assert sorted(int(k) for k in gt) == [0, 1, 2, 3]


def test_ray_failing_shard_is_reported_and_a_rerun_resumes(tmp_path, local_ray):
    cfg = small_cfg(num_renders=4, min_per_scene=1, max_per_scene=1)
    preset = write_preset(tmp_path / "preset.json", cfg)
    failing = [sys.executable, "-c", "import sys; sys.exit(3)"]
    with pytest.raises(DataPipeError, match=r"2 of 2 shard\(s\) failed after 2 attempt\(s\).*run the same command"):
        ray_run(preset, tmp_path / "out", num_shards=2, runner=failing, retries=1)
    assert (tmp_path / "out" / "_shards" / "shard_0000_of_0002.log").read_text().count("=== attempt") == 2
    summary = ray_run(preset, tmp_path / "out", num_shards=2, runner=FAKE_RUNNER)
    assert summary["scenes"] == 4
    with pytest.raises(DataPipeError, match="already holds scenes"):
        ray_run(preset, tmp_path / "out", num_shards=2, runner=FAKE_RUNNER)


def test_a_left_behind_runner_is_stopped_but_nothing_else(tmp_path):
    """A retry ends the runner its killed predecessor left (matched by the shard folder in its command
    line); a stale pid file naming any other process is ignored."""
    import os
    import socket
    import subprocess
    from datapipe.engine.distributed import _stop_previous_runner
    shard = tmp_path / "shard_0000_of_0001"
    pid_file = tmp_path / "shard_0000_of_0001.pid"
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    runner = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)", "--out", str(shard)])
    try:
        pid_file.write_text(f"{socket.gethostname()} {other.pid}\n")
        _stop_previous_runner(pid_file, shard)
        assert other.poll() is None                                   # not ours to stop
        pid_file.write_text(f"{socket.gethostname()} {os.getpid()}\n")
        _stop_previous_runner(pid_file, shard)                        # (nor the test itself)
        pid_file.write_text(f"{socket.gethostname()} {runner.pid}\n")
        _stop_previous_runner(pid_file, shard)
        assert runner.wait(timeout=10) == -9
    finally:
        for p in (other, runner):
            if p.poll() is None:
                p.kill()
            p.wait()
