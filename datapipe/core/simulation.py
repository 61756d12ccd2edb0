"""Drop the scene's instances into the bin with Blender's rigid-body world, then freeze the result.

`Simulation(cfg, blend_scene).run(instances, rng)`:

1. chooses the substeps for this scene (`plan_substeps`): a part falling from the highest spawn
   point hits at v = sqrt(2 g h); one substep may move it at most half the thinnest thing it could
   pass through (the thinnest part's collision shape, the bin's wall/floor thickness), so
   substeps = ceil(v * frame_time / (0.5 * thinnest)), at least `simulation.substeps`, at most
   `simulation.max_substeps` (`substeps_capped` says when the cap was hit);
2. configures the scene's rigid-body world (substeps, solver iterations, point cache frames
   1 .. 1 + max_frames) and resets its cache, so a scene never replays or continues the previous
   scene's simulation (the same instances and poses give the same result whatever ran before);
3. steps frames in order with `scene.frame_set(f)`. A body is at rest when its linear speed (of
   its centre) and its angular speed times its radius both stay below min(settle_speed, 20% of
   its size per second) for `settle_frames` frames and at least 0.5 s, and it moved less than
   min(1 mm, 10% of its size) over that window: the rest is confirmed, not a momentary slow-down
   (the test, over a window that slides with the frames, is `datapipe/checks/settle.py`).
   Bullet's deactivation uses the same speeds (`_let_sleep`): a body below them for 2 s sleeps,
   so the numerical creep of a resting pile (< 1 mm/s, yet resetting the confirmation window
   again and again) ends instead of running the stage to max_frames.
   It stops when every body is at rest or gone for good (below the floor, or outside the walls
   below their top), else after max_frames frames: the bodies still moving are then reported in
   `unsettled`, never silently frozen. A drop stage that is not the last also stops when every
   body is at rest or creeping (below its at-rest speed over the window, yet drifting further than
   the motion limit): the creeping ones stay ACTIVE into the next stage (`drop_in_stages`);
4. reads each body's evaluated world matrix, deletes the parts that left the bin (centre of their
   world bounding box outside the zone's footprint: "left the bin") or fell through the floor
   (below floor_z - margin: "fell through the floor"), and freezes the others: their rigid body is
   removed (and the convex pieces of decomposed parts deleted), their matrix_world set to the
   final pose, the world's cache freed and the world disabled, so rendering at any frame shows
   exactly these poses;
5. measures the frozen result independently (`datapipe.checks.physics_check`): interpenetrating pairs,
   parts under the floor, floating parts.

`rng` is accepted for the contract but not drawn from: Bullet is deterministic for a given
initial state, which `ObjectManager.populate(rng)` already fixed.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import bpy
import numpy as np
from mathutils import Matrix

from ..config import Config
from ..checks.physics_check import Part, SceneCheck, check_scene, physics_line
from ..checks.settle import RestTest, settle_speeds
from ..world import SILENT, Reporter
from .objects import COM_PROP, SIM_MESH_PROP, STAGE_LAYERS, Instance, ObjectManager
from .scene import INSIDE_MARGIN, BlendScene, ensure_rigidbody_world, remove_rigid_bodies

FRAME_START = 1
LEFT_BIN = "left the bin"
FELL_THROUGH = "fell through the floor"
GRAVITY = 9.81                 # m/s^2
SUBSTEP_FRACTION = 0.5         # one substep moves a part at most this x the thinnest width


@dataclass
class SubstepPlan:
    substeps: int
    impact_speed: float        # m/s, from the highest spawn point
    thinnest: float            # m, the thinnest part width or wall the substeps guard
    capped: bool               # the rule asked for more than simulation.max_substeps


@dataclass
class SimResult:
    frames: int                                   # frames simulated (<= cfg.simulation.max_frames)
    settled: bool                                 # every remaining body came to rest (confirmed)
    kept: list[Instance]                          # still in the bin; matrix_world = final pose
    removed: list[tuple[Instance, str]]           # deleted from the scene, with the reason
    poses: dict[str, np.ndarray] = field(default_factory=dict)   # name -> final 4x4 world pose (kept)
    unsettled: list[tuple[str, float]] = field(default_factory=list)  # kept, still moving: (name, m/s)
    plan: SubstepPlan | None = None
    check: SceneCheck | None = None               # independent check of the frozen result
    seconds: float = 0.0                          # wall time of the simulation (without the check)
    attempts: int = 1                             # drops made (> 1: redrawn, see drop_scene)
    placement_seconds: float = 0.0                # drop_scene: time spent populating (all attempts)
    stages: int = 1                               # drop stages (a deep spawn column drops in stages)
    fill: dict | None = None                      # scene.fill: the share drawn and the share reached

    def summary(self) -> dict:
        """What scene.json and the progress line report about the drop (lengths in mm). No timings:
        scene.json holds the dataset's content only (the run's timings are in run.json)."""
        c = self.check
        out = {
            "parts": len(self.kept), "frames": self.frames, "settled": self.settled,
            "substeps": self.plan.substeps if self.plan else None,
            "substeps_capped": bool(self.plan and self.plan.capped),
            "impact_speed": round(self.plan.impact_speed, 4) if self.plan else None,
            "removed": [{"name": inst.name, "reason": why} for inst, why in self.removed],
            "unsettled": [{"name": n, "speed": round(v, 5)} for n, v in self.unsettled],
            "attempts": self.attempts,
        }
        if self.stages > 1:
            out["stages"] = self.stages
        if self.fill is not None:
            out["fill"] = dict(self.fill)
        if c is not None:
            out.update({
                "max_interpenetration_mm": round(c.max_depth * 1000, 3),
                "interpenetrating_pairs": [{"a": a, "b": b, "depth_mm": round(d * 1000, 3)} for a, b, d in c.pairs],
                "below_floor": [{"name": n, "depth_mm": round(d * 1000, 3)} for n, d in c.below_floor],
                "floating": [{"name": n, "gap_mm": round(g * 1000, 3)} for n, g in c.floating],
            })
        return out

    def short(self) -> str:
        """One progress-line fragment: '9 parts, 3 removed (left the bin), 1 unsettled, 64 frames x 13 substeps'."""
        return physics_line(self.summary())


def redraw_rng(scene_seed: int, attempt: int) -> np.random.Generator:
    """The generator of redraw `attempt` (1, 2, ...) of a scene: derived from the scene's seed only,
    so a redrawn scene is the same in every run, shard and resume."""
    return np.random.default_rng(np.random.SeedSequence([int(scene_seed) & 0xFFFFFFFF, 0x52445257, int(attempt)]))


def drop_scene(objects: ObjectManager, simulation: "Simulation", rng: np.random.Generator,
               scene_seed: int) -> tuple[SimResult, np.random.Generator]:
    """Populate and simulate; when more than `simulation.redraw_lost_share` of the parts is lost,
    draw the scene again from `redraw_rng(scene_seed, k)`, at most `simulation.redraw_attempts`
    times. Returns the last drop's result and the generator it used (the scene draws on from it)."""
    cfg = simulation.cfg.simulation
    attempt, placing = 0, 0.0
    while True:
        t0 = time.perf_counter()
        simulation.progress.begin("placement", "" if attempt == 0 else f"(redraw {attempt})")
        insts = objects.populate(rng, staged=True)
        placing += time.perf_counter() - t0
        simulation.progress.begin("simulation", f"{len(insts)} parts" + (
            f" (scene.fill {objects.last_fill['share']:.2f} of the bin)" if objects.last_fill else ""))
        res = drop_in_stages(objects, simulation, insts)
        res.attempts, res.placement_seconds, res.fill = attempt + 1, placing, objects.last_fill
        lost = len(res.removed) / max(1, len(insts))
        if lost <= cfg.redraw_lost_share or attempt >= cfg.redraw_attempts:
            return res, rng
        attempt += 1
        objects.clear()
        rng = redraw_rng(scene_seed, attempt)


def drop_in_stages(objects: ObjectManager, simulation: "Simulation", instances: list[Instance]) -> SimResult:
    """Simulate the spawn column in stages of STAGE_LAYERS layers: stage k's parts get their rigid
    bodies only once stages < k have settled, lowered to just above the pile (the highest point of
    the parts kept so far + layer_gap), so hundreds of parts never fall from a column many times the
    bin's height (impact speed, substeps, parts thrown over the walls). Each stage is one
    `Simulation.run` with its own substep plan and settle criteria over every part in the bin; the
    parts at rest at the end of a stage stay where they lay as PASSIVE bodies (`_freeze_settled`),
    the parts still moving start the next stage at rest where they were. A stage before the last
    ends once its parts not at rest all creep (slower than the at-rest speed, see `_step`): a part
    sliding at 2-3 mm/s on the frozen pile held a stage for 100-200 frames before, with every
    frozen part costing Bullet every substep; it now slides on in the next stage. A column of <=
    STAGE_LAYERS layers is one plain run."""
    waves = sorted({inst.layer // STAGE_LAYERS for inst in instances})
    if len(waves) <= 1:
        return simulation.run(instances)
    active = [inst for inst in instances if inst.layer // STAGE_LAYERS == waves[0]]
    removed: list[tuple[Instance, str]] = []
    frames, seconds, plan = 0, 0.0, None
    frozen: set[str] = set()
    for w in waves:
        if w != waves[0]:
            wave = [inst for inst in instances if inst.layer // STAGE_LAYERS == w]
            _lower_onto(wave, active, float(simulation.cfg.simulation.layer_gap))
            objects.activate(wave)
            active = active + wave
        res = simulation.run(active, final=w == waves[-1])
        if w != waves[-1]:
            frozen |= _freeze_settled(res, frozen)
        frames, seconds = frames + res.frames, seconds + res.seconds
        removed += res.removed
        if plan is None or (res.plan and res.plan.substeps > plan.substeps):
            plan = res.plan
        active = res.kept
        state = "settled" if res.settled else f"{len(res.unsettled)} still moving after {res.frames} frames"
        simulation.progress.note(f"drop stage {waves.index(w) + 1}/{len(waves)}: {state}, "
                                 f"{len(res.kept)} parts in the bin, {len(removed)} lost")
    res.kept.sort(key=lambda inst: inst.mask_index)
    res.frames, res.seconds, res.removed, res.plan, res.stages = frames, seconds, removed, plan, len(waves)
    return res


def _freeze_settled(res: SimResult, frozen: set[str]) -> set[str]:
    """The parts at rest at the end of a drop stage (the settle test confirmed them) become PASSIVE
    for the later stages: they keep supporting the pile and colliding with every part that lands
    on them, but Bullet no longer integrates or solves them, so a stage costs about its own new
    parts, not the whole pile (120 parts: 69 -> 12-19 CPU s, benchmarks/results/physics.md). The
    price: a landing part no longer pushes the pile below it. Measured with the whole pile live,
    a stage of 24 parts moved 21 of the 24 parts below it by more than 1 mm (median 5 mm, 90th
    percentile 17 mm: the pile compacting); frozen, they stay where they came to rest. A part
    still moving at the stage's end stays ACTIVE."""
    moving = {name for name, _ in res.unsettled}
    out = set()
    for inst in res.kept:
        if inst.name in frozen or inst.name in moving:
            continue
        for o in (inst.obj, *inst.obj.children):   # the convex pieces of a decomposed part too
            if o.rigid_body is not None:
                o.rigid_body.type = 'PASSIVE'
        out.add(inst.name)
    return out


def _world_corners(obj) -> np.ndarray:
    M = np.array(obj.matrix_world, dtype=np.float64)
    return np.array([tuple(v) for v in obj.bound_box], dtype=np.float64) @ M[:3, :3].T + M[:3, 3]


def _lower_onto(wave: list[Instance], pile: list[Instance], gap: float) -> None:
    """Move the wave (spheres that do not overlap each other) straight down until its lowest point
    is `gap` above the pile's highest one; never up."""
    top = max((_world_corners(inst.obj)[:, 2].max() for inst in pile), default=-math.inf)
    bottom = min(_world_corners(inst.obj)[:, 2].min() for inst in wave)
    dz = min(0.0, top + gap - bottom)
    for inst in wave:
        M = inst.obj.matrix_world.copy()
        M[2][3] += dz
        inst.obj.matrix_world = M
    bpy.context.view_layer.update()


def settle_sizes(instances: list[Instance], corners: list[np.ndarray]) -> np.ndarray:
    """Each body's size (m) for the settle test: its template's largest extent, else its box's."""
    return np.array([max(inst.size, 1e-4) if inst.size else float(np.ptp(c, axis=0).max())
                     for inst, c in zip(instances, corners)], dtype=np.float64)


def plan_substeps(cfg: Config, bs: BlendScene, instances: list[Instance], frame_time: float) -> SubstepPlan:
    """Substeps so that a part at its impact speed moves at most SUBSTEP_FRACTION x the thinnest
    part (or the wall/floor) per substep."""
    sim = cfg.simulation
    if not instances:
        return SubstepPlan(int(sim.substeps), 0.0, 0.0, False)
    lowest = []
    for inst in instances:
        M = np.array(inst.obj.matrix_world, dtype=np.float64)
        c = np.array([tuple(v) for v in inst.obj.bound_box], dtype=np.float64) @ M[:3, :3].T + M[:3, 3]
        lowest.append(float(c[:, 2].min()))
    h = max(0.0, max(lowest) - bs.floor_z)
    thin = min(inst.thin for inst in instances if inst.thin > 0) if any(i.thin > 0 for i in instances) else 0.0
    wall = float(cfg.scene.bin_wall_thickness)
    thinnest = min(x for x in (thin, wall) if x > 0)
    v = math.sqrt(2 * GRAVITY * h)
    need = math.ceil(v * frame_time / (SUBSTEP_FRACTION * thinnest)) if thinnest > 0 else 1
    n = max(int(sim.substeps), need)
    capped = n > int(sim.max_substeps)
    return SubstepPlan(min(n, int(sim.max_substeps)), v, thinnest, capped)


class Simulation:
    def __init__(self, cfg: Config, blend_scene: BlendScene, progress: Reporter = SILENT):
        self.cfg = cfg
        self.progress = progress       # where the drop's steps and frames are reported (the run's tracker)
        self.blend_scene = blend_scene
        self.margin = INSIDE_MARGIN
        self._meshes: dict[str, tuple[np.ndarray, np.ndarray]] = {}   # mesh name -> (verts, tris)

    def _configure_world(self, substeps: int) -> bpy.types.RigidBodyWorld:
        sim = self.cfg.simulation
        scene = self.blend_scene.scene
        rbw = ensure_rigidbody_world(scene)
        rbw.enabled = True
        rbw.time_scale = 1.0
        # each of these assignments resets the world's cache (rna update), even with equal values
        rbw.substeps_per_frame = int(substeps)
        rbw.solver_iterations = int(sim.solver_iterations)
        rbw.point_cache.frame_start = FRAME_START
        rbw.point_cache.frame_end = FRAME_START + int(sim.max_frames)
        return rbw

    def run(self, instances: list[Instance], rng: np.random.Generator | None = None, *,
            final: bool = True) -> SimResult:
        """Simulate `instances` to rest. `final=False` (a drop stage, see drop_in_stages): the parts
        kept stay rigid bodies, set at rest where they lay, for the next stage; no check."""
        t0 = time.perf_counter()
        scene = self.blend_scene.scene
        dt = scene.render.fps_base / scene.render.fps
        plan = plan_substeps(self.cfg, self.blend_scene, instances, dt)
        # model-frame bounding boxes, read before the simulation swaps in re-centred meshes
        corners = [np.array([tuple(c) for c in inst.obj.bound_box], dtype=np.float64) for inst in instances]
        offsets = [self._use_com_mesh(inst) for inst in instances]   # T_sim_model per instance
        self._let_sleep(instances, corners)
        rbw = self._configure_world(plan.substeps)
        scene.frame_set(FRAME_START)               # back to the initial state: Bullet world rebuilt
        frames, settled, mats, unsettled = self._step(instances, offsets, corners, dt, final)

        kept: list[Instance] = []
        removed: list[tuple[Instance, str]] = []
        poses: dict[str, np.ndarray] = {}
        bs = self.blend_scene
        for inst, M, c in zip(instances, mats, corners):
            centre = (c @ M[:3, :3].T + M[:3, 3]).mean(axis=0)
            if not bs.inside_footprint(centre, self.margin):
                removed.append((inst, LEFT_BIN))
            elif centre[2] < bs.floor_z - self.margin:
                removed.append((inst, FELL_THROUGH))
            else:
                kept.append(inst)
                poses[inst.name] = M
        gone = {inst.name for inst, _ in removed}
        unsettled = [(n, v) for n, v in unsettled if n not in gone]
        for inst, _ in removed:
            _delete_with_pieces(inst.obj)
        if not final:
            self._rest_here(kept, poses, rbw)
            return SimResult(frames=frames, settled=settled and not unsettled, kept=kept, removed=removed,
                             poses=poses, unsettled=unsettled, plan=plan, seconds=time.perf_counter() - t0)
        self._freeze(kept, poses, rbw)
        seconds = time.perf_counter() - t0
        res = SimResult(frames=frames, settled=settled and not unsettled, kept=kept, removed=removed,
                        poses=poses, unsettled=unsettled, plan=plan, seconds=seconds)
        res.check = self.check(kept, poses)
        return res

    def _let_sleep(self, instances: list[Instance], corners: list[np.ndarray]) -> None:
        """Bullet's deactivation with the settle test's own speeds: a body slower than its at-rest
        speed (linear, and angular times its radius) for Bullet's deactivation time (2 s) sleeps with
        its whole island: it stops being integrated and stops creeping, and wakes when a moving body
        touches it. Blender's defaults (0.4 m/s, 0.5 rad/s) would put a falling 20 mm part to sleep."""
        sizes = settle_sizes(instances, corners)
        v = settle_speeds(float(self.cfg.simulation.settle_speed), sizes)
        for inst, v_lin, r in zip(instances, v, sizes / 2):
            rb = inst.obj.rigid_body
            rb.use_deactivation = True
            rb.deactivate_linear_velocity = float(v_lin)
            rb.deactivate_angular_velocity = float(v_lin / r)

    def _rest_here(self, kept: list[Instance], poses: dict[str, np.ndarray], rbw) -> None:
        """Between drop stages: the kept parts' initial poses become where they came to rest (model
        mesh back, rigid body kept), the cache is freed so the next run starts from them."""
        rbw.point_cache.frame_end = rbw.point_cache.frame_end
        self.blend_scene.scene.frame_set(FRAME_START)
        for inst in kept:
            model_mesh = inst.obj.get("datapipe_model_mesh")
            if model_mesh is not None:
                inst.obj.data = model_mesh
                del inst.obj["datapipe_model_mesh"]
            inst.obj.matrix_world = Matrix(poses[inst.name].tolist())
        bpy.context.view_layer.update()


    def _step(self, instances: list[Instance], offsets: list[np.ndarray], corners: list[np.ndarray], dt: float,
              final: bool = True):
        """Step until every body is at rest (confirmed) or gone, or max_frames; a stage that is not
        the last (`final=False`) also stops when the bodies not at rest are all creeping (below their
        at-rest speed over the whole window, yet drifting further than the motion limit: sliding
        slowly on the frozen pile, 2-3 mm/s): they stay ACTIVE and go on sliding in the next stage,
        where the last stage's settle test confirms them like every other part. Returns (frames,
        settled, model-frame world poses, [(name, speed m/s)] of the bodies still moving). The
        per-frame test runs on all bodies at once (arrays of n poses): at 120 parts and ~1000
        frames a per-body Python loop cost seconds of its own."""
        sim = self.cfg.simulation
        scene = self.blend_scene.scene
        n = len(instances)
        sizes = settle_sizes(instances, corners)
        radius = sizes / 2
        C = np.array(corners, dtype=np.float64).reshape(n, 8, 3)
        T = np.array(offsets, dtype=np.float64).reshape(n, 4, 4)

        def state():
            dg = bpy.context.evaluated_depsgraph_get()
            mats = np.array([inst.obj.evaluated_get(dg).matrix_world for inst in instances],
                            dtype=np.float64).reshape(n, 4, 4) @ T
            return mats, np.einsum("nij,nkj->nki", mats[:, :3, :3], C) + mats[:, None, :3, 3]

        mats, pts = state()
        test = RestTest(sizes, float(sim.settle_speed), int(sim.settle_frames), dt, pts)
        rest = np.zeros(n, dtype=bool)
        speed = np.zeros(n)
        frames, settled = 0, n == 0
        for k in range(1, int(sim.max_frames) + 1):
            scene.frame_set(FRAME_START + k)
            frames = k
            self.progress.advance(k, int(sim.max_frames))
            prev, (mats, pts) = mats, state()
            lin = np.linalg.norm(mats[:, :3, 3] - prev[:, :3, 3], axis=1) / dt
            cos = (np.einsum("nij,nij->n", prev[:, :3, :3], mats[:, :3, :3]) - 1) / 2   # trace(R_prev^T R)
            speed = np.maximum(lin, np.arccos(np.clip(cos, -1.0, 1.0)) / dt * radius)
            rest = test.update(speed, pts)
            if np.all(self._gone(pts) | rest):
                settled = True
                break
            if not final and np.all(self._gone(pts) | test.creeping()):
                break
        moving = ~(self._gone(pts) | rest)
        return frames, settled, mats, [(inst.name, float(speed[j])) for j, inst in enumerate(instances) if moving[j]]

    def _gone(self, corners: np.ndarray) -> np.ndarray:
        """Per body (corners: n x 8 x 3): below the floor, or outside the walls and below their top:
        it cannot come back."""
        bs = self.blend_scene
        c = corners.mean(axis=1)
        gone = c[:, 2] < bs.floor_z - self.margin
        if self.cfg.scene.make_bin:
            outside = np.any(np.abs(c[:, :2] - bs.drop_zone_center[:2]) > bs.drop_zone_half[:2] + self.margin, axis=1)
            gone |= outside & (corners[:, :, 2].max(axis=1) < bs.wall_top_z)
        return gone

    def check(self, kept: list[Instance], poses: dict[str, np.ndarray]) -> SceneCheck:
        """Independent check of the frozen result (model meshes at the final poses)."""
        parts = []
        for inst in kept:
            me = inst.obj.data
            if me.name not in self._meshes:
                v, t, _ = ObjectManager.model_mesh_of(me)
                self._meshes[me.name] = (v, t)
            v, t = self._meshes[me.name]
            parts.append(Part(inst.name, v, t, poses[inst.name]))
        bs = self.blend_scene
        walls = (bs.drop_zone_center, bs.drop_zone_half) if self.cfg.scene.make_bin else None
        return check_scene(parts, bs.floor_z, walls)

    @staticmethod
    def _use_com_mesh(inst: Instance) -> np.ndarray:
        """Blender puts a rigid body's centre of mass at the object origin. If the template has a
        copy re-centred on its centre of mass, simulate with that (same world placement) and return
        T_sim_model, which maps the simulated pose back to the model frame."""
        me = inst.obj.data
        sim_mesh = me.get(SIM_MESH_PROP)
        if sim_mesh is None:
            return np.eye(4)
        com = np.asarray(me[COM_PROP], dtype=np.float64)
        M = np.array(inst.obj.matrix_world, dtype=np.float64)
        T_model_sim = np.eye(4)
        T_model_sim[:3, 3] = com
        inst.obj["datapipe_model_mesh"] = me
        inst.obj.data = sim_mesh
        inst.obj.matrix_world = Matrix((M @ T_model_sim).tolist())
        return np.linalg.inv(T_model_sim)

    def _freeze(self, kept: list[Instance], poses: dict[str, np.ndarray], rbw) -> None:
        scene = self.blend_scene.scene
        for inst in kept:
            for child in list(inst.obj.children):  # convex pieces of a decomposed part
                bpy.data.objects.remove(child, do_unlink=True)
        remove_rigid_bodies([inst.obj for inst in kept])
        for inst in kept:
            model_mesh = inst.obj.get("datapipe_model_mesh")
            if model_mesh is not None:             # back to the template's mesh (model frame)
                inst.obj.data = model_mesh
                del inst.obj["datapipe_model_mesh"]
            inst.obj.matrix_world = Matrix(poses[inst.name].tolist())
        # free the cache and park the world: nothing moves when the renderer changes frames
        rbw.point_cache.frame_end = rbw.point_cache.frame_end
        scene.frame_set(FRAME_START)
        rbw.enabled = False
        bpy.context.view_layer.update()
        for inst in kept:                          # report exactly what will be rendered
            poses[inst.name] = np.array(inst.obj.matrix_world, dtype=np.float64)


def _delete_with_pieces(obj: bpy.types.Object) -> None:
    for child in list(obj.children):
        bpy.data.objects.remove(child, do_unlink=True)
    bpy.data.objects.remove(obj, do_unlink=True)
