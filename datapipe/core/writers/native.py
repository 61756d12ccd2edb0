"""Native output: per-scene JSON annotations, run.json, and the original's output_dict.pickle.

Pure data (no bpy). Every file is written to a temporary name and renamed, so a crash leaves either
the old or the new file, never half of one: a killed run loses at most the scene in progress.
"""
from __future__ import annotations

import json
import os
import pickle
from pathlib import Path
from typing import Any

import numpy as np

RUN_FILE = "run.json"
SCENE_FILE = "scene.json"
LEGACY_PICKLE = "output_dict.pickle"


def config_identity(cfg_dict: dict) -> dict:
    """What makes two runs the same dataset: the whole config except the output folder (JSON-normalised)."""
    d = json.loads(json.dumps(cfg_dict))
    d["output"] = {k: v for k, v in d.get("output", {}).items() if k != "path"}
    return d


def scene_name(scene_id: int) -> str:
    return f"scene.{scene_id + 1:04d}"


def render_name(render_id: int) -> str:
    return f"render.{render_id + 1:04d}"


def _plain(obj: Any):
    """numpy -> lists/floats so json can write it."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def write_json_atomic(path: str | os.PathLike, data: Any) -> None:
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=1, default=_plain) + "\n")
    os.replace(tmp, path)


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


def read_json(path: str | os.PathLike) -> Any:
    return json.loads(Path(path).read_text())


def scene_complete(scene_dir: Path) -> bool:
    f = scene_dir / SCENE_FILE
    if not f.is_file():
        return False
    try:
        return bool(read_json(f).get("complete"))
    except (json.JSONDecodeError, OSError):
        return False


def write_scene(scene_dir: Path, scene: dict) -> None:
    write_json_atomic(scene_dir / SCENE_FILE, scene)


def legacy_scene_entry(scene: dict) -> dict:
    """One scene of the original's output_dict layout (design.md), plus T_cam_obj (OpenCV)."""
    entry = {}
    for r in scene["renders"]:
        entry[r["name"]] = {
            "wrld2cam_pose": np.asarray(r["T_world_blcam"], dtype=np.float64),
            "objects_in_scene": [
                {"name": o["name"], "filename": o["filename"], "mask_index": o["mask_index"],
                 "cam2obj_pose": np.asarray(o["cam2obj_pose"], dtype=np.float64),
                 "T_cam_obj": np.asarray(o["T_cam_obj"], dtype=np.float64)}
                for o in r["objects"]],
        }
    return entry


def update_legacy_pickle(out_dir: Path, scene: dict) -> None:
    """Add one scene to output_dict.pickle (re-written atomically, as the original did per scene)."""
    path = out_dir / LEGACY_PICKLE
    data = load_legacy_output(path) if path.is_file() else {}
    data[scene["name"]] = legacy_scene_entry(scene)
    data = dict(sorted(data.items()))
    write_bytes_atomic(path, pickle.dumps(data, protocol=4))


def load_legacy_output(path: Path) -> dict:
    """Our own output_dict.pickle: dicts, lists, strings, numbers and numpy float arrays only."""
    return _OutputUnpickler(open(path, "rb")).load()


class _OutputUnpickler(pickle.Unpickler):
    _ALLOWED = {("numpy.core.multiarray", "_reconstruct"), ("numpy", "ndarray"), ("numpy", "dtype"),
                ("numpy._core.multiarray", "_reconstruct"), ("numpy.core.multiarray", "scalar")}

    def find_class(self, module, name):
        if (module, name) in self._ALLOWED:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"output_dict.pickle holds an unexpected {module}.{name}; refusing to load it")
