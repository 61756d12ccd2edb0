"""Per-scene bin size and wall height draws. No bpy (core/scene.py rebuilds the bin from a draw).

`scene.bin_size_scale` [min, max] multiplies the drop zone's x and y half extents (one factor per
axis, each uniform in the range) and `scene.bin_wall_scale` [min, max] the wall height (the drop
zone's height by default). The floor stays where it is (the zone's bottom), so parts, camera target
and light keep their reference. Both ranges at [1, 1] (the default) draw nothing: the bin of the
config, and the same output as before these fields existed.
"""
from __future__ import annotations

import numpy as np


def varies(scene_cfg) -> bool:
    return list(scene_cfg.bin_size_scale) != [1.0, 1.0] or list(scene_cfg.bin_wall_scale) != [1.0, 1.0]


def _uniform(rng: np.random.Generator, lo_hi) -> float:
    lo, hi = (float(v) for v in lo_hi)
    return lo if hi <= lo else float(rng.uniform(lo, hi))


def draw_bin(scene_cfg, half_extents, rng: np.random.Generator) -> dict:
    """One scene's bin around a zone of `half_extents` (x, y, z half sizes, m): what scene.json
    records and `BlendScene.apply_bin` builds. Draw order: x scale, y scale, wall scale."""
    h = np.asarray(half_extents, dtype=np.float64)
    sx, sy = _uniform(rng, scene_cfg.bin_size_scale), _uniform(rng, scene_cfg.bin_size_scale)
    sw = _uniform(rng, scene_cfg.bin_wall_scale)
    return {"half_size": [float(h[0] * sx), float(h[1] * sy), float(h[2])],
            "wall_height": float(2 * h[2] * sw), "size_scale": [sx, sy], "wall_scale": sw}
