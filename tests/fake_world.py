"""A World (datapipe/world.py; the real one is datapipe.core.world) without Blender, for testing the run loop: analytic boxes on a floor,
rendered by numpy ray casting (tests/fixtures_native.py), files written with the pipeline's own
writers. Deterministic from the rng the pipeline hands it, like the Blender world.

    pipe = Pipeline(cfg, out, world=BoxWorld.factory(crash_at=2))   # raises in the 3rd render it makes
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

import fixtures_native as fx
from datapipe.world import SILENT, Part, SceneStart, View
from datapipe.geometry import BLENDER_TO_OPENCV, intrinsics_from_sensor
from datapipe.io.native import write_render_maps


class Crash(RuntimeError):
    """What a killed process would be: the run stops in the middle of a render."""


class BoxWorld:
    instances = []          # every world made, in order (a test reads how many were built)

    def __init__(self, cfg, out: Path, *, crash_at: int | None = None):
        self.cfg, self.out = cfg, Path(out)
        self.crash_at = crash_at
        self.renders = 0
        self.import_count = 0
        self.setup_notes: list[str] = []
        self.closed = False
        self.objs: list = []
        self.parts: list = []
        self.picked: list[list[str]] = []     # the names each pick_step removed, in call order
        self.progress = SILENT                # the run's reporter, handed over by report_to
        BoxWorld.instances.append(self)

    @classmethod
    def factory(cls, **kw):
        return lambda cfg, out: cls(cfg, out, **kw)

    def report_to(self, progress) -> None:
        self.progress = progress

    def setup(self) -> None:
        self.import_count = len(self.cfg.objects)
        W, H = self.cfg.camera.resolution
        c = self.cfg.camera
        self.K = intrinsics_from_sensor(c.focal_length, c.sensor_width, W, H)

    def model_meshes(self) -> dict:
        return fx.box_meshes(1)

    def start_scene(self, scene_id: int, base_seed: int, rng: np.random.Generator, n_renders: int) -> SceneStart:
        self.objs = fx.scene_objects(int(rng.integers(2 ** 31)), 0)
        counts: dict[int, int] = {}
        parts = []
        for k, (obj_id, _) in enumerate(self.objs):
            counts[obj_id] = counts.get(obj_id, -1) + 1
            entry = self.cfg.objects[obj_id - 1]
            parts.append(Part(f"{entry.name}_{counts[obj_id]:03d}", entry.filepath, obj_id, k + 1))
        poses = [int(p) for p in rng.permutation(len(self.cfg.camera.poses))[:n_renders]]
        sim = {"parts": len(parts), "frames": int(rng.integers(20, 90)), "settled": True, "removed": []}
        self.parts = parts
        return SceneStart(parts=parts, simulation=sim, pose_indices=poses, seconds={"placement": 0.0, "simulation": 0.0},
                          poses=[T for _, T in self.objs])

    def pick_step(self, scene_id: int, base_seed: int, rng: np.random.Generator, n_renders: int,
                  remove: list[str]) -> SceneStart:
        """scene.picks: the named boxes go; the others stay where they lay (no physics here: the
        run loop's sequencing is what this world tests). Parts keep their mask index, as in Blender."""
        self.picked.append(list(remove))
        keep = [k for k, p in enumerate(self.parts) if p.name not in set(remove)]
        self.objs, self.parts = [self.objs[k] for k in keep], [self.parts[k] for k in keep]
        poses = [int(p) for p in rng.permutation(len(self.cfg.camera.poses))[:n_renders]]
        sim = {"parts": len(self.parts), "frames": int(rng.integers(5, 30)), "settled": True, "removed": []}
        return SceneStart(parts=list(self.parts), simulation=sim, pose_indices=poses,
                          seconds={"placement": 0.0, "simulation": 0.0}, poses=[T for _, T in self.objs])

    def render(self, render_dir: Path, pose_index: int, seed: int, *, scene_id: int, render_id: int,
               base_seed: int) -> View:
        if self.crash_at is not None and self.renders == self.crash_at:
            raise Crash(f"crashed in render {self.renders}")
        self.renders += 1
        W, H = self.cfg.camera.resolution
        pos, tgt = fx.DEFAULT_POSES[pose_index % len(fx.DEFAULT_POSES)]
        T_wc = fx.look_at(pos, tgt)
        depth, index, nrm = fx.raycast(self.K, T_wc, self.objs, W, H)
        index = np.array([0] + [p.mask_index for p in self.parts])[index]     # ray cast: list position + 1
        nc = nrm @ T_wc[:3, :3]
        files = write_render_maps(Path(render_dir), {
            "rgb": np.ascontiguousarray(fx.shade(index, nrm)[..., ::-1]),
            "depth": {"Z": depth.astype(np.float32)},
            "normals": {"X": nc[..., 0], "Y": nc[..., 1], "Z": nc[..., 2]},
            "mask": {"Y": index.astype(np.float32)}})
        return View(files=files, K=self.K, resolution=(W, H), T_world_cam=T_wc,
                    T_world_blcam=T_wc @ BLENDER_TO_OPENCV, T_world_obj=[T for _, T in self.objs],
                    mask=index, rgb=fx.shade(index, nrm), seconds={"render": 0.0, "write": 0.0})

    def finish_scene(self) -> None:
        self.objs, self.parts = [], []

    def close(self) -> None:
        self.closed = True
