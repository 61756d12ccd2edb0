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
from distributed_helpers import assert_recorded_as_written, killing, legacy, local_ray  # noqa: F401  (local_ray: a fixture)

pytestmark = pytest.mark.usefixtures("remembered_model_analysis")   # box models analysed once (tests/model_memo.py)

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
    # the merged run's manifest, as a one-process run's: --force removes exactly the run's files
    assert_recorded_as_written(out)
    from datapipe.io import outdir
    from tree_hash import hashes
    user = {"logs/my_notes.txt": "notes", "sheets/overview_annotated.png": "mine", "_shards": "a file of mine"}
    for rel, text in user.items():
        (out / rel).write_text(text)
    user_hashes = {k: hashes(out)[k] for k in user}
    removed, kept = outdir.remove_run_files(outdir.check_force(out))      # before: refused (no manifest)
    assert kept == sorted(user) and removed > 10
    assert {k: v for k, v in hashes(out).items() if v != "dir"} == user_hashes


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
    assert_recorded_as_written(out)                         # the BOP files too, written through the guard


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


# ------------------------------------------------------------------------------------------------
# the merge writes through the output folder's guard and records a manifest (issue #33)
#
# Shards and a one-process run of the same preset made by the pipeline on the fake world (tests/
# fake_world.py, no Blender), once per module; each test merges copies of the shards. Every test
# here fails on the code before the change (the merge wrote by path and recorded nothing: --force
# and --resume refused the merged folder, a link at the temporary file or models/ was followed into
# the victim folder, a link at a scene or render folder gave an OSError, not a refusal naming it).

from datapipe.engine.distributed import _copy_models, _place_scene  # noqa: E402  (wrapped below)
from datapipe.engine.pipeline import Pipeline  # noqa: E402
from datapipe.io import outdir  # noqa: E402
from datapipe.io.writers import Writers  # noqa: E402
from fake_world import BoxWorld  # noqa: E402
from test_outdir_by_record import ISSUE_FORCE_FILES, user_files  # noqa: E402
from test_outdir_safety import _victim  # noqa: E402
from test_run_loop import small_cfg as loop_cfg  # noqa: E402
from tree_hash import hashes  # noqa: E402


def pipeline_run(cfg, out, **kw):
    events = list(Pipeline(cfg, out, world=BoxWorld.factory(), **kw).run())
    assert events[-1].stage == "done", events[-1]
    return events


@pytest.fixture(scope="module")
def fake_shards(tmp_path_factory):
    """(preset, one-process run, [shard 0/2, shard 1/2]) of test_run_loop's preset (5 renders in 4 scenes),
    native only and symmetries given (no detection): about 0.3 s a run. BOP through the merge: the Ray tests."""
    tmp = tmp_path_factory.mktemp("fake_shards")
    cfg = loop_cfg(tmp, formats=("native",))
    for e in cfg.objects:
        e.symmetries = "none"
    pipeline_run(cfg, tmp / "single")
    shards = [tmp / f"shard{i}" for i in range(2)]
    for i, d in enumerate(shards):
        pipeline_run(cfg, d, shard=(i, 2))
    return cfg, tmp / "single", shards


def shard_copies(fake_shards, tmp_path) -> list[Path]:
    _, _, shards = fake_shards
    return [Path(shutil.copytree(d, tmp_path / d.name, symlinks=True)) for d in shards]


def test_merged_run_has_the_manifest_of_a_one_process_run(fake_shards, tmp_path):
    cfg, single, _ = fake_shards
    merge_shards(shard_copies(fake_shards, tmp_path), tmp_path / "merged", config=cfg.to_dict())
    merged = tmp_path / "merged"
    # the same records (path, size, sha256; run.json and the COCO files by path), the same folders
    assert (merged / "manifest.json").read_bytes() == (single / "manifest.json").read_bytes()
    a, b = hashes(single, skip={"run.json"}), hashes(merged, skip={"run.json"})
    assert a == b                                       # and the same bytes everywhere else


def test_force_and_resume_treat_a_merged_run_as_a_one_process_run(fake_shards, tmp_path):
    cfg, single, _ = fake_shards
    out = tmp_path / "merged"
    merge_shards(shard_copies(fake_shards, tmp_path), out, config=cfg.to_dict())
    dataset = hashes(out, skip={"run.json"})
    pipeline_run(cfg, out, resume=True)                 # before: refused (no record of run.json)
    assert hashes(out, skip={"run.json"}) == dataset    # nothing to do, nothing rewritten
    user = user_files(out, ISSUE_FORCE_FILES)
    events = pipeline_run(cfg, out, force=True)         # before: refused (no DataPipe manifest)
    assert {k: hashes(out).get(k) for k in user} == user
    said = next(e.message for e in events if e.message.startswith("--force:"))
    assert all(k in said for k in user), said
    assert (hashes(out, skip={"run.json", "manifest.json", "sheets", "bop", *user})     # the user's folders
            == hashes(single, skip={"run.json", "manifest.json"}))


def _wrap(monkeypatch, name, before):
    """Run `before(dst)` ahead of distributed.NAME(..., dst, ...) (the same last positional argument
    before and after the change)."""
    from datapipe.engine import distributed
    orig = getattr(distributed, name)

    def wrapped(*args, **kw):
        before(Path(args[-1]))
        return orig(*args, **kw)
    monkeypatch.setattr(distributed, name, wrapped)


def _plant(link: Path, target: Path) -> Path:
    link.symlink_to(target)
    return link


def _plant_temporary(mp, out, victim):      # a link at run.json's temporary, made while BOP is written
    orig, planted = Writers.catch_up, []

    def catch_up(self, scene_dir, scene):
        if not planted:
            planted.append(_plant(out / "run.json.tmp", victim / "scene.json"))
        return orig(self, scene_dir, scene)
    mp.setattr(Writers, "catch_up", catch_up)
    return planted


def _plant_at(rel, target_of, *, real_scene=False):
    def plant(mp, out, victim):
        planted = []

        def before(dst):
            if not planted and (dst.name == rel.split("/")[0]):
                if real_scene:                  # the scene folder made meanwhile, a link in it
                    dst.mkdir()
                planted.append(_plant(out / rel, target_of(victim)))
        _wrap(mp, "_copy_models" if rel == "models" else "_place_scene", before)
        return planted
    return plant


MID_MERGE = {
    "temporary_file": _plant_temporary,
    "models": _plant_at("models", lambda v: v),
    "scene_folder": _plant_at("scene.0002", lambda v: v),
    "render_folder": _plant_at("scene.0002/render.0001", lambda v: v / "sub", real_scene=True),
}


@pytest.mark.parametrize("case", sorted(MID_MERGE))
def test_a_link_made_during_the_merge_is_refused_and_never_followed(fake_shards, tmp_path, monkeypatch, case):
    cfg, _, _ = fake_shards
    shards = shard_copies(fake_shards, tmp_path)
    victim = _victim(tmp_path)
    victim_before = hashes(victim)
    planted = MID_MERGE[case](monkeypatch, tmp_path / "merged", victim)
    with pytest.raises(outdir.OutputStateError) as ei:
        merge_shards(shards, tmp_path / "merged", config=cfg.to_dict())
    msg = str(ei.value)
    assert planted and str(planted[0]) in msg and "symbolic link" in msg and "fix:" in msg, msg
    assert hashes(victim) == victim_before


def test_a_link_in_a_shards_scene_is_refused_not_moved_into_the_run(fake_shards, tmp_path):
    cfg, _, _ = fake_shards
    shards = shard_copies(fake_shards, tmp_path)
    victim = _victim(tmp_path)
    victim_before = hashes(victim)
    rdir = next(p for p in sorted(shards[1].glob("scene.*/render.0001")))
    shutil.rmtree(rdir)
    rdir.symlink_to(victim / "sub")
    with pytest.raises(outdir.OutputStateError) as ei:
        merge_shards(shards, tmp_path / "merged", config=cfg.to_dict())
    assert str(rdir) in str(ei.value) and "symbolic link" in str(ei.value)
    assert hashes(victim) == victim_before
    assert not any(p.is_symlink() for p in (tmp_path / "merged").rglob("*"))
