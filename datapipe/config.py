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
from .pickle_depth import pickle_depth
from .text_rules import name_problem, output_folder_problem, path_problem, short as _short

SCHEMA_VERSION = 1

MESH_SUFFIXES = (".obj", ".ply", ".stl", ".glb", ".gltf")
OUTPUT_KINDS = ("rgb", "depth", "normals", "mask", "object_coords")   # object_coords: only when listed
FORMATS = ("native", "bop")
ENGINES = ("CYCLES",)
DEVICES = ("CPU", "GPU")
# AUTO: DECOMPOSED for clearly concave meshes, else CONVEX_HULL. DECOMPOSED and MESH: a compound of
# convex pieces (Blender's moving triangle meshes threw concave parts out; see core/collision.py)
COLLISION_SHAPES = ("AUTO", "DECOMPOSED", "MESH", "CONVEX_HULL", "BOX", "SPHERE", "CAPSULE", "CYLINDER", "CONE")
SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")
UNWRAP_METHODS = ("auto", "heterodyne", "multi-frequency", "number-theoretic")   # datapipe.sl.unwrap
SAMPLER_KINDS = ("pool", "bin_view")
FRINGE_MODES = ("auto", "fast", "render")   # structured_light.fringe_mode (core/fringe_fast.py);
                                            # auto: render when a configured material is shiny, else fast
REFLECTION_FILTERS = ("auto", "local", "global", "off")
OTHER_OBJECTS = ("auto", "hide", "keep")   # scene.other_objects (core/scene.py)   # structured_light.reflection_filter (sl/filters.py)
MAX_RESOLUTION = 8192
# Upper limits: beyond them a preset is a typo, not a dataset (validate() says so before any work).
MAX_RENDERS = 1_000_000            # ~12 days of Cycles at 1 s per render (= seeds.MAX_PLAN_RENDERS)
MAX_SAMPLES = 4096                 # Cycles paths per pixel of the RGB layer
MAX_SL_SAMPLES = 1024              # fringe paths per camera pixel
MAX_STEPS = 32                     # phase steps: noise falls as 1/sqrt(steps); 32 is 2.8x better than 4
MAX_PERIODS = 8                    # fringe frequencies
MAX_INSTANCES = 500                # instances of one object per scene
MAX_FRINGE_BYTES = 16 * 2**30      # one render's fringe patterns + stack (see fringe_memory_bytes)
MAX_FREE_NESTING = 8              # lists/dicts inside a free-form field (a material list of dicts of lists: 3)
MAX_PICKLE_NESTING = 1000          # containers in an input pickle (the original's: 5); hashing a key nested
                                   # ~120,000 deep overflowed CPython's 8 MB C stack (datapipe/pickle_depth.py)
MAX_FIELD_OF_VIEW_DEG = 150.0      # camera/projector full angle across the sensor width
MIN_FRINGE_CAMERA_PX = 3.0         # finest fringe period on the camera sensor (sampling limit, > 2)
FRINGE_SUPERSAMPLE = 2             # = core.structured_light.FRINGE_SUPERSAMPLE (this module has no bpy)


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
    fill: list[float] | None = None    # [min, max] share of the bin's inner volume the parts' convex hulls
                                       # fill, drawn per scene (datapipe/fill.py); each entry's instance
                                       # count stays within [min_instances, max_instances]
    blend_file: str | None = None      # open this .blend first; its object "drop_zone" wins over the above
    other_objects: str = "auto"        # objects of the open scene DataPipe did not make (Blender's startup
                                       # cube and light...): "hide" them from the renders for the run,
                                       # "keep" them in; "auto": keep with a blend_file, else hide
    seed: int = 0                      # base seed; scene i derives its own (see datapipe.seeds)
    bin_material: Any = "file"         # floor + walls: "file" (built-in 0.5 grey, roughness 0.6), a
                                       # preset name, a dict of Principled BSDF values, or a list of
                                       # those: one drawn per scene (core/materials.py)


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
    material: Any = "file"             # "file" (what the mesh carries), a preset name, a dict of
                                       # Principled BSDF values, or a list drawn per instance (core/materials.py)
    bop_models: str = ""               # instead of filepath: a BOP dataset's models folder (obj_XXXXXX.ply
                                       # in mm + models_info.json); one entry per object (io/bop_models.py)
    bop_obj_ids: list[int] = field(default_factory=list)   # ... its objects to drop; [] = all
    obj_id: int = 0                    # the id exported (scene.json, BOP); 0 = position + 1 (BOP: its own)
    symmetries: Any = "auto"           # models_info.json symmetries: "auto" (BOP: the source's, else
                                       # detected), "detect", {"tolerance": f}, "none", or a dict of
                                       # symmetries_discrete / symmetries_continuous (mm) (io/symmetry.py)


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
    fringe_mode: str = "auto"          # "fast": one flat-lit render (+ coarse bounce layers), patterns
                                       # synthesised (core/fringe_fast.py); "render": every pattern
                                       # path-traced (the reference; sl_fringe_modes.md); "auto": render
                                       # when a configured material is shiny (mirrored fringes), else fast
    sensor: str = "industrial"         # datapipe.sl.sensor preset
    exposure: float | str = "auto"     # scale on linear radiance before the sensor model, or "auto":
                                       # metered per render from the fringes (datapipe.sl.exposure)
    hdr: list[float] | str = "auto"    # "auto": shorter exposures added per render while highlights
                                       # clip (none on scenes without: one exposure, no extra work);
                                       # or relative exposure factors fused per pixel, e.g. [1, 4, 16];
                                       # empty = always one exposure
    reflection_filter: str = "auto"    # "local": drop pixels whose frequencies disagree in modulation (light
                                       # of two paths); "global": also render a row code with the fringes
                                       # (+steps path-traced patterns) and drop mirror ghosts whose light
                                       # left the projector from another row; "auto": global on renders
                                       # with shiny surfaces (render mode), local otherwise; "off"
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
    samples: int = 16                  # native RGB layer; with the denoiser 42 dB against 1024 samples
                                       # at 0.64x the time of 32 undenoised (36.9 dB): rgb_quality.md
    threads: int = 0                   # 0 = all cores
    denoise: bool = True               # OpenImageDenoise (CPU) on the RGB, albedo + normal guided
    adaptive_threshold: float = 0.0    # Cycles adaptive sampling noise threshold; 0 = off (fixed samples)
    persistent_data: bool = False      # keep Cycles' scene data between the renders of a scene
    max_bounces: int = 4
    light_power: float = 50.0          # W, area light above the bin (the scene's key light)
    outputs: list[str] = _vec(*OUTPUT_KINDS[:4])


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
    device: str | None = None          # a real scanner (datapipe/devices.py, `python -m datapipe sensors`): fills
                                       # camera, projector and structured_light; the preset's own fields win
    binning: int = 1                   # the device's camera binning (resolution / binning), one it offers
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
            problems.append(Problem("schema_version", f"unsupported schema version {_short(version)}",
                                    f"use schema_version {SCHEMA_VERSION} (re-save the preset)"))
        from .devices import apply_device
        data = apply_device(data, problems)      # a device fills the sections the preset leaves out
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
        """Relative mesh and .blend paths -> absolute, against `base_dir`. A path the OS cannot take
        (NUL, lone surrogate) stays as given: validate() names it."""
        base = Path(base_dir)

        def resolved(p):
            if not isinstance(p, str) or not p or os.path.isabs(p) or path_problem(p):
                return p
            try:
                return str((base / p).resolve())
            except (RuntimeError, OSError):      # a symlink loop (RuntimeError before Python 3.13)
                return os.path.abspath(base / p)
        for obj in self.objects:
            obj.filepath = resolved(obj.filepath)
            obj.bop_models = resolved(obj.bop_models)
        self.scene.blend_file = resolved(self.scene.blend_file)

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
        return obj.name or Path(obj.filepath or obj.bop_models).stem

    def obj_id(self, index: int) -> int:
        """The id entry `index` exports (after io.bop_models.expand_bop_objects)."""
        return int(self.objects[index].obj_id) or index + 1


# ------------------------------------------------------------------------------------------------
# dict -> dataclass with type checks (collects problems instead of raising at the first one)

def _type_name(tp) -> str:
    return getattr(tp, "__name__", str(tp))


def _build(tp, value, path: str, problems: list[Problem]):
    if tp is Any:                    # free-form JSON (materials): checked by validate()
        depth = _nesting(value, MAX_FREE_NESTING)
        if depth > MAX_FREE_NESTING:
            problems.append(Problem(path, f"nested more than {MAX_FREE_NESTING} levels deep (lists or objects "
                                    "inside each other)", "give a name, an object of values, or a list of those "
                                    "(a material needs 3 levels)"))
            return None
        return copy.deepcopy(value)
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
        for a in non_none:       # a value of one member type stays that type (exposure: 0.5 or "auto")
            if a in (str, bool) and isinstance(value, a) or \
                    a in (int, float) and isinstance(value, (int, float)) and not isinstance(value, bool):
                return _build(a, value, path, problems)
        return _build(non_none[0], value, path, problems)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            problems.append(Problem(path, f"expected a number, got {_short(value)}", "give a number"))
            return 0.0
        try:
            return float(value)
        except OverflowError:                  # an integer with hundreds of digits
            problems.append(Problem(path, "number too large", "give a number below 1e308"))
            return 0.0
    if tp is int:
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            problems.append(Problem(path, f"expected an integer, got {_short(value)}", "give a whole number"))
            return 0
        if not -2**63 <= value < 2**63:        # beyond every limit below; keeps messages printable
            problems.append(Problem(path, "integer too large", "give a number of a sensible size"))
            return 0
        return value
    if tp is bool:
        if not isinstance(value, bool):
            problems.append(Problem(path, f"expected true/false, got {_short(value)}", "give true or false"))
            return False
        return value
    if tp is str:
        if not isinstance(value, str):
            problems.append(Problem(path, f"expected a string, got {_short(value)}", "give a string"))
            return ""
        return value
    raise TypeError(f"unsupported config type {_type_name(tp)} at {path}")


def _nesting(value, limit: int) -> int:
    """How deep lists/dicts nest in `value` (a scalar: 0), counted without recursion and only up
    to limit + 1 (a preset nested 950 deep must not reach Python's recursion limit)."""
    deepest, stack = 0, [(value, 0)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, (list, tuple, dict)):
            if d + 1 > limit:
                return d + 1
            deepest = max(deepest, d + 1)
            stack.extend((x, d + 1) for x in (v.values() if isinstance(v, dict) else v))
    return deepest


def _join(path: str, key) -> str:
    if not (isinstance(key, str) and key.isidentifier()):     # '', 'a b', 3: quoted, so the path is never empty
        return f"{path}[{_short(key)}]"
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
    # >= 3 projector px per fringe: the real limit on any period (a wider projector than
    # MAX_RESOLUTION is refused anyway), checked before the unwrapping maths sees the numbers
    width = pr.resolution[0] if len(pr.resolution) == 2 and 1 <= pr.resolution[0] <= MAX_RESOLUTION \
        else MAX_RESOLUTION
    if max(sl.periods) * 3 > width:
        add("structured_light.periods", f"{_short(max(sl.periods))} periods across {width} px leave fewer than 3 "
            "px per fringe", f"give at most {width // 3} periods (the finest fringe), or raise the projector width")
        return
    if sl.unwrap in UNWRAP_METHODS:
        from .sl import plan_unwrap      # pure numpy; the decoder owns the rules for period sets
        try:
            plan_unwrap(sl.periods, sl.unwrap)
        except ValueError as e:
            msg, fix = _split_fix(str(e))
            add("structured_light.periods", f"cannot be unwrapped: {msg}", fix or "use a set the message "
                "suggests, e.g. [1, 8, 64] (hierarchical), [70, 64, 59] or [13, 7] (number-theoretic)")


def validate(cfg: Config, *, check_files: bool = True) -> list[Problem]:
    """Every problem at once, each with its field path and the fix. Empty list = valid.

    Runs the named steps of `VALIDATION_STEPS` in order. A field that holds NaN or infinity is
    reported once (by `_check_finite`); later steps do not repeat it with a second message."""
    ck = _Checks()
    _check_finite(ck, cfg, check_files)
    non_finite = {p.path for p in ck.problems}
    for step in VALIDATION_STEPS:
        step(ck, cfg, check_files)
    return [p for i, p in enumerate(ck.problems) if i < len(non_finite) or p.path not in non_finite]


class _Checks:
    """The problem list and the small checks every validation step uses."""

    def __init__(self):
        self.problems: list[Problem] = []

    def add(self, path: str, msg: str, fix: str) -> None:
        self.problems.append(Problem(path, msg, fix))

    def positive(self, path, v, fix="give a value > 0") -> bool:
        if not (_is_number(v) and math.isfinite(v) and v > 0):
            self.add(path, f"must be > 0, got {_short(v)}", fix)
            return False
        return True

    def at_most(self, path, v, hi, why: str) -> bool:
        if _is_number(v) and v > hi:
            self.add(path, f"{v} is more than {hi} ({why})", f"give at most {hi}")
            return False
        return True

    def int_range(self, path, v, lo, hi, what: str) -> bool:
        if v < lo:
            self.add(path, f"must be >= {lo}, got {v}", f"give at least {lo} {what}")
            return False
        return self.at_most(path, v, hi, f"more {what} than any useful run needs")

    def vector(self, path, v, n, *, pos=False) -> bool:
        if len(v) != n:
            self.add(path, f"needs {n} numbers, got {len(v)}", f"give {n} numbers")
            return False
        if not all(_finite(x) for x in v):
            self.add(path, "contains NaN or infinity", "give finite numbers")
            return False
        if pos and not all(x > 0 for x in v):
            self.add(path, f"all values must be > 0, got {v}", "give positive sizes")
            return False
        return True

    def min_max(self, path, lo_name, hi_name, lo, hi, lo_bound=0) -> bool:
        ok = True
        if lo < lo_bound:
            self.add(f"{path}.{lo_name}", f"must be >= {lo_bound}, got {lo}", f"set it to {lo_bound} or more")
            ok = False
        if hi < lo_bound:
            self.add(f"{path}.{hi_name}", f"must be >= {lo_bound}, got {hi}", f"set it to {lo_bound} or more")
            ok = False
        if lo > hi:
            self.add(f"{path}.{lo_name}", f"{lo_name} ({lo}) > {hi_name} ({hi})", f"make {lo_name} <= {hi_name}")
            ok = False
        return ok

    def resolution(self, path, res) -> bool:
        if len(res) != 2:
            self.add(path, f"needs [width, height], got {res}", "give two integers [width, height]")
            return False
        ok = True
        for name, v in zip(("width", "height"), res):
            if not 1 <= v <= MAX_RESOLUTION:
                self.add(path, f"{name} {v} outside 1..{MAX_RESOLUTION}",
                         f"give a {name} between 1 and {MAX_RESOLUTION}")
                ok = False
        return ok

    def path(self, path, v: str) -> bool:
        """A path string the OS can take (no NUL, no lone surrogate: text_rules)."""
        problem = path_problem(v)
        if problem is not None:
            self.add(path, *problem)
        return problem is None

    def choice(self, path, v, options) -> bool:
        if v not in options:
            self.add(path, f"unknown value {_short(v)}", f"use one of {', '.join(map(str, options))}")
            return False
        return True

    def has(self, prefix: str) -> bool:
        """Is there already a problem at `prefix` or below it?"""
        return any(p.path == prefix or p.path.startswith((prefix + ".", prefix + "[")) for p in self.problems)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _finite(v) -> bool:
    try:
        return _is_number(v) and math.isfinite(v)
    except OverflowError:            # an int too large for a float
        return False


def _check_finite(ck: _Checks, cfg: Config, check_files: bool) -> None:
    """No NaN or infinity anywhere: one problem per field (a list is reported at its own path)."""
    def walk(obj, path):
        if dataclasses.is_dataclass(obj):
            for f in dataclasses.fields(obj):
                walk(getattr(obj, f.name), _join(path, f.name))
        elif isinstance(obj, list):
            if any(_is_number(x) and not _finite(x) for x in obj):
                ck.add(path, "contains NaN or infinity", "give finite numbers")
            else:
                for i, x in enumerate(obj):
                    if dataclasses.is_dataclass(x):
                        walk(x, f"{path}[{i}]")
        elif isinstance(obj, float) and not math.isfinite(obj):
            ck.add(path, f"must be a finite number, got {obj!r}", "give a finite number")
    walk(cfg, "")


def _check_scene(ck: _Checks, cfg: Config, check_files: bool) -> None:
    s = cfg.scene
    ck.int_range("scene.num_renders", s.num_renders, 1, MAX_RENDERS, "renders")
    if ck.min_max("scene", "min_renders_per_scene", "max_renders_per_scene",
                  s.min_renders_per_scene, s.max_renders_per_scene, lo_bound=1):
        ck.at_most("scene.max_renders_per_scene", s.max_renders_per_scene, MAX_RENDERS,
                   "more renders per scene than the run may have")
    ck.vector("scene.drop_zone_loc", s.drop_zone_loc, 3)
    ck.vector("scene.drop_zone_scale", s.drop_zone_scale, 3, pos=True)
    ck.positive("scene.bin_wall_thickness", s.bin_wall_thickness)
    ck.choice("scene.other_objects", s.other_objects, OTHER_OBJECTS)
    if not 0 <= s.seed < 2**32:
        ck.add("scene.seed", f"must be in 0..2^32-1, got {s.seed}", "give a non-negative 32-bit integer")
    if s.blend_file and ck.path("scene.blend_file", s.blend_file) and check_files:
        if not os.path.isfile(s.blend_file):
            ck.add("scene.blend_file", _not_found(s.blend_file), "give the path of an existing .blend")
        elif not s.blend_file.lower().endswith(".blend"):
            ck.add("scene.blend_file", f"not a .blend file: {s.blend_file}", "give a .blend file")
        else:
            _check_blend_header(ck, s.blend_file)


BLEND_MAGICS = (b"BLENDER", b"\x28\xb5\x2f\xfd", b"\x1f\x8b")   # plain, zstd (3.0+), gzip (older) .blend


def _check_blend_header(ck: _Checks, path: str) -> None:
    """The first bytes of a .blend: a file that is not one fails here, before Blender is started
    (the Blender preflight then reads the file itself: core/preflight.check_blend)."""
    try:
        with open(path, "rb") as f:
            head = f.read(12)
    except OSError as e:
        ck.add("scene.blend_file", f"cannot read {path}: {e.strerror or e}", "check the file's permissions")
        return
    if not head.startswith(BLEND_MAGICS):
        ck.add("scene.blend_file", f"{path} is not a Blender file (it starts with {_short(head[:7])}, not "
               "b'BLENDER' or a compressed .blend)", "give a .blend saved by Blender")


def _not_found(path: str) -> str:
    if os.path.islink(path):
        return f"file not found: {path} is a symbolic link to nothing (its target is missing, or a loop)"
    return f"file not found: {path}"


def _check_mesh_path(ck: _Checks, path: str, filepath: str, check_files: bool) -> None:
    if not filepath:
        ck.add(path, "empty", "give the path of a mesh file (.obj, .ply, .stl, .glb, .gltf)")
        return
    if not ck.path(path, filepath):
        return
    suffix = Path(filepath).suffix.lower()
    if check_files and os.path.isdir(filepath):
        ck.add(path, f"is a folder, not a mesh file: {filepath}", "give the path of one mesh file inside it")
    elif suffix not in MESH_SUFFIXES:
        ck.add(path, f"not a mesh file: {filepath}", f"use one of {', '.join(MESH_SUFFIXES)}")
    elif check_files and not os.path.isfile(filepath):
        ck.add(path, _not_found(filepath), "check the path (relative paths are resolved against the "
               "preset's folder)")


def _check_bop_entry(ck: _Checks, p: str, o: ObjectEntry, check_files: bool) -> None:
    from .errors import DataPipeError
    from .io.bop_models import bop_ids
    if not (isinstance(o.bop_obj_ids, list) and all(isinstance(i, int) and i >= 1 for i in o.bop_obj_ids)):
        ck.add(f"{p}.bop_obj_ids", f"expected a list of object ids >= 1, got {_short(o.bop_obj_ids)}",
               "list BOP object ids, e.g. [1, 5, 7], or [] for all")
    elif not o.bop_models:
        ck.add(f"{p}.bop_models", "empty, but bop_obj_ids is given", "give the BOP dataset's models folder")
    elif o.filepath:
        ck.add(f"{p}.filepath", "given together with bop_models", "give either a mesh file or a BOP models "
               "folder per entry")
    elif check_files:
        try:
            bop_ids(o, p)
        except DataPipeError as e:
            ck.add(*_split_field(str(e)))


def _split_field(message: str) -> tuple[str, str, str]:
    """'field: what (fix: how)' -> (field, what, how)."""
    field, _, rest = message.partition(": ")
    what, fix = _split_fix(rest)
    return field, what, fix or "see docs/DATASETS.md"


def _check_symmetries(ck: _Checks, p: str, s) -> None:
    from .errors import DataPipeError
    from .io.symmetry import check_symmetries
    if isinstance(s, dict) and set(s) == {"tolerance"}:
        if not (_is_number(s["tolerance"]) and 0 < s["tolerance"] < 0.5):
            ck.add(f"{p}.symmetries.tolerance", f"got {_short(s['tolerance'])}", "give a fraction of the "
                   "diameter in (0, 0.5), e.g. 0.01")
    elif isinstance(s, dict):
        try:
            check_symmetries(s, f"{p}.symmetries")
        except DataPipeError as e:
            ck.add(*_split_field(str(e)))
    elif s not in ("auto", "detect", "none"):
        ck.add(f"{p}.symmetries", f"unknown value {_short(s)}", "use \"auto\", \"detect\", \"none\", "
               "{\"tolerance\": 0.01} or a dict of symmetries_discrete / symmetries_continuous")


def _check_objects(ck: _Checks, cfg: Config, check_files: bool) -> None:
    if not cfg.objects:
        ck.add("objects", "no objects to drop", "add at least one object entry (a mesh file)")
    for i, o in enumerate(cfg.objects):
        p = f"objects[{i}]"
        if o.bop_models or o.bop_obj_ids:
            _check_bop_entry(ck, p, o, check_files)
        else:
            _check_mesh_path(ck, f"{p}.filepath", o.filepath, check_files)
        _check_symmetries(ck, p, o.symmetries)
        if o.obj_id < 0:
            ck.add(f"{p}.obj_id", f"must be >= 0, got {o.obj_id}", "give a BOP object id >= 1, or 0 for the "
                   "entry's position + 1")
        ck.positive(f"{p}.scale", o.scale)
        ck.positive(f"{p}.mass", o.mass)
        ck.choice(f"{p}.collision_shape", o.collision_shape, COLLISION_SHAPES)
        ck.min_max(p, "min_instances", "max_instances", o.min_instances, o.max_instances)
        if o.max_instances > MAX_INSTANCES:
            ck.add(f"{p}.max_instances", f"{o.max_instances} instances is beyond what one bin holds",
                   f"use at most {MAX_INSTANCES} instances per object")
        if not 0 <= o.friction:
            ck.add(f"{p}.friction", f"must be >= 0, got {o.friction}", "give a friction >= 0")
        if not 0 <= o.restitution <= 1:
            ck.add(f"{p}.restitution", f"must be in 0..1, got {o.restitution}", "give a restitution in 0..1")
    if check_files:
        from .io.bop_models import planned_obj_ids
        ids: dict[int, str] = {}
        for origin, k in planned_obj_ids(cfg):
            if k in ids:
                ck.add(origin.split(" ")[0] + ".obj_id", f"obj_id {k} is also the id of {ids[k]}",
                       "give each object a unique obj_id (0: its position + 1)")
            ids.setdefault(k, origin)
    if cfg.objects and sum(o.max_instances for o in cfg.objects) < 1:
        ck.add("objects", "every entry has max_instances = 0, so scenes would be empty",
               "give at least one entry max_instances >= 1")
    _check_object_names(ck, cfg)


def _check_object_names(ck: _Checks, cfg: Config) -> None:
    """Names Blender can hold whole with an instance number (text_rules), and unique ones."""
    for i, o in enumerate(cfg.objects):
        if ck.has(f"objects[{i}].filepath") and not o.name:
            continue                          # the name would come from a path already refused
        problem = name_problem(cfg.object_name(i), suffix="_000")   # instance k: f"{name}_{k:03d}"
        if problem is None and cfg.object_name(i).startswith("datapipe_"):
            problem = (f"{_short(cfg.object_name(i))} starts with 'datapipe_', the prefix of DataPipe's own objects "
                       "(templates, lights, the bin), whose names it could take", "give a name without that prefix")
        if problem is not None:
            what, fix = problem
            if not o.name:
                what, fix = f"the name taken from the file name, {what}", f"set objects[{i}].name: {fix}"
            ck.add(f"objects[{i}].name", what, fix)
    seen: dict[str, int] = {}
    for i, o in enumerate(cfg.objects):
        name = o.name or Path(o.filepath or o.bop_models).stem
        if name in seen:
            ck.add(f"objects[{i}].name", f"name {name!r} is already used by objects[{seen[name]}] (instance names "
                   "and annotations would collide)", "give this entry a unique name")
        seen.setdefault(name, i)


def _check_camera(ck: _Checks, cfg: Config, check_files: bool) -> None:
    c, s = cfg.camera, cfg.scene
    ck.positive("camera.focal_length", c.focal_length)
    ck.positive("camera.sensor_width", c.sensor_width)
    ck.choice("camera.sensor_fit", c.sensor_fit, SENSOR_FITS)
    ck.resolution("camera.resolution", c.resolution)
    ck.positive("camera.clip_start", c.clip_start)
    if c.clip_end <= c.clip_start:
        ck.add("camera.clip_end", f"clip_end ({c.clip_end}) <= clip_start ({c.clip_start})",
               "make clip_end > clip_start")
    _check_field_of_view(ck, "camera", c.focal_length, c.sensor_width, "sensor sees",
                         ": parts would be a few pixels or less",
                         "give a focal length of a real lens (industrial cameras: 4-50 mm)")
    pool = c.sampler.kind == "pool"
    if not c.poses and pool:
        ck.add("camera.poses", "no camera poses", "add at least one pose (location + quaternion wxyz)")
    for i, pose in enumerate(c.poses):
        ck.vector(f"camera.poses[{i}].location", pose.location, 3)
        if ck.vector(f"camera.poses[{i}].rotation", pose.rotation, 4):
            if math.sqrt(sum(q * q for q in pose.rotation)) < 1e-6:
                ck.add(f"camera.poses[{i}].rotation", "zero quaternion", "give a unit quaternion (w, x, y, z)")
    if pool and c.poses and s.max_renders_per_scene > len(c.poses):
        ck.add("scene.max_renders_per_scene",
               f"{s.max_renders_per_scene} renders per scene but only {len(c.poses)} camera poses "
               "(poses are drawn without replacement within a scene)",
               "add camera poses or lower max_renders_per_scene")


def _check_field_of_view(ck: "_Checks", device: str, focal: float, sensor: float, verb: str, why: str,
                         fix: str) -> None:
    """A lens wider than MAX_FIELD_OF_VIEW_DEG (once focal length and sensor width are valid)."""
    if ck.has(f"{device}.focal_length") or ck.has(f"{device}.sensor_width"):
        return
    fov = 2 * math.degrees(math.atan(sensor / (2 * focal)))
    if fov > MAX_FIELD_OF_VIEW_DEG:
        ck.add(f"{device}.focal_length", f"{focal} mm on a {sensor} mm {verb} {fov:.1f} deg across "
               f"(more than {MAX_FIELD_OF_VIEW_DEG:g}{why})", fix)


def _split_fix(text: str) -> tuple[str, str | None]:
    """'what (fix: how)' -> ('what', 'how'), so a wrapped message does not say "(fix:" twice."""
    head, sep, tail = text.partition(" (fix: ")
    return (head, tail[:-1] if tail.endswith(")") else tail) if sep else (text, None)


def _check_projector(ck: _Checks, cfg: Config, check_files: bool) -> None:
    if not cfg.structured_light.enabled:
        return
    pr = cfg.projector
    ck.positive("projector.focal_length", pr.focal_length)
    ck.positive("projector.sensor_width", pr.sensor_width)
    ck.resolution("projector.resolution", pr.resolution)
    ck.vector("projector.location", pr.location, 3)
    if len(pr.rotation) not in (3, 4):
        ck.add("projector.rotation", f"needs 3 (XYZ Euler, rad) or 4 (quaternion wxyz) numbers, got "
               f"{len(pr.rotation)}", "give [rx, ry, rz] or [w, x, y, z]")
    elif len(pr.rotation) == 4 and math.sqrt(sum(q * q for q in pr.rotation)) < 1e-6:
        ck.add("projector.rotation", "zero quaternion", "give a unit quaternion (w, x, y, z)")
    ck.positive("projector.power", pr.power)
    _check_field_of_view(ck, "projector", pr.focal_length, pr.sensor_width, "DMD throws", "",
                         "give the focal length of a real projector lens (8-50 mm)")


def _check_structured_light(ck: _Checks, cfg: Config, check_files: bool) -> None:
    sl, pr = cfg.structured_light, cfg.projector
    if not sl.enabled:
        return
    if sl.steps < 3:
        ck.add("structured_light.steps", f"must be >= 3, got {sl.steps}",
               "use 3 or more phase steps (4 or more avoids gamma errors)")
    ck.at_most("structured_light.steps", sl.steps, MAX_STEPS, "more steps than lower the phase noise usefully")
    if len(sl.periods) > MAX_PERIODS:
        ck.add("structured_light.periods", f"{len(sl.periods)} frequencies (more than {MAX_PERIODS})",
               "three frequencies unwrap any useful range, e.g. [1, 8, 64]")
    else:
        _check_sl_periods(sl, pr, ck.add)
    ck.choice("structured_light.unwrap", sl.unwrap, UNWRAP_METHODS)
    ck.choice("structured_light.fringe_mode", sl.fringe_mode, FRINGE_MODES)
    ck.choice("structured_light.reflection_filter", sl.reflection_filter, REFLECTION_FILTERS)
    if sl.reflection_filter == "global" and sl.fringe_mode == "fast":
        ck.add("structured_light.reflection_filter", "'global' checks a path-traced row code, and fast mode "
               "synthesises the patterns (no mirrored light to find)", "set structured_light.fringe_mode to "
               "'render' or 'auto', or reflection_filter to 'local'")
    if not (0.2 <= sl.projector_gamma <= 5.0):
        ck.add("structured_light.projector_gamma", f"must be a number in [0.2, 5], got {sl.projector_gamma!r}",
               "use 1.0 for a linear projector, ~2.2 for a typical DLP/LCD response")
    from .sl.sensor import PRESETS
    if sl.sensor not in PRESETS:
        ck.add("structured_light.sensor", f"unknown sensor preset {sl.sensor!r}", f"use one of {sorted(PRESETS)}")
    ck.int_range("structured_light.samples", sl.samples, 1, MAX_SL_SAMPLES, "samples")
    _check_exposure(sl, ck.add)
    _check_fringe_memory(ck, cfg)
    _check_fringe_size(ck, cfg)


def builds_row_code(sl: "StructuredLightConfig", fringe_mode: str) -> bool:
    """Whether the structured-light camera builds the global reflection filter's row code: the
    patterns are path-traced (`fringe_mode`, resolved) and reflection_filter is "auto" (rendered on
    shiny renders) or "global" (every render)."""
    return fringe_mode == "render" and sl.reflection_filter in ("auto", "global")


def _fringe_frames(cfg: Config) -> int:
    """Fringe images per render: F*N, plus the row code (N) where the global reflection filter may
    run (an upper bound: fringe_mode "auto" may resolve to render)."""
    s = cfg.structured_light
    rows = s.steps if builds_row_code(s, "fast" if s.fringe_mode == "fast" else "render") else 0
    return len(s.periods) * s.steps + rows


def fringe_memory_bytes(cfg: Config) -> int:
    """Peak memory of one render's fringe work: every pattern as a float RGBA Blender image plus the
    rendered stack read back at FRINGE_SUPERSAMPLE x the camera resolution (float32) and its mean;
    with `hdr`, the fused float32 stack and one exposure's sensor output besides."""
    (Wp, Hp), (W, H) = cfg.projector.resolution, cfg.camera.resolution
    ss = FRINGE_SUPERSAMPLE
    hdr = 8 * W * H if cfg.structured_light.hdr else 0
    return _fringe_frames(cfg) * (Wp * Hp * 16 + W * H * ss * ss * 4 + W * H * 4 + hdr)


def _check_fringe_memory(ck: _Checks, cfg: Config) -> None:
    if ck.has("structured_light") or ck.has("projector.resolution") or ck.has("camera.resolution"):
        return
    need = fringe_memory_bytes(cfg)
    if need > MAX_FRINGE_BYTES:
        ck.add("structured_light.steps", f"{len(cfg.structured_light.periods)} frequencies x {cfg.structured_light.steps} "
               f"steps need about {need / 2**30:.1f} GiB for the fringe stack (limit "
               f"{MAX_FRINGE_BYTES / 2**30:.0f} GiB)", "use fewer steps or frequencies, or a smaller projector or "
               "camera resolution (the row code of reflection_filter 'global'/'auto' and hdr add to it)")


def fringe_period_camera_px(cfg: Config) -> float:
    """Predicted finest fringe period in camera pixels, the worst camera pose.

    One projector pixel at distance d is d * sensor_p / (f_p * W_p) metres wide; the camera sees a
    length L at distance d' as L * fx_cam / d' pixels. In camera-object axes the camera looks down
    -Z, so a projector at z_p > 0 sits behind the camera: d = d' + z_p for a part d' in front of
    the camera. Distances d' are from each camera pose to the drop zone centre."""
    from .sl.triangulate import intrinsics_from_blender
    c, pr, sl = cfg.camera, cfg.projector, cfg.structured_light
    fx_cam = float(intrinsics_from_blender(c.focal_length, c.sensor_width, int(c.resolution[0]),
                                           int(c.resolution[1]), c.sensor_fit,
                                           sensor_height_mm=c.sensor_width)[0, 0])
    fringe_proj_px = pr.resolution[0] / max(sl.periods)
    metres_per_proj_px = pr.sensor_width / (pr.focal_length * pr.resolution[0])   # at 1 m
    worst = math.inf
    for d in camera_distances(cfg):
        d_cam = max(d, c.clip_start)
        d_proj = max(d_cam + pr.location[2], c.clip_start)
        worst = min(worst, fringe_proj_px * metres_per_proj_px * d_proj * fx_cam / d_cam)
    return worst


def camera_distances(cfg: Config) -> list[float]:
    """Camera-to-bin distances a run can render from (m): each pool pose to the drop zone centre, or
    the bin_view sampler's distance range."""
    c = cfg.camera
    if c.sampler.kind == "bin_view":
        return [float(d) for d in c.sampler.distance]
    return [math.dist(p.location, cfg.scene.drop_zone_loc) for p in c.poses] or [1.0]


def _check_fringe_size(ck: _Checks, cfg: Config) -> None:
    if any(ck.has(p) for p in ("structured_light.periods", "projector", "camera", "scene.drop_zone_loc")) or \
            (cfg.camera.sampler.kind == "bin_view" and len(cfg.camera.sampler.distance) != 2):
        return
    px = fringe_period_camera_px(cfg)
    if px < MIN_FRINGE_CAMERA_PX:
        ck.add("structured_light.periods", f"the finest fringe ({max(cfg.structured_light.periods)} periods) is "
               f"about {px:.2f} camera pixels wide at the working distance (need >= {MIN_FRINGE_CAMERA_PX:g}: the "
               "camera cannot resolve it and the depth map would be empty)",
               "lower the finest period count, raise camera.resolution or camera.focal_length, or raise "
               "projector.focal_length")


def _check_render(ck: _Checks, cfg: Config, check_files: bool) -> None:
    r = cfg.render
    ck.choice("render.engine", r.engine, ENGINES)
    ck.choice("render.device", r.device, DEVICES)
    ck.int_range("render.samples", r.samples, 1, MAX_SAMPLES, "samples")
    if r.threads < 0:
        ck.add("render.threads", f"must be >= 0, got {r.threads}", "use 0 for all cores")
    ck.at_most("render.threads", r.threads, 1024, "more threads than any machine has")
    ck.int_range("render.max_bounces", r.max_bounces, 0, 1024, "bounces")
    if not (0.0 <= r.adaptive_threshold < 1.0):
        ck.add("render.adaptive_threshold", f"must be in [0, 1), got {r.adaptive_threshold}",
               "use 0 (off) or a noise threshold such as 0.01")
    if r.light_power < 0:
        ck.add("render.light_power", f"must be >= 0, got {r.light_power}", "give a power >= 0 W")
    if not r.outputs:
        ck.add("render.outputs", "no outputs requested, so a run would write nothing",
               f"list some of {', '.join(OUTPUT_KINDS)}")
    for i, k in enumerate(r.outputs):
        ck.choice(f"render.outputs[{i}]", k, OUTPUT_KINDS)
    if len(set(r.outputs)) != len(r.outputs):
        ck.add("render.outputs", f"duplicate entries in {r.outputs}", "list each output once")


def _check_simulation(ck: _Checks, cfg: Config, check_files: bool) -> None:
    m = cfg.simulation
    ck.int_range("simulation.substeps", m.substeps, 1, 1000, "substeps")
    if m.max_substeps < m.substeps:
        ck.add("simulation.max_substeps", f"must be >= simulation.substeps ({m.substeps}), got {m.max_substeps}",
               "give a maximum at least as large as the minimum")
    ck.at_most("simulation.max_substeps", m.max_substeps, 10_000, "more substeps than any scene needs")
    ck.int_range("simulation.solver_iterations", m.solver_iterations, 1, 1000, "iterations")
    ck.int_range("simulation.max_frames", m.max_frames, 1, 100_000, "frames")
    ck.positive("simulation.settle_speed", m.settle_speed)
    ck.int_range("simulation.settle_frames", m.settle_frames, 1, 100_000, "frames")
    if m.layer_gap < 0:
        ck.add("simulation.layer_gap", f"must be >= 0, got {m.layer_gap}", "give a gap >= 0 m")
    _check_redraw(m, ck.add)


def _check_output(ck: _Checks, cfg: Config, check_files: bool) -> None:
    o, r = cfg.output, cfg.render
    if not o.path:
        ck.add("output.path", "empty", "give an output folder")
    elif output_folder_problem(o.path):
        ck.add("output.path", *output_folder_problem(o.path))
    for i, f in enumerate(o.formats):
        ck.choice(f"output.formats[{i}]", f, FORMATS)
    if not o.formats:
        ck.add("output.formats", "no output format", "use [\"native\"] and/or \"bop\"")
    if "bop" in o.formats:
        for need in ("rgb", "depth", "mask"):
            if need not in r.outputs:
                ck.add("render.outputs", f"the BOP format needs the {need!r} output",
                       f"add {need!r} to render.outputs or drop 'bop' from output.formats")


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


def _check_variety(ck: _Checks, cfg: Config, check_files: bool) -> None:
    """Per-scene variety: bin shape ranges, the camera sampler, the lighting ranges."""
    s = cfg.scene
    ck.problems += _range_problems("scene.bin_size_scale", s.bin_size_scale, lo_bound=0.05, hi_bound=20.0)
    ck.problems += _range_problems("scene.bin_wall_scale", s.bin_wall_scale, lo_bound=0.05, hi_bound=20.0)
    if s.fill is not None:
        from .fill import MAX_FILL
        ck.problems += _range_problems("scene.fill", s.fill, lo_bound=0.0, hi_bound=MAX_FILL)
    ck.problems += _sampler_problems(cfg)
    ck.problems += _lighting_problems(cfg.lighting)


def _check_materials(ck: "_Checks", cfg: "Config", check_files: bool) -> None:
    """objects[i].material and scene.bin_material (name, dict or list)."""
    from .core.materials import material_problem   # no bpy at import: the rules live with the builder
    for i, o in enumerate(cfg.objects):
        problem = material_problem(o.material)
        if problem is not None:
            ck.add(f"objects[{i}].material", *problem)
    problem = material_problem(cfg.scene.bin_material)
    if problem is not None:
        ck.add("scene.bin_material", *problem)


def _check_device(ck: "_Checks", cfg: "Config", check_files: bool) -> None:
    """device (a known scanner) and binning (one it offers)."""
    from .devices import device_problem
    problem = device_problem(cfg.device, cfg.binning)
    if problem is not None:
        ck.problems.append(problem)


# The steps validate() runs, in order. A new field's checks go into a small step function here.
VALIDATION_STEPS = (_check_scene, _check_objects, _check_camera, _check_variety, _check_projector, _check_structured_light,
                    _check_render, _check_simulation, _check_output, _check_materials, _check_device)


def _check_exposure(sl: "StructuredLightConfig", add) -> None:
    """structured_light.exposure (number > 0 or "auto") and .hdr (distinct factors > 0)."""
    from .sl.exposure import exposure_problem, hdr_problem   # the rules live with the code using them
    for path, problem in (("structured_light.exposure", exposure_problem(sl.exposure)),
                          ("structured_light.hdr", hdr_problem(sl.hdr))):
        if problem is not None:
            add(path, *problem)


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
    except RecursionError:
        raise ConfigError(Problem("<file>", "JSON nested too deeply to be a preset",
                                  "give a preset: a few levels of objects and lists")) from None
    except ValueError:                         # an integer of more than 4,300 digits (Python's limit)
        raise ConfigError(Problem("<file>", "cannot read a number: an integer of more than 4,300 digits",
                                  "give numbers of a sensible size (no field needs more than 20 digits)")) from None
    return Config.from_dict(data, base_dir=base_dir)


def load(path: str | os.PathLike) -> Config:
    """Load a JSON preset or an original-layout DataPipe pickle (detected by content)."""
    path = Path(path)
    if not path.is_file():
        raise ConfigError(Problem("<file>", f"preset not found: {path}", "give the path of a .json preset or .pickle"))
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise ConfigError(Problem("<file>", f"cannot read {path}: {e.strerror or e}",
                                  "check the file's permissions")) from None
    if raw[:1] == b"\x80" or path.suffix.lower() in (".pickle", ".pkl"):
        return load_legacy_pickle(raw, base_dir=path.parent)
    try:
        text = raw.decode("utf-8-sig")         # a BOM (Windows editors) is not a JSON error
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
    depth = pickle_depth(raw, MAX_PICKLE_NESTING)
    if depth is not None and depth > MAX_PICKLE_NESTING:     # before unpickling: deep tuples crash hash()
        raise ConfigError(Problem("<pickle>", f"containers nested more than {MAX_PICKLE_NESTING} levels deep: "
                                  "no DataPipe inputs pickle is", "give an original DataPipe inputs pickle "
                                  "(5 levels) or a JSON preset"))
    try:
        data = _RefusingUnpickler(io.BytesIO(raw)).load()
    except ConfigError:
        raise
    except MemoryError:     # a length field (BINBYTES8, ...) larger than memory: corrupt or hostile
        raise ConfigError(Problem("<pickle>", f"cannot read the pickle: it declares a value larger than the "
                                  f"memory ({len(raw)} bytes in the file)", "give an original DataPipe inputs "
                                  "pickle or a JSON preset; this one is damaged")) from None
    except Exception as e:  # truncated or corrupt pickles raise many types
        reason = f"{type(e).__name__}: {e}" if str(e) else type(e).__name__
        raise ConfigError(Problem("<pickle>", f"cannot read the pickle ({reason})", "give an original DataPipe "
                                  "inputs pickle or a JSON preset")) from None
    cfg = from_legacy_dict(data)
    if base_dir is not None:
        cfg.resolve_paths(base_dir)
    return cfg


_POSE_LIST_KEYS = ("world2cam_pose_list", "wrlld2cam_pose_list", "wrl2cam_pose_list")


def from_legacy_dict(d: dict) -> Config:
    """Map the original DataPipe input dict (layout in docs/CONVENTIONS.md) onto a Config.

    Every value is converted through `_Legacy`, so a wrong type anywhere is a ConfigError naming
    the pickle's own key path, never a traceback."""
    if not isinstance(d, dict):
        raise ConfigError(Problem("<pickle>", f"expected a dict, got {type(d).__name__}",
                                  "give an original DataPipe inputs pickle"))
    lg = _Legacy()
    known = {"camera", "projector", "scene", "objects", "output"}
    for k in d:
        if k not in known:
            lg.add(_join("", k), "unknown section in the legacy pickle", f"known sections: {', '.join(sorted(known))}")
    cfg = Config()
    cam = lg.section(d, "camera")
    pose_key = next((k for k in _POSE_LIST_KEYS if k in cam), None)
    if pose_key is not None:
        cfg.camera.poses = []
        for i, pose in enumerate(lg.items(cam, pose_key, f"camera.{pose_key}")):
            loc = lg.numbers(pose, "location", f"camera.{pose_key}[{i}]", 3)
            rot = lg.numbers(pose, "rotation", f"camera.{pose_key}[{i}]", 4)
            if loc is not None and rot is not None:
                cfg.camera.poses.append(CameraPose(location=loc, rotation=rot))
    for key in ("focal_length", "sensor_width"):
        lg.number(cam, key, "camera", cfg.camera, key)
    if "resolution" in cam:
        hw = lg.numbers(cam, "resolution", "camera", 2, int)
        if hw is not None:
            cfg.camera.resolution = [hw[1], hw[0]]          # the original stored [height, width]
    if "is_structured_light" in cam:
        cfg.structured_light.enabled = bool(cam["is_structured_light"])

    proj = lg.section(d, "projector")
    pose = lg.section(proj, "proj2cam_pose", "projector")
    if pose:
        cfg.projector.location = lg.numbers(pose, "location", "projector.proj2cam_pose", 3) or cfg.projector.location
        cfg.projector.rotation = lg.numbers(pose, "rotation", "projector.proj2cam_pose") or cfg.projector.rotation
    for key in ("focal_length", "sensor_width"):
        lg.number(proj, key, "projector", cfg.projector, key)
    if "resolution" in proj:
        hw = lg.numbers(proj, "resolution", "projector", 2, int)
        if hw is not None:
            cfg.projector.resolution = [hw[1], hw[0]]

    sc = lg.section(d, "scene")
    for key in ("num_renders", "max_renders_per_scene", "min_renders_per_scene"):
        lg.number(sc, key, "scene", cfg.scene, key, int)
    for key in ("drop_zone_loc", "drop_zone_scale"):
        if key in sc:
            setattr(cfg.scene, key, lg.numbers(sc, key, "scene", 3) or getattr(cfg.scene, key))

    objs = lg.section(d, "objects")
    for i, o in enumerate(lg.items(objs, "objects_list", "objects.objects_list")):
        p = f"objects.objects_list[{i}]"
        if not isinstance(o, dict) or "filepath" not in o:
            lg.add(p, "needs at least 'filepath'", "fix or remove this entry")
            continue
        if not isinstance(o["filepath"], str):
            lg.add(f"{p}.filepath", f"expected a path string, got {_short(o['filepath'])}", "give the mesh's path")
            continue
        e = ObjectEntry(filepath=o["filepath"])
        for src, dst, conv in (("scale", "scale", float), ("mass", "mass", float), ("min", "min_instances", int),
                               ("max", "max_instances", int)):
            lg.number(o, src, p, e, dst, conv)
        e.collision_shape = o.get("collision_shape", e.collision_shape)
        if not isinstance(e.collision_shape, str):
            lg.add(f"{p}.collision_shape", f"expected a string, got {_short(e.collision_shape)}",
                   f"use one of {', '.join(COLLISION_SHAPES)}")
        if "max" not in o:
            e.max_instances = 1                              # the original's default
        cfg.objects.append(e)
    out = lg.section(d, "output")
    if "path" in out:
        if isinstance(out["path"], str):
            cfg.output.path = out["path"]
        else:
            lg.add("output.path", f"expected a folder path, got {_short(out['path'])}", "give the output folder")
    if lg.problems:
        raise ConfigError(lg.problems)
    return cfg


class _Legacy:
    """Typed reads from the original's dicts; each bad value becomes a Problem at its key path."""

    def __init__(self):
        self.problems: list[Problem] = []

    def add(self, path, msg, fix) -> None:
        self.problems.append(Problem(path, msg, fix))

    def section(self, d: dict, key: str, parent: str = "") -> dict:
        v = d.get(key) or {}
        if not isinstance(v, dict):
            self.add(_join(parent, key), f"expected a dict, got {type(v).__name__}", "give this section as a dict")
            return {}
        return v

    def items(self, d: dict, key: str, path: str) -> list:
        v = d.get(key) or []
        if not isinstance(v, (list, tuple)):
            self.add(path, f"expected a list, got {type(v).__name__}", "give a list")
            return []
        return list(v)

    def _convert(self, v, conv, path):
        try:
            if isinstance(v, (bool, str, bytes)) or not isinstance(v, (int, float)):
                raise TypeError
            x = conv(v)
            if conv is int and (x != v or not -2**63 <= x < 2**63):
                raise ValueError
            return x
        except (TypeError, ValueError, OverflowError):
            what = "a whole number" if conv is int else "a number"
            self.add(path, f"expected {what}, got {_short(v)}", f"give {what}")
            return None

    def number(self, d: dict, key: str, parent: str, target, attr: str, conv=float) -> None:
        if key in d:
            x = self._convert(d[key], conv, _join(parent, key))
            if x is not None:
                setattr(target, attr, x)

    def numbers(self, d, key: str, parent: str, n: int | None = None, conv=float) -> list | None:
        path = _join(parent, key)
        v = d.get(key) if isinstance(d, dict) else None
        if not isinstance(v, (list, tuple)) or (n is not None and len(v) != n):
            self.add(path, f"expected {n or 'a list of'} numbers, got {_short(v)}",
                     f"give {n or 'the'} numbers as a list")
            return None
        xs = [self._convert(x, conv, f"{path}[{i}]") for i, x in enumerate(v)]
        return None if any(x is None for x in xs) else xs


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
