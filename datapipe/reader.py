"""Reading a run folder back (the public `datapipe.api.read_run`): run.json, every complete scene's
scene.json, and each render's files as numpy arrays in the project's conventions (docs/CONVENTIONS.md:
metres, OpenCV camera frame, planar depth with NaN where there is no data). No bpy.

    run = read_run("out/demo")
    run.status, run.config, run.stats            # run.json
    for r in run.renders:                        # every render of every complete scene, in order
        r.K, r.T_world_cam, r.objects            # scene.json (poses as 4x4 arrays, visib_fract, ...)
        r.rgb, r.depth, r.sl_depth, r.mask       # read from the files on each access (None: not written)

Image arrays are read on access and not kept, so walking a large run holds one render at a time.
"""
from __future__ import annotations

import errno
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from .config import Config
from .errors import DataPipeError, OutputStateError
from .io.exr import read_depth, read_exr, read_mask, read_normals, read_object_coords
from .io import layout
from .io.files import read_json
from .io.input_files import MAX_JSON_BYTES, read_regular

# an object record's matrices in scene.json: given as numpy arrays
_OBJECT_MATRICES = ("T_cam_obj", "cam2obj_pose")


class _MapFile:
    """A Render attribute read from its file on each access: `reader(path)`, None when the run did not
    write that output (one class for the maps that need no more than their reader)."""

    def __init__(self, kind: str, reader, doc: str):
        self.kind, self.reader, self.__doc__ = kind, reader, doc

    def __get__(self, render, owner=None):
        if render is None:
            return self
        p = render._file(self.kind)
        return self.reader(p) if p is not None else None


@dataclass
class Render:
    """One render: its scene.json record and its files. Arrays are (H, W[, C]); None when the run did
    not write that output (e.g. `sl_depth` with structured light off)."""
    scene: str                     # "scene.0001"
    name: str                      # "render.0001"
    path: Path                     # the render folder
    record: dict                   # the render's scene.json record as stored (lists, not arrays)
    K: np.ndarray                  # (3, 3) camera intrinsics, pixel centres at integers
    resolution: tuple[int, int]    # (W, H)
    T_world_cam: np.ndarray        # (4, 4) camera pose in the world, OpenCV camera frame, m
    objects: list[dict]            # per visible-or-not part: name, obj_id, mask_index, T_cam_obj (4x4 array,
                                   # m), px_count_visib, visib_fract (BOP's), material ...
    files: dict[str, Path] = field(default_factory=dict)     # output kind -> file
    distortion: list | None = None  # OpenCV k1 k2 p1 p2 k3 of a distorting lens (docs/CALIBRATION.md), else None

    def _file(self, kind: str) -> Path | None:
        p = self.files.get(kind)
        return p if p is not None and p.is_file() else None

    def _png(self, kind: str, flags: int) -> np.ndarray | None:
        p = self._file(kind)
        if p is None:
            return None
        img = cv2.imread(str(p), flags)
        if img is None:
            raise OSError(errno.EIO, "not a readable PNG (truncated or corrupt; was the disk full?)", str(p))
        return img

    @property
    def rgb(self) -> np.ndarray | None:
        """(H, W, 3) uint8, RGB order (sRGB, as rgb.png holds it)."""
        img = self._png("rgb", cv2.IMREAD_COLOR)
        return None if img is None else np.ascontiguousarray(img[..., ::-1])

    @property
    def sl_valid(self) -> np.ndarray | None:
        """(H, W) bool: the scanner has depth there (sl_valid.png == 255)."""
        img = self._png("sl_valid", cv2.IMREAD_GRAYSCALE)
        return None if img is None else img == 255

    depth = _MapFile("depth", read_depth,
                     "(H, W) float32 z-buffer depth: planar, along the camera z axis, m; NaN where no surface.")
    sl_depth = _MapFile("sl_depth", read_depth,
                        "(H, W) float32 structured-light (scanner) depth, m; NaN where the scanner gives no data.")
    sl_debug = _MapFile("sl_debug", read_exr,
                        "The decoder's channels (`structured_light.debug`): confidence, reason, phase, sigma_z, ...")
    mask = _MapFile("mask", read_mask, "(H, W) int32 instance mask: an object's `mask_index`, 0 = background.")
    normals = _MapFile("normals", read_normals, "(H, W, 3) float32 unit normals in the OpenCV camera frame.")
    object_coords = _MapFile("object_coords", read_object_coords,     # X, Y, Z channels, or R, G, B
                             "(H, W, 3) float32 model coordinates (m) of the part at each pixel; NaN off parts.")


@dataclass
class Scene:
    """One complete scene: its scene.json (simulation record, drawn bin/lighting, parts) and renders."""
    name: str
    path: Path
    record: dict
    renders: list[Render]


@dataclass
class Run:
    """A run folder: run.json and its complete scenes (a running or cancelled run has fewer)."""
    path: Path
    record: dict                   # run.json as stored
    scenes: list[Scene]
    skipped: list[tuple[Path, str]] = field(default_factory=list)   # read_run(skip_damaged=True): the
                                   # damaged scene.json files left out, each with the reason

    @property
    def status(self) -> str:
        """"complete", "running" (or killed), "cancelled" or "failed"."""
        return str(self.record.get("status", "unknown"))

    @property
    def seed(self) -> int | None:
        return self.record.get("seed")

    @property
    def stats(self) -> dict:
        """run.json's stats: seconds per stage, simulation frames, physics, visib_fract summary."""
        return self.record.get("stats") or {}

    @property
    def warnings(self) -> list[dict]:
        """The quality gates' warnings: [{"render": "scene.0001/render.0001", "warning": ...}]."""
        return list(self.record.get("warnings") or [])

    @property
    def config(self):
        """The Config the run was made with (run.json's `config`, parsed again)."""
        return Config.from_dict(self.record["config"])

    @property
    def renders(self) -> list[Render]:
        """Every render of every complete scene, in order."""
        return [r for s in self.scenes for r in s.renders]

    @property
    def models_info(self) -> dict[int, dict]:
        """models/models_info.json (BOP conventions, mm): obj_id -> diameter, extents, symmetries."""
        p = self.path / layout.MODELS_DIR / layout.MODELS_INFO
        return {int(k): v for k, v in read_json(p).items()} if p.is_file() else {}

    def model_file(self, obj_id: int) -> Path:
        """The part's mesh as the run wrote it: models/obj_XXXXXX.ply, in mm (BOP)."""
        from .io.models import model_filename
        return self.path / layout.MODELS_DIR / model_filename(obj_id)


def read_run(path: str | os.PathLike, *, skip_damaged: bool = False) -> Run:
    """The run in folder `path` (a finished one, or what a running / stopped one has completed).

    A scene folder without scene.json (or whose scene.json does not say `"complete": true`) is a scene
    not finished yet and is not in the result. A scene.json that is there but not a DataPipe record
    (cut short, a JSON list, a folder or a FIFO in its place, renders without their fields) is never
    left out silently: OutputStateError naming the file, or with `skip_damaged=True` the scene is left
    out and listed in `Run.skipped` as (path, reason).

    Raises DataPipeError when `path` is not a DataPipe run folder, OutputStateError when its run.json
    or a scene.json is not a DataPipe record."""
    out = Path(path)
    if not out.is_dir():
        raise DataPipeError(f"run: {out} is not a folder (fix: give the output folder of a DataPipe run, "
                            "the --out of `python -m datapipe run`)")
    run_file = out / layout.RUN_FILE
    if not run_file.is_file():
        raise DataPipeError(f"run: {out} has no {layout.RUN_FILE}: not a DataPipe run folder (fix: give the "
                            "output folder of a DataPipe run)")
    from .io.outdir import read_record
    record = read_record(run_file, "run record")
    scenes, skipped = [], []
    for sdir in layout.scene_dirs(out):
        try:
            scene = _scene_record(sdir)
            if scene is not None:
                scenes.append(Scene(sdir.name, sdir, scene, [_render(sdir, scene, rd) for rd in _renders(sdir, scene)]))
        except OutputStateError as e:
            if not skip_damaged:
                raise
            skipped.append((sdir / layout.SCENE_FILE, str(e)))
    return Run(out, record, scenes, skipped)


def _scene_record(sdir: Path) -> dict | None:
    """A complete scene's scene.json; None for a scene not finished (no scene.json, or not complete);
    OutputStateError for one that is there but not a DataPipe record."""
    p = sdir / layout.SCENE_FILE
    if not os.path.lexists(p):
        return None
    fix = ("(fix: restore the file from a backup, or make the scene again: `python -m datapipe run PRESET --out "
           "DIR --resume` after moving the scene folder away; read_run(path, skip_damaged=True) reads the rest)")
    try:
        data = json.loads(read_regular(p, MAX_JSON_BYTES).decode("utf-8"))
    except DataPipeError as e:           # a folder, a FIFO, a device in its place; unreadable
        raise OutputStateError(f"{p}: not a DataPipe scene.json: {e} {fix}") from None
    except (ValueError, RecursionError) as e:          # cut short, not UTF-8, nested without end
        raise OutputStateError(f"{p}: not a DataPipe scene.json: not valid JSON ({type(e).__name__}: "
                               f"{str(e)[:80]}) {fix}") from None
    if not isinstance(data, dict):
        raise OutputStateError(f"{p}: not a DataPipe scene.json: a JSON {type(data).__name__}, not an object {fix}")
    return data if data.get("complete", False) else None


def _renders(sdir: Path, scene: dict) -> list[dict]:
    renders = scene.get("renders")
    if not isinstance(renders, list) or not all(isinstance(rd, dict) and isinstance(rd.get("name"), str)
                                                and all(k in rd for k in ("K", "resolution", "T_world_cam"))
                                                for rd in renders):
        raise OutputStateError(f"{sdir / layout.SCENE_FILE}: not a DataPipe scene.json (its renders lack name, "
                               "K, resolution or T_world_cam) (fix: give the folder of a DataPipe run, or move "
                               "the foreign file away)")
    return renders


def _render(sdir: Path, scene: dict, rd: dict) -> Render:
    objects = []
    if not (isinstance(rd.get("objects", []), list) and all(isinstance(o, dict) for o in rd.get("objects", []))):
        raise OutputStateError(f"{sdir / layout.SCENE_FILE}: not a DataPipe scene.json: render {rd['name']!r}'s "
                               "objects are not a list of records (fix: restore the file, or move the scene folder away)")
    try:
        for o in rd.get("objects", []):
            o = dict(o)
            for k in _OBJECT_MATRICES:
                if k in o:
                    o[k] = np.asarray(o[k], dtype=np.float64)
            objects.append(o)
        files = {kind: layout.render_file(sdir, rd, kind) for kind in layout.RENDER_FILES}
        W, H = (int(v) for v in rd["resolution"])
        K, T = np.asarray(rd["K"], dtype=np.float64), np.asarray(rd["T_world_cam"], dtype=np.float64)
    except (TypeError, ValueError, AttributeError) as e:
        raise OutputStateError(f"{sdir / layout.SCENE_FILE}: not a DataPipe scene.json: render {rd['name']!r} has "
                               f"a malformed field ({e}) (fix: restore the file, or move the scene folder away)") from None
    return Render(scene=sdir.name, name=rd["name"], path=sdir / rd["name"], record=rd, K=K, resolution=(W, H),
                  T_world_cam=T, objects=objects, files=files,
                  distortion=rd.get("distortion"))
