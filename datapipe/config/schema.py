"""The Config schema: the dataclasses the UI (or a preset) writes and the pipeline reads, and the
constants of what a field may hold. No bpy here.

Units: metres, radians, kilograms; focal lengths and sensor widths in millimetres (as Blender shows
them). Resolutions are [width, height] (the original pickle stored [height, width]; the legacy
loader swaps them). What a field may hold (choices, upper limits) is limits.py; parsing a dict is
parse.py, the field rules validate.py.
"""
from __future__ import annotations

import copy
import dataclasses
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ..errors import ConfigError, Problem
from ..text_rules import path_problem
from .limits import OUTPUT_KINDS, SCHEMA_VERSION

def _vec(*values: float):
    return field(default_factory=lambda: list(values))


@dataclass
class TexturesConfig:
    """Textures drawn per scene (datapipe/draws/textures.py, built by core/textures.py) on the `targets`:
    a procedural Blender texture of one of `kinds` (its parameters and two colours drawn), or with
    "image" in `kinds` a texture set of `image_folder` (colour, roughness and normal maps recognised by
    file name). No target: off (nothing drawn, nothing built)."""
    targets: list[str] = field(default_factory=list)   # of TEXTURE_TARGETS: "bin" (walls), "floor", "parts"
    kinds: list[str] = _vec("noise", "voronoi", "wave", "brick", "checker")   # of TEXTURE_KINDS
    image_folder: str = ""             # texture sets (e.g. CC0 PBR sets); needs "image" in kinds
    feature_size: list[float] = _vec(0.005, 0.05)   # m, size of the texture's features (1 / Blender scale)
    contrast: list[float] = _vec(0.2, 0.8)          # 1 - dark albedo / bright albedo of the two colours
    albedo: list[float] = _vec(0.2, 0.8)            # linear albedo (value) of the bright colour
    saturation: list[float] = _vec(0.0, 0.6)        # HSV saturation of the colours (hue uniform)


@dataclass
class PicksConfig:
    """scene.picks: a bin that empties as a robot picks (datapipe/draws/picks.py, docs/DATASETS.md).
    After a pile's renders, `per_step` parts are removed, chosen by `order` ("top": highest point
    first, as a robot picks; "visible": largest visible fraction in the step's renders first;
    "random"), the rest settle again from where they lay, and the pile is rendered again, until
    `until` parts remain. Each step is a scene of its own."""
    per_step: int = 1
    order: str = "top"
    until: int = 0


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
                                                   # factor from [min, max] (datapipe.draws.bin_shape)
    bin_wall_scale: list[float] = _vec(1.0, 1.0)   # per scene: wall height (the zone's) times [min, max]
    fill: list[float] | None = None    # [min, max] share of the bin's inner volume the parts' convex hulls
                                       # fill, drawn per scene (datapipe/draws/fill.py); each entry's instance
                                       # count stays within [min_instances, max_instances]
    blend_file: str | None = None      # open this .blend first; its object "drop_zone" wins over the above
    other_objects: str = "auto"        # objects of the open scene DataPipe did not make (Blender's startup
                                       # cube and light...): "hide" them from the renders for the run,
                                       # "keep" them in; "auto": keep with a blend_file, else hide
    seed: int = 0                      # base seed; scene i derives its own (see datapipe.draws.seeds)
    bin_material: Any = "file"         # floor + walls: "file" (built-in 0.5 grey, roughness 0.6), a
                                       # preset name, a dict of Principled BSDF values, or a list of
                                       # those: one drawn per scene (core/materials.py)
    textures: TexturesConfig = field(default_factory=TexturesConfig)   # textures drawn per scene on bin,
                                       # floor and parts (off: no targets)
    picks: PicksConfig | None = None   # pick sequences: each pile emptied step by step (PicksConfig); None: off


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
    annotate: bool = True              # false: a distractor: falls, collides, occludes and is rendered, but is in
                                       # no ground truth (scene_gt, COCO, BOP, models) and 0 in mask.exr
    shape: Any = None                  # instead of filepath: a procedural distractor, e.g. {"kind": "box", "size":
                                       # [[min x, y, z], [max ...]]} (m), size drawn per instance (shapes.py)
    origin: str = "file"               # the model frame's origin: "file" (the mesh file's) or "bbox_center"
                                       # (the centre of its 3D bounding box, BOP's convention) (core/objects.py)


@dataclass
class CameraPose:
    """Blender camera object's world pose: location (m) and quaternion (w, x, y, z); looks down local -Z."""
    location: list[float] = _vec(0.0, 0.0, 1.0)
    rotation: list[float] = _vec(1.0, 0.0, 0.0, 0.0)


@dataclass
class CameraSamplerConfig:
    """How each render's camera pose is chosen. "pool": drawn from `camera.poses` (without
    replacement within a scene); "bin_view": a look-at pose around the bin floor's centre, drawn
    per render from the ranges below (datapipe.draws.camera_sampler explains the angles)."""
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
    intrinsics: list[float] | None = None    # [fx, fy, cx, cy] px at `resolution` (a calibration); wins over
                                             # focal_length/sensor_width; None: theirs, principal point centred
    distortion: list[float] | None = None    # OpenCV k1 k2 p1 p2 k3 (docs/CALIBRATION.md); None/zeros: none
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
    intrinsics: list[float] | None = None    # [fx, fy, cx, cy] px (a calibration); wins over focal_length
    power: float = 5.0                 # emission strength of the light's node tree (a grey 0.5
                                       # floor at 0.8 m gets fringe peaks of ~1.0 linear radiance)


@dataclass
class StructuredLightConfig:
    """Defaults chosen in benchmarks/results/sl_render.md (docs/SL_SETTINGS.md)."""
    enabled: bool = False
    periods: list[int] = _vec(1, 8, 64)   # fringe periods across the projector width, coarse -> fine;
                                          # finest ~5 camera px per period at 320 px wide (keep >= 4)
    steps: int = 4                     # phase steps per period (4: one clipped sample tolerated)
    unwrap: str = "auto"
    samples: int = 4                   # fringe render paths per camera pixel (2x2 point sub-samples; rounded up to 4n)
    fringe_mode: str = "auto"          # "fast": one flat-lit render (+ coarse bounce layers), patterns
                                       # synthesised (core/fringe_fast.py); "render": every pattern
                                       # path-traced (the reference; sl_fringe_modes.md); "quadrature":
                                       # white + cos, sin per period path-traced, every step mixed from
                                       # them (sl/fringe_basis.py: exact, render's paths, sl_glossy_modes.md;
                                       # three images per Cycles layer, one per colour, when every
                                       # material is grey: 4 layers instead of 9);
                                       # "auto": quadrature when a configured material is shiny (mirrored
                                       # fringes; render with a projector gamma), else fast
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
    ambient: str = "off"               # "scene": the scene's own lights (lighting section, key light, world)
                                       # also reach the fringe images (one projector-off layer added to
                                       # every frame: shot noise, clipping; docs/STRUCTURED_LIGHT.md);
                                       # "off": the projector's light alone


@dataclass
class LightingConfig:
    """Lighting drawn per scene (datapipe.draws.lighting), each value uniform in its [min, max]. A config
    without a `lighting` section (null) keeps the fixed key light of `render.light_power`."""
    key_power: list[float] = _vec(25.0, 100.0)                  # W, the area light above the bin
    key_color_temperature: list[float] = _vec(3000.0, 6500.0)   # K, blackbody colour of the key light
    key_size: list[float] = _vec(0.5, 1.5)                      # m, side of the square area light
    key_position_jitter: float = 0.5                            # m, horizontal offset (uniform in a disc)
    ambient: list[float] = _vec(0.0, 0.2)                       # world (white) background strength
    per_render: bool = False                                    # draw all of the above per render, not per scene
    environment: str = ""                                       # an .hdr/.exr environment map or a folder of
                                                                # them (one drawn per draw); "": none
    environment_strength: list[float] = _vec(0.5, 1.5)          # its world strength
    environment_rotation_deg: list[float] = _vec(0.0, 360.0)    # its rotation about the world's Z axis


@dataclass
class RenderConfig:
    engine: str = "CYCLES"
    device: str = "CPU"
    samples: int = 16                  # native RGB layer; with the denoiser 42 dB against 1024 samples
                                       # at 0.64x the time of 32 undenoised (36.9 dB): rgb_quality.md
    sampling_pattern: str = "SCENE"    # Cycles' sampling pattern of the native render (the fringe calls keep
                                       # the scene's): SCENE (the scene's own; a new scene's is TABULATED_SOBOL),
                                       # TABULATED_SOBOL, BLUE_NOISE, AUTOMATIC (SAMPLING_PATTERNS); blue noise:
                                       # +0.26-0.33 dB at the same CPU (benchmarks/results/view_settings.md)
    threads: int = 0                   # 0 = all cores
    denoise: bool = True               # OpenImageDenoise (CPU) on the RGB, albedo + normal guided
    denoise_prefilter: str = "ACCURATE"  # OIDN's guide passes: ACCURATE (denoised first), FAST, NONE (as
                                       # rendered); Cycles' denoising_prefilter (DENOISE_PREFILTERS)
    denoise_quality: str = "HIGH"      # OIDN's network: HIGH, BALANCED, FAST; Cycles' denoising_quality
                                       # (what each costs and loses: benchmarks/results/view_settings.md)
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
    bop_sensor: str | None = None      # BOP-Industrial name of the scanner's folders (gray_NAME/, depth_NAME/ ...);
                                       # None: after the device's vendor ("zivid", "photoneo"), "sl" without
                                       # a device (datapipe/io/bop_sensor.py)
    xyz_crop: bool = False             # BOP: GDRNPP's amodal xyz_crop/ pickles per instance (io/xyz_crop.py)
    amodal_coco: bool = False          # BOP: UOAIS' scene_gt_coco_amodal.json beside scene_gt_coco.json (io/amodal.py)


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
        from .parse import from_dict      # below this module: handed the class it builds (tests/test_layering.py)
        return from_dict(cls, data, base_dir=base_dir)

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
        self.scene.textures.image_folder = resolved(self.scene.textures.image_folder)
        if self.lighting is not None:
            self.lighting.environment = resolved(self.lighting.environment)

    def copy(self) -> "Config":
        return copy.deepcopy(self)

    # -- validation -------------------------------------------------------------------------------
    def problems(self, *, check_files: bool = True) -> list[Problem]:
        from .validate import validate    # below this module: it reads the Config it is handed
        return validate(self, check_files=check_files)

    def validate(self, *, check_files: bool = True) -> "Config":
        from .validate import validate
        problems = validate(self, check_files=check_files)
        if problems:
            raise ConfigError(problems)
        return self

    # -- derived values ---------------------------------------------------------------------------
    def object_name(self, index: int) -> str:
        obj = self.objects[index]
        if obj.name or obj.filepath or obj.bop_models or not isinstance(obj.shape, dict):
            return obj.name or Path(obj.filepath or obj.bop_models).stem
        return str(obj.shape.get("kind", ""))        # a procedural distractor: its kind

    def obj_id(self, index: int) -> int:
        """The id entry `index` exports (after io.bop_models.expand_bop_objects)."""
        return int(self.objects[index].obj_id) or index + 1
