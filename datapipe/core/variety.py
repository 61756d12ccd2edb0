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
from ..draws import environment, textures
from ..draws.seeds import (TEXTURE_PARTS, TEXTURE_STATIC, bin_rng, camera_rng, lighting_render_rng, lighting_rng,
                           scene_seed, texture_rng)


class SceneVariety:
    def __init__(self, cfg: Config, blend_scene, camera):
        self.cfg, self.blend, self.camera = cfg, blend_scene, camera
        tex = cfg.scene.textures      # the user's files, listed once per run (validate() checked them)
        self.texture_sets = textures.texture_sets(tex.image_folder) if tex.targets and tex.image_folder else []
        li = cfg.lighting
        self.env_maps = environment.find_maps(li.environment) if li is not None and li.environment else []

    @property
    def lighting_per_render(self) -> bool:
        return self.cfg.lighting is not None and bool(self.cfg.lighting.per_render)

    def _draw_lighting(self, rng: np.random.Generator) -> dict:
        """The key light and ambient (draws/lighting.py), then the environment map when one is given."""
        draw = draw_lighting(self.cfg.lighting, rng)
        if self.env_maps:
            draw["environment"] = environment.draw_environment(self.cfg.lighting, self.env_maps, rng)
        return draw

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
        if self.cfg.scene.textures.targets:
            draws = textures.draw_static(self.cfg.scene.textures, texture_rng(base, scene, TEXTURE_STATIC),
                                         self.texture_sets)
            if draws:
                self.blend.set_textures(draws)
                rec["textures"] = {t: textures.record(d) for t, d in draws.items()}
        if self.cfg.lighting is not None and not self.lighting_per_render:
            rec["lighting"] = self._draw_lighting(lighting_rng(base, scene))
            self.blend.apply_lighting(rec["lighting"])
        return rec

    def apply_parts(self, instances, base: int, scene: int, labels: list[str]) -> list[dict] | None:
        """Draw and build the part instances' textures (scene.textures.targets has "parts") on each
        instance's own material spec; the draws per instance (scene.json), or None when off."""
        tex = self.cfg.scene.textures
        if "parts" not in tex.targets:
            return None
        from . import materials as mats
        from . import textures as built
        draws = textures.draw_parts(tex, texture_rng(base, scene, TEXTURE_PARTS), len(instances), self.texture_sets)
        specs = mats.instance_specs(self.cfg, instances, scene_seed(base, scene))
        for k, (inst, d) in enumerate(zip(instances, draws)):
            mats.assign(inst.obj, built.build(specs[inst.name], d, world_space=False, default=built.PART_DEFAULT,
                                              tag=f"part{k}"))
        built.remove_unused()
        return [textures.record(d) for d in draws]

    def apply_render(self, base: int, scene: int, render: int) -> dict | None:
        """With lighting.per_render: draw and apply this render's lighting (its record), else None."""
        if not self.lighting_per_render:
            return None
        draw = self._draw_lighting(lighting_render_rng(base, scene, render))
        self.blend.apply_lighting(draw)
        return draw

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
