"""The Config: the one thing the UI (or a preset) writes and the pipeline reads. No bpy here.

- schema.py      the dataclasses (Config and its sections)
- limits.py      what a field may hold: the choices and the upper limits
- parse.py       dict -> Config with type checks (Config.from_dict)
- validate.py    validate(): every problem at once (field path + fix) before any Blender work;
                 validate_sl.py the projector / structured-light rules, checks.py their helpers
- plan.py        what a config will do at run time (camera distances, fringe memory, row code)
- calibration.py `"device": <calibration file>`: the file's camera and projector sections, their rules
- files.py       JSON presets, the original DataPipe pickle (a safe unpickler; pickle_depth.py reads
                 its nesting first), package presets
- legacy.py      the original add-on's input dict <-> Config

Each module imports only the ones listed below it in tests/test_layering.py's CONFIG_FLOORS: schema's
Config calls down into parse and validate, which never import it at run time.

The names below are the package's public ones: `from datapipe.config import Config, load, validate`.
"""
from ..errors import ConfigError, Problem
from .files import assets_dir, default_config, load, load_legacy_pickle, loads, presets_dir, save
from .legacy import from_legacy_dict, to_legacy_dict
from .plan import (FRINGE_SUPERSAMPLE, builds_row_code, camera_distances, fringe_memory_bytes,
                   fringe_period_camera_px)
from .limits import (AMBIENT_MODES, COLLISION_SHAPES, ORIGINS, DEVICES, ENGINES, FORMATS, FRINGE_MODES, MAX_FIELD_OF_VIEW_DEG,
                     MAX_FREE_NESTING, MAX_FRINGE_BYTES, MAX_INSTANCES, MAX_PERIODS, MAX_PICKLE_NESTING,
                     MAX_INT32, MAX_RENDERS, MAX_RESOLUTION, MAX_SAMPLES, MAX_SL_SAMPLES, MAX_STEPS, MESH_SUFFIXES,
                     MIN_FRINGE_CAMERA_PX, MIN_POSITIVE, OTHER_OBJECTS, OUTPUT_KINDS, PICK_ORDERS, REFLECTION_FILTERS, SAMPLER_KINDS,
                     SCHEMA_VERSION, SENSOR_FITS, UNWRAP_METHODS)
from .limits import DENOISE_PREFILTERS, DENOISE_QUALITIES, SAMPLING_PATTERNS, TEXTURE_KINDS, TEXTURE_TARGETS
from .schema import (CameraConfig, CameraPose, CameraSamplerConfig, PicksConfig,
                     Config, LightingConfig, ObjectEntry, OutputConfig, ProjectorConfig, RenderConfig,
                     SceneConfig, SimulationConfig, StructuredLightConfig, TexturesConfig)
from .validate import BLEND_MAGICS, VALIDATION_STEPS, validate

__all__ = [
    "ConfigError", "Problem",
    "assets_dir", "default_config", "load", "load_legacy_pickle", "loads", "presets_dir", "save",
    "from_legacy_dict", "to_legacy_dict",
    "FRINGE_SUPERSAMPLE", "builds_row_code", "camera_distances", "fringe_memory_bytes", "fringe_period_camera_px",
    "AMBIENT_MODES", "COLLISION_SHAPES", "ORIGINS", "DEVICES", "ENGINES", "FORMATS", "FRINGE_MODES", "MAX_FIELD_OF_VIEW_DEG",
    "MAX_FREE_NESTING",
    "MAX_FRINGE_BYTES", "MAX_INSTANCES", "MAX_PERIODS", "MAX_PICKLE_NESTING", "MAX_RENDERS", "MAX_RESOLUTION",
    "MAX_SAMPLES", "MAX_SL_SAMPLES", "MAX_STEPS", "MESH_SUFFIXES", "MIN_FRINGE_CAMERA_PX", "OTHER_OBJECTS",
    "OUTPUT_KINDS", "PICK_ORDERS", "REFLECTION_FILTERS", "SAMPLER_KINDS", "SCHEMA_VERSION", "SENSOR_FITS",
    "TEXTURE_KINDS", "TEXTURE_TARGETS", "UNWRAP_METHODS", "DENOISE_PREFILTERS", "DENOISE_QUALITIES",
    "SAMPLING_PATTERNS",
    "CameraConfig", "CameraPose", "CameraSamplerConfig", "Config", "LightingConfig", "ObjectEntry", "OutputConfig",
    "PicksConfig", "ProjectorConfig", "RenderConfig", "SceneConfig", "SimulationConfig", "StructuredLightConfig", "TexturesConfig",
    "BLEND_MAGICS", "VALIDATION_STEPS", "validate",
]
