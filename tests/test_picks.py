"""scene.picks (a bin that empties as a robot picks): the choice of each step (datapipe/draws/picks.py),
whole sequences per shard, the refusals, and the run loop's sequences with the fake world
(tests/fake_world.py): each step a scene of its own whose parts are the step before's minus the
ones it removed; a kill mid-sequence + --resume and two shards merged write what one run writes.
The Blender side (parts settle again, 0 lost, 0 interpenetrating) is tests/blender/test_picks_blender.py.
"""
import json

import numpy as np
import pytest

import fixtures_native as fx
from fake_world import BoxWorld, Crash
from datapipe.config import PicksConfig
from datapipe.draws import picks
from datapipe.draws.seeds import shard_scenes
from datapipe.engine.distributed import merge_shards
from datapipe.errors import ConfigError
from datapipe.io import layout
from datapipe.reader import read_run
from test_run_loop import annotations, finished_run, run, shard_runs

pytestmark = pytest.mark.usefixtures("remembered_model_analysis")   # box models analysed once (tests/model_memo.py)


def picks_cfg(tmp_path, order="top", per_step=1, until=0, num_renders=9):
    cfg = fx.default_config(num_renders=num_renders, min_per_scene=1, max_per_scene=1, resolution=(64, 48),
                            formats=("native", "bop"), mesh_dir=tmp_path / "meshes")
    for o in cfg.objects:                  # 3 parts at most (the fake world drops 2 or 3 boxes)
        o.min_instances, o.max_instances = 1, 1
    cfg.output.overview = False
    cfg.scene.picks = PicksConfig(per_step=per_step, order=order, until=until)
    return cfg


def scenes(out):
    return {p.parent.name: json.loads(p.read_text()) for p in sorted(out.glob("scene.*/scene.json"))}


# -- the choice ------------------------------------------------------------------------------------
def test_choose_orders():
    names = ["a", "b", "c", "d"]
    assert picks.choose("top", names, 2, heights=np.array([0.01, 0.05, 0.03, 0.05])) == ["b", "d"]  # tie: name
    assert picks.choose("visible", names, 1, visible=np.array([0.2, 0.1, 0.9, 0.5])) == ["c"]
    r1 = picks.choose("random", names, 3, rng=picks.pick_rng(7, 3))
    assert r1 == picks.choose("random", names, 3, rng=picks.pick_rng(7, 3)) and len(set(r1)) == 3
    assert picks.choose("top", names, 0, heights=np.zeros(4)) == []
    assert picks.choose("top", names, 9, heights=np.arange(4.0)) == ["d", "c", "b", "a"]


def test_top_heights_from_the_model_at_its_pose():
    """A box of half height 0.01 m turned 90 deg about x (its y half extent 0.015 becomes vertical)."""
    v = np.array([[sx * 0.02, sy * 0.015, sz * 0.01] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    T = np.eye(4)
    T[:3, :3] = [[1, 0, 0], [0, 0, -1], [0, 1, 0]]
    T[:3, 3] = [0.1, 0.0, 0.2]
    assert picks.top_heights([T], [v])[0] == pytest.approx(0.215, abs=1e-12)


def test_sequence_length_and_step_count(tmp_path):
    cfg = picks_cfg(tmp_path, per_step=2, until=0)
    assert picks.sequence_length(cfg) == 1 + 2                  # 3 parts: 2, then the last 1
    assert [picks.step_count(n, cfg) for n in (3, 1, 0)] == [2, 1, 0]
    cfg.scene.picks = None
    assert picks.sequence_length(cfg) == 1


def test_shards_hold_whole_sequences():
    for n_scenes, group, n in ((9, 4, 2), (40, 11, 3), (5, 1, 2), (7, 3, 5)):
        ranges = [shard_scenes(n_scenes, (i, n), group) for i in range(n)]
        assert [k for r in ranges for k in r] == list(range(n_scenes))
        assert all(len(r) == 0 or r.start % group == 0 for r in ranges)
    # group 1: the split of one scene at a time, as before sequences
    assert [shard_scenes(10, (i, 3)) for i in range(3)] == [range(0, 3), range(3, 6), range(6, 10)]


# -- refusals --------------------------------------------------------------------------------------
@pytest.mark.parametrize("change, field, hint", [
    (dict(order="highest"), "scene.picks.order", "top, visible, random"),
    (dict(until=3), "scene.picks.until", "give until below 3"),
    (dict(per_step=4), "scene.picks.per_step", "at most 3"),
    (dict(per_step=0), "scene.picks.per_step", "at least one"),
])
def test_bad_picks_refused_before_any_work(tmp_path, change, field, hint):
    cfg = picks_cfg(tmp_path)
    for k, v in change.items():
        setattr(cfg.scene.picks, k, v)
    out = tmp_path / "out"
    with pytest.raises(ConfigError) as e:
        run(cfg, out)
    assert any(p.path == field and hint in p.fix for p in e.value.problems), e.value.problems
    assert not out.exists()


def test_visible_order_needs_the_mask(tmp_path):
    cfg = picks_cfg(tmp_path, order="visible")
    cfg.render.outputs = ["rgb", "depth"]
    cfg.output.formats = ["native"]
    with pytest.raises(ConfigError, match="scene.picks.order"):
        cfg.validate()


# -- the run loop ------------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """One uninterrupted run, shared by the tests below (each writes only into its own tmp_path)."""
    tmp = tmp_path_factory.mktemp("picks_ref")
    return finished_run(picks_cfg(tmp), tmp / "ref")


def test_each_step_is_a_scene_without_the_removed_parts(reference):
    cfg, out, pipe = reference
    L = pipe.sequence_length
    assert L == 4 and len(pipe.plan) == 9          # piles at scenes 0 and 4; the third cut short by the plan
    recs = scenes(out)
    read = read_run(out)                           # the reader takes the steps as scenes like any other
    assert [sc.record["picks"]["step"] for sc in read.scenes] == [i % L for i in range(len(pipe.plan))]
    gt = json.loads((out / "bop/train_pbr/000000/scene_gt.json").read_text())
    for i in range(len(pipe.plan)):
        rec = recs[layout.scene_name(i)]
        first, step = i - i % L, i % L
        pk = rec["picks"]
        assert pk["pile"] == layout.scene_name(first) and pk["step"] == step and rec["complete"]
        names = [o["name"] for o in rec["objects"]]
        if step == 0:
            assert pk["removed"] == [] and pk["parent"] is None
            removed_so_far = set()
            continue
        before = recs[layout.scene_name(i - 1)]
        assert pk["parent"] == before["name"]
        prev = [o["name"] for o in before["objects"]]
        assert names == [n for n in prev if n not in pk["removed"]]
        assert len(pk["removed"]) == min(1, len(prev))
        removed_so_far |= set(pk["removed"])
        # a removed part is in no later step's ground truth (scene.json and BOP: by mask index)
        assert not removed_so_far & set(names)
        assert not removed_so_far & {o["name"] for r in rec["renders"] for o in r["objects"]}
        pile = recs[layout.scene_name(first)]
        gone = {o["mask_index"] for o in pile["objects"] if o["name"] in removed_so_far}
        for r in rec["renders"]:
            assert len(gt[str(r["image_id"])]) == len(names)
            mask = fx_read_mask(out / rec["name"] / r["files"]["mask"])
            assert not gone & set(np.unique(mask).tolist())
        # "top": the removed box is the one reaching highest, from the boxes' own corners
        if pk["removed"]:
            tops = {}
            for o in before["renders"][0]["objects"]:
                T_world_obj = np.asarray(before["renders"][0]["T_world_cam"]) @ np.asarray(o["T_cam_obj"])
                half = np.array(fx.BOX_HALF[o["obj_id"] - 1])
                corners = np.array([[a, b, c] for a in (-1, 1) for b in (-1, 1) for c in (-1, 1)]) * half
                tops[o["name"]] = (corners @ T_world_obj[:3, :3].T + T_world_obj[:3, 3])[:, 2].max()
            assert pk["removed"] == [max(tops, key=tops.get)]


def fx_read_mask(path):
    from datapipe.io.exr import read_exr
    return np.rint(read_exr(path)["Y"]).astype(int)


def test_kill_mid_sequence_then_resume_equals_one_run(reference, tmp_path):
    cfg, ref, pipe = reference
    out = tmp_path / "crashed"
    with pytest.raises(Crash):                     # in scene 5: the second pile's first pick step
        run(cfg, out, world=BoxWorld.factory(crash_at=5))
    done = json.loads((out / layout.RUN_FILE).read_text())["scenes_done"]
    assert done == [layout.scene_name(i) for i in range(5)]
    _, events = run(cfg, out, resume=True)
    world = BoxWorld.instances[-1]
    assert [e.scene for e in events if e.stage == "skip"] == [0, 1, 2, 3, 4]
    # the second pile's drop is replayed (complete, not rendered again): the steps after it start
    # from the same pile, so the same parts are picked
    assert world.renders == 4 and any("replayed" in (e.message or "") for e in events)
    assert annotations(out) == annotations(ref)


def test_shards_merge_into_the_one_run(reference, tmp_path):
    cfg, ref, _ = reference
    shards = shard_runs(cfg, tmp_path)
    assert [pipe.scene_ids for _, pipe in shards] == [range(0, 4), range(4, 9)]
    merge_shards([d for d, _ in shards], tmp_path / "merged")
    assert annotations(tmp_path / "merged") == annotations(ref)


def test_no_picks_no_record(tmp_path):
    cfg = picks_cfg(tmp_path, num_renders=2)
    cfg.scene.picks = None
    pipe, _ = run(cfg, tmp_path / "out")
    assert pipe.sequence_length == 1 and BoxWorld.instances[-1].picked == []
    assert all("picks" not in s for s in scenes(tmp_path / "out").values())


def test_visible_order_removes_the_most_visible_part_of_the_step_before(tmp_path):
    cfg = picks_cfg(tmp_path, order="visible", num_renders=4)
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 2
    cfg.scene.num_renders = 8
    cfg.scene.seed = 1             # a pile whose boxes occlude each other: one box is the most visible
    run(cfg, tmp_path / "out")
    recs = list(scenes(tmp_path / "out").values())
    assert [r["picks"]["step"] for r in recs] == [0, 1, 2, 3]
    unique = 0
    for before, rec in zip(recs, recs[1:]):
        if not rec["picks"]["removed"]:
            continue
        mean = {o["name"]: np.mean([x["visib_fract"] for r in before["renders"] for x in r["objects"]
                                    if x["name"] == o["name"]]) for o in before["objects"]}
        best = max(mean.values())
        assert mean[rec["picks"]["removed"][0]] == best
        assert rec["picks"]["removed"][0] == min(n for n, v in mean.items() if v == best)   # ties: name
        unique += len(mean) > 1 and sorted(mean.values())[-2] < best
    assert unique >= 1             # the order decided at least once, not only the tie-break
