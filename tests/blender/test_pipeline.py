"""End to end: preset -> Pipeline -> files, checked against independent ground truth.

Poses are checked by projecting the source mesh file's own vertices (parsed here, not by the code
under test) through K and T_cam_obj onto the rendered instance mask.
"""
import json
import os
import pickle
import signal
import subprocess
import sys
import time
from pathlib import Path

import bpy
import numpy as np
import pytest

from datapipe import config as C
from datapipe.engine.pipeline import Pipeline
from datapipe.io.exr import read_depth, read_mask, read_normals

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from cli_runs import kill_at_scene  # noqa: E402


def tiny_config(num_renders=3, res=(96, 72), samples=2):
    cfg = C.default_config()
    cfg.scene.num_renders = num_renders
    cfg.scene.min_renders_per_scene, cfg.scene.max_renders_per_scene = 1, 2
    cfg.camera.resolution = list(res)
    cfg.render.samples = samples
    cfg.render.threads = 2
    cfg.simulation.max_frames = 120
    for o in cfg.objects:
        o.min_instances, o.max_instances = 1, 2
    # finest fringe >= 3 camera px (config validation refuses finer ones: the camera cannot resolve them)
    cfg.structured_light.periods = [1, 4] if res[0] < 32 else ([1, 8] if res[0] < 96 else [1, 4, 16])
    return cfg


def run(cfg, out, **kw):
    events = list(Pipeline(cfg, out, **kw).run())
    assert events[-1].stage == "done", events[-1]
    return events


def obj_vertices(path):
    return np.array([[float(t) for t in line.split()[1:4]] for line in open(path) if line.startswith("v ")])


def scenes(out):
    return sorted(out.glob("scene.*/scene.json"))


def test_run_writes_every_output_and_annotation(tmp_path):
    cfg = tiny_config()
    out = tmp_path / "out"
    events = run(cfg, out)
    assert any(e.stage == "render" and e.eta is not None for e in events)
    assert any("render" in e.seconds for e in events if e.stage == "render")
    run_rec = json.loads((out / "run.json").read_text())
    assert run_rec["status"] == "complete"
    assert run_rec["stats"]["imports"] == len(cfg.objects)          # each mesh file read once per run
    n_renders, n_parts = 0, 0
    for sj in scenes(out):
        scene = json.loads(sj.read_text())
        assert scene["complete"]
        sim = scene["simulation"]                                    # the drop, reported
        assert sim["parts"] == len(scene["objects"]) and sim["substeps"] >= cfg.simulation.substeps
        for key in ("removed", "unsettled", "interpenetrating_pairs", "below_floor", "floating"):
            assert isinstance(sim[key], list), key
        assert sim["max_interpenetration_mm"] >= 0 and sim["attempts"] == 1
        n_parts += sim["parts"]
        done = next(e for e in events if e.stage == "scene_done" and e.scene == scene["scene_id"])
        assert done.line().endswith(f"{sim['frames']} frames x {sim['substeps']} substeps")
    physics = run_rec["stats"]["physics"]                           # the run summary
    assert physics["parts"] == n_parts and physics["scenes"] == len(scenes(out))
    assert f"physics: {n_parts} parts in {physics['scenes']} scenes" in events[-1].line()
    for sj in scenes(out):
        scene = json.loads(sj.read_text())
        for r in scene["renders"]:
            n_renders += 1
            rdir = sj.parent / r["name"]
            for kind in ("rgb", "depth", "normals", "mask"):
                assert (sj.parent / r["files"][kind]).is_file(), kind
            assert "object_coords" not in r["files"] and not (rdir / "object_coords.exr").exists()
            W, H = cfg.camera.resolution
            depth = read_depth(rdir / "depth.exr")
            assert depth.shape == (H, W) and depth.dtype == np.float32
            mask = read_mask(rdir / "mask.exr")
            normals = read_normals(rdir / "normals.exr")
            assert normals.shape == (H, W, 3)
            on = np.isfinite(normals).all(-1) & (np.abs(normals).sum(-1) > 0)
            assert np.allclose(np.linalg.norm(normals[on], axis=-1), 1, atol=0.05)
            # visible normals face the camera: n . (point - camera) < 0 in the OpenCV frame
            ids = {o["mask_index"] for o in r["objects"]}
            assert set(np.unique(mask)) - {0} <= ids
            for o in r["objects"]:
                assert o["px_count_visib"] == int((mask == o["mask_index"]).sum())
                T = np.array(o["T_cam_obj"])
                assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6)   # rigid: scale baked
            assert np.isfinite(depth).mean() > 0.9                                  # the bin fills the view
    assert n_renders == cfg.scene.num_renders
    # object_coords not asked for: no layer, no AOV, no file
    assert [vl.name for vl in bpy.context.scene.view_layers] == ["datapipe"]
    assert len(bpy.context.scene.view_layers["datapipe"].aovs) == 0
    legacy = pickle.loads((out / "output_dict.pickle").read_bytes())
    assert sorted(legacy) == [p.parent.name for p in scenes(out)]
    first = next(iter(next(iter(legacy.values())).values()))
    assert first["wrld2cam_pose"].shape == (4, 4) and {"name", "filename", "mask_index", "cam2obj_pose",
                                                         "T_cam_obj"} <= set(first["objects_in_scene"][0])
    assert (out / "models" / "models_info.json").is_file()


def test_poses_project_onto_their_masks(tmp_path):
    cfg = tiny_config(num_renders=2, res=(240, 180), samples=1)
    out = tmp_path / "out"
    run(cfg, out)
    verts = {i + 1: obj_vertices(o.filepath) * o.scale for i, o in enumerate(cfg.objects)}
    checked = 0
    for sj in scenes(out):
        scene = json.loads(sj.read_text())
        for r in scene["renders"]:
            K = np.array(r["K"])
            mask = read_mask(sj.parent / r["name"] / "mask.exr")
            H, W = mask.shape
            for o in r["objects"]:
                if o["px_count_visib"] < 30:
                    continue
                T = np.array(o["T_cam_obj"])
                pc = verts[o["obj_id"]] @ T[:3, :3].T + T[:3, 3]
                uv = pc @ K.T
                uv = uv[:, :2] / uv[:, 2:]
                import cv2
                hull = cv2.convexHull(np.round(uv * 16).astype(np.int32))
                sil = np.zeros((H, W), np.uint8)
                cv2.fillConvexPoly(sil, hull, 1, lineType=cv2.LINE_8, shift=4)
                sil = cv2.dilate(sil, np.ones((3, 3), np.uint8))     # 1 px: hull rasterisation vs pixel centres
                own = mask == o["mask_index"]
                inside = (sil[own] > 0).mean()
                assert inside > 0.97, f"{o['name']}: only {inside:.2%} of its mask lies in its projected hull"
                checked += 1
    assert checked >= 3


def test_same_seed_same_annotations_and_other_seed_differs(tmp_path):
    cfg = tiny_config(num_renders=2, res=(32, 24), samples=1)
    run(cfg, tmp_path / "a")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    run(cfg, tmp_path / "b")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    run(cfg, tmp_path / "c", seed=123)
    a, b, c = ([json.loads(p.read_text()) for p in scenes(tmp_path / x)] for x in "abc")
    assert a == b
    assert a != c


def test_killed_run_resumes_to_the_same_dataset(tmp_path):
    cfg = tiny_config(num_renders=3, res=(32, 24), samples=1)
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 1     # 3 scenes
    C.save(cfg, tmp_path / "p.json")
    full, part = tmp_path / "full", tmp_path / "part"
    cmd = [sys.executable, "-m", "datapipe", "run", str(tmp_path / "p.json")]
    subprocess.run(cmd + ["--out", str(full), "--quiet"], check=True, capture_output=True)
    # kill the second run as soon as its first scene is complete
    assert kill_at_scene(cmd + ["--out", str(part)], "scene.0001", 60) == -signal.SIGKILL
    assert len(scenes(part)) < 3
    r = subprocess.run(cmd + ["--out", str(part)], capture_output=True, text=True)
    assert r.returncode == 2 and "--resume" in r.stderr                 # refused without --resume
    r = subprocess.run(cmd + ["--out", str(part), "--resume"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert "already complete" in r.stderr
    a = [json.loads(p.read_text()) for p in scenes(full)]
    b = [json.loads(p.read_text()) for p in scenes(part)]
    assert a == b
    # byte for byte (issue #21), output_dict.pickle included; the overview's title names its folder,
    # run.json and logs say when and how long it ran
    def files(d):
        return {f.relative_to(d): f.read_bytes() for f in d.rglob("*")
                if f.is_file() and f.name not in ("run.json", "overview.png") and f.suffix != ".log"}
    assert files(full) == files(part)
    stats = [json.loads((d / "run.json").read_text())["stats"] for d in (full, part)]
    assert stats[0]["frames"] == stats[1]["frames"] and stats[0]["physics"] == stats[1]["physics"]
    assert stats[1]["imports"] == 2 * stats[0]["imports"]          # two calls read the mesh files
    # per-step wall and CPU seconds (--quiet too), the killed call's scene counted with the resumed ones
    for st in stats:
        steps = st["steps"]
        assert {k: steps[k]["n"] for k in ("placement", "simulation", "render", "annotate")} == \
            {"placement": 3, "simulation": 3, "render": 3, "annotate": 3}
        assert steps["render"]["cpu_s"] > 0 and steps["render"]["wall_s"] > 0
    assert stats[0]["steps"]["setup"]["n"] == 1 and stats[1]["steps"]["setup"]["n"] == 2


def test_shards_make_the_same_scenes(tmp_path):
    cfg = tiny_config(num_renders=3, res=(32, 24), samples=1)
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 1
    run(cfg, tmp_path / "one")
    got = []
    for k in range(2):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        run(cfg, tmp_path / f"s{k}", shard=(k, 2))
        got += [json.loads(p.read_text()) for p in scenes(tmp_path / f"s{k}")]
    assert got == [json.loads(p.read_text()) for p in scenes(tmp_path / "one")]


def test_scenes_leave_no_data_behind(tmp_path):
    cfg = tiny_config(num_renders=4, res=(16, 12), samples=1)
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 1
    counts = []
    pipe = Pipeline(cfg, tmp_path / "o")
    for ev in pipe.run():
        if ev.stage == "scene_done":
            counts.append({k: len(getattr(bpy.data, k)) for k in
                           ("objects", "meshes", "materials", "images", "collections", "lights")})
    assert len(counts) == 4
    assert all(c == counts[0] for c in counts), counts


def test_cancel_keeps_what_was_written(tmp_path):
    cfg = tiny_config(num_renders=3, res=(16, 12), samples=1)
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 1
    pipe = Pipeline(cfg, tmp_path / "o")
    stages = []
    for ev in pipe.run():
        stages.append(ev.stage)
        if ev.stage == "scene_done":
            pipe.cancel()
    # cancel between scenes: the next scene is not started
    assert stages[-1] == "cancelled"
    assert (tmp_path / "o" / "scene.0001" / "scene.json").is_file()
    rec = json.loads((tmp_path / "o" / "run.json").read_text())
    assert rec["status"] == "cancelled" and rec["scenes_done"] == ["scene.0001"]


def _start(cmd):
    return subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.PIPE, text=True)


def test_7_ctrl_c_stops_at_a_safe_point_and_resumes(tmp_path):
    """Defect #7: Ctrl-C printed a KeyboardInterrupt traceback and left run.json "running"."""
    cfg = tiny_config(num_renders=3, res=(32, 24), samples=1)
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 1     # 3 scenes
    C.save(cfg, tmp_path / "p.json")
    out = tmp_path / "o"
    cmd = [sys.executable, "-m", "datapipe", "run", str(tmp_path / "p.json"), "--out", str(out)]
    proc = _start(cmd)
    err = []
    for line in proc.stderr:
        err.append(line)
        if "render.0001 rendered" in line:
            proc.send_signal(signal.SIGINT)
            break
    err += proc.stderr.readlines()
    assert proc.wait(timeout=120) == 130, "".join(err)
    text = "".join(err)
    assert "Traceback" not in text and "cancelled" in text
    rec = json.loads((out / "run.json").read_text())
    assert rec["status"] == "cancelled" and len(rec["scenes_done"]) < 3
    r = subprocess.run(cmd + ["--resume", "--quiet"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert json.loads((out / "run.json").read_text())["status"] == "complete"
    assert all(json.loads(p.read_text())["complete"] for p in scenes(out)) and len(scenes(out)) == 3


def test_7_second_ctrl_c_stops_at_once_and_stays_resumable(tmp_path):
    cfg = tiny_config(num_renders=2, res=(96, 72), samples=4096)    # a render of tens of seconds
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 1
    C.save(cfg, tmp_path / "p.json")
    out = tmp_path / "o"
    proc = _start([sys.executable, "-m", "datapipe", "run", str(tmp_path / "p.json"), "--out", str(out)])
    for line in proc.stderr:
        if "dropping parts" in line:
            break
    time.sleep(2.0)                                  # inside the first (long) Cycles render now
    proc.send_signal(signal.SIGINT)
    time.sleep(0.3)
    t0 = time.perf_counter()
    proc.send_signal(signal.SIGINT)
    code = proc.wait(timeout=30)
    text = proc.stderr.read()
    assert code == 130 and time.perf_counter() - t0 < 5, text
    assert "Traceback" not in text and "stopped at once" in text
    assert json.loads((out / "run.json").read_text())["status"] == "cancelled"
    assert not any(json.loads(p.read_text()).get("complete") for p in scenes(out))
    from datapipe.io.outdir import OutLock
    with OutLock(out):                               # the dead run's lock is gone with it
        pass


class _Killed(BaseException):
    """Stands for SIGKILL at one exact point: nothing after it runs, nothing is cleaned up by us."""


def test_4_kill_right_after_scene_json_is_repaired_on_resume(tmp_path, monkeypatch):
    """Defect #4: a kill right after a scene.json lost that scene from output_dict.pickle and from
    run.json's scenes_done for good. Also: a complete scene.json whose image is gone is made again."""
    from datapipe.io import legacy
    cfg = tiny_config(num_renders=2, res=(32, 24), samples=1)
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 1      # 2 scenes
    out = tmp_path / "o"

    def killed(self, scene_dir, scene):
        raise _Killed
    monkeypatch.setattr(legacy.LegacyPickleWriter, "add_scene", killed)
    with pytest.raises(_Killed):
        list(Pipeline(cfg, out).run())
    monkeypatch.undo()
    assert json.loads((out / "scene.0001" / "scene.json").read_text())["complete"]
    assert json.loads((out / "run.json").read_text())["scenes_done"] == []
    bpy.ops.wm.read_factory_settings(use_empty=True)
    run(cfg, out, resume=True)
    assert set(pickle.loads((out / "output_dict.pickle").read_bytes())) == {"scene.0001", "scene.0002"}
    assert json.loads((out / "run.json").read_text())["scenes_done"] == ["scene.0001", "scene.0002"]
    before = json.loads((out / "scene.0001" / "scene.json").read_text())
    (out / "scene.0001" / "render.0001" / "rgb.png").unlink()
    bpy.ops.wm.read_factory_settings(use_empty=True)
    events = run(cfg, out, resume=True)
    assert [e.scene for e in events if e.stage == "scene_done"] == [0]          # remade, scene 2 skipped
    assert (out / "scene.0001" / "render.0001" / "rgb.png").is_file()
    assert json.loads((out / "scene.0001" / "scene.json").read_text()) == before


def test_quality_gate_warns_and_strict_stops(tmp_path):
    """Defect #6: a black dataset finished with exit 0 and no word."""
    from datapipe.engine.pipeline import QualityError
    cfg = tiny_config(num_renders=1, res=(32, 24), samples=1)
    cfg.render.light_power = 0.0
    cfg.structured_light.enabled = False
    events = run(cfg, tmp_path / "o")
    line = next(e.line() for e in events if e.stage == "render")
    assert "warning: RGB is black" in line
    rec = json.loads((tmp_path / "o" / "run.json").read_text())
    assert rec["warnings"][0]["render"] == "scene.0001/render.0001" and "black" in rec["warnings"][0]["warning"]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    with pytest.raises(QualityError, match="scene.0001/render.0001: RGB is black"):
        list(Pipeline(cfg, tmp_path / "s", strict=True).run())
    assert json.loads((tmp_path / "s" / "run.json").read_text())["status"] == "failed"
