"""Dense piles (scene.fill, drops in stages) and the lines inside a scene (datapipe/engine/progress.py), with
real bpy: Bullet, Cycles on the CPU (tiny renders)."""
import json

import numpy as np
import pytest

from datapipe import config as C
from datapipe.engine.pipeline import Pipeline
from datapipe.draws.fill import hull_volume
from datapipe.engine.progress import STEP

FLOOR_TOL = 0.002      # m: Bullet's contact margin and resting penetration under load (test_simulation)


def obj_vertices(path):
    return np.array([[float(t) for t in line.split()[1:4]] for line in open(path) if line.startswith("v ")])


def dense_cfg(out):
    """~70 half-size demo parts in a 12 x 10 x 8 cm bin: a spawn column of 6+ layers, so 3+ stages."""
    cfg = C.default_config()
    cfg.scene.num_renders = 1
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 1
    cfg.scene.drop_zone_loc, cfg.scene.drop_zone_scale = [0.0, 0.0, 0.04], [0.06, 0.05, 0.04]
    cfg.scene.fill = [0.15, 0.15]
    for o in cfg.objects:
        o.scale, o.mass, o.collision_shape = 0.5, o.mass / 8, "CONVEX_HULL"
        o.min_instances, o.max_instances = 0, 200
    cfg.camera.resolution = [96, 72]
    cfg.camera.poses = [C.CameraPose(location=[0.0, 0.0, 0.35], rotation=[1.0, 0.0, 0.0, 0.0])]
    cfg.structured_light.enabled = False
    cfg.render.samples, cfg.render.threads = 1, 2
    cfg.simulation.max_frames = 150    # per stage; what is checked here needs no pile at rest (staged
                                       # drops, none lost, inside the bin, visible fractions): 12 of ~70
                                       # parts still creep at < 2 mm/s after the last stage (300: 6), 10 s less
    cfg.output.formats = ["native", "bop"]
    cfg.output.overview = False
    cfg.output.path = str(out)
    return cfg


def test_fill_drops_a_dense_pile_in_stages_and_reports_visible_fractions(tmp_path):
    out = tmp_path / "out"
    cfg = dense_cfg(out)
    events = list(Pipeline(cfg, out).run())
    assert events[-1].stage == "done", events[-1]
    scene = json.loads(next(out.glob("scene.*/scene.json")).read_text())
    sim = scene["simulation"]
    # the counts come from the hull volumes, measured here independently of the code under test
    vols = {o.name: hull_volume(obj_vertices(o.filepath) * o.scale) for o in cfg.objects}
    bin_v = 0.12 * 0.10 * 0.08
    names = [o["name"].rsplit("_", 1)[0] for o in scene["objects"]]
    share = sum(vols[n] for n in names) / bin_v
    assert 0.15 <= share < 0.15 + max(vols.values()) / bin_v + 1e-9     # reached, overshot by < one part
    assert sim["fill"]["share"] == pytest.approx(0.15) and sim["fill"]["reached"] == pytest.approx(share, abs=1e-3)
    assert len(names) >= 60 and sim["stages"] >= 3
    assert sim["removed"] == [], sim["removed"]                          # no part lost
    assert sim["max_interpenetration_mm"] < 1.0
    # every part inside the walls and on/above the floor, from the mesh files' own vertices
    rd = scene["renders"][0]
    T_world_cam = np.asarray(rd["T_world_cam"])
    for o, n in zip(scene["objects"], names):
        rec = next(r for r in rd["objects"] if r["name"] == o["name"])
        T = T_world_cam @ np.asarray(rec["T_cam_obj"])
        v = obj_vertices(next(e.filepath for e in cfg.objects if e.name == n)) * 0.5
        w = v @ T[:3, :3].T + T[:3, 3]
        assert w[:, 2].min() >= -FLOOR_TOL, o["name"]
        assert np.all(np.abs(w[:, :2]) <= np.array([0.06, 0.05]) + FLOOR_TOL), o["name"]
    # run.json: the visible fractions of this dense pile, as BOP's visib_fract (bop writer) has them
    vf = json.loads((out / "run.json").read_text())["stats"]["visib_fract"]
    gt_info = json.loads(next((out / "bop").rglob("scene_gt_info.json")).read_text())
    bop = np.array([a["visib_fract"] for infos in gt_info.values() for a in infos])
    assert vf["instances"] == len(bop) == len(names)
    # run.json's quantiles are the inverted CDF (a value that occurs) to the histogram's 0.001 bins
    assert vf["median"] == pytest.approx(float(np.quantile(bop, 0.5, method="inverted_cdf")), abs=0.0015)
    assert vf["median"] < 0.8                                           # a pile, not parts lying apart


def test_progress_lines_name_each_step_and_what_renders_in_order(tmp_path):
    cfg = C.default_config()
    cfg.scene.num_renders = 2
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 2
    cfg.camera.resolution = [96, 72]
    cfg.render.samples, cfg.render.threads = 8, 2
    for o in cfg.objects:
        o.min_instances, o.max_instances = 1, 2
    cfg.structured_light.periods, cfg.structured_light.fringe_mode = [1, 4, 16], "render"
    cfg.structured_light.samples = 4
    cfg.output.overview = False
    lines = []
    events = list(Pipeline(cfg, tmp_path / "out", on_step=lines.append, heartbeat_s=0.2).run())
    assert events[-1].stage == "done"
    assert all(p.stage == STEP for p in lines)
    starts = []                               # each step's first line, in order
    for p in lines:
        if not starts or (p.step, p.render) != (starts[-1].step, starts[-1].render):
            starts.append(p)
    seq = [p.step for p in starts]
    per_render = ["render", "write", "fringes", "decode", "maps", "annotate"]
    assert seq == ["placement", "simulation", *per_render, *per_render, "write"], seq    # + the scene's files
    native, fringes = starts[2], starts[4]
    assert "rgb" in native.what and "96 x 72" in native.what and "8 samples" in native.what
    assert "12 fringe layers (3 periods x 4 steps)" in fringes.what and "192 x 144" in fringes.what  # 2x supersampled
    # Cycles' own progress reaches the lines (render_stats): samples counted up to the layer total
    samples = [p.count for p in lines if p.count is not None and p.count[2].startswith("sample")]
    assert samples and all(0 <= n <= of for n, of, _ in samples)
    # the second render knows the first one's steps: its ETA is a number, not a bound
    second = [p for p in lines if p.render == 1 and p.eta is not None]
    assert second and not second[-1].eta_lower
    assert all(p.line().startswith(f"[{p.done}/2]") for p in lines)
