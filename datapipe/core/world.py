"""The real world of a run: `BlenderWorld`, the bpy side of the protocol in datapipe/world.py (bpy is
imported inside its methods, so the run loop imports this module without Blender).
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from ..config import Config
from ..draws.seeds import scene_seed
from ..world import SILENT, Part, Reporter, SceneStart, View


class BlenderWorld:
    """The bpy side of one run: built once, then scene after scene."""

    imports_meshes = True      # Blender imports the part files: the gate's mesh preflight applies

    def __init__(self, cfg: Config, out: Path):
        self.cfg, self.out = cfg, out
        self.sl = None
        self.blend = None
        self.instances: list = []                    # the annotated parts of the pile (_keep)
        self.pile: list = []
        self.setup_notes: list[str] = []
        self.progress: Reporter = SILENT             # the run's reporter (report_to), handed on to the parts
        self.simulation = self.renderer = None

    @property
    def import_count(self) -> int:
        return self.objects.import_count

    def setup(self) -> None:
        from .camera import BlendCamera
        from .objects import ObjectManager
        from .renderer import Renderer
        from .scene import BlendScene
        from .simulation import Simulation
        from .variety import SceneVariety

        self.blend = BlendScene(self.cfg)
        self.blend.setup()
        if self.blend.hidden_others:
            names = self.blend.hidden_others
            self.setup_notes.append(f"hid {len(names)} object(s) of the open scene from the renders for this run: "
                                    f"{', '.join(names[:8])}{' ...' if len(names) > 8 else ''} (scene.other_objects "
                                    "'keep' renders them)")
        bscene = self.blend.scene
        self.camera = BlendCamera(self.cfg, bscene)
        self.camera.setup()
        self.variety = SceneVariety(self.cfg, self.blend, self.camera)
        self.objects = ObjectManager(self.cfg, self.blend)
        self.objects.load_sources()
        self.simulation = Simulation(self.cfg, self.blend)
        self.renderer = Renderer(self.cfg, bscene, self.camera)
        self.renderer.setup()
        if self.cfg.structured_light.enabled:
            from .structured_light import StructuredLightCamera
            self.sl = StructuredLightCamera(self.cfg, bscene, self.camera, self.renderer)
            self.sl.setup()

    def report_to(self, progress: Reporter) -> None:
        """Report this world's steps to `progress` (the run's tracker; SILENT after the run): the drop's
        through the Simulation, the renders' (native and structured light) through the Renderer."""
        self.progress = progress
        for part in (self.simulation, self.renderer):
            if part is not None:
                part.progress = progress

    def model_meshes(self) -> dict:
        """{obj_id: (verts m, faces, normals)} of every annotated object entry (scale baked), for OUT/models
        (a distractor is in no ground truth, so it has no model)."""
        return {self.cfg.obj_id(i): self.objects.model_mesh(i) for i, e in enumerate(self.cfg.objects) if e.annotate}

    def start_scene(self, scene_id: int, base_seed: int, rng: np.random.Generator, n_renders: int) -> SceneStart:
        t0 = time.perf_counter()
        from .simulation import drop_scene
        drawn = self.variety.apply_scene(base_seed, scene_id)      # bin and lights first: placement fits the bin
        t1 = time.perf_counter()
        # populate + simulate (again from a derived seed when too many parts were lost)
        sim, rng = drop_scene(self.objects, self.simulation, rng, scene_seed(base_seed, scene_id))
        t2 = time.perf_counter()
        pose_indices = self.variety.pose_plan(rng, n_renders)
        from . import materials        # on a random stream of their own: a list changes no pose
        labels = materials.apply_to_instances(self.cfg, sim.kept, scene_seed(base_seed, scene_id))
        part_textures = self.variety.apply_parts(sim.kept, base_seed, scene_id, labels)   # None: no part textures
        if part_textures is not None:
            drawn.setdefault("textures", {})["parts"] = part_textures
        self.labels = {inst.name: lab for inst, lab in zip(sim.kept, labels)}
        self.drawn = drawn
        self._keep(sim.kept)
        return SceneStart(parts=self._parts(), simulation=self._summary(sim),
                          pose_indices=list(pose_indices), drawn=drawn,
                          seconds={"placement": t1 - t0 + sim.placement_seconds,
                                   "simulation": t2 - t1 - sim.placement_seconds},
                          poses=[sim.poses[inst.name] for inst in self.instances])

    def pick_step(self, scene_id: int, base_seed: int, rng: np.random.Generator, n_renders: int,
                  remove: list[str]) -> SceneStart:
        """scene.picks: delete the parts named `remove`, give the others their rigid bodies again and
        let them settle from where they lay (a simulation from rest, checked like a drop), then draw
        the step's camera poses. The bin, lights and materials stay the pile's."""
        import bpy
        t0 = time.perf_counter()
        gone = set(remove)
        for inst in self.pile:                # settled parts are plain objects (no rigid body, no pieces)
            if inst.name in gone:
                bpy.data.objects.remove(inst.obj, do_unlink=True)
        rest = [inst for inst in self.pile if inst.name not in gone]     # distractors stay: never picked
        self.progress.begin("simulation", f"{len(rest)} parts settling after {len(gone)} picked")   # run.json's steps
        self.objects.activate(rest)
        sim = self.simulation.run(rest)
        self._keep(sim.kept)
        pose_indices = self.variety.pose_plan(rng, n_renders)
        return SceneStart(parts=self._parts(), simulation=self._summary(sim), pose_indices=list(pose_indices),
                          drawn=self.drawn, seconds={"simulation": time.perf_counter() - t0},
                          poses=[sim.poses[inst.name] for inst in self.instances])

    def _keep(self, kept: list) -> None:
        """The pile after a drop or a pick step: every part in the bin (`pile`), and the annotated ones
        (`instances`): distractors (objects[i].annotate: false) fall, occlude and render, but are no
        part of the annotations, neither in the scene's parts nor in any T_world_obj of the renders."""
        self.pile = list(kept)
        self.instances = [inst for inst in kept if inst.annotated]

    def _summary(self, sim) -> dict:
        summary = sim.summary()
        if any(not e.annotate for e in self.cfg.objects):
            summary["distractors"] = len(self.pile) - len(self.instances)
        return summary

    def _parts(self) -> list[Part]:
        return [_part(inst, self.labels[inst.name], self.cfg.obj_id(inst.entry_index)) for inst in self.instances]

    def render(self, render_dir: Path, pose_index: int | None, seed: int, *, scene_id: int, render_id: int,
               base_seed: int) -> View:
        T_world_cam, sampled = self.variety.place_camera(pose_index, base_seed, scene_id, render_id)
        lighting = self.variety.apply_render(base_seed, scene_id, render_id)      # None: lighting per scene
        T_world_blcam = np.array(self.camera.obj.matrix_world, dtype=np.float64)
        t0 = time.perf_counter()
        out = self.renderer.render(render_dir, seed)
        t1 = time.perf_counter()
        cycles_s = float(getattr(out, "seconds", t1 - t0) or 0.0)
        view = View(files=dict(out.files), K=self.camera.K, resolution=tuple(self.camera.resolution),
                    T_world_cam=T_world_cam, T_world_blcam=T_world_blcam,
                    T_world_obj=[np.array(inst.obj.matrix_world, dtype=np.float64) for inst in self.instances],
                    mask=out.mask, rgb=out.rgb, camera_sampler=sampled, distortion=self.camera.distortion,
                    lighting=lighting,
                    seconds={"render": cycles_s, "write": max(0.0, (t1 - t0) - cycles_s)})  # EXR read-back + writes
        if self.sl is not None:
            t2 = time.perf_counter()
            files, view.structured_light = self.sl.process(render_dir, seed, T_world_cam)
            view.files.update(files)
            view.seconds["structured_light"] = time.perf_counter() - t2
        return view

    def finish_scene(self) -> None:
        """Delete what the scene created (templates, camera, projector stay)."""
        self.objects.clear()

    def close(self) -> None:
        """Remove the projector lights, patterns, fringe layers and the object-coordinate layer
        (nothing left in the user's scene) and render the scene's other objects again."""
        if self.sl is not None:
            self.sl.teardown()
            self.sl = None
        if getattr(self, "renderer", None) is not None:
            self.renderer.teardown()
        if self.blend is not None:
            self.blend.restore_other_objects()


def _part(inst, material: str, obj_id: int) -> Part:
    return Part(name=inst.name, filename=inst.filename, obj_id=obj_id, mask_index=inst.mask_index,
                material=material)
