"""Pick sequences (`scene.picks`): which scenes form one pile's sequence, and which parts each step
removes. No bpy: the run loop (engine/pipeline.py) calls these; the world removes the parts and
lets the rest settle (core/world.py `pick_step`).

A pile (one drop) is scene `p * L` of the run; its pick steps 1 .. L-1 are the scenes that follow,
`L = sequence_length(cfg)` scenes per pile, so scene numbers, seeds and shards stay functions of
the config alone: a shard holds whole sequences (`draws/seeds.py` `shard_scenes(group=L)`), and a
step can be re-made after a kill by replaying its pile's drop and earlier steps (each deterministic).
"""
from __future__ import annotations

import math

import numpy as np

from .seeds import _derive

_PICK = 0x5049434B          # domain tag 'PICK'


def most_parts(cfg) -> int:
    """The most parts a pile can hold that a robot may pick: every annotated object entry at its
    max_instances (distractors, `annotate: false`, stay in the bin: never picked)."""
    return int(sum(o.max_instances for o in cfg.objects if getattr(o, "annotate", True)))


def fewest_parts(cfg) -> int:
    """The fewest pickable parts a pile is dropped with: every annotated object entry at its
    min_instances (distractors are never picked)."""
    return int(sum(o.min_instances for o in cfg.objects if getattr(o, "annotate", True)))


def sequence_length(cfg) -> int:
    """Scenes per pile: 1 without picks, else the drop and enough pick steps to bring the fullest
    pile down to `until` parts. A pile dropped with fewer parts (fewer drawn, or parts lost) reaches
    `until` earlier; its later steps remove nothing (docs/DATASETS.md)."""
    pk = cfg.scene.picks
    if pk is None:
        return 1
    return 1 + max(0, math.ceil((most_parts(cfg) - pk.until) / pk.per_step))


def pile_of(scene_id: int, length: int) -> tuple[int, int]:
    """(first scene of its pile, step within the sequence) of scene `scene_id`."""
    return scene_id - scene_id % length, scene_id % length


def pick_rng(base: int, scene: int) -> np.random.Generator:
    """The generator of a step's "random" choice: a stream of its own (placement, poses and noise
    draw from theirs), derived from (base seed, the step's scene index) only."""
    return np.random.default_rng(_derive(_PICK, base, scene))


def top_heights(poses: list[np.ndarray], verts: list[np.ndarray]) -> np.ndarray:
    """Highest world z of each part: its model vertices (m) at its world pose (4x4)."""
    return np.array([float((v @ T[:3, :3].T + T[:3, 3])[:, 2].max()) for T, v in zip(poses, verts)])


def choose(order: str, names: list[str], count: int, *, heights: np.ndarray | None = None,
           visible: np.ndarray | None = None, rng: np.random.Generator | None = None) -> list[str]:
    """The `count` parts a step removes, in the order a robot would pick them.

    "top": highest point first (heights, m); "visible": largest visible fraction first (the mean over
    the previous step's renders); "random": drawn from `rng`. Ties fall to the name, so the choice
    depends on nothing but its inputs."""
    count = max(0, min(count, len(names)))
    if count == 0:
        return []
    if order == "random":
        idx = rng.choice(len(names), size=count, replace=False)
        return [names[int(k)] for k in idx]
    key = heights if order == "top" else visible
    if key is None or len(key) != len(names):
        raise ValueError(f"scene.picks.order {order!r} needs one value per part")
    ranked = sorted(range(len(names)), key=lambda k: (-float(key[k]), names[k]))
    return [names[k] for k in ranked[:count]]


def step_count(remaining: int, cfg) -> int:
    """Parts the next step removes from a pile of `remaining`: per_step, never below `until`."""
    pk = cfg.scene.picks
    return max(0, min(pk.per_step, remaining - pk.until))
