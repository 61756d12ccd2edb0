"""Simulation: parts end in the bin, escapees are removed with a reason, settling stops early, the
result is frozen for rendering, and the same seed gives the same poses whatever ran before."""
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from mathutils import Matrix  # noqa: E402

from datapipe.config import ObjectEntry, assets_dir, default_config  # noqa: E402
from datapipe.checks.settle import SETTLE_CONFIRM_S  # noqa: E402
from datapipe.core.objects import ObjectManager  # noqa: E402
from datapipe.core.scene import BlendScene  # noqa: E402
from datapipe.core.simulation import Simulation  # noqa: E402
from datapipe.draws.seeds import scene_rng  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
ASSETS = assets_dir()
FLOOR_TOL = 0.002     # m: Bullet contact margin (0.5 mm) and resting penetration under load


def parse_obj_vertices(path):
    return np.array([[float(x) for x in line.split()[1:4]] for line in Path(path).read_text().splitlines()
                     if line.startswith("v ")])


def world_vertices(inst, scale=1.0):
    v = parse_obj_vertices(inst.filename) * scale
    M = np.array(inst.obj.matrix_world)
    return v @ M[:3, :3].T + M[:3, 3]


def make(cfg):
    bs = BlendScene(cfg).setup()
    om = ObjectManager(cfg, bs).load_sources()
    return bs, om, Simulation(cfg, bs)


def one_part_cfg(name="nut", n=1):
    cfg = default_config()
    cfg.objects = [ObjectEntry(filepath=str(ASSETS / f"{name}.obj"), mass=0.02, min_instances=n,
                               max_instances=n, name=name)]
    return cfg


def place(inst, location, R=np.eye(3)):
    M = np.eye(4)
    M[:3, :3], M[:3, 3] = R, location
    inst.obj.matrix_world = Matrix(M.tolist())


def test_default_preset_parts_end_in_the_bin():
    cfg = default_config()
    bs, om, sim = make(cfg)
    insts = om.populate(scene_rng(cfg.scene.seed, 0))
    res = sim.run(insts, scene_rng(cfg.scene.seed, 0))
    assert res.kept and not res.removed
    assert 0 < res.frames <= cfg.simulation.max_frames
    c, h = np.array(cfg.scene.drop_zone_loc), np.array(cfg.scene.drop_zone_scale)
    floor_z = c[2] - h[2]
    for inst in res.kept:
        v = world_vertices(inst)
        assert v[:, 2].min() >= floor_z - FLOOR_TOL, inst.name
        assert np.all(np.abs(v[:, :2] - c[:2]) <= h[:2] + FLOOR_TOL), inst.name      # within the walls
        assert v[:, 2].max() < c[2] + h[2]                   # everything fell down below the rim
        assert inst.obj.rigid_body is None                   # frozen
    assert {i.name for i in res.kept} == set(res.poses)


def test_escaped_parts_are_removed_with_a_reason():
    cfg = one_part_cfg(n=3)
    bs, om, sim = make(cfg)
    insts = om.populate(np.random.default_rng(0))
    c, h = bs.drop_zone_center, bs.drop_zone_half
    place(insts[0], [c[0] + h[0] + 0.15, c[1], c[2]])                  # beside the bin: falls past it
    place(insts[1], [c[0], c[1], bs.floor_z - 0.5])                    # under the occlusion box
    place(insts[2], [c[0], c[1], bs.floor_z + 0.02])                   # in the bin
    names = [i.name for i in insts]
    res = sim.run(insts, np.random.default_rng(0))
    reasons = {inst.name: why for inst, why in res.removed}
    assert reasons == {names[0]: "left the bin", names[1]: "fell through the floor"}
    assert [i.name for i in res.kept] == [names[2]]
    assert names[0] not in bpy.data.objects and names[1] not in bpy.data.objects
    assert res.settled and res.frames < cfg.simulation.max_frames      # escapees do not hold it up
    om.clear()
    assert not [n for n in names if n in bpy.data.objects]


def test_resting_part_settles_within_a_few_frames():
    cfg = one_part_cfg("nut")
    bs, om, sim = make(cfg)
    (inst,) = om.populate(np.random.default_rng(0))
    rest = [0.02, -0.01, bs.floor_z + 0.006 + 0.0005]       # the nut is 12 mm thick (+ contact margin)
    place(inst, rest)
    res = sim.run([inst], np.random.default_rng(0))
    assert res.settled and res.kept == [inst]
    window = max(cfg.simulation.settle_frames, round(SETTLE_CONFIRM_S * bs.scene.render.fps))
    assert res.frames <= window + 3                          # at rest from the start: the confirmation only
    assert np.allclose(np.array(inst.obj.matrix_world)[:3, 3], rest, atol=1e-3)


def test_result_is_frozen_for_rendering():
    cfg = default_config()
    bs, om, sim = make(cfg)
    res = sim.run(om.populate(scene_rng(0, 1)))
    poses = {i.name: np.array(i.obj.matrix_world) for i in res.kept}
    for f in (1, 7, 60, cfg.simulation.max_frames + 30):
        bs.scene.frame_set(f)
        for inst in res.kept:
            assert np.allclose(np.array(inst.obj.matrix_world), poses[inst.name], atol=1e-7), (f, inst.name)
    for inst in res.kept:
        assert np.allclose(res.poses[inst.name], poses[inst.name], atol=1e-6)


def _run_scene(om, sim, seed):
    res = sim.run(om.populate(scene_rng(0, seed)), scene_rng(0, seed))
    out = {i.name: np.array(i.obj.matrix_world, dtype=np.float64) for i in res.kept}
    removed = sorted(i.name for i, _ in res.removed)
    om.clear()
    return out, removed, res.frames


def test_same_seed_same_poses_whatever_ran_before():
    cfg = default_config()
    bs, om, sim = make(cfg)
    a1, rem1, f1 = _run_scene(om, sim, 0)
    b, _, _ = _run_scene(om, sim, 1)
    a2, rem2, f2 = _run_scene(om, sim, 0)
    assert a1.keys() == a2.keys() and rem1 == rem2 and f1 == f2
    for k in a1:
        assert np.abs(a1[k] - a2[k]).max() <= 1e-6, k
    assert a1.keys() != b.keys() or any(np.abs(a1[k] - b[k]).max() > 1e-3 for k in a1)


_FRESH = """
import json, sys, numpy as np, bpy
sys.path.insert(0, {root!r})
from datapipe.config import default_config
from datapipe.core.scene import BlendScene
from datapipe.core.objects import ObjectManager
from datapipe.core.simulation import Simulation
from datapipe.draws.seeds import scene_rng
bpy.ops.wm.read_factory_settings(use_empty=True)
cfg = default_config()
bs = BlendScene(cfg).setup(); om = ObjectManager(cfg, bs).load_sources(); sim = Simulation(cfg, bs)
res = sim.run(om.populate(scene_rng(0, 2)), scene_rng(0, 2))
print("POSES" + json.dumps({{i.name: np.array(i.obj.matrix_world).tolist() for i in res.kept}}))
"""


def test_scene_in_fresh_process_equals_scene_after_others():
    cfg = default_config()
    bs, om, sim = make(cfg)
    _run_scene(om, sim, 0)
    _run_scene(om, sim, 1)
    here, _, _ = _run_scene(om, sim, 2)
    out = subprocess.run([sys.executable, "-c", _FRESH.format(root=str(ROOT))], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    line = next(x for x in out.stdout.splitlines() if x.startswith("POSES"))
    fresh = {k: np.array(v) for k, v in json.loads(line[5:]).items()}
    assert fresh.keys() == here.keys()
    for k in here:
        assert np.abs(fresh[k] - here[k]).max() <= 1e-6, k


def test_no_growth_over_scenes():
    cfg = default_config()
    bs, om, sim = make(cfg)
    counts = None
    for seed in range(3):
        _run_scene(om, sim, seed)
        now = (len(bpy.data.objects), len(bpy.data.meshes), len(bpy.data.collections),
               len(bs.scene.rigidbody_world.collection.objects))
        counts = counts or now
        assert now == counts


def test_centre_of_mass_off_the_origin(tmp_path):
    """A cube whose file origin is a corner must still come to rest on a face (Blender would
    otherwise put its centre of mass at that corner), and its reported pose is in the file's frame."""
    p = tmp_path / "cube.obj"
    v = np.array([(x, y, z) for x in (0, 0.03) for y in (0, 0.03) for z in (0, 0.03)], dtype=float)
    faces = [(1, 2, 4, 3), (5, 7, 8, 6), (1, 5, 6, 2), (3, 4, 8, 7), (1, 3, 7, 5), (2, 6, 8, 4)]
    p.write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v) +
                 "".join("f " + " ".join(map(str, f)) + "\n" for f in faces))
    cfg = default_config()
    cfg.objects = [ObjectEntry(filepath=str(p), mass=0.05, min_instances=1, max_instances=1, name="cube")]
    bs, om, sim = make(cfg)
    (inst,) = om.populate(np.random.default_rng(5))
    res = sim.run([inst])
    assert res.kept == [inst] and res.settled
    assert inst.obj.data == om.templates[0].obj.data               # back on the model-frame mesh
    w = world_vertices(inst)
    z = np.sort(w[:, 2])
    assert z[0] >= bs.floor_z - FLOOR_TOL
    assert z[3] - z[0] < 0.002                                 # four corners on the floor: lies on a face
    assert z[4] - z[0] == pytest.approx(0.03, abs=0.002)


# -- stiff and extreme parts (issue 11); the long sweeps live in benchmarks/bench_physics.py ----------

sys.path.insert(0, str(ROOT / "tests"))
import physics_parts  # noqa: E402


@pytest.fixture
def parts(tmp_path, monkeypatch):
    monkeypatch.setenv("DATAPIPE_CACHE", str(tmp_path / "cache"))
    return physics_parts.write_all(tmp_path / "parts")


def _cfg(entries, **sim):
    cfg = default_config()
    cfg.objects = [ObjectEntry(filepath=p, mass=m, min_instances=n, max_instances=n, name=Path(p).stem,
                               collision_shape=shape) for p, m, n, shape in entries]
    for k, v in sim.items():
        setattr(cfg.simulation, k, v)
    return cfg


def _assert_clean(res, n):
    """Nothing lost, at rest, and the independent check finds no pair deeper than 0.5 mm, nothing
    under the floor and nothing floating more than 2 mm from everything."""
    assert not res.removed and len(res.kept) == n
    assert res.settled and not res.unsettled
    c = res.check
    assert not c.pairs and not c.below_floor and not c.floating, c


def test_concave_parts_with_mesh_shape_are_decomposed_and_stay_in_the_bin(parts):
    cfg = _cfg([(parts["u_channel"], 0.03, 3, "MESH"), (parts["l_bracket"], 0.02, 3, "AUTO")])
    bs, om, sim = make(cfg)
    assert [t.shape for t in om.templates] == ["DECOMPOSED", "DECOMPOSED"]     # AUTO: clearly concave
    assert om.decomposed_from_cache == 0
    insts = om.populate(scene_rng(0, 0))
    for inst in insts:                       # a compound of hidden convex pieces, one per CoACD piece
        assert inst.obj.rigid_body.collision_shape == 'COMPOUND'
        kids = list(inst.obj.children)
        assert len(kids) >= 2 and all(k.rigid_body.collision_shape == 'CONVEX_HULL' and k.hide_render for k in kids)
    res = sim.run(insts, scene_rng(0, 0))
    _assert_clean(res, 6)
    assert not bpy.data.collections["datapipe_collision"].objects        # pieces gone once frozen
    # a second run reads the decompositions from the disk cache
    bpy.ops.wm.read_factory_settings(use_empty=True)
    _, om2, _ = make(cfg)
    assert om2.decomposed_from_cache == 2


def test_thin_plates_and_washers_do_not_tunnel(parts):
    cfg = _cfg([(parts["plate"], 0.012, 3, "AUTO"), (parts["washer"], 0.004, 3, "AUTO")])
    bs, om, sim = make(cfg)
    res = sim.run(om.populate(scene_rng(0, 1)), scene_rng(0, 1))
    # one substep may move a part half the 1 mm plate at the impact speed (or the max is reported)
    dt = 1 / bs.scene.render.fps
    assert res.plan.thinnest == pytest.approx(0.001, rel=1e-3)
    assert res.plan.capped or res.plan.impact_speed * dt / res.plan.substeps <= 0.0005 + 1e-9
    _assert_clean(res, 6)


def test_five_millimetre_parts_with_a_heavy_light_mix(parts):
    cfg = _cfg([(parts["peg5"], 0.001, 4, "AUTO"), (parts["nut5"], 0.001, 4, "AUTO"),
                (str(ASSETS / "peg.obj"), 1.0, 1, "AUTO")])                    # 1000:1 masses
    bs, om, sim = make(cfg)
    res = sim.run(om.populate(scene_rng(0, 2)), scene_rng(0, 2))
    _assert_clean(res, 9)


def test_frame_cap_with_parts_moving_is_reported(parts):
    cfg = _cfg([(parts["peg5"], 0.001, 2, "AUTO")], max_frames=3)
    bs, om, sim = make(cfg)
    res = sim.run(om.populate(scene_rng(0, 0)), scene_rng(0, 0))
    assert res.frames == 3 and not res.settled
    assert sorted(n for n, _ in res.unsettled) == sorted(i.name for i in res.kept)
    assert all(v > 0.01 for _, v in res.unsettled)                    # still falling
    s = res.summary()
    assert s["settled"] is False and len(s["unsettled"]) == 2 and "2 unsettled" in res.short()


def test_scene_is_redrawn_when_too_many_parts_are_lost(monkeypatch):
    """A drop that loses parts is redrawn from derived seeds, at most redraw_attempts times, and the
    same scene seed always gives the same redraws."""
    from datapipe.core import simulation as S
    cfg = one_part_cfg(n=2)
    cfg.simulation.redraw_lost_share = 0.4
    cfg.simulation.redraw_attempts = 2
    bs, om, sim = make(cfg)
    real_run, seen = sim.run, []

    def run(insts, rng=None):               # the first drop loses a part, redraws do not
        if not seen:
            place(insts[0], [bs.drop_zone_center[0] + bs.drop_zone_half[0] + 0.15, 0, bs.top_z])
        seen.append([np.array(i.obj.matrix_world).round(9).tolist() for i in insts])
        return real_run(insts, rng)
    monkeypatch.setattr(sim, "run", run)
    res, rng = S.drop_scene(om, sim, scene_rng(0, 3), 1234)
    assert res.attempts == 2 and not res.removed and len(res.kept) == 2
    assert res.summary()["attempts"] == 2 and "drop 2" in res.short()
    first_redraw = seen[1]
    om.clear()
    seen.clear()
    cfg.simulation.redraw_attempts = 0      # no redraws: the lossy drop is kept, and reported
    res0, _ = S.drop_scene(om, sim, scene_rng(0, 3), 1234)
    assert res0.attempts == 1 and len(res0.removed) == 1
    om.clear()
    # the redraw is a function of the scene seed alone
    a = om.populate(S.redraw_rng(1234, 1))
    assert [np.array(i.obj.matrix_world).round(9).tolist() for i in a] == first_redraw


def test_staged_drop_freezes_the_settled_pile_and_sleeps_at_the_settle_speeds(monkeypatch):
    """A drop in stages: the parts at rest after a stage are PASSIVE in the later stages (Bullet
    integrates only what still moves), every body sleeps below the settle test's own speeds, and
    the frozen pile keeps the guarantees: none lost, no pair deeper than 0.5 mm, all at rest, the
    same seed the same poses."""
    from datapipe.core import objects as O
    from datapipe.core import simulation as S
    monkeypatch.setattr(O, "STAGE_LAYERS", 1)      # one spawn layer a stage: 3 stages from 3 layers
    monkeypatch.setattr(S, "STAGE_LAYERS", 1)
    cfg = one_part_cfg("nut", n=12)
    cfg.scene.drop_zone_loc, cfg.scene.drop_zone_scale = [0.0, 0.0, 0.05], [0.045, 0.045, 0.05]
    bs, om, sim = make(cfg)
    real_run, seen = sim.run, []
    # at rest below min(settle_speed, 20% of the size per second); the nut's largest extent (its
    # across-corners width) is 34.6 mm, 20% of it per second is above the default 5 mm/s
    v_rest = min(cfg.simulation.settle_speed, 0.2 * 0.03464)

    def run(insts, rng=None, *, final=True):       # the bodies' types as each stage starts
        seen.append({i.name: i.obj.rigid_body.type for i in insts})
        res = real_run(insts, rng, final=final)
        if not final:
            seen[-1]["rest"] = {i.name for i in res.kept} - {n for n, _ in res.unsettled}
            rbs = [i.obj.rigid_body for i in res.kept]
            assert all(rb.use_deactivation for rb in rbs)
            assert np.allclose([rb.deactivate_linear_velocity for rb in rbs], v_rest, rtol=0.01)
            assert np.allclose([rb.deactivate_angular_velocity for rb in rbs], v_rest / 0.01732, rtol=0.01)
        return res
    monkeypatch.setattr(sim, "run", run)

    def drop():
        res, _ = S.drop_scene(om, sim, scene_rng(0, 1), 99)
        assert all(i.obj.rigid_body is None for i in res.kept)          # frozen for rendering
        poses = {n: M.copy() for n, M in res.poses.items()}
        om.clear()
        return res, poses

    res, poses = drop()
    assert len(seen) >= 3, "the column must drop in 3+ stages for this test"
    for before, now in zip(seen, seen[1:]):
        passive = {n for n, t in now.items() if t == 'PASSIVE'}
        assert passive == before["rest"] | {n for n, t in before.items() if t == 'PASSIVE'}
        assert passive and len(passive) < len(now) - 1                   # the new parts fall ACTIVE
    assert not res.removed and len(res.kept) == 12 and res.settled
    assert res.check.pairs == [] and res.check.below_floor == []
    seen.clear()
    _, again = drop()
    assert max(np.abs(again[n] - poses[n]).max() for n in poses) < 1e-6   # m: same seed, same poses


def test_a_stage_before_the_last_ends_when_its_parts_only_creep(monkeypatch):
    """A drop stage that is not the last stops once every part is below its at-rest speed over the
    settle window, even where the motion test is not met (the creeping parts go on ACTIVE in the
    next stage; the last stage still waits for the whole settle test). Made visible by a motion
    limit of 0: no part is ever at rest, so a stage before the last ends when all creep, the last
    one at max_frames with every part reported unsettled. Before, every stage ran to max_frames."""
    from datapipe.checks import settle
    from datapipe.core import objects as O
    from datapipe.core import simulation as S
    monkeypatch.setattr(O, "STAGE_LAYERS", 1)
    monkeypatch.setattr(S, "STAGE_LAYERS", 1)
    monkeypatch.setattr(settle, "SETTLE_MOTION", 0.0)
    cfg = one_part_cfg("nut", n=12)
    cfg.scene.drop_zone_loc, cfg.scene.drop_zone_scale = [0.0, 0.0, 0.05], [0.045, 0.045, 0.05]
    cfg.simulation.max_frames = 150
    bs, om, sim = make(cfg)
    real_run, stages = sim.run, []

    def run(insts, rng=None, *, final=True):
        res = real_run(insts, rng, final=final)
        stages.append((final, res.frames, len(res.unsettled), len(res.kept)))
        return res
    monkeypatch.setattr(sim, "run", run)
    res, _ = S.drop_scene(om, sim, scene_rng(0, 1), 99)
    assert len(stages) >= 3, "the column must drop in 3+ stages for this test"
    for final, frames, unsettled, kept in stages[:-1]:
        assert not final and frames < cfg.simulation.max_frames and unsettled == kept
    assert stages[-1][0] and stages[-1][1] == cfg.simulation.max_frames and not res.settled
    assert not res.removed and res.check.pairs == []
    om.clear()
