"""DataPipe: synthetic 6D-pose datasets for bin picking with a simulated structured-light camera.

`datapipe.config` and `datapipe.sl` are free of Blender; everything under `datapipe.core` and
`datapipe.ui` needs the `bpy` module (or runs inside Blender).
"""
__version__ = "0.1.0"


def register():
    """Blender add-on entry point (the UI lives in datapipe.ui; bpy is imported only here)."""
    from .ui import register as _register
    _register()


def unregister():
    from .ui import unregister as _unregister
    _unregister()
