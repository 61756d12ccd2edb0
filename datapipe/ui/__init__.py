"""DataPipe's Blender add-on UI: the `DataPipe` sidebar tab of the 3D viewport.

- `props`      the PropertyGroup tree `bpy.types.Scene.datapipe` (mirrors `datapipe.config.Config`; a
               package, one module per group of Config sections)
- `convert`    `props_to_config(props) -> Config`, `config_to_props(cfg, props)`: the one mapping
- `operators`  thin operators `datapipe.*` (build a Config, call core)
- `panels`     panels and UI lists
- `presets`    built-in (read-only) and user JSON presets
- `preview`    viewport previews (object entry, camera, projector) and the drop zone box
- `runner`     steps `Pipeline.run()` under `bpy.app.timers`, or blocking in background mode

`register()` / `unregister()` register every class from one tuple, in order (and unregister them
reversed); `datapipe.register()` delegates here lazily.
"""
from __future__ import annotations

import bpy

from . import operators, panels, props, runner

CLASSES = props.CLASSES + operators.CLASSES + panels.CLASSES

_register_classes, _unregister_classes = bpy.utils.register_classes_factory(CLASSES)


def register() -> None:
    _register_classes()
    props.register_pointer()


def unregister() -> None:
    runner.stop_for_unregister()
    props.unregister_pointer()
    _unregister_classes()


__all__ = ["register", "unregister", "CLASSES"]
