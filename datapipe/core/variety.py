"""Scene variety in the Blender world: per-scene bin and lighting, per-render camera pose.

The draws are pure (`datapipe.draws.bin_shape`, `datapipe.draws.lighting`, `datapipe.draws.camera_sampler`), each
from its own seed stream of (base seed, scene[, render]) (`datapipe.draws.seeds`), so --resume and shards
make the same scenes, and a feature left off draws nothing and changes no other draw: a config
without variety renders exactly as before.

Per scene, before the parts are placed: `apply_scene` rebuilds the bin (placement and the "left the
bin" test follow the drawn size) and sets the lights; it returns what scene.json records. Per render:
`place_camera` moves the camera (and the projector parented to it) to the pool pose or to a pose
drawn around the bin floor's centre, returning T_world_cam and the drawn parameters.
"""
from __future__ import annotations

import numpy as np

from ..draws import bin_shape
from .. import materials_spec
from ..draws.camera_sampler import draw_bin_view
from ..config import Config
from ..draws.lighting import draw_lighting
from ..draws.seeds import bin_rng, camera_rng, lighting_rng, scene_seed


class SceneVariety:
    def __init__(self, cfg: Config, blend_scene, camera):
        self.cfg, self.blend, self.camera = cfg, blend_scene, camera

    @property
    def sampled(self) -> bool:
        return self.cfg.camera.sampler.kind == "bin_view"

    def apply_scene(self, base: int, scene: int) -> dict:
        """Draw and apply scene `scene`'s bin material (from a list), bin shape and lighting;
        {"bin_material": ..., "bin": ..., "lighting": ...} for the features that are on (empty when
        none is)."""
        rec = {}
        if isinstance(self.cfg.scene.bin_material, list):        # before a rebuild, which uses it
            spec = materials_spec.draw_bin(self.cfg.scene.bin_material, scene_seed(base, scene))
            self.blend.set_bin_material(spec)
            rec["bin_material"] = materials_spec.label(spec)
        if bin_shape.varies(self.cfg.scene):
            rec["bin"] = bin_shape.draw_bin(self.cfg.scene, self.blend.base_half, bin_rng(base, scene))
            self.blend.apply_bin(rec["bin"])
        if self.cfg.lighting is not None:
            rec["lighting"] = draw_lighting(self.cfg.lighting, lighting_rng(base, scene))
            self.blend.apply_lighting(rec["lighting"])
        return rec

    def pose_plan(self, rng: np.random.Generator, n: int) -> list:
        """Per render of the scene: a pool index (drawn without replacement from the scene's `rng`,
        as always) or, with the bin_view sampler, None (drawn per render in `place_camera`)."""
        return [None] * n if self.sampled else self.camera.draw_poses(rng, n)

    def place_camera(self, pose_index, base: int, scene: int, render: int) -> tuple[np.ndarray, dict | None]:
        """Move the camera for one render: (T_world_cam, the sampler's record or None for the pool)."""
        if pose_index is not None:
            return self.camera.set_pose(pose_index), None
        view = draw_bin_view(self.cfg.camera.sampler, self.blend.floor_center, camera_rng(base, scene, render))
        return self.camera.set_view(view), view.record()
