"""Deterministic seeds and the scene plan. No bpy.

One base seed per run. Scene `i` (0-based) gets seeds derived from (base, i) only, so any scene can
be re-made alone, a killed run resumes identically, and shards produce the same dataset as one
process. The plan (how many renders each scene has) is drawn up front from the base seed alone.
"""
from __future__ import annotations

import random

import numpy as np

_PLAN, _SCENE, _RENDER = 0x504C414E, 0x5343454E, 0x52454E44   # domain tags: 'PLAN', 'SCEN', 'REND'
_CAMERA, _LIGHT, _BIN = 0x43414D53, 0x4C494748, 0x42494E53       # 'CAMS', 'LIGH', 'BINS'
_TEXTURE, _LIGHT_RENDER = 0x54455854, 0x4C495252                  # 'TEXT', 'LIRR'
TEXTURE_STATIC, TEXTURE_PARTS = 0, 1                              # texture_rng's two streams


def _derive(*words: int) -> int:
    return int(np.random.SeedSequence([int(w) & 0xFFFFFFFF for w in words]).generate_state(1)[0])


def scene_seed(base: int, scene: int) -> int:
    """32-bit seed of scene `scene` (Python `random`, NumPy, placement, simulation)."""
    return _derive(_SCENE, base, scene)


def render_seed(base: int, scene: int, render: int) -> int:
    """Seed of one render (Cycles sampling seed, sensor noise). Below 2**31 for Cycles' int seed."""
    return _derive(_RENDER, base, scene, render) & 0x7FFFFFFF


def scene_rng(base: int, scene: int) -> np.random.Generator:
    return np.random.default_rng(scene_seed(base, scene))


def camera_rng(base: int, scene: int, render: int) -> np.random.Generator:
    """The generator of one render's sampled camera pose: its own stream, so turning the sampler on
    or off changes no other draw (placement, simulation, noise)."""
    return np.random.default_rng(_derive(_CAMERA, base, scene, render))


def lighting_rng(base: int, scene: int) -> np.random.Generator:
    """The generator of one scene's drawn lighting (its own stream, like `camera_rng`)."""
    return np.random.default_rng(_derive(_LIGHT, base, scene))


def lighting_render_rng(base: int, scene: int, render: int) -> np.random.Generator:
    """The generator of one render's drawn lighting (`lighting.per_render`): a stream apart from the
    per-scene one, so switching per_render on changes no other draw."""
    return np.random.default_rng(_derive(_LIGHT_RENDER, base, scene, render))


def texture_rng(base: int, scene: int, which: int) -> np.random.Generator:
    """The generator of one scene's drawn textures: `TEXTURE_STATIC` (bin, floor: before the drop)
    or `TEXTURE_PARTS` (the part instances: after it). Streams of their own (draws/textures.py)."""
    return np.random.default_rng(_derive(_TEXTURE, base, scene, which))


def bin_rng(base: int, scene: int) -> np.random.Generator:
    """The generator of one scene's drawn bin size (its own stream, like `camera_rng`)."""
    return np.random.default_rng(_derive(_BIN, base, scene))


def seed_python(base: int, scene: int) -> None:
    """Seed Python's and NumPy's global generators for code we do not control."""
    s = scene_seed(base, scene)
    random.seed(s)
    np.random.seed(s)


MAX_PLAN_RENDERS = 1_000_000      # = config.MAX_RENDERS: a hard stop for callers that skip validate()


def plan_scenes(num_renders: int, min_per_scene: int, max_per_scene: int, base: int) -> list[int]:
    """Renders per scene, summing to `num_renders`; the last scene may be cut short.

    Drawn in vectorised chunks (the same numbers as one draw per scene: NumPy's bounded integers
    are a per-value stream), so a million renders plan in milliseconds. Bad bounds raise
    ValueError instead of looping forever (min 0) or failing inside NumPy (min > max)."""
    if not 1 <= min_per_scene <= max_per_scene:
        raise ValueError(f"renders per scene: need 1 <= min ({min_per_scene}) <= max ({max_per_scene})")
    if not 0 <= num_renders <= MAX_PLAN_RENDERS:
        raise ValueError(f"num_renders {num_renders} outside 0..{MAX_PLAN_RENDERS}")
    rng = np.random.default_rng(_derive(_PLAN, base))
    chunks, total = [], 0
    while total < num_renders:
        n = max(16, (num_renders - total) // min_per_scene + 1)     # at least enough, usually
        draw = rng.integers(min_per_scene, max_per_scene + 1, size=n)
        chunks.append(draw)
        total += int(draw.sum())
    if not chunks:
        return []
    sizes = np.concatenate(chunks)
    ends = np.cumsum(sizes)
    k = int(np.searchsorted(ends, num_renders))          # first scene that reaches the total
    plan = sizes[:k + 1].astype(int)
    plan[k] -= int(ends[k] - num_renders)
    return plan.tolist()


def parse_shard(text: str) -> tuple[int, int]:
    """'i/n' (0-based i) -> (i, n)."""
    try:
        i, n = (int(x) for x in text.split("/"))
    except ValueError:
        raise ValueError(f"--shard must look like i/n (e.g. 0/4), got {text!r}") from None
    if n < 1 or not 0 <= i < n:
        raise ValueError(f"--shard {text}: need 0 <= i < n")
    return i, n


def shard_scenes(num_scenes: int, shard: tuple[int, int], group: int = 1) -> range:
    """Contiguous scene range of shard (i, n); shards partition range(num_scenes). `group`: scenes
    go to shards in whole groups of this many (a pick sequence, datapipe/draws/picks.py: its steps
    need the pile of the step before); 1 is one scene at a time."""
    i, n = shard
    groups = -(-num_scenes // group)
    lo = groups * i // n * group
    hi = min(groups * (i + 1) // n * group, num_scenes)
    return range(lo, hi)
