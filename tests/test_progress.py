"""Lines inside a scene (datapipe/engine/progress.py) without Blender: the ETA arithmetic, the heartbeat on a
fake clock, and the step events of a run on the fake world (tests/fake_world.py), whose renders
report their steps as the Blender world does."""
import json
import time

import numpy as np
import pytest

import fixtures_native as fx
from fake_world import BoxWorld
from datapipe.engine.pipeline import Pipeline
from datapipe.engine.progress import STEP, Tracker, estimate_eta
from datapipe.visibility import VisibStats
from datapipe.world import SILENT

pytestmark = pytest.mark.usefixtures("remembered_model_analysis")   # box models analysed once (tests/model_memo.py)


def test_eta_adds_current_step_later_steps_and_later_renders():
    # a structured-light Cycles call 30 s in and 25% done: 90 s left in it; decode 10 s and maps 5 s
    # follow (their means so far); 3 renders after this one at 200 s each
    eta, lower = estimate_eta("fringes", 30.0, 0.25, {"render": 100.0, "decode": 10.0, "maps": 5.0},
                              per_render=200.0, renders_after=3)
    assert eta == pytest.approx(90 + 15 + 600) and not lower


def test_eta_without_a_fraction_uses_the_steps_mean_and_never_goes_negative():
    eta, lower = estimate_eta("decode", 4.0, None, {"decode": 10.0, "maps": 5.0}, 100.0, 0)
    assert eta == pytest.approx(6 + 5) and not lower
    eta, _ = estimate_eta("decode", 40.0, None, {"decode": 10.0, "maps": 5.0}, 100.0, 0)
    assert eta == pytest.approx(5)


def test_eta_before_the_first_render_is_a_lower_bound_or_unknown():
    # the first render's native Cycles call, half done after 60 s: at least the other 60 s
    eta, lower = estimate_eta("render", 60.0, 0.5, {}, None, renders_after=4)
    assert eta == pytest.approx(60) and lower
    assert estimate_eta("simulation", 5.0, None, {}, None, renders_after=4) == (None, True)


def test_tracker_heartbeat_on_a_fake_clock():
    now = [0.0]
    lines = []
    t = Tracker(lines.append, heartbeat_s=30.0, clock=lambda: now[0])
    t.at(done=0, total=2, scene=0, render=None, per_render=None, renders_after=1)
    t.begin("simulation", "80 parts")                       # a step start is always a line
    for k in range(1, 601):                                 # 600 frames at 0.1 s each: 60 s
        now[0] += 0.1
        t.advance(k, 600)
    assert [p.count[0] for p in lines[1:]] == [300, 600]    # one line per 30 s, not per frame
    assert all(p.stage == STEP and p.step == "simulation" for p in lines)
    # a render finishes: its steps' seconds become the history the next render's ETA uses
    t.begin("render", "rgb")
    now[0] += 100.0
    t.render_done()
    t.at(done=1, total=2, scene=0, render=1, per_render=170.0, renders_after=0)
    t.begin("render", "rgb")
    now[0] += 25.0
    t.cycles_stats("Remaining: 00:10.00 | Mem: 2M | Sample 4/16")
    p = t.progress()
    assert p.count == (4, 16, "sample")
    assert p.eta == pytest.approx(10.0) and not p.eta_lower          # Cycles' own estimate
    assert "sample 4/16" in p.line() and "ETA 10s" in p.line()
    t.cycles_stats("Mem: 2M | Rendered 1/4 Tiles, Sample 8/16")         # samples count per tile
    p = t.progress()
    assert p.count == (8, 16, "sample") and t.fraction() == pytest.approx(1.5 / 4)
    assert "sample 8/16, 25s in - tile 2/4" in p.line()
    assert p.eta == pytest.approx(25 * 2.5 / 1.5)


def test_cycles_eta_from_its_remaining_estimate_not_from_a_stale_sample_count():
    """What Cycles reports without tiles (measured, bpy 5.0 in the background, 1224 x 1024 at 64
    samples): "Sample 1/64" with "Remaining: 00:12.41" 0.25 s in, then nothing until "Sample 64/64"
    at 18.3 s. Extrapolating 1/64 gave a full-resolution render "ETA > 7m27s" 30 s into a 30 s call."""
    now = [0.0]
    t = Tracker(lambda p: None, heartbeat_s=30.0, clock=lambda: now[0])
    t.at(done=0, total=1, scene=0, render=0, per_render=None, renders_after=0)
    t.begin("render", "rgb")
    now[0] = 12.0                                                   # scene sync, BVH: no samples yet
    t.cycles_stats("Mem: 70M | Sample 0/64")
    now[0] = 12.25
    t.cycles_stats("Remaining: 00:12.41 | Mem: 70M | Sample 1/64")
    now[0] = 20.0
    p = t.progress()
    assert p.eta == pytest.approx(12.41 - 7.75) and p.eta_lower    # later steps not known yet
    now[0] = 40.0                                                   # past Cycles' estimate, still rendering
    p = t.progress()
    assert p.eta is None and p.eta_lower
    # no "Remaining" (an older Blender): the rate of the samples since the first one reported
    t.begin("fringes", "9 layers")
    now[0] = 42.0
    t.cycles_stats("Mem: 70M | Sample 1/16")
    now[0] = 50.0
    assert t.progress().eta is None                                 # one count: no rate yet, no guess
    t.cycles_stats("Mem: 70M | Sample 5/16")
    now[0] = 52.0
    assert t.progress().eta == pytest.approx(2.0 * 11 - 2.0)        # 2 s per sample, 11 to go


class SteppingWorld(BoxWorld):
    """The fake world reporting its steps as core/simulation.py, renderer.py and structured_light.py do:
    through the reporter the run hands it (report_to)."""

    def start_scene(self, *a, **kw):
        self.progress.begin("placement")
        self.progress.begin("simulation", "3 parts")
        for k in range(1, 4):
            self.progress.advance(k, 200)
        return super().start_scene(*a, **kw)

    def render(self, *a, **kw):
        self.progress.begin("render", "rgb, depth")
        c0 = time.process_time()
        while time.process_time() - c0 < BUSY_S:          # a Cycles call: CPU-bound
            pass
        self.progress.advance(16, 16, "sample")
        self.progress.begin("write", "native files")
        view = super().render(*a, **kw)
        self.progress.begin("decode", "12 images")
        time.sleep(IDLE_S)                                  # waiting: wall time
        return view


BUSY_S, IDLE_S = 0.05, 0.1


def test_step_events_of_a_run_on_the_fake_world(tmp_path):
    cfg = fx.default_config(num_renders=3, min_per_scene=1, max_per_scene=2, resolution=(64, 48),
                            formats=("native",), mesh_dir=tmp_path / "meshes")
    cfg.output.overview = False
    steps = []
    pipe = Pipeline(cfg, tmp_path / "out", world=SteppingWorld.factory(), on_step=steps.append,
                    heartbeat_s=1e6)     # no heartbeat lines: the step starts only
    events = list(pipe.run())
    assert events[-1].stage == "done"
    assert {p.stage for p in steps} == {STEP}
    # each render: its scene's steps first (first render of a scene), then render, write, decode
    kinds = [p.step for p in steps]
    first = kinds.index("render")
    assert kinds[:first] == ["placement", "simulation"]
    assert kinds[first:first + 4] == ["render", "write", "decode", "annotate"]
    assert all(p.scene is not None for p in steps)
    renders = [p for p in steps if p.step == "render" and p.count is None]
    assert [p.done for p in renders] == [0, 1, 2]
    # the first render's ETA knows nothing of later renders: a lower bound or none; the last one's
    # counts only what is left of it (nothing after it) and is not a bound
    assert renders[0].eta is None or renders[0].eta_lower
    last = [p for p in steps if p.done == 2 and p.step == "decode"][-1]
    assert last.eta is not None and not last.eta_lower
    # the scene's own file writing comes after its renders: it counts them done, has no render in
    # progress, and its ETA holds only the renders still to come (none after the last scene's)
    scene_writes = [p for p in steps if p.step == "write" and p.render is None]
    assert len(scene_writes) == len(pipe.plan)
    ends = [sum(pipe.plan[:k + 1]) for k in range(len(pipe.plan))]
    assert [p.done for p in scene_writes] == ends
    last_write = scene_writes[-1]
    assert last_write.done == last_write.total == 3 and "[3/3]" in last_write.line()
    assert last_write.eta is not None and last_write.eta < 1.0       # write history only: no decode/render time
    assert BoxWorld.instances[-1].progress is SILENT    # the run's tracker is gone with the run
    rec = json.loads((tmp_path / "out" / "run.json").read_text())
    vf = rec["stats"]["visib_fract"]
    parts = sum(len(r["objects"]) for sj in sorted((tmp_path / "out").glob("scene.*/scene.json"))
                for r in json.loads(sj.read_text())["renders"])
    assert vf["instances"] == parts and sum(vf["deciles"]) == parts
    assert 0.0 <= vf["p10"] <= vf["median"] <= vf["p90"] <= 1.0
    # run.json times each step, wall and CPU (the whole process's, every thread), over the run
    st = rec["stats"]["steps"]
    n_scenes = len(pipe.plan)
    assert {k: v["n"] for k, v in st.items()} == {"setup": 1, "placement": n_scenes, "simulation": n_scenes,
                                                  "render": 3, "write": 3 + n_scenes, "decode": 3, "annotate": 3}
    assert st["render"]["cpu_s"] >= 3 * BUSY_S - 1e-3 and st["render"]["wall_s"] >= st["render"]["cpu_s"] * 0.5
    # (no upper bound on a sleeping step's CPU: the process's other threads, e.g. BLAS workers spinning
    # after a call, count too, as they do in a real run)
    assert st["decode"]["wall_s"] >= 3 * IDLE_S - 1e-3
    assert sum(v["wall_s"] for v in st.values()) <= events[-1].elapsed


def test_step_times_without_progress_lines_and_over_a_resume(tmp_path):
    """--quiet still times the steps; a resumed run adds its steps to the earlier calls'."""
    cfg = fx.default_config(num_renders=3, min_per_scene=1, max_per_scene=1, resolution=(32, 24),
                            formats=("native",), mesh_dir=tmp_path / "meshes")
    cfg.output.overview = False
    out = tmp_path / "out"
    pipe = Pipeline(cfg, out, world=SteppingWorld.factory())
    for ev in pipe.run():
        if ev.stage == "scene_done":
            pipe.cancel()                     # stop after the first scene
    first = json.loads((out / "run.json").read_text())["stats"]["steps"]
    assert first["render"]["n"] == 1 and first["setup"]["n"] == 1
    list(Pipeline(cfg, out, world=SteppingWorld.factory(), resume=True).run())
    st = json.loads((out / "run.json").read_text())["stats"]["steps"]
    assert st["render"]["n"] == 3 and st["placement"]["n"] == 3 and st["setup"]["n"] == 2
    assert st["render"]["cpu_s"] >= 3 * BUSY_S - 1e-3


def test_visib_stats_median_within_a_bin():
    rng = np.random.default_rng(0)
    f = rng.uniform(0, 1, 5001) ** 2
    s = VisibStats()
    s.add(f[:2000])
    s.add(f[2000:])
    out = s.summary()
    assert out["instances"] == 5001
    assert out["median"] == pytest.approx(np.quantile(f, 0.5, method="inverted_cdf"), abs=1e-3)
    assert out["p90"] == pytest.approx(np.quantile(f, 0.9, method="inverted_cdf"), abs=1e-3)
    assert out["below_0.1"] == pytest.approx(np.mean(f < 0.1), abs=1e-4)      # rounded to 4 digits
