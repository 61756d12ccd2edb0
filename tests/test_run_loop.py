"""The run loop (engine/pipeline.py) with a fake world (tests/fake_world.py), no Blender: run.json,
resume after a crash, cancel, shards + merge, writers caught up on resume, refusals.

The reference is always an uninterrupted single run of the same preset and seed: a resumed,
cancelled-then-resumed or sharded-then-merged run must write the very same annotations.
"""
import json
import pickle
import re
import shutil

import pytest

import fixtures_native as fx
from fake_world import BoxWorld, Crash
from datapipe.engine.pipeline import Pipeline
from datapipe.engine.distributed import merge_shards
from datapipe.errors import DataPipeError
from datapipe.io import layout

pytestmark = pytest.mark.usefixtures("remembered_model_analysis")   # box models analysed once (tests/model_memo.py)


def small_cfg(tmp_path, formats=("native", "bop")):
    cfg = fx.default_config(num_renders=5, min_per_scene=1, max_per_scene=2, resolution=(64, 48),
                            formats=formats, mesh_dir=tmp_path / "meshes")
    cfg.output.overview = False
    return cfg


def run(cfg, out, world=None, **kw):
    pipe = Pipeline(cfg, out, world=world or BoxWorld.factory(), **kw)
    return pipe, list(pipe.run())


def finished_run(cfg, out):
    """An uninterrupted run to its end, as the reference fixtures keep it: (cfg, out, pipeline)."""
    pipe, events = run(cfg, out)
    assert events[-1].stage == "done"
    return cfg, out, pipe


def shard_runs(cfg, tmp_path, n=2):
    """The run in `n` shards, each to its end: [(its folder, its pipeline)]."""
    shards = []
    for i in range(n):
        d = tmp_path / f"shard{i}"
        pipe, events = run(cfg, d, shard=(i, n))
        assert events[-1].stage == "done"
        shards.append((d, pipe))
    return shards


def annotations(out) -> dict:
    """Every file a run's consumers read, as text (scene.json, BOP JSON) or plain data (the pickle)."""
    files = {p.relative_to(out).as_posix(): p.read_text() for p in sorted(out.glob("scene.*/scene.json"))}
    for p in sorted((out / "bop").rglob("*.json")) if (out / "bop").is_dir() else []:
        # the COCO info's date_created says when the chunk was first written: a run's own time
        files[p.relative_to(out).as_posix()] = re.sub(r'"date_created": ?"[^"]*"', '"date_created": "-"',
                                                      p.read_text())
    if (out / layout.LEGACY_PICKLE).is_file():
        files[layout.LEGACY_PICKLE] = repr(pickle.loads((out / layout.LEGACY_PICKLE).read_bytes()))
    return files


@pytest.fixture
def reference(tmp_path):
    return finished_run(small_cfg(tmp_path), tmp_path / "ref")


def test_run_json_scenes_and_writers(reference):
    cfg, out, pipe = reference
    rec = json.loads((out / layout.RUN_FILE).read_text())
    names = [layout.scene_name(i) for i in range(len(pipe.plan))]
    assert rec["status"] == "complete" and rec["plan"] == pipe.plan and rec["shard"] == [0, 1]
    assert rec["scenes"] == names and rec["scenes_done"] == names
    assert rec["stats"]["imports"] == len(cfg.objects) and set(rec["stats"]["frames"]) == set(names)
    assert sum(pipe.plan) == cfg.scene.num_renders and len(pipe.plan) >= 3
    data = annotations(out)
    for i, n in enumerate(pipe.plan):
        scene = json.loads(data[f"{names[i]}/scene.json"])
        assert scene["complete"] and len(scene["renders"]) == n
        assert [r["image_id"] for r in scene["renders"]] == list(range(sum(pipe.plan[:i]), sum(pipe.plan[:i + 1])))
        for r in scene["renders"]:
            assert sum(o["px_count_visib"] for o in r["objects"]) > 0
    gt = json.loads(data["bop/train_pbr/000000/scene_gt.json"])
    assert sorted(map(int, gt)) == list(range(cfg.scene.num_renders))
    assert set(pickle.loads((out / layout.LEGACY_PICKLE).read_bytes())) == set(names)
    assert (out / layout.MODELS_DIR / layout.MODELS_INFO).is_file()
    assert not (out / layout.SHEETS_DIR).exists()          # the overview is drawn by cli/ui, not the run loop
    assert BoxWorld.instances[-1].closed


def test_crash_then_resume_equals_one_run(reference, tmp_path):
    cfg, ref, pipe = reference
    out = tmp_path / "crashed"
    crash_at = pipe.plan[0] + 1                    # inside the second scene, or at the start of the third
    with pytest.raises(Crash):
        run(cfg, out, world=BoxWorld.factory(crash_at=crash_at))
    assert BoxWorld.instances[-1].closed            # the world is closed even when the run dies
    rec = json.loads((out / layout.RUN_FILE).read_text())
    assert rec["status"] == "running" and rec["scenes_done"] == [layout.scene_name(0)]
    assert not layout.scene_complete(out / layout.scene_name(1))
    with pytest.raises(DataPipeError, match="not empty"):
        Pipeline(cfg, out, world=BoxWorld.factory()).check()
    built = len(BoxWorld.instances)
    _, events = run(cfg, out, resume=True)
    assert len(BoxWorld.instances) == built + 1
    assert [e.scene for e in events if e.stage == "skip"] == [0]
    assert events[-1].stage == "done" and events[-1].done == cfg.scene.num_renders
    assert annotations(out) == annotations(ref)
    assert json.loads((out / layout.RUN_FILE).read_text())["status"] == "complete"


def test_cancel_then_resume_equals_one_run(reference, tmp_path):
    cfg, ref, _ = reference
    out = tmp_path / "cancelled"
    pipe = Pipeline(cfg, out, world=BoxWorld.factory())
    events = []
    for ev in pipe.run():
        events.append(ev)
        if ev.stage == "render":
            pipe.cancel()
    assert events[-1].stage == "cancelled"
    assert [e.stage for e in events].count("render") == 1
    assert json.loads((out / layout.RUN_FILE).read_text())["status"] == "cancelled"
    first = layout.read_scene(out / layout.scene_name(0))
    assert len(first["renders"]) == 1 and first["complete"] == (pipe.plan[0] == 1)
    _, events = run(cfg, out, resume=True)
    assert events[-1].stage == "done"
    assert annotations(out) == annotations(ref)


def test_shards_merge_into_the_one_run(reference, tmp_path):
    cfg, ref, _ = reference
    shards = shard_runs(cfg, tmp_path)
    assert all(pipe.total == sum(pipe.plan[k] for k in pipe.scene_ids) for _, pipe in shards)
    merged = tmp_path / "merged"
    summary = merge_shards([d for d, _ in shards], merged)
    assert summary["scenes"] == len(json.loads((ref / layout.RUN_FILE).read_text())["plan"])
    assert annotations(merged) == annotations(ref)
    run_rec = json.loads((merged / layout.RUN_FILE).read_text())
    assert run_rec["status"] == "complete"
    # the merged run's stats, as one process writes them: what the scenes record (frames, physics,
    # visible fractions) equals the one process's; the shards' step times and counts add up
    one, st = json.loads((ref / layout.RUN_FILE).read_text())["stats"], run_rec["stats"]
    for k in ("frames", "physics", "visib_fract"):
        assert st[k] == one[k], k
    assert st["visib_fract"]["instances"] > 0
    shard_stats = [m["stats"] for m in run_rec["merged_from"]]
    assert st["imports"] == sum(x["imports"] for x in shard_stats)
    for step, tot in st["steps"].items():
        assert tot["n"] == sum(x["steps"].get(step, {}).get("n", 0) for x in shard_stats) > 0
        assert tot["cpu_s"] == pytest.approx(sum(x["steps"].get(step, {}).get("cpu_s", 0.0) for x in shard_stats))
    assert set(st["steps"]) == set(one["steps"]) and "write" in st["steps"]     # the scene files step at least


def test_resume_catches_up_writers_without_building_a_world(reference):
    cfg, out, _ = reference
    before = annotations(out)
    shutil.rmtree(out / "bop")
    (out / layout.LEGACY_PICKLE).unlink()
    built = len(BoxWorld.instances)
    _, events = run(cfg, out, resume=True)
    assert len(BoxWorld.instances) == built            # nothing to render: no world at all
    assert events[-1].stage == "done" and "nothing to do" in events[-1].message
    assert annotations(out) == before


def test_resume_refuses_another_seed(reference):
    cfg, out, _ = reference
    with pytest.raises(DataPipeError, match="different preset or seed"):
        Pipeline(cfg, out, resume=True, seed=cfg.scene.seed + 1, world=BoxWorld.factory()).check()


class _GpuWorld(BoxWorld):
    """A world whose renderer reports the Cycles backend it set (core/renderer.py: Renderer.device)."""
    backend = "OPTIX"

    def setup(self) -> None:
        super().setup()
        self.renderer = type("R", (), {"device": self.backend})()


def test_run_json_says_which_backend_rendered_a_gpu_run(reference, tmp_path):
    """render.device GPU: run.json names the backend Cycles used (OPTIX, CUDA, ... or CPU where the
    machine has no GPU); a CPU run's run.json has no such key (nothing a run does not use)."""
    _, ref, _ = reference
    assert "render_device" not in json.loads((ref / layout.RUN_FILE).read_text())
    cfg = small_cfg(tmp_path, formats=("native",))
    cfg.render.device = "GPU"
    for backend in ("OPTIX", "CPU"):
        _GpuWorld.backend = backend
        out = tmp_path / backend
        run(cfg, out, world=_GpuWorld)
        assert json.loads((out / layout.RUN_FILE).read_text())["render_device"] == backend
