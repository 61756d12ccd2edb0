"""The Config: the one thing the UI (or a preset) writes and the pipeline reads. No bpy here.

Plain dataclasses, JSON load/save with a schema version, loading of the original DataPipe pickle
layout through an unpickler that refuses every class, and `validate()` that reports every problem
at once (field path + fix) before any Blender work starts.

Units: metres, radians, kilograms; focal lengths and sensor widths in millimetres (as Blender shows
them). Resolutions are [width, height] (the original pickle stored [height, width]; the legacy
loader swaps them).
"""
from __future__ import annotations

import copy
import dataclasses
import io
import json
import math
import os
import pickle
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import ConfigError, Problem
from .io.files import write_text_atomic

SCHEMA_VERSION = 1

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf")
OUTPUT_KINDS = ("rgb", "depth", "normals", "mask")
FORMATS = ("native", "bop")
# AUTO: DECOMPOSED for clearly concave meshes, else CONVEX_HULL. DECOMPOSED and MESH: a compound of
# convex pieces (Blender's moving triangle meshes threw concave parts out; see core/collision.py)
COLLISION_SHAPES = ("AUTO", "DECOMPOSED", "MESH", "CONVEX_HULL", "BOX", "SPHERE", "CAPSULE", "CYLINDER", "CONE")
SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")
UNWRAP_METHODS = ("auto", "heterodyne", "multi-frequency", "number-theoretic")   # datapipe.sl.unwrap
SAMPLER_KINDS = ("pool", "bin_view")
MAX_RESOLUTION = 8192


def _vec(*values: float):
    return field(default_factory=lambda: list(values))


@dataclass
class SceneConfig:
    """How many renders, how they group into scenes (one drop each), and where parts are dropped."""
    num_renders: int = 4               # total renders in the run
    min_renders_per_scene: int = 1     # camera poses per scene, drawn without replacement
    max_renders_per_scene: int = 1
    drop_zone_loc: list[float] = _vec(0.0, 0.0, 0.1)     # centre of the bin's inner volume, m
    drop_zone_scale: list[float] = _vec(0.15, 0.1, 0.1)  # half-extents, m
    make_bin: bool = True              # build a floor + walls around the drop zone (else: floor only)
    bin_wall_thickness: float = 0.01   # m
    bin_size_scale: list[float] = _vec(1.0, 1.0)   # per scene: zone x and y half extents times a
                                                   # factor from [min, max] (datapipe.bin_shape)
    bin_wall_scale: list[float] = _vec(1.0, 1.0)   # per scene: wall height (the zone's) times [min, max]
    blend_file: str | None = None      # open this .blend first; its object "drop_zone" wins over the above
    seed: int = 0                      # base seed; scene i derives its own (see datapipe.seeds)


@dataclass
class ObjectEntry:
    """One source mesh and how many instances of it go into each scene."""
    filepath: str = ""
    scale: float = 1.0                 # file units -> metres
    mass: float = 0.05                 # kg per instance
    collision_shape: str = "AUTO"      # see COLLISION_SHAPES
    min_instances: int = 1
    max_instances: int = 2
    friction: float = 0.5
    restitution: float = 0.1
    name: str = ""                     # defaults to the file stem


@dataclass
class CameraPose:
    """Blender camera object's world pose: location (m) and quaternion (w, x, y, z); looks down local -Z."""
    location: list[float] = _vec(0.0, 0.0, 1.0)
    rotation: list[float] = _vec(1.0, 0.0, 0.0, 0.0)


@dataclass
class CameraSamplerConfig:
    """How each render's camera pose is chosen. "pool": drawn from `camera.poses` (without
    replacement within a scene); "bin_view": a look-at pose around the bin floor's centre, drawn
    per render from the ranges below (datapipe.camera_sampler explains the angles)."""
    kind: str = "pool"
    distance: list[float] = _vec(0.6, 0.85)        # m, camera centre to the look-at target
    tilt_deg: list[float] = _vec(0.0, 25.0)        # optical axis from straight down
    azimuth_deg: list[float] = _vec(0.0, 360.0)    # direction target -> camera, from world +X
    roll_deg: list[float] = _vec(-180.0, 180.0)    # image rotation about the optical axis
    target_jitter: float = 0.02                    # m, target = floor centre + a point of this disc


@dataclass
class CameraConfig:
    focal_length: float = 16.0         # mm
    sensor_width: float = 11.3         # mm (2/3" industrial sensor)
    sensor_fit: str = "AUTO"
    resolution: list[int] = _vec(320, 240)   # [width, height] px
    clip_start: float = 0.05           # m
    clip_end: float = 10.0             # m
    poses: list[CameraPose] = field(default_factory=lambda: [CameraPose()])
    sampler: CameraSamplerConfig = field(default_factory=CameraSamplerConfig)


@dataclass
class ProjectorConfig:
    """The fringe projector: a spot light parented to the camera (pose in camera-object axes)."""
    focal_length: float = 16.0         # mm
    sensor_width: float = 11.3         # mm (DMD width)
    resolution: list[int] = _vec(912, 570)   # [width, height] px (DLP 0.23" class)
    location: list[float] = _vec(-0.15, 0.0, 0.0)        # m, relative to the camera object
    rotation: list[float] = _vec(0.0, math.radians(-8.5), 0.0)  # XYZ Euler rad, or quaternion wxyz
    power: float = 5.0                 # emission strength of the light's node tree (a grey 0.5
                                       # floor at 0.8 m gets fringe peaks of ~1.0 linear radiance)


@dataclass
class StructuredLightConfig:
    """Defaults chosen in benchmarks/results/sl_render.md (README: "Structured light defaults")."""
    enabled: bool = False
    periods: list[int] = _vec(1, 8, 64)   # fringe periods across the projector width, coarse -> fine;
                                          # finest ~5 camera px per period at 320 px wide (keep >= 4)
    steps: int = 4                     # phase steps per period (4: one clipped sample tolerated)
    unwrap: str = "auto"
    samples: int = 4                   # fringe render paths per camera pixel (2x2 point sub-samples)
    sensor: str = "industrial"         # datapipe.sl.sensor preset
    exposure: float = 0.5              # scales linear radiance before the sensor model (0.5: no
                                       # saturation on 0.8-albedo parts from ~0.65 m)
    debug: bool = False                # also write wrapped/absolute phase, modulation, reasons
    projector_gamma: float = 1.0       # projector response exponent (emits pattern ** gamma; 1 = linear);
                                       # the decoder corrects the phase ripple it causes


@dataclass
class LightingConfig:
    """Lighting drawn per scene (datapipe.lighting), each value uniform in its [min, max]. A config
    without a `lighting` section (null) keeps the fixed key light of `render.light_power`."""
    key_power: list[float] = _vec(25.0, 100.0)                  # W, the area light above the bin
    key_color_temperature: list[float] = _vec(3000.0, 6500.0)   # K, blackbody colour of the key light
    key_size: list[float] = _vec(0.5, 1.5)                      # m, side of the square area light
    key_position_jitter: float = 0.5                            # m, horizontal offset (uniform in a disc)
    ambient: list[float] = _vec(0.0, 0.2)                       # world (white) background strength


@dataclass
class RenderConfig:
    engine: str = "CYCLES"
    device: str = "CPU"
    samples: int = 32                  # native RGB layer
    threads: int = 0                   # 0 = all cores
    denoise: bool = False
    max_bounces: int = 4
    light_power: float = 50.0          # W, area light above the bin (the scene's key light)
    outputs: list[str] = _vec(*OUTPUT_KINDS)


@dataclass
class SimulationConfig:
    substeps: int = 10                 # rigid-body substeps per frame, at least; more per scene when
                                       # the thinnest part or wall would be crossed in one substep
    max_substeps: int = 100            # ... at most (a scene that needs more reports it)
    solver_iterations: int = 10
    max_frames: int = 200              # hard cap on simulated frames (24 fps)
    settle_speed: float = 0.005        # m/s: a body below this (and below 20% of its size per s) ...
    settle_frames: int = 5             # ... for this many consecutive frames, and at least 0.5 s
                                       # with < 1 mm motion (10% of its size if smaller), is at rest
    layer_gap: float = 0.005           # m between spawn layers
    redraw_lost_share: float = 1.0     # redraw a scene when more than this share of its parts is lost
                                       # (left the bin / fell through); 1.0: never
    redraw_attempts: int = 2           # ... at most this many times (each from its own derived seed)


@dataclass
class OutputConfig:
    path: str = "output"
    formats: list[str] = _vec("native")
    legacy_pickle: bool = True         # also write the original's output_dict.pickle
    overview: bool = True              # write the run's overview sheet at the end


@dataclass
class Config:
    scene: SceneConfig = field(default_factory=SceneConfig)
    objects: list[ObjectEntry] = field(default_factory=list)
    camera: CameraConfig = field(default_factory=CameraConfig)
    projector: ProjectorConfig = field(default_factory=ProjectorConfig)
    structured_light: StructuredLightConfig = field(default_factory=StructuredLightConfig)
    render: RenderConfig = field(default_factory=RenderConfig)
    lighting: LightingConfig | None = None
    simulation: SimulationConfig = field(default_factory=SimulationConfig)
    output: OutputConfig = field(default_factory=OutputConfig)
    schema_version: int = SCHEMA_VERSION

    # -- conversion -------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: dict, *, base_dir: str | os.PathLike | None = None) -> "Config":
        """Build from a dict (e.g. parsed JSON). Unknown keys and wrong types are ConfigErrors.

        Relative object/blend paths are resolved against `base_dir` (the preset's folder)."""
        problems: list[Problem] = []
        if not isinstance(data, dict):
            raise ConfigError(Problem("<root>", f"expected a JSON object, got {type(data).__name__}",
                                      "write the preset as {\"scene\": {...}, \"objects\": [...], ...}"))
        version = data.get("schema_version", SCHEMA_VERSION)
        if version != SCHEMA_VERSION:
            problems.append(Problem("schema_version", f"unsupported schema version {version!r}",
                                    f"use schema_version {SCHEMA_VERSION} (re-save the preset)"))
        cfg = _build(cls, data, "", problems)
        if base_dir is not None:
            cfg.resolve_paths(base_dir)
        if problems:
            # report the semantic problems too (all at once), except at fields already flagged
            flagged = {p.path for p in problems}
            problems += [p for p in validate(cfg) if p.path not in flagged]
            raise ConfigError(problems)
        return cfg

    def resolve_paths(self, base_dir: str | os.PathLike) -> None:
        base = Path(base_dir)
        for obj in self.objects:
            if obj.filepath and not os.path.isabs(obj.filepath):
                obj.filepath = str((base / obj.filepath).resolve())
        if self.scene.blend_file and not os.path.isabs(self.scene.blend_file):
            self.scene.blend_file = str((base / self.scene.blend_file).resolve())

    def copy(self) -> "Config":
        return copy.deepcopy(self)

    # -- validation -------------------------------------------------------------------------------
    def problems(self, *, check_files: bool = True) -> list[Problem]:
        return validate(self, check_files=check_files)

    def validate(self, *, check_files: bool = True) -> "Config":
        problems = validate(self, check_files=check_files)
        if problems:
            raise ConfigError(problems)
        return self

    # -- derived values ---------------------------------------------------------------------------
    def object_name(self, index: int) -> str:
        obj = self.objects[index]
        return obj.name or Path(obj.filepath).stem


# ------------------------------------------------------------------------------------------------
# dict -> dataclass with type checks (collects problems instead of raising at the first one)

def _type_name(tp) -> str:
    return getattr(tp, "__name__", str(tp))


def _build(tp, value, path: str, problems: list[Problem]):
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            problems.append(Problem(path or "<root>", f"expected an object, got {type(value).__name__}",
                                    f"give {path or 'the preset'} as a JSON object"))
            return tp()
        hints = typing.get_type_hints(tp)
        names = {f.name for f in dataclasses.fields(tp)}
        for key in value:
            if key not in names:
                problems.append(Problem(_join(path, key), "unknown key",
                                        f"remove it; known keys here: {', '.join(sorted(names))}"))
        kwargs = {}
        for f in dataclasses.fields(tp):
            if f.name in value:
                kwargs[f.name] = _build(hints[f.name], value[f.name], _join(path, f.name), problems)
        return tp(**kwargs)
    if origin is list:
        (item_tp,) = typing.get_args(tp)
        if isinstance(value, tuple):
            value = list(value)
        if not isinstance(value, list):
            problems.append(Problem(path, f"expected a list, got {type(value).__name__}",
                                    f"give {path} as a JSON array"))
            return []
        return [_build(item_tp, v, f"{path}[{i}]", problems) for i, v in enumerate(value)]
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        non_none = [a for a in args if a is not type(None)]
        return _build(non_none[0], value, path, problems)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            problems.append(Problem(path, f"expected a number, got {value!r}", "give a number"))
            return 0.0
        return float(value)
    if tp is int:
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            problems.append(Problem(path, f"expected an integer, got {value!r}", "give a whole number"))
            return 0
        return value
    if tp is bool:
        if not isinstance(value, bool):
            problems.append(Problem(path, f"expected true/false, got {value!r}", "give true or false"))
            return False
        return value
    if tp is str:
        if not isinstance(value, str):
            problems.append(Problem(path, f"expected a string, got {value!r}", "give a string"))
            return ""
        return value
    raise TypeError(f"unsupported config type {_type_name(tp)} at {path}")


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


# ------------------------------------------------------------------------------------------------
# validation

def _check_redraw(m: SimulationConfig, add) -> None:
    if not (math.isfinite(m.redraw_lost_share) and 0.0 <= m.redraw_lost_share <= 1.0):
        add("simulation.redraw_lost_share", f"must be in [0, 1], got {m.redraw_lost_share}",
            "give a share of parts between 0 and 1 (1 never redraws)")
    if not 0 <= m.redraw_attempts <= 10:
        add("simulation.redraw_attempts", f"must be in 0..10, got {m.redraw_attempts}",
            "give a small number of retries (each costs one more simulation)")


def _check_sl_periods(sl, pr, add) -> None:
    """structured_light.periods: what datapipe.sl.plan_unwrap decodes (hierarchical, heterodyne,
    number-theoretic sets such as [13, 7] or [9, 10, 11]) with >= 3 projector px per fringe."""
    if not sl.periods:
        add("structured_light.periods", "empty", "give fringe periods, e.g. [1, 8, 64]")
        return
    if any(k < 1 for k in sl.periods):
        add("structured_light.periods", f"periods must be >= 1, got {sl.periods}", "give positive periods")
        return
    if pr.resolution and len(pr.resolution) == 2 and max(sl.periods) * 3 > pr.resolution[0]:
        add("structured_light.periods", f"{max(sl.periods)} periods across {pr.resolution[0]} px leave "
            "fewer than 3 px per fringe", "lower the finest period count or raise the projector width")
    if sl.unwrap in UNWRAP_METHODS:
        from .sl import plan_unwrap      # pure numpy; the decoder owns the rules for period sets
        try:
            plan_unwrap(sl.periods, sl.unwrap)
        except ValueError as e:
            add("structured_light.periods", f"cannot be unwrapped: {e}", "use a set the message suggests, "
                "e.g. [1, 8, 64] (hierarchical), [70, 64, 59] or [13, 7] (number-theoretic)")


def validate(cfg: Config, *, check_files: bool = True) -> list[Problem]:
    """Every problem at once, each with its field path and the fix. Empty list = valid."""
    P: list[Problem] = []
    add = lambda path, msg, fix: P.append(Problem(path, msg, fix))  # noqa: E731

    def positive(path, v, fix="give a value > 0"):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
            add(path, f"must be > 0, got {v!r}", fix)

    def vector(path, v, n, *, pos=False):
        if len(v) != n:
            add(path, f"needs {n} numbers, got {len(v)}", f"give {n} numbers")
            return False
        if not all(math.isfinite(x) for x in v):
            add(path, "contains NaN or infinity", "give finite numbers")
            return False
        if pos and not all(x > 0 for x in v):
            add(path, f"all values must be > 0, got {v}", "give positive sizes")
        return True

    def min_max(path, lo_name, hi_name, lo, hi, lo_bound=0):
        if lo < lo_bound:
            add(f"{path}.{lo_name}", f"must be >= {lo_bound}, got {lo}", f"set it to {lo_bound} or more")
        if lo > hi:
            add(f"{path}.{lo_name}", f"{lo_name} ({lo}) > {hi_name} ({hi})",
                f"make {lo_name} <= {hi_name}")

    def resolution(path, res):
        if len(res) != 2:
            add(path, f"needs [width, height], got {res}", "give two integers [width, height]")
            return
        for name, v in zip(("width", "height"), res):
            if not 1 <= v <= MAX_RESOLUTION:
                add(path, f"{name} {v} outside 1..{MAX_RESOLUTION}", f"give a {name} between 1 and {MAX_RESOLUTION}")

    def choice(path, v, options):
        if v not in options:
            add(path, f"unknown value {v!r}", f"use one of {', '.join(map(str, options))}")

    s = cfg.scene
    if s.num_renders < 1:
        add("scene.num_renders", f"must be >= 1, got {s.num_renders}", "ask for at least one render")
    min_max("scene", "min_renders_per_scene", "max_renders_per_scene",
            s.min_renders_per_scene, s.max_renders_per_scene, lo_bound=1)
    vector("scene.drop_zone_loc", s.drop_zone_loc, 3)
    vector("scene.drop_zone_scale", s.drop_zone_scale, 3, pos=True)
    positive("scene.bin_wall_thickness", s.bin_wall_thickness)
    if not 0 <= s.seed < 2**32:
        add("scene.seed", f"must be in 0..2^32-1, got {s.seed}", "give a non-negative 32-bit integer")
    if s.blend_file and check_files:
        if not os.path.isfile(s.blend_file):
            add("scene.blend_file", f"file not found: {s.blend_file}", "give the path of an existing .blend")
        elif not s.blend_file.lower().endswith(".blend"):
            add("scene.blend_file", f"not a .blend file: {s.blend_file}", "give a .blend file")

    if not cfg.objects:
        add("objects", "no objects to drop", "add at least one object entry (a mesh file)")
    for i, o in enumerate(cfg.objects):
        p = f"objects[{i}]"
        if not o.filepath:
            add(f"{p}.filepath", "empty", "give the path of a mesh file (.obj, .ply, .stl, .glb, .gltf)")
        else:
            suffix = Path(o.filepath).suffix.lower()
            if suffix not in MESH_SUFFIXES:
                add(f"{p}.filepath", f"not a mesh file: {o.filepath}",
                    f"use one of {', '.join(MESH_SUFFIXES)}")
            elif check_files and not os.path.isfile(o.filepath):
                add(f"{p}.filepath", f"file not found: {o.filepath}", "check the path (relative paths are "
                    "resolved against the preset's folder)")
        positive(f"{p}.scale", o.scale)
        positive(f"{p}.mass", o.mass)
        choice(f"{p}.collision_shape", o.collision_shape, COLLISION_SHAPES)
        min_max(p, "min_instances", "max_instances", o.min_instances, o.max_instances)
        if o.max_instances > 500:
            add(f"{p}.max_instances", f"{o.max_instances} instances is beyond what one bin holds",
                "use at most 500 instances per object")
        if not 0 <= o.friction:
            add(f"{p}.friction", f"must be >= 0, got {o.friction}", "give a friction >= 0")
        if not 0 <= o.restitution <= 1:
            add(f"{p}.restitution", f"must be in 0..1, got {o.restitution}", "give a restitution in 0..1")
    seen: dict[str, int] = {}
    for i, o in enumerate(cfg.objects):
        name = o.name or Path(o.filepath).stem
        if name in seen:
            add(f"objects[{i}].name", f"name {name!r} is already used by objects[{seen[name]}] (instance names "
                "and annotations would collide)", "give this entry a unique name")
        seen.setdefault(name, i)
    if cfg.objects and sum(o.max_instances for o in cfg.objects) < 1:
        add("objects", "every entry has max_instances = 0, so scenes would be empty",
            "give at least one entry max_instances >= 1")

    c = cfg.camera
    positive("camera.focal_length", c.focal_length)
    positive("camera.sensor_width", c.sensor_width)
    choice("camera.sensor_fit", c.sensor_fit, SENSOR_FITS)
    resolution("camera.resolution", c.resolution)
    positive("camera.clip_start", c.clip_start)
    if c.clip_end <= c.clip_start:
        add("camera.clip_end", f"clip_end ({c.clip_end}) <= clip_start ({c.clip_start})", "make clip_end > clip_start")
    pool = c.sampler.kind == "pool"
    if not c.poses and pool:
        add("camera.poses", "no camera poses", "add at least one pose (location + quaternion wxyz)")
    for i, pose in enumerate(c.poses):
        vector(f"camera.poses[{i}].location", pose.location, 3)
        if vector(f"camera.poses[{i}].rotation", pose.rotation, 4):
            norm = math.sqrt(sum(q * q for q in pose.rotation))
            if norm < 1e-6:
                add(f"camera.poses[{i}].rotation", "zero quaternion", "give a unit quaternion (w, x, y, z)")
    if pool and c.poses and s.max_renders_per_scene > len(c.poses):
        add("scene.max_renders_per_scene",
            f"{s.max_renders_per_scene} renders per scene but only {len(c.poses)} camera poses "
            "(poses are drawn without replacement within a scene)",
            "add camera poses or lower max_renders_per_scene")

    P += _range_problems("scene.bin_size_scale", s.bin_size_scale, lo_bound=0.05, hi_bound=20.0)
    P += _range_problems("scene.bin_wall_scale", s.bin_wall_scale, lo_bound=0.05, hi_bound=20.0)
    P += _sampler_problems(cfg)
    P += _lighting_problems(cfg.lighting)

    sl = cfg.structured_light
    pr = cfg.projector
    if sl.enabled:
        positive("projector.focal_length", pr.focal_length)
        positive("projector.sensor_width", pr.sensor_width)
        resolution("projector.resolution", pr.resolution)
        vector("projector.location", pr.location, 3)
        if len(pr.rotation) not in (3, 4):
            add("projector.rotation", f"needs 3 (XYZ Euler, rad) or 4 (quaternion wxyz) numbers, got {len(pr.rotation)}",
                "give [rx, ry, rz] or [w, x, y, z]")
        positive("projector.power", pr.power)
        if sl.steps < 3:
            add("structured_light.steps", f"must be >= 3, got {sl.steps}", "use 3 or more phase steps (4 or more "
                "avoids gamma errors)")
        _check_sl_periods(sl, pr, add)
        choice("structured_light.unwrap", sl.unwrap, UNWRAP_METHODS)
        if not (isinstance(sl.projector_gamma, (int, float)) and 0.2 <= sl.projector_gamma <= 5.0):
            add("structured_light.projector_gamma", f"must be a number in [0.2, 5], got {sl.projector_gamma!r}",
                "use 1.0 for a linear projector, ~2.2 for a typical DLP/LCD response")
        try:
            from .sl import SensorModel
            SensorModel.preset(sl.sensor)
        except ValueError:
            from .sl.sensor import PRESETS
            add("structured_light.sensor", f"unknown sensor preset {sl.sensor!r}", f"use one of {sorted(PRESETS)}")
        if sl.samples < 1:
            add("structured_light.samples", f"must be >= 1, got {sl.samples}", "give at least 1 sample")
        positive("structured_light.exposure", sl.exposure)

    r = cfg.render
    choice("render.engine", r.engine, ("CYCLES",))
    choice("render.device", r.device, ("CPU", "GPU"))
    if r.samples < 1:
        add("render.samples", f"must be >= 1, got {r.samples}", "give at least 1 sample")
    if r.threads < 0:
        add("render.threads", f"must be >= 0, got {r.threads}", "use 0 for all cores")
    if r.max_bounces < 0:
        add("render.max_bounces", f"must be >= 0, got {r.max_bounces}", "give 0 or more bounces")
    if r.light_power < 0:
        add("render.light_power", f"must be >= 0, got {r.light_power}", "give a power >= 0 W")
    for i, k in enumerate(r.outputs):
        choice(f"render.outputs[{i}]", k, OUTPUT_KINDS)
    if len(set(r.outputs)) != len(r.outputs):
        add("render.outputs", f"duplicate entries in {r.outputs}", "list each output once")

    m = cfg.simulation
    if m.substeps < 1:
        add("simulation.substeps", f"must be >= 1, got {m.substeps}", "give at least 1 substep")
    if m.max_substeps < m.substeps:
        add("simulation.max_substeps", f"must be >= simulation.substeps ({m.substeps}), got {m.max_substeps}",
            "give a maximum at least as large as the minimum")
    if m.solver_iterations < 1:
        add("simulation.solver_iterations", f"must be >= 1, got {m.solver_iterations}", "give at least 1 iteration")
    if m.max_frames < 1:
        add("simulation.max_frames", f"must be >= 1, got {m.max_frames}", "give at least 1 frame")
    positive("simulation.settle_speed", m.settle_speed)
    if m.settle_frames < 1:
        add("simulation.settle_frames", f"must be >= 1, got {m.settle_frames}", "give at least 1 frame")
    if m.layer_gap < 0:
        add("simulation.layer_gap", f"must be >= 0, got {m.layer_gap}", "give a gap >= 0 m")
    _check_redraw(m, add)

    o = cfg.output
    if not o.path:
        add("output.path", "empty", "give an output folder")
    for i, f in enumerate(o.formats):
        choice(f"output.formats[{i}]", f, FORMATS)
    if not o.formats:
        add("output.formats", "no output format", "use [\"native\"] and/or \"bop\"")
    if "bop" in o.formats:
        for need in ("rgb", "depth", "mask"):
            if need not in r.outputs:
                add("render.outputs", f"the BOP format needs the {need!r} output",
                    f"add {need!r} to render.outputs or drop 'bop' from output.formats")
    return P


def _range_problems(path: str, v, *, lo_bound: float | None = None, hi_bound: float | None = None,
                    unit: str = "") -> list[Problem]:
    """A [min, max] range: two finite numbers, min <= max, within [lo_bound, hi_bound]."""
    if len(v) != 2 or not all(math.isfinite(x) for x in v):
        return [Problem(path, f"needs [min, max] as two finite numbers, got {v}", "give two numbers [min, max]")]
    out = []
    if v[0] > v[1]:
        out.append(Problem(path, f"min {v[0]:g} > max {v[1]:g}", "give [min, max] with min <= max"))
    if lo_bound is not None and min(v) < lo_bound:
        out.append(Problem(path, f"values must be >= {lo_bound:g}{unit}, got {v}", f"keep the range at or above {lo_bound:g}{unit}"))
    if hi_bound is not None and max(v) > hi_bound:
        out.append(Problem(path, f"values must be <= {hi_bound:g}{unit}, got {v}", f"keep the range at or below {hi_bound:g}{unit}"))
    return out


def _sampler_problems(cfg: Config) -> list[Problem]:
    """camera.sampler: kind, ranges, and ranges that can lose the bin from view."""
    sm, c = cfg.camera.sampler, cfg.camera
    if sm.kind not in SAMPLER_KINDS:
        return [Problem("camera.sampler.kind", f"unknown value {sm.kind!r}", f"use one of {', '.join(SAMPLER_KINDS)}")]
    if sm.kind == "pool":
        return []
    p = "camera.sampler"
    out = _range_problems(f"{p}.distance", sm.distance, lo_bound=1e-3, unit=" m")
    out += _range_problems(f"{p}.tilt_deg", sm.tilt_deg, lo_bound=0.0, hi_bound=89.0, unit=" deg")
    out += _range_problems(f"{p}.azimuth_deg", sm.azimuth_deg)
    out += _range_problems(f"{p}.roll_deg", sm.roll_deg)
    if not (math.isfinite(sm.target_jitter) and sm.target_jitter >= 0):
        out.append(Problem(f"{p}.target_jitter", f"must be >= 0, got {sm.target_jitter}", "give a jitter >= 0 m"))
    if out:
        return out
    if min(sm.distance) <= c.clip_start or max(sm.distance) >= c.clip_end:
        out.append(Problem(f"{p}.distance", f"{sm.distance} m reaches outside the clip range "
                           f"({c.clip_start:g}..{c.clip_end:g} m): the target would be clipped",
                           "keep the distances between camera.clip_start and camera.clip_end"))
    res, fit = c.resolution, c.sensor_fit
    if len(res) == 2 and min(res) >= 1 and c.focal_length > 0 and c.sensor_width > 0 and fit in SENSOR_FITS:
        from .camera_sampler import view_problems
        from .geometry import intrinsics_from_blender
        K = intrinsics_from_blender(c.focal_length, c.sensor_width, res[0], res[1], fit)
        half_fov = math.degrees(min(math.atan(res[0] / 2 / K[0, 0]), math.atan(res[1] / 2 / K[1, 1])))
        s = cfg.scene
        if len(s.drop_zone_scale) == 3 and len(s.bin_size_scale) == 2 and len(s.bin_wall_scale) == 2:
            walls = 2 * s.drop_zone_scale[2] * max(s.bin_wall_scale) if s.make_bin else 0.0   # highest walls
            floor = [h * min(s.bin_size_scale) for h in s.drop_zone_scale[:2]]              # smallest bin
            out += [Problem(*t) for t in view_problems(sm, floor, walls, half_fov)]
    return out


def _lighting_problems(li: LightingConfig | None) -> list[Problem]:
    if li is None:
        return []
    p = "lighting"
    out = _range_problems(f"{p}.key_power", li.key_power, lo_bound=0.0, unit=" W")
    out += _range_problems(f"{p}.key_color_temperature", li.key_color_temperature, lo_bound=1000.0,
                           hi_bound=40000.0, unit=" K")
    out += _range_problems(f"{p}.key_size", li.key_size, lo_bound=1e-3, unit=" m")
    out += _range_problems(f"{p}.ambient", li.ambient, lo_bound=0.0)
    if not (math.isfinite(li.key_position_jitter) and li.key_position_jitter >= 0):
        out.append(Problem(f"{p}.key_position_jitter", f"must be >= 0, got {li.key_position_jitter}",
                           "give a jitter >= 0 m"))
    return out


# ------------------------------------------------------------------------------------------------
# files: JSON presets and the original DataPipe pickle

def save(cfg: Config, path: str | os.PathLike) -> None:
    """Write a JSON preset atomically (write, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(cfg.to_dict(), indent=2) + "\n")


def loads(text: str, *, base_dir=None) -> Config:
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise ConfigError(Problem("<file>", f"not valid JSON: {e}", "fix the JSON syntax at the line shown")) from None
    return Config.from_dict(data, base_dir=base_dir)


def load(path: str | os.PathLike) -> Config:
    """Load a JSON preset or an original-layout DataPipe pickle (detected by content)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(Problem("<file>", f"preset not found: {path}", "give the path of a .json preset or .pickle"))
    raw = path.read_bytes()
    if raw[:1] == b"\x80" or path.suffix.lower() in (".pickle", ".pkl"):
        return load_legacy_pickle(raw, base_dir=path.parent)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError(Problem("<file>", f"{path} is neither JSON nor a pickle", "give a .json preset")) from None
    return loads(text, base_dir=path.parent)


class _RefusingUnpickler(pickle.Unpickler):
    """Plain containers and numbers only: any class or callable (the way a pickle runs code) is refused."""

    def find_class(self, module, name):
        raise ConfigError(Problem("<pickle>", f"refused to load {module}.{name}: a DataPipe preset holds only "
                                  "dicts, lists, numbers and strings", "load only presets you trust; re-save "
                                  "it as JSON"))


def load_legacy_pickle(raw: bytes, *, base_dir=None) -> Config:
    try:
        data = _RefusingUnpickler(io.BytesIO(raw)).load()
    except ConfigError:
        raise
    except Exception as e:  # truncated or corrupt pickles raise many types
        raise ConfigError(Problem("<pickle>", f"cannot read the pickle: {e}", "give an original DataPipe "
                                  "inputs pickle or a JSON preset")) from None
    cfg = from_legacy_dict(data)
    if base_dir is not None:
        cfg.resolve_paths(base_dir)
    return cfg


_POSE_LIST_KEYS = ("world2cam_pose_list", "wrlld2cam_pose_list", "wrl2cam_pose_list")


def from_legacy_dict(d: dict) -> Config:
    """Map the original DataPipe input dict (see design.md) onto a Config."""
    P: list[Problem] = []
    if not isinstance(d, dict):
        raise ConfigError(Problem("<pickle>", f"expected a dict, got {type(d).__name__}", "give an original DataPipe inputs pickle"))
    known = {"camera", "projector", "scene", "objects", "output"}
    for k in d:
        if k not in known:
            P.append(Problem(k, "unknown section in the legacy pickle", f"known sections: {', '.join(sorted(known))}"))
    cfg = Config()
    cam = d.get("camera", {}) or {}
    pose_key = next((k for k in _POSE_LIST_KEYS if k in cam), None)
    if pose_key is not None:
        cfg.camera.poses = []
        for i, pose in enumerate(cam[pose_key] or []):
            try:
                cfg.camera.poses.append(CameraPose(location=[float(v) for v in pose["location"]],
                                                   rotation=[float(v) for v in pose["rotation"]]))
            except (KeyError, TypeError, ValueError):
                P.append(Problem(f"camera.{pose_key}[{i}]", "needs 'location' [x,y,z] and 'rotation' [w,x,y,z]",
                                 "fix or remove this pose"))
    for key in ("focal_length", "sensor_width"):
        if key in cam:
            setattr(cfg.camera, key, float(cam[key]))
    if "resolution" in cam:
        h, w = cam["resolution"]               # the original stored [height, width]
        cfg.camera.resolution = [int(w), int(h)]
    if "is_structured_light" in cam:
        cfg.structured_light.enabled = bool(cam["is_structured_light"])

    proj = d.get("projector", {}) or {}
    pose = proj.get("proj2cam_pose")
    if pose:
        cfg.projector.location = [float(v) for v in pose.get("location", cfg.projector.location)]
        cfg.projector.rotation = [float(v) for v in pose.get("rotation", cfg.projector.rotation)]
    for key in ("focal_length", "sensor_width"):
        if key in proj:
            setattr(cfg.projector, key, float(proj[key]))
    if "resolution" in proj:
        h, w = proj["resolution"]
        cfg.projector.resolution = [int(w), int(h)]

    sc = d.get("scene", {}) or {}
    for key in ("num_renders", "max_renders_per_scene", "min_renders_per_scene"):
        if key in sc:
            setattr(cfg.scene, key, int(sc[key]))
    if "drop_zone_loc" in sc:
        cfg.scene.drop_zone_loc = [float(v) for v in sc["drop_zone_loc"]]
    if "drop_zone_scale" in sc:
        cfg.scene.drop_zone_scale = [float(v) for v in sc["drop_zone_scale"]]

    objs = (d.get("objects", {}) or {}).get("objects_list", []) or []
    for i, o in enumerate(objs):
        try:
            cfg.objects.append(ObjectEntry(
                filepath=str(o["filepath"]), scale=float(o.get("scale", 1.0)), mass=float(o.get("mass", 0.05)),
                collision_shape=str(o.get("collision_shape", "CONVEX_HULL")),
                min_instances=int(o.get("min", 1)), max_instances=int(o.get("max", 1))))
        except (KeyError, TypeError, ValueError):
            P.append(Problem(f"objects.objects_list[{i}]", "needs at least 'filepath'", "fix or remove this entry"))
    out = d.get("output", {}) or {}
    if "path" in out:
        cfg.output.path = str(out["path"])
    if P:
        raise ConfigError(P)
    return cfg


def to_legacy_dict(cfg: Config) -> dict:
    """The original's input dict, for users who still drive the old add-on."""
    return {
        "camera": {"world2cam_pose_list": [{"rotation": list(p.rotation), "location": list(p.location)}
                                           for p in cfg.camera.poses],
                   "focal_length": cfg.camera.focal_length, "sensor_width": cfg.camera.sensor_width,
                   "resolution": [cfg.camera.resolution[1], cfg.camera.resolution[0]],
                   "is_structured_light": cfg.structured_light.enabled},
        "projector": {"proj2cam_pose": {"rotation": list(cfg.projector.rotation),
                                        "location": list(cfg.projector.location)},
                      "focal_length": cfg.projector.focal_length, "sensor_width": cfg.projector.sensor_width,
                      "resolution": [cfg.projector.resolution[1], cfg.projector.resolution[0]]},
        "scene": {"num_renders": cfg.scene.num_renders,
                  "max_renders_per_scene": cfg.scene.max_renders_per_scene,
                  "min_renders_per_scene": cfg.scene.min_renders_per_scene,
                  "drop_zone_loc": list(cfg.scene.drop_zone_loc),
                  "drop_zone_scale": list(cfg.scene.drop_zone_scale)},
        "objects": {"objects_list": [{"filepath": o.filepath, "scale": o.scale, "mass": o.mass,
                                      "collision_shape": o.collision_shape, "max": o.max_instances,
                                      "min": o.min_instances} for o in cfg.objects]},
        "output": {"path": cfg.output.path},
    }


def assets_dir() -> Path:
    return Path(__file__).resolve().parent / "assets"


def presets_dir() -> Path:
    return Path(__file__).resolve().parent / "presets"


def default_config() -> Config:
    """The embedded demo: a small bin with a few small parts, low resolution, 2 scenes."""
    return load(presets_dir() / "default.json")
