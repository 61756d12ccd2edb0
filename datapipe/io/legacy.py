"""The original DataPipe's output_dict.pickle (layout in docs/ARCHITECTURE.md), plus the OpenCV-frame T_cam_obj:

    {'scene.0001': {'render.0001': {'wrld2cam_pose': 4x4, 'objects_in_scene': [{'name', 'filename',
     'mask_index', 'cam2obj_pose': 4x4 (Blender camera frame), 'T_cam_obj': 4x4 (OpenCV)}]}}}

Re-written atomically after every scene, as the original did."""
from __future__ import annotations

import io
import pickle
from pathlib import Path

import numpy as np

from ..errors import OutputStateError
from . import layout
from .files import write_bytes_atomic


def legacy_scene_entry(scene: dict) -> dict:
    """One scene of the original's output_dict layout, plus T_cam_obj (OpenCV)."""
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


def legacy_bytes(data: dict) -> bytes:
    """The pickle of `data`, scenes in name order, as a function of the values alone: without the memo
    (`Pickler.fast`) the bytes do not depend on which objects happen to be shared (a scene entry
    built in memory shares its name strings, one loaded from the file or scene.json does not), so a
    resumed run writes the same bytes as an uninterrupted one."""
    buf = io.BytesIO()
    pickler = pickle.Pickler(buf, protocol=4)
    pickler.fast = True
    pickler.dump(dict(sorted(data.items())))
    return buf.getvalue()


def write_legacy_output(path: Path, data: dict) -> None:
    write_bytes_atomic(path, legacy_bytes(data))


def load_legacy_output(path: Path) -> dict:
    """Our own output_dict.pickle: dicts, lists, strings, numbers and numpy float arrays only."""
    with open(path, "rb") as f:
        return _OutputUnpickler(f).load()


class _OutputUnpickler(pickle.Unpickler):
    _ALLOWED = {("numpy.core.multiarray", "_reconstruct"), ("numpy", "ndarray"), ("numpy", "dtype"),
                ("numpy._core.multiarray", "_reconstruct"), ("numpy.core.multiarray", "scalar")}

    def find_class(self, module, name):
        if (module, name) in self._ALLOWED:
            return super().find_class(module, name)
        raise pickle.UnpicklingError(f"output_dict.pickle holds an unexpected {module}.{name}; refusing to load it")


class LegacyPickleWriter:
    """output_dict.pickle. Per scene (a run: re-written after every scene, so a crash loses at most the
    scene in progress) or, with batch=True, once at finish() from scratch (a merge of finished shards)."""

    name = "legacy_pickle"

    def __init__(self, out_dir: str | Path, *, batch: bool = False):
        self.path = Path(out_dir) / layout.LEGACY_PICKLE
        self.batch = batch
        self._data: dict | None = None

    def start(self) -> None:
        self._data = {} if self.batch or not self.path.is_file() else self._load_own()

    def _load_own(self) -> dict:
        """The pickle an earlier call of this run wrote (resume), or a refusal naming it."""
        try:
            data = load_legacy_output(self.path)
        except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError, IndexError,
                KeyError, ImportError, RecursionError, MemoryError) as e:
            data = e
        if not isinstance(data, dict):
            why = f"{type(data).__name__}: {data}" if isinstance(data, BaseException) else "not a dict"
            raise OutputStateError(f"output: {self.path} is not the {layout.LEGACY_PICKLE} a DataPipe run writes "
                                   f"({why}); it is not loaded (fix: move it out of the folder, then --resume writes it "
                                   "again from the scenes' scene.json)")
        return data

    def has_scene(self, scene_dir: Path, scene: dict) -> bool:
        if self._data is None:
            self.start()
        return scene["name"] in self._data

    def add_scene(self, scene_dir: Path, scene: dict) -> None:
        if self._data is None:
            self.start()
        self._data[scene["name"]] = legacy_scene_entry(scene)
        if not self.batch:
            write_legacy_output(self.path, self._data)

    def finish(self) -> dict:
        if self.batch and self._data is not None:
            write_legacy_output(self.path, self._data)
        return {}
