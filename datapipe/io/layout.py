"""The native output layout (docs/ARCHITECTURE.md): every file and folder name of a run, spelled once.

    OUT/run.json  OUT/output_dict.pickle  OUT/models/  OUT/bop/  OUT/sheets/
    OUT/scene.0001/scene.json
    OUT/scene.0001/render.0001/rgb.png depth.exr normals.exr mask.exr sl_depth.exr sl_valid.png sl_debug.exr
                                    [sl_gray.png point_cloud.ply]

A scene is complete when its scene.json exists and says `"complete": true` (scene.json is written
last, atomically). Everything that reads runs (show, BOP export, Ray merge, resume) asks here.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Iterator

RUN_FILE = "run.json"
SCENE_FILE = "scene.json"
LEGACY_PICKLE = "output_dict.pickle"
MODELS_DIR = "models"
MODELS_INFO = "models_info.json"
BOP_DIR = "bop"
SHEETS_DIR = "sheets"
BLENDER_LOG = "blender.log"          # Blender's own output (datapipe.engine.blender_log)
OVERVIEW_FILE = "overview.png"
GRID_FILE = "grid.png"              # `show --grid N`: N random renders on one sheet
SCENE_PREFIX = "scene."
RENDER_PREFIX = "render."

# render output kind -> file name inside the render folder
RENDER_FILES = {
    "rgb": "rgb.png",
    "depth": "depth.exr",
    "normals": "normals.exr",
    "mask": "mask.exr",
    "object_coords": "object_coords.exr",
    "sl_depth": "sl_depth.exr",
    "sl_valid": "sl_valid.png",
    "sl_debug": "sl_debug.exr",
    "sl_gray": "sl_gray.png",            # the scanner's grey image (only when render.outputs lists it)
    "point_cloud": "point_cloud.ply",    # its organised point cloud (io/point_cloud.py; only when listed)
}


def scene_name(scene_id: int) -> str:
    """Folder of scene `scene_id` (0-based): scene.0001, ... (the original's names)."""
    return f"{SCENE_PREFIX}{scene_id + 1:04d}"


def render_name(render_id: int) -> str:
    return f"{RENDER_PREFIX}{render_id + 1:04d}"


def render_file(scene_dir: str | os.PathLike, render: dict, kind: str) -> Path:
    """Path of output `kind` of one render record of scene.json: its `files` entry (relative to the
    scene folder), else the layout's default name in the render folder."""
    scene_dir = Path(scene_dir)
    rel = render.get("files", {}).get(kind)
    return scene_dir / rel if rel else scene_dir / render["name"] / RENDER_FILES[kind]


def read_scene(scene_dir: str | os.PathLike) -> dict | None:
    """scene.json of a scene folder; None when it is missing or unreadable (a scene killed mid-way).
    Read only as a regular file (io/input_files.py): a FIFO in its place is not waited on."""
    from ..errors import DataPipeError
    from .input_files import MAX_JSON_BYTES, read_regular
    try:
        scene = json.loads(read_regular(Path(scene_dir) / SCENE_FILE, MAX_JSON_BYTES).decode("utf-8"))
    except (DataPipeError, ValueError, RecursionError):      # JSONDecodeError and UnicodeDecodeError are ValueErrors
        return None
    return scene if isinstance(scene, dict) else None      # a foreign file: not a scene of ours


def scene_complete(scene_dir: str | os.PathLike) -> bool:
    scene = read_scene(scene_dir)
    return bool(scene is not None and scene.get("complete", False))


def scene_dirs(run_dir: str | os.PathLike) -> list[Path]:
    """Every scene folder of a run (complete or not), in order."""
    return sorted(p for p in Path(run_dir).glob(SCENE_PREFIX + "*") if p.is_dir())


def iter_scenes(run_dir: str | os.PathLike) -> Iterator[tuple[Path, dict]]:
    """(scene folder, scene.json) of every complete scene of a run, in order."""
    for p in scene_dirs(run_dir):
        scene = read_scene(p)
        if scene is not None and scene.get("complete", False):
            yield p, scene


def config_identity(cfg_dict: dict) -> dict:
    """What makes two runs the same dataset: the whole config except the output folder (JSON-normalised)."""
    d = json.loads(json.dumps(cfg_dict))
    d["output"] = {k: v for k, v in d.get("output", {}).items() if k != "path"}
    return d
