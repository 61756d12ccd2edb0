"""Cheap runs for the tests and for the benchmarks that measure such runs (benchmarks/bench_picks.py):
a small preset, a maps-only variant of it, and a `datapipe run` killed at a given scene (the resume
tests). No bpy here: the killed runs are subprocesses."""
from __future__ import annotations

import signal
import subprocess

from datapipe import config as C


def small_config(num_renders: int, res: tuple[int, int], samples: int = 1, *, per_scene: int = 1,
                 instances: int | None = None, threads: int | None = None) -> C.Config:
    """The default preset made cheap: `num_renders` renders, `per_scene` of them per scene, at `res`
    (W, H) with `samples` Cycles samples and no structured light (what such a run measures is the
    drop and the files, not the scanner); with `instances`, every object entry drops exactly that
    many parts; with `threads`, Cycles uses that many."""
    cfg = C.default_config()
    cfg.scene.num_renders = num_renders
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = per_scene
    cfg.camera.resolution = list(res)
    cfg.render.samples = samples
    if threads is not None:
        cfg.render.threads = threads
    cfg.structured_light.enabled = False
    if instances is not None:
        for o in cfg.objects:
            o.min_instances = o.max_instances = instances
    return cfg


def maps_only(cfg: C.Config, max_frames: int = 60) -> C.Config:
    """Only the RGB, depth and mask maps, no output_dict.pickle or overview sheet, a short simulation."""
    cfg.render.outputs = ["rgb", "depth", "mask"]
    cfg.output.legacy_pickle = cfg.output.overview = False
    cfg.simulation.max_frames = max_frames
    return cfg


def kill_at_scene(cmd: list[str], scene: str, timeout: float) -> int:
    """Start `cmd` (a `datapipe run` without --quiet), kill it (SIGKILL, as a crashed machine) at
    the first progress line that names the parts of `scene` (e.g. "scene.0002": that scene is
    complete, the next one under way); returns its exit code, -SIGKILL when it was killed there."""
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
    for line in proc.stderr:
        if scene in line and "parts," in line:
            proc.send_signal(signal.SIGKILL)
            break
    proc.wait(timeout=timeout)
    return proc.returncode
