"""Cheap Blender runs for the tests: a small config, and a CLI run killed once a scene is complete
(the resume tests)."""
import signal
import subprocess

from datapipe import config as C


def small_config(num_renders: int, per_scene: int, resolution, samples: int = 1, *,
                 instances: int | None = None) -> C.Config:
    """The default preset made cheap: `num_renders` renders, `per_scene` of them per scene, at
    `resolution` (W, H) with `samples` Cycles samples on 2 threads, no structured light; with
    `instances`, every object entry drops exactly that many parts."""
    cfg = C.default_config()
    cfg.scene.num_renders = num_renders
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = per_scene
    cfg.camera.resolution = list(resolution)
    cfg.render.samples = samples
    cfg.render.threads = 2
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


def kill_after_scene(cmd: list[str], scene: str, timeout: float) -> None:
    """Start the CLI run `cmd` and SIGKILL it (a crashed machine) as soon as its progress reports the
    parts of `scene` (e.g. "scene.0002"): that scene is complete, the next one under way."""
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
    for line in proc.stderr:
        if scene in line and "parts," in line:
            proc.send_signal(signal.SIGKILL)
            break
    proc.wait(timeout=timeout)
    assert proc.returncode == -signal.SIGKILL
