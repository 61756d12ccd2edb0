"""`datapipe run` as a user starts it, cut down for the tests that kill and resume runs and for the
benchmarks that measure such runs (benchmarks/bench_picks.py): a small preset and a run killed at
a given scene. No bpy here: the runs are subprocesses."""
from __future__ import annotations

import signal
import subprocess

from datapipe import config as C


def small_config(scenes: int, res: tuple[int, int], samples: int = 1) -> C.Config:
    """The default preset with `scenes` scenes of one render each at `res`, `samples` Cycles samples
    and no structured light: what such a run measures is the drop, not the images."""
    cfg = C.default_config()
    cfg.scene.num_renders = scenes
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 1
    cfg.camera.resolution = list(res)
    cfg.render.samples = samples
    cfg.structured_light.enabled = False
    return cfg


def kill_at_scene(cmd: list[str], scene: str, timeout: float) -> int:
    """Start `cmd` (a `datapipe run` without --quiet), kill it (SIGKILL, as a crashed machine) at
    the first progress line that names the parts of `scene` (e.g. "scene.0002"); returns its exit
    code, -SIGKILL when it was killed there."""
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
    for line in proc.stderr:
        if scene in line and "parts," in line:
            proc.send_signal(signal.SIGKILL)
            break
    proc.wait(timeout=timeout)
    return proc.returncode
