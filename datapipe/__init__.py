"""DataPipe: synthetic 6D-pose datasets for bin picking with a simulated structured-light camera.

Scripts use `datapipe.api` (docs/API.md); its names are also here, imported on first use
(`datapipe.run(...)`, `datapipe.load_preset(...)`), so `import datapipe` itself stays light: Blender
imports the package to register the add-on. Everything under `datapipe.core` and `datapipe.ui` needs
the `bpy` module (or runs inside Blender); every other module imports without it (`config`, `sl`,
`io`, `draws`, `checks`, `engine`, `api`, ...).
"""
from .version import __version__  # noqa: F401  (the one place it is written: datapipe/version.py)

# datapipe.api's public names (its __all__), spelled here so that `import datapipe` does not import the API
API_NAMES = (
    "presets", "load_preset", "validate", "check", "preset_warnings", "run", "read_run", "patterns", "scan", "decode",
    "camera_matrix",
    "Config", "SceneConfig", "ObjectEntry", "CameraConfig", "CameraPose", "CameraSamplerConfig", "ProjectorConfig",
    "StructuredLightConfig", "RenderConfig", "LightingConfig", "SimulationConfig", "OutputConfig",
    "Problem", "ConfigError", "DataPipeError", "OutputStateError", "Progress", "Run", "Scene", "Render",
    "Scan", "DecodeResult", "Reason",
)


def __getattr__(name):
    """The public API's names at the package root, imported when first used (PEP 562)."""
    if name in API_NAMES:
        from . import api
        return getattr(api, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(API_NAMES))


def register():
    """Blender add-on entry point (the UI lives in datapipe.ui; bpy is imported only here)."""
    from .ui import register as _register
    _register()


def unregister():
    from .ui import unregister as _unregister
    _unregister()
