"""The world a run renders, as the run loop (engine/pipeline.py) sees it: a small protocol, the
records it returns, and the `Reporter` it reports its steps through. No bpy; the real world is
`BlenderWorld` (core/world.py). This module sits below core/ and engine/ so that both build on it
and neither imports the other's side: core/ reports through the reporter it is handed, the engine
hands it one (its `Tracker`, engine/progress.py).

The pipeline owns the run: plan, seeds, folders, resume, cancel, shards, run.json, the writers, the
annotations. A world only makes things: once `setup()`, then per scene `start_scene(scene_id, base_seed,
rng, n)` (draw the bin and lights, drop parts, settle, pick camera poses) and per render
`render(render_dir, pose_index, seed, scene_id=, render_id=, base_seed=)` (place the camera,
files + what the annotations need), then `finish_scene()`; `close()` at the end. With `scene.picks`
a pile's later steps come from `pick_step(scene_id, base_seed, rng, n, remove)` (delete the named
parts, settle the rest from where they lay, pick camera poses) instead of `start_scene`, and
`finish_scene()` follows the sequence's last step. Between `setup()` and `close()` the run hands the
world its reporter (`report_to(tracker)`), and `SILENT` back when the run ends. Tests pass a fake
world (tests/fake_world.py: analytic boxes, numpy ray casting) to check the run loop without Blender.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from contextlib import nullcontext
from typing import ContextManager, Protocol

import numpy as np



@dataclass
class Part:
    """One object instance of a scene, as the annotations name it."""
    name: str               # "{entry name}_{k:03d}", numbered within the scene
    filename: str           # the mesh file it was imported from
    obj_id: int             # its Config.objects entry's obj_id (Config.obj_id)
    mask_index: int         # its pass index in mask.exr (1..n; 0 = background)
    material: str = "file"  # the material label it was given (core/materials.py; "file": the mesh's own)


@dataclass
class SceneStart:
    """A scene after the drop: the parts that stayed, the drop's record, the camera poses to render."""
    parts: list[Part]
    simulation: dict                    # scene.json's "simulation": frames, settled, removed [{name, reason}], ...
    pose_indices: list              # pool index per render, or None where the camera pose is drawn per render
    drawn: dict = field(default_factory=dict)        # scene.json's per-scene draws: {"bin": ..., "lighting": ...}
    seconds: dict = field(default_factory=dict)      # {"placement": s, "simulation": s}
    poses: list = field(default_factory=list)        # per part, its settled 4x4 world pose (scene.picks' "top")


@dataclass
class View:
    """One render: its files and what its annotations are computed from."""
    files: dict[str, Path]              # output kind -> written file (native, then structured light)
    K: np.ndarray                       # 3x3
    resolution: tuple[int, int]         # (W, H)
    T_world_cam: np.ndarray             # 4x4, OpenCV camera frame
    T_world_blcam: np.ndarray           # 4x4, the Blender camera object's world matrix
    T_world_obj: list[np.ndarray]       # per part of the scene, in SceneStart.parts order
    mask: np.ndarray | None             # (H, W) pass indices, None without a mask output
    rgb: np.ndarray | None = None       # (H, W, 3) uint8, for the quality gates (not kept)
    camera_sampler: dict | None = None      # the drawn camera pose's parameters (bin_view sampler)
    lighting: dict | None = None            # the render's drawn lighting (lighting.per_render)
    structured_light: dict | None = None    # the render's structured_light record (files excluded)
    seconds: dict = field(default_factory=dict)      # {"render": s, "write": s, "structured_light": s}
    distortion: list | None = None      # the lens's OpenCV k1 k2 p1 p2 k3 (docs/CALIBRATION.md), None: none


class Reporter(Protocol):
    """What a world reports its steps into: the run's step lines and run.json's step times. `step`
    is one of engine/progress.py's STEPS; `cycles` wraps one Cycles call (its samples and tiles)."""

    def begin(self, step: str, what: str = "") -> None: ...

    def advance(self, n: int, of: int | None, unit: str = "frame") -> None: ...

    def note(self, message: str) -> None: ...

    def end(self) -> None: ...

    def cycles(self, step: str, what: str) -> ContextManager: ...


class Silent:
    """The reporter of a world outside a run (the add-on's preview, a test): it reports nothing."""

    def begin(self, step: str, what: str = "") -> None:
        pass

    def advance(self, n: int, of: int | None, unit: str = "frame") -> None:
        pass

    def note(self, message: str) -> None:
        pass

    def end(self) -> None:
        pass

    def cycles(self, step: str, what: str) -> ContextManager:
        return nullcontext()


SILENT = Silent()


class World(Protocol):
    import_count: int                   # mesh files read this run
    setup_notes: list[str]              # what setup() did that the user should hear about

    def setup(self) -> None: ...

    def report_to(self, progress: Reporter) -> None: ...

    def model_meshes(self) -> dict: ...

    def start_scene(self, scene_id: int, base_seed: int, rng: np.random.Generator, n_renders: int) -> SceneStart: ...

    def render(self, render_dir: Path, pose_index: int | None, seed: int, *, scene_id: int, render_id: int,
               base_seed: int) -> View: ...

    def pick_step(self, scene_id: int, base_seed: int, rng: np.random.Generator, n_renders: int,
                  remove: list[str]) -> SceneStart: ...

    def finish_scene(self) -> None: ...

    def close(self) -> None: ...
