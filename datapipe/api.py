"""DataPipe's public Python API: what a script needs, without the command line (docs/API.md).

    import datapipe.api as dp
    cfg = dp.load_preset("default")                # a shipped preset, or a .json / original .pickle path
    cfg.scene.num_renders = 2                      # a Config is plain dataclasses: change it in code
    problems = dp.validate(cfg)                    # [] or every problem (field path, message, fix)
    run = dp.run(cfg, "out/mine", on_progress=lambda p: print(p.line()))
    for r in run.renders: r.rgb, r.depth, r.sl_depth, r.mask, r.K, r.objects
    scan = dp.scan(radiance, cfg)                  # fringe radiance -> the scanner's depth + confidence

Importing this module does not import Blender (bpy): `run` and `validate(..., blender=True)` start it.
Mistakes in what a script passes raise `ConfigError` / `DataPipeError` naming the field and the fix,
before any work; `run` goes through the very checks and steps of `python -m datapipe run`.
"""
from __future__ import annotations

import os
import sys
import threading
from contextlib import contextmanager, redirect_stdout
from pathlib import Path
from typing import Callable

import numpy as np

from .config import (CameraConfig, CameraPose, CameraSamplerConfig, Config, LightingConfig, ObjectEntry,
                     OutputConfig, ProjectorConfig, RenderConfig, SceneConfig, SimulationConfig,
                     StructuredLightConfig, load, presets_dir)
from .errors import ConfigError, DataPipeError, OutputStateError, Problem
from .reader import Render, Run, Scene, read_run
from .engine.progress import Progress
from .sl import DecodeResult, Reason, Scan

from . import API_NAMES

__all__ = list(API_NAMES)         # spelled once, in datapipe/__init__.py (the root's lazy names)


# -- presets and configs ---------------------------------------------------------------------------

def presets() -> list[str]:
    """The names of the presets shipped in datapipe/presets/ ("default", "bin_picking", ...)."""
    return sorted(p.stem for p in presets_dir().glob("*.json"))


def load_preset(preset: str | os.PathLike) -> Config:
    """A Config from a shipped preset's name (see `presets()`), or from the path of a JSON preset or
    an original DataPipe inputs pickle (relative mesh paths resolve against the file's folder).
    Raises ConfigError (field path + fix) for a missing file or a field of the wrong type; the field
    rules are `validate`'s."""
    text = os.fspath(preset)
    if text in presets():
        return load(presets_dir() / f"{text}.json")
    if not Path(text).is_file() and os.sep not in text and "." not in text:
        raise ConfigError(Problem("<preset>", f"no shipped preset named {text!r} and no file of that name",
                                  f"give one of {', '.join(presets())} or the path of a .json preset"))
    return load(text)


def validate(cfg: Config, *, blender: bool = False, check_files: bool = True) -> list[Problem]:
    """Every problem of `cfg` at once (field path, message, fix). Raises nothing for a bad config.

    Without Blender: the type of every field (a value set in code is checked as a preset's would
    be) and every field rule: what `run` checks first. `blender=True` adds what `python -m datapipe
    validate` adds when the fields pass: each mesh file imported and measured, `scene.blend_file`
    read by Blender, the part counts against the bin (imports bpy); then [] means `run` can start.
    `check_files=False` skips the look at files on disk (existence, headers)."""
    try:
        cfg = _checked_types(cfg)
    except ConfigError as e:
        return list(e.problems)
    problems = cfg.problems(check_files=check_files)
    if problems or not blender:
        return problems
    from .engine.session import check_config
    try:
        check_config(cfg)
    except ConfigError as e:
        return list(e.problems)
    return []


def check(cfg: Config, *, blender: bool = False) -> Config:
    """`validate`, raising: ConfigError with every problem (field path, message, fix), else `cfg`."""
    problems = validate(cfg, blender=blender)
    if problems:
        raise ConfigError(problems)
    return cfg


def _checked_types(cfg) -> Config:
    """`cfg` parsed again from its dict: a field set in code to a value of the wrong type (a string
    for a count, None for a list) is a ConfigError naming it, as in a preset, not a TypeError from
    deep inside a rule. Returns the parsed copy."""
    if not isinstance(cfg, Config):
        raise DataPipeError(f"cfg: must be a datapipe Config, got {type(cfg).__name__} (fix: "
                            "dp.load_preset(...), dp.Config(...) or dp.Config.from_dict(a_dict))")
    return Config.from_dict(cfg.to_dict())


def preset_warnings(cfg: Config) -> list[str]:
    """What `python -m datapipe validate` warns about a valid config without refusing it: a part
    that does not fit the drop zone, a bin outside a device's working distance or view, fringe work
    larger than this machine's memory (the gate's warnings, without Blender)."""
    from .engine import gate
    return gate.run_checks(cfg, blender=False).warnings


# -- running ---------------------------------------------------------------------------------------

def run(cfg: Config, out: str | os.PathLike | None = None, *, on_progress: Callable[[Progress], None] | None = None,
        resume: bool = False, force: bool = False, seed: int | None = None, shard: tuple[int, int] = (0, 1),
        strict: bool = False, verbose: bool = False) -> Run:
    """Make the dataset `cfg` describes in folder `out` (default: `cfg.output.path`), as
    `python -m datapipe run` does, in this process, and return it read back (`read_run`).

    Same checks first (the folder's name, every field, the folder's state, the Blender preflight of
    the mesh files): a mistake raises ConfigError / DataPipeError with the field and the fix before
    anything is written. Same files (run.json, scene folders, models/, output_dict.pickle, the
    overview sheet), same lock (one run per folder), Blender's output in OUT/blender.log
    (`verbose=True`: on the terminal too). `cfg` itself is not changed.

    on_progress(Progress): every event of the run (`p.stage`: setup, scene, render, scene_done, skip,
    done, cancelled) and the lines inside a scene (stage "step": placing, simulating, each Cycles
    call, decoding, writing; at least every 30 s while a step lasts, then possibly from a helper
    thread). `p.line()` is the text the command line prints; `p.done` / `p.total` count renders.
    resume / force / seed / shard / strict: as `--resume`, `--force`, `--seed`, `--shard i/n`,
    `--strict`. Ctrl-C stops after the render in progress (the returned run says "cancelled";
    `resume=True` continues), a second Ctrl-C ends the process at once (exit status 130)."""
    from .engine.session import check_run_input, run_pipeline
    cfg = _checked_types(cfg)              # (a copy: the caller's config is not changed)
    check_run_input(cfg, out, seed)
    with _printing_to_terminal(on_progress) as callback:
        pipe, _ = run_pipeline(cfg, out, resume=resume, force=force, shard=_shard(shard), seed=seed,
                               strict=strict, verbose=verbose, on_event=callback, on_step=callback)
    return read_run(pipe.out)


@contextmanager
def _printing_to_terminal(on_progress):
    """The callback with its print() on the terminal. During a run fd 1 carries Blender's C output
    into OUT/blender.log (datapipe.engine.blender_log), and a `sys.stdout` that writes to fd 1 would take
    the script's progress lines there too; so the callback writes to fd 1 as it was before the run.
    A `sys.stdout` that is not fd 1 (a notebook, an IDE, pytest) is left as it is."""
    if on_progress is None:
        yield None
        return
    try:
        to_fd1 = sys.stdout.fileno() == 1
    except (AttributeError, OSError, ValueError):      # io.UnsupportedOperation is an OSError
        to_fd1 = False
    if not to_fd1:
        yield on_progress
        return
    sys.stdout.flush()
    terminal = os.fdopen(os.dup(1), "w", buffering=1, encoding=sys.stdout.encoding, errors="backslashreplace")
    lock = threading.Lock()                 # step lines may come from the heartbeat thread

    def callback(p):
        with lock, redirect_stdout(terminal):
            on_progress(p)
    try:
        yield callback
    finally:
        terminal.close()


def _shard(shard) -> tuple[int, int]:
    try:
        i, n = (int(v) for v in shard)
    except (TypeError, ValueError):
        raise DataPipeError(f"shard: must be (i, n), got {shard!r} (fix: e.g. shard=(0, 4) for the first of "
                            "4 parts; (0, 1) is the whole run)") from None
    if not 0 <= i < n:
        raise DataPipeError(f"shard: {shard!r} needs 0 <= i < n (fix: e.g. shard=(0, 4))")
    return i, n


# -- structured light without Blender -----------------------------------------------------------------

def camera_matrix(cfg: Config) -> np.ndarray:
    """The camera's 3x3 intrinsics K of `cfg` (OpenCV, pixel centres at integers), as the runs write it
    (`camera.intrinsics` when given: a calibration, docs/CALIBRATION.md)."""
    from .geometry import camera_intrinsics
    return camera_intrinsics(cfg.camera)


def patterns(cfg: Config) -> np.ndarray:
    """The fringe images the projector of `cfg` shows, in stack order: (F*N, H_proj, W_proj) float32
    in [0, 1], F = len(structured_light.periods), N = structured_light.steps (frequency-major)."""
    from .geometry import projector_resolution
    from .sl import fringe_patterns
    w, h = projector_resolution(cfg)
    s = cfg.structured_light
    return fringe_patterns(w, h, s.periods, s.steps, gamma=s.projector_gamma)


def scan(radiance, cfg: Config, *, seed: int = 0, T_world_cam=None) -> Scan:
    """The scanner of `cfg` (structured_light + projector + camera) on a stack of linear fringe
    radiance, as the pipeline runs it on its renders: exposure (auto / HDR), the sensor's noise
    (seeded by `seed`), decoding, the reflection and edge filters.

    radiance: (F*N, H, W) linear radiance in `patterns(cfg)` order at the camera's resolution (the
    row code's N images may follow). Returns sl.Scan: `.result.depth` (H, W) float32 m, NaN = no
    data; `.result.confidence` the probability that the fringe orders are right; `.result.reason`
    per pixel (sl.Reason); `.sigma_z` the depth noise (m). Depth is in the camera frame; `T_world_cam`
    (4x4, default identity) only places it in a world."""
    from .sl import Scanner
    T = np.eye(4) if T_world_cam is None else np.asarray(T_world_cam, dtype=np.float64)
    return Scanner.from_config(cfg).scan(radiance, seed, camera_matrix(cfg), T)


def decode(images, cfg: Config, *, noise_sigma=None, saturation: float | None = None) -> DecodeResult:
    """Decode captured fringe images (a camera's intensities: no sensor model or filters added) with
    the geometry and patterns of `cfg`: camera K, projector pose, periods, steps, unwrapping, gamma.

    images: (F*N, H, W) in `patterns(cfg)` order, any numeric type. noise_sigma: the images' noise
    (a number, an (H, W) array or a function of the signal); None fits it from the stack.
    saturation: samples at or above it are left out (default: the integer type's maximum).
    Returns sl.DecodeResult: depth (H, W) float32 m in the camera frame (NaN = none), valid,
    confidence, reason, points, ..."""
    from .geometry import projection_matrix, projector_matrix, projector_resolution
    from .sl import decode as sl_decode
    s = cfg.structured_light
    eye = np.eye(4)
    return sl_decode(images, periods=s.periods, steps=s.steps, P_cam=projection_matrix(camera_matrix(cfg), eye),
                     P_proj=projector_matrix(cfg, eye), proj_size=projector_resolution(cfg), unwrap=s.unwrap,
                     noise_sigma=noise_sigma, saturation=saturation, projector_gamma=s.projector_gamma)
