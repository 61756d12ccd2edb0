"""The writers of a run behind one small interface, chosen from `cfg.output` in one place.

    writers = open_writers(cfg.output, out_dir)     # native scene.json, output_dict.pickle, BOP
    writers.start()                                  # once, before the first scene
    writers.add_scene(scene_dir, scene)              # a complete scene: every writer, in order
    writers.catch_up(scene_dir, scene)               # a complete scene some writer may lack (resume, merge)
    writers.finish()                                 # once, at the end: {writer name: summary}

Each writer has `name`, `start()`, `has_scene(scene_dir, scene)`, `add_scene(scene_dir, scene)`,
`finish() -> dict`. The native scene.json is always written and always first: it is the run's own
record ("scene complete", resume, merge), whatever `output.formats` lists; output_dict.pickle when
`output.legacy_pickle`; BOP (OUT/bop) when "bop" is in `output.formats`.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any, Protocol

from . import layout


class SceneWriter(Protocol):
    name: str

    def start(self) -> None: ...

    def has_scene(self, scene_dir: Path, scene: dict) -> bool: ...

    def add_scene(self, scene_dir: Path, scene: dict) -> Any: ...

    def finish(self) -> dict: ...


def _output_value(output, key: str, default):
    """`cfg.output` may be the OutputConfig or its dict (a run.json's preset)."""
    if isinstance(output, dict):
        return output.get(key, default)
    return getattr(output, key, default)


class Writers:
    """The run's writers, called in order."""

    def __init__(self, writers: list[SceneWriter]):
        self.writers = list(writers)

    @property
    def names(self) -> list[str]:
        return [w.name for w in self.writers]

    def start(self) -> None:
        for w in self.writers:
            w.start()

    def add_scene(self, scene_dir: Path, scene: dict) -> None:
        for w in self.writers:
            w.add_scene(scene_dir, scene)

    def catch_up(self, scene_dir: Path, scene: dict) -> list[str]:
        """Add a complete scene to every writer that does not hold it yet; returns their names."""
        added = []
        for w in self.writers:
            if not w.has_scene(scene_dir, scene):
                w.add_scene(scene_dir, scene)
                added.append(w.name)
        return added

    def finish(self) -> dict:
        return {w.name: w.finish() for w in self.writers}


def open_writers(output, out_dir: str | Path, *, batch: bool = False, sensor: str | None = None) -> Writers:
    """The writers `output` (OutputConfig or its dict) asks for, writing into `out_dir`; `sensor`:
    the scanner's BOP sensor name (io/bop_sensor.sensor_for_config; None: "sl").

    batch=True: a whole finished run is written at once (a merge): files that the per-scene mode
    re-writes after every scene are written once, at finish()."""
    from .legacy import LegacyPickleWriter
    from .native import NativeWriter

    out = Path(out_dir)
    writers: list[SceneWriter] = [NativeWriter(out)]
    if _output_value(output, "legacy_pickle", True):
        writers.append(LegacyPickleWriter(out, batch=batch))
    if "bop" in _output_value(output, "formats", ["native"]):
        from .bop import BopWriter
        from .bop_sensor import CUSTOM_RIG
        writers.append(BopWriter(out / layout.BOP_DIR, sensor=sensor or CUSTOM_RIG,
                                 xyz_crop=bool(_output_value(output, "xyz_crop", False)),
                                 amodal_coco=bool(_output_value(output, "amodal_coco", False))))
    return Writers(writers)
