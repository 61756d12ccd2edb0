"""Drop the scene's instances into the bin with Blender's rigid-body world, then freeze the result.

`Simulation(cfg, blend_scene).run(instances, rng)`:

1. configures the scene's rigid-body world (substeps, solver iterations, point cache frames
   1 .. 1 + max_frames) and resets its cache, so a scene never replays or continues the previous
   scene's simulation (the same instances and poses give the same result whatever ran before);
2. steps frames in order with `scene.frame_set(f)`; after each frame the speed of a body is the
   largest displacement of its bounding-box corners divided by the frame time (so spinning
   counts too); it stops early when every body is either at rest (speed < settle_speed for
   settle_frames consecutive frames) or already below the floor (gone for good), else after
   max_frames frames;
3. reads each body's evaluated world matrix, deletes the parts that left the bin (centre of their
   world bounding box outside the zone's footprint: "left the bin") or fell through the floor
   (below floor_z - margin: "fell through the floor"), and freezes the others: their rigid body is
   removed, their matrix_world set to the final pose, the world's cache freed and the world
   disabled, so rendering at any frame shows exactly these poses.

`rng` is accepted for the contract but not drawn from: Bullet is deterministic for a given
initial state, which `ObjectManager.populate(rng)` already fixed.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import bpy
import numpy as np
from mathutils import Matrix

from ..config import Config
from .objects import COM_PROP, SIM_MESH_PROP, Instance
from .scene import INSIDE_MARGIN, BlendScene, ensure_rigidbody_world, remove_rigid_body

FRAME_START = 1
LEFT_BIN = "left the bin"
FELL_THROUGH = "fell through the floor"


@dataclass
class SimResult:
    frames: int                                   # frames simulated (<= cfg.simulation.max_frames)
    settled: bool                                 # every remaining body came to rest
    kept: list[Instance]                          # still in the bin; matrix_world = final pose
    removed: list[tuple[Instance, str]]           # deleted from the scene, with the reason
    poses: dict[str, np.ndarray] = field(default_factory=dict)   # name -> final 4x4 world pose (kept)


class Simulation:
    def __init__(self, cfg: Config, blend_scene: BlendScene):
        self.cfg = cfg
        self.blend_scene = blend_scene
        self.margin = INSIDE_MARGIN

    def _configure_world(self) -> bpy.types.RigidBodyWorld:
        sim = self.cfg.simulation
        scene = self.blend_scene.scene
        rbw = ensure_rigidbody_world(scene)
        rbw.enabled = True
        rbw.time_scale = 1.0
        # each of these assignments resets the world's cache (rna update), even with equal values
        rbw.substeps_per_frame = int(sim.substeps)
        rbw.solver_iterations = int(sim.solver_iterations)
        rbw.point_cache.frame_start = FRAME_START
        rbw.point_cache.frame_end = FRAME_START + int(sim.max_frames)
        return rbw

    def run(self, instances: list[Instance], rng: np.random.Generator | None = None) -> SimResult:
        sim = self.cfg.simulation
        bs = self.blend_scene
        scene = bs.scene
        corners = [np.array([tuple(c) for c in inst.obj.bound_box], dtype=np.float64) for inst in instances]
        offsets = [self._use_com_mesh(inst) for inst in instances]   # T_sim_model per instance
        rbw = self._configure_world()
        scene.frame_set(FRAME_START)               # back to the initial state: Bullet world rebuilt
        dt = scene.render.fps_base / scene.render.fps

        def world_state():
            """Model-frame world poses and world bounding-box corners of every instance."""
            dg = bpy.context.evaluated_depsgraph_get()
            mats = [np.array(inst.obj.evaluated_get(dg).matrix_world, dtype=np.float64) @ off
                    for inst, off in zip(instances, offsets)]
            pts = [c @ M[:3, :3].T + M[:3, 3] for c, M in zip(corners, mats)]
            return mats, pts

        mats, prev = world_state()
        still = np.zeros(len(instances), dtype=int)
        frames, settled = 0, len(instances) == 0
        for k in range(1, int(sim.max_frames) + 1):
            scene.frame_set(FRAME_START + k)
            frames = k
            mats, pts = world_state()
            done = True
            for j, (p0, p1) in enumerate(zip(prev, pts)):
                speed = float(np.linalg.norm(p1 - p0, axis=1).max()) / dt
                still[j] = still[j] + 1 if speed < sim.settle_speed else 0
                gone = p1.mean(axis=0)[2] < bs.floor_z - self.margin
                if not (gone or still[j] >= sim.settle_frames):
                    done = False
            prev = pts
            if done:
                settled = True
                break

        kept: list[Instance] = []
        removed: list[tuple[Instance, str]] = []
        poses: dict[str, np.ndarray] = {}
        for inst, M, p in zip(instances, mats, prev):
            lo, hi = p.min(axis=0), p.max(axis=0)
            centre = (lo + hi) / 2
            if not bs.inside_footprint(centre, self.margin):
                removed.append((inst, LEFT_BIN))
            elif centre[2] < bs.floor_z - self.margin:
                removed.append((inst, FELL_THROUGH))
            else:
                kept.append(inst)
                poses[inst.name] = M
        for inst, _ in removed:
            bpy.data.objects.remove(inst.obj, do_unlink=True)
        self._freeze(kept, poses, rbw)
        return SimResult(frames=frames, settled=settled, kept=kept, removed=removed, poses=poses)

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
            remove_rigid_body(inst.obj)
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
