"""DataPipe: synthetic 6D-pose datasets for bin picking with a simulated structured-light camera.

Everything under `datapipe.core` and `datapipe.ui` needs the `bpy` module (or runs inside Blender);
every other module imports without it (`config`, `sl`, `io`, `draws`, `checks`, `engine`, ...).
"""
__version__ = "0.1.0"


def register():
    """Blender add-on entry point (the UI lives in datapipe.ui; bpy is imported only here)."""
    from .ui import register as _register
    _register()


def unregister():
    from .ui import unregister as _unregister
    _unregister()
