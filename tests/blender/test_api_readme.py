"""The README's scripting example (section "Scripting") runs as printed: the code block is taken from
README.md and run as a script in a fresh Python (one render at 160 x 120 with structured light, real
Cycles), and what it prints is checked against the run's files read independently (OpenEXR, json)
and the files against the bin floor's analytic depth."""
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import OpenEXR

ROOT = Path(__file__).resolve().parents[2]
LINE = re.compile(r"^(scene\.\d{4})/(render\.\d{4}): (\d+) parts, scanner depth on ([\d.]+)% of the image, "
                  r"median \|scanner - z-buffer\| ([\d.]+) mm$", re.M)


def readme_script() -> str:
    section = (ROOT / "README.md").read_text().split("\n## Scripting\n", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(r"```python\n(.*?)```", section, re.S)
    assert len(blocks) == 1
    return blocks[0]


def exr_channel(path, name) -> np.ndarray:
    with OpenEXR.File(str(path), separate_channels=True) as f:
        return np.asarray(f.parts[0].channels[name].pixels, dtype=np.float32)


def floor_depth(K, T_world_cam, W, H) -> np.ndarray:
    """Planar depth of the plane z = 0 (the bin floor's top: drop zone centre 0.1 - half height 0.1)."""
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    d_cam = np.stack([u, v, np.ones_like(u)], -1) @ np.linalg.inv(K).T          # z = 1: t is planar depth
    d_world = d_cam @ T_world_cam[:3, :3].T
    return -T_world_cam[2, 3] / d_world[..., 2]


def test_readme_script_runs(tmp_path):
    code = readme_script()
    assert len(code.strip().splitlines()) <= 15
    (tmp_path / "script.py").write_text(code)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    proc = subprocess.run([sys.executable, "script.py"], cwd=tmp_path, env=env, capture_output=True, text=True,
                          timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    printed = proc.stdout

    run_dir = tmp_path / "out" / "scripted"
    record = json.loads((run_dir / "run.json").read_text())
    assert record["status"] == "complete"
    assert record["config"]["camera"]["resolution"] == [160, 120] and record["plan"] == [1]
    # the progress lines reach the terminal (not blender.log, where Blender's own output goes)
    assert "[1/1] scene.0001/render.0001 rendered" in printed and "rendering (Cycles)" in printed
    assert "rendering (Cycles)" not in (run_dir / "blender.log").read_text()
    scene_files = sorted(run_dir.glob("scene.*/scene.json"))
    assert len(scene_files) == 1
    scene = json.loads(scene_files[0].read_text())
    rd = scene["renders"][0]
    rdir = scene_files[0].parent / rd["name"]

    gt = exr_channel(rdir / "depth.exr", "Z")
    sl = exr_channel(rdir / "sl_depth.exr", "Z")
    mask = np.rint(exr_channel(rdir / "mask.exr", "Y")).astype(int)
    visible = {o["mask_index"] for o in rd["objects"] if o["px_count_visib"] > 0}
    assert set(np.unique(mask)) - {0} == visible
    assert len(rd["objects"]) == len(scene["objects"]) >= 5        # the default preset drops 5..11 parts

    # what it printed is what the files say
    lines = LINE.findall(printed)
    assert len(lines) == 1, printed
    sname, rname, parts, share, median = lines[0]
    both = np.isfinite(gt) & np.isfinite(sl)
    assert (sname, rname, int(parts)) == (scene["name"], rd["name"], len(scene["objects"]))
    assert abs(float(share) - 100 * both.mean()) <= 0.05 + 1e-9
    assert abs(float(median) - 1000 * np.median(np.abs(sl - gt)[both])) <= 0.0005 + 1e-9
    # a scanner's numbers: depth on a good part of the view (default preset at 320 x 240: 57%), errors
    # at the noise level (0.09 mm there), not the z-buffer copied
    assert 0.3 < both.mean() < 0.95 and 0.005 < float(median) < 1.0

    # the z-buffer depth against the floor's analytic depth where the floor is seen: the bin's inner
    # floor (away from the walls and parts)
    T = np.array(rd["T_world_cam"])
    W, H = rd["resolution"]
    z_floor = floor_depth(np.array(rd["K"]), T, W, H)
    d_cam = np.stack(np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float)) + [np.ones((H, W))], -1)
    hit = T[:3, 3] + z_floor[..., None] * (d_cam @ np.linalg.inv(np.array(rd["K"])).T @ T[:3, :3].T)
    near_part = np.zeros_like(mask, bool)
    for dy in range(-2, 3):
        for dx in range(-2, 3):
            near_part |= np.roll(mask, (dy, dx), (0, 1)) > 0
    floor = (np.abs(hit[..., 0]) < 0.1) & (np.abs(hit[..., 1]) < 0.05) & ~near_part
    assert floor.sum() > 500
    np.testing.assert_allclose(gt[floor], z_floor[floor], atol=1e-4)   # Cycles' z pass: float32 at 0.8 m

    # the run read back in this process, and resumed from the config it records: nothing to make
    import datapipe.api as dp
    run = dp.read_run(run_dir)
    assert run.status == "complete" and [r.name for r in run.renders] == [rd["name"]]
    np.testing.assert_array_equal(run.renders[0].sl_depth, sl)
    before = scene_files[0].read_bytes()
    events = []
    again = dp.run(run.config, run_dir, resume=True, on_progress=events.append)
    assert again.status == "complete" and scene_files[0].read_bytes() == before
    assert [e.stage for e in events] == ["skip", "done"] and "nothing to do" in events[-1].message


def test_validate_with_blender_lists_the_preflights_problems(tmp_path):
    """validate(cfg, blender=True) is `python -m datapipe validate`: a mesh file without faces passes the
    field rules, and Blender's import of it is refused, as a problem in the list, not an exception."""
    import datapipe.api as dp
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 0.01 0 0\nv 0 0.01 0\n")
    cfg = dp.load_preset("default")
    cfg.objects[1].filepath = str(tmp_path / "points.obj")
    assert dp.validate(cfg) == []
    problems = dp.validate(cfg, blender=True)
    assert [p.path for p in problems] == ["objects[1].filepath"], problems
    assert "face" in problems[0].message and problems[0].fix
    assert dp.validate(dp.load_preset("default"), blender=True) == []
