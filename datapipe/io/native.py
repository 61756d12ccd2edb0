"""The native annotations: one scene.json per scene (docs/ARCHITECTURE.md), written last and atomically
so that its existence with `"complete": true` means the scene is complete."""
from __future__ import annotations

from pathlib import Path

from . import layout
from .files import write_json_atomic


def write_scene(scene_dir: Path, scene: dict) -> None:
    write_json_atomic(Path(scene_dir) / layout.SCENE_FILE, scene)


class NativeWriter:
    """scene.json of each finished scene (the run's own record: always written, whatever the formats)."""

    name = "native"

    def __init__(self, out_dir: str | Path):
        self.out = Path(out_dir)

    def start(self) -> None:
        pass

    def has_scene(self, scene_dir: Path, scene: dict) -> bool:
        return layout.scene_complete(scene_dir)

    def add_scene(self, scene_dir: Path, scene: dict) -> None:
        write_scene(scene_dir, scene)

    def finish(self) -> dict:
        return {}


def write_render_maps(render_dir: Path, maps: dict) -> dict[str, Path]:
    """Write one render's output maps into its folder under the layout's names, in the order given:
    {kind: {channel: (H, W) array}} as EXR, {kind: uint8 image (BGR or grey)} as PNG. Returns
    {kind: path}."""
    from ..exr import write_exr
    from .files import imwrite_atomic

    render_dir = Path(render_dir)
    files = {}
    for kind, data in maps.items():
        path = render_dir / layout.RENDER_FILES[kind]
        if path.suffix == ".exr":
            write_exr(path, data)
        else:
            imwrite_atomic(path, data)
        files[kind] = path
    return files
