"""BOP export (https://github.com/thodan/bop_toolkit/blob/master/docs/bop_datasets_format.md). No bpy.

Pure numpy / scipy / cv2 / json: reads the native output layout (docs/ARCHITECTURE.md) and writes
the BOP-scenewise layout BlenderProc's `write_bop` users know:

    BOP_ROOT/
      camera.json                    {cx, cy, fx, fy, width, height, depth_scale}
      models/obj_000001.ply          x y z nx ny nz (mm) + faces;  models_info.json (mm, symmetries)
      models_eval/obj_000001.ply     the models resampled for BOP's evaluation (io/models_eval.py),
                                     models_info.json measured on them
      train_pbr/000000/              chunk = image_id // chunk_size, im_id = image_id % chunk_size
        rgb/000000.jpg               the native rgb.png as JPEG (quality 95; rgb_format="png": a copy)
        depth/000000.png             z-buffer depth, uint16, depth_mm = value * depth_scale, 0 = no data
        depth_sl/000000.png          structured-light depth, same encoding (when the run has it)
        mask/000000_000001.png       full (unoccluded) silhouette of annotation 1, 0/255
        mask_visib/000000_000001.png visible part of annotation 1 (native mask.exr == mask_index)
        object_coords/000000.exr     model x, y, z in mm in channels R, G, B (OpenCV reads 3 channels),
                                     NaN off parts (when rendered)
        gray_S/ depth_S/ mask_S/ mask_visib_S/ scene_camera_S.json scene_gt_S.json scene_gt_info_S.json
                                     the structured-light scanner as BOP-Industrial sensor S
                                     (io/bop_sensor.py; renders with structured light; `_write_sensor`)
        scene_camera.json  scene_gt.json  scene_gt_info.json
        scene_gt_coco.json           COCO instances (bop_toolkit's calc_gt_coco: RLE of mask_visib,
                                     amodal bbox, "ignore" when visib_fract < 0.1)
        datapipe.json                im_id -> native scene/render names and the global image_id

Masks are named IMID_GTID with GTID the index of the annotation in the image's scene_gt list.

Full silhouettes: the renders give only the visible mask, so `mask/` is rasterised here from the
model (models/obj_*.ply, the mesh Blender rendered, scale baked) posed with cam_K and T_cam_obj: a
pixel belongs to the silhouette when its centre (integer coordinates) lies inside a projected
triangle. Like bop_toolkit's calc_gt_info (which renders on a 3x canvas) the count `px_count_all`
and `bbox_obj` include the part of the silhouette cut off by the image border (up to one image size
beyond each side). The visible mask is added to the silhouette so that visib_fract <= 1 even where
the rasteriser and the renderer disagree on an edge pixel. Triangles with a vertex closer than
1 mm to the camera plane are skipped (bin-picking parts are always well in front of the camera).

Statistics follow bop_toolkit's calc_gt_info, except that the visible mask is the renderer's exact
instance mask instead of a depth test with a tolerance: px_count_visib = pixels of mask_visib,
px_count_valid = silhouette pixels (in the image) with valid ground-truth depth, visib_fract =
px_count_visib / px_count_all, bboxes as (x, y, w, h) with w = x_max - x_min (bop_toolkit's
calc_2d_bbox), and both bboxes [-1, -1, -1, -1] when nothing is visible.
"""
from __future__ import annotations

import datetime
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping

import cv2
import numpy as np

from ..errors import DataPipeError
from .exr import COORDS_CHANNELS, read_depth, read_mask, read_object_coords, write_exr
from . import layout
from . import guard
from .files import (copy_atomic, imwrite_atomic, make_dirs, own_file, own_file_present, read_json, read_json_or_empty,
                    read_own_json_or_empty, write_json_lines_atomic)
from .models import (Model, copy_models, load_listed_models, model_filename, model_info, read_ply, write_models,
                     write_ply)
from .models_eval import SPACING_MM, resample_for_eval, vertex_normals
from .bop_sensor import CUSTOM_RIG, check_sensor_name, sensor_for_config
from .bop_format import encode_depth, gt_info, mask_to_rle
from .silhouette import mask_bbox, rasterize_silhouette
from .amodal import AMODAL_COCO_FILE, amodal_annotation
from .xyz_crop import rasterize_xyz, write_xyz_crop, xyz_crop_info, xyz_file

SPLIT = "train_pbr"
RGB_FORMATS = ("jpg", "png")
RGB_FORMAT = "jpg"           # the official train_pbr splits (and bop_toolkit's dataset_params for them)
JPG_QUALITY = 95             # bop_toolkit's inout.save_im default, BlenderProc's write_bop default
MODELS_EVAL_DIR = "models_eval"
OBJECT_COORDS_DIR = "object_coords"


# ------------------------------------------------------------------------------------------------
# helpers

def _mat(x, shape) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.shape != shape:
        raise DataPipeError(f"expected a {shape} matrix in scene.json, got shape {a.shape}")
    return a


# ------------------------------------------------------------------------------------------------
# the writer

CHUNK_FILES = ("scene_camera", "scene_gt", "scene_gt_info", "datapipe")
DISTORTION_KEY = "cam_dist"   # scene_camera: OpenCV k1 k2 p1 p2 k3 of a distorting lens (not BOP's; readers skip it)
SENSOR_FILES = ("scene_camera", "scene_gt", "scene_gt_info")    # NAME_{sensor}.json of the scanner
COCO_VISIB_MIN = 0.1      # bop_toolkit's calc_gt_coco: annotations less visible than this are "ignore"


@dataclass
class _ImageEntry:
    """What one native render adds to its chunk's JSON files."""
    image_id: int
    chunk: int
    im_id: int
    camera: dict
    gts: list
    infos: list
    meta: dict
    coco: dict
    sensor: dict | None = None     # {"scene_camera": ..., "scene_gt": ..., "scene_gt_info": ...} of the scanner
    coco_amodal: dict | None = None       # output.amodal_coco (io/amodal.py)


class BopWriter:
    """Add native scenes one at a time to a BOP dataset; safe to call after every scene.

    Images are written first, then each touched chunk's JSON files are re-written atomically (write
    a temporary file, rename), so a crash loses nothing written before, and re-adding a scene (a
    resumed run) overwrites its own entries. One writer per BOP folder at a time. It is also the
    run's "bop" writer (datapipe.io.writers): start / has_scene / add_scene / finish."""

    name = "bop"

    def __init__(self, bop_root: str | os.PathLike, *, depth_scale: float = 0.1, chunk_size: int = 1000,
                 split: str = SPLIT, models_dir: str | os.PathLike | None = None, rgb_format: str = RGB_FORMAT,
                 jpg_quality: int = JPG_QUALITY, eval_spacing_mm: float = SPACING_MM, sensor: str = CUSTOM_RIG,
                 xyz_crop: bool = False, amodal_coco: bool = False):
        check_options(depth_scale=depth_scale, chunk_size=chunk_size, split=split, rgb_format=rgb_format,
                      jpg_quality=jpg_quality)
        self.sensor = check_sensor_name(sensor, "sensor")
        if not (eval_spacing_mm > 0):
            raise DataPipeError(f"eval_spacing_mm must be > 0 mm, got {eval_spacing_mm}")
        self.rgb_format = rgb_format
        self.xyz_crop = bool(xyz_crop)            # GDRNPP's SPLIT/xyz_crop/ pickles (io/xyz_crop.py)
        self.amodal_coco = bool(amodal_coco)      # UOAIS' scene_gt_coco_amodal.json (io/amodal.py)
        self.jpg_quality = int(jpg_quality)
        self.eval_spacing_mm = float(eval_spacing_mm)
        self.root = Path(bop_root)
        self.depth_scale = float(depth_scale)
        self.chunk_size = int(chunk_size)
        self.split = split
        make_dirs(self.root)
        self._models: dict[int, Model] | None = None
        self._chunks: dict[int, dict[str, dict]] = {}    # chunks in memory: the last scene's (see add_scene)
        self._chunks_touched: set[int] = set()
        self._camera_written = (self.root / "camera.json").is_file()
        self.images_written = 0
        if models_dir is not None:
            self.set_models(models_dir)

    def start(self) -> None:
        pass

    # -- models -----------------------------------------------------------------------------------
    @property
    def models_dir(self) -> Path:
        return self.root / layout.MODELS_DIR

    def set_models(self, source: str | os.PathLike | Mapping[int, tuple]) -> None:
        """Copy a native models/ folder (obj_*.ply + models_info.json), or write {obj_id: mesh};
        then write models_eval/ from them."""
        if isinstance(source, Mapping):
            write_models(self.models_dir, source)
        else:
            copy_models(source, self.models_dir)
        self._models = None
        self._write_models_eval()

    def _write_models_eval(self) -> None:
        """models_eval/: every model resampled (io/models_eval.py) and its own models_info.json,
        measured on the resampled meshes as written (bop_toolkit's calc_model_info on models_eval/
        gives the same numbers); symmetries are the models/ entries' (the same object)."""
        out = self.root / MODELS_EVAL_DIR
        make_dirs(out)
        with own_file(self.models_dir / layout.MODELS_INFO) as p:
            base = read_json(p)
        info = {}
        for obj_id, m in self.models().items():
            v, f = resample_for_eval(m.verts_mm, m.faces, self.eval_spacing_mm)
            path = out / model_filename(obj_id)
            write_ply(path, v, f, vertex_normals(v, f))
            written, _ = read_ply(path)                 # the file's own (float32) coordinates
            sym = {k: val for k, val in base.get(str(obj_id), {}).items() if k.startswith("symmetries_")}
            info[str(obj_id)] = {**model_info(written), **sym}
        write_json_lines_atomic(out / layout.MODELS_INFO, info)

    def models(self) -> dict[int, Model]:
        if self._models is None:
            self._models = load_listed_models(self.models_dir)
        return self._models

    # -- chunks -----------------------------------------------------------------------------------
    def chunk_dir(self, chunk: int) -> Path:
        return self.root / self.split / f"{chunk:06d}"

    def _chunk(self, chunk: int) -> dict[str, dict]:
        if chunk not in self._chunks:
            d = self.chunk_dir(chunk)
            # the run's own files read back (read_own_json_or_empty: never another file as the run's)
            data = {name: read_own_json_or_empty(d / f"{name}.json") for name in CHUNK_FILES}
            for name in SENSOR_FILES:
                data[f"{name}_"] = read_own_json_or_empty(d / f"{name}_{self.sensor}.json")
            coco = read_own_json_or_empty(d / "scene_gt_coco.json")
            data["coco"] = _coco_per_image(coco)
            if self.amodal_coco:
                data["coco_amodal"] = _coco_per_image(read_own_json_or_empty(d / AMODAL_COCO_FILE))
            data["created"] = coco.get("info", {}).get("date_created")      # kept when the chunk grows
            self._chunks[chunk] = data
        return self._chunks[chunk]

    def _coco(self, data: dict, which: str = "coco") -> dict:
        """scene_gt_coco.json of a chunk (bop_toolkit's calc_gt_coco layout, amodal boxes, RLE masks),
        or (which="coco_amodal") its amodal sibling."""
        obj_ids = sorted(self.models()) or sorted({a["category_id"] for e in data[which].values()
                                                   for a in e["annotations"]})
        images, anns = [], []
        for key in sorted(data[which], key=int):
            e = data[which][key]
            if e["image"] is not None:
                images.append(e["image"])
            for a in e["annotations"]:
                anns.append({"id": len(anns) + 1, **a})
        if not data.get("created"):
            data["created"] = datetime.datetime.now(datetime.timezone.utc).isoformat(" ")
        created = data["created"]
        return {"info": {"description": f"DataPipe {self.split}", "url": "", "version": "0.1.0",
                         "year": int(created[:4]), "contributor": "DataPipe", "date_created": created},
                "licenses": [],
                "categories": [{"id": i, "name": str(i), "supercategory": "datapipe"} for i in obj_ids],
                "images": images, "annotations": anns}

    def _flush(self, chunks: Iterable[int]) -> None:
        for c in sorted(set(chunks)):
            data = self._chunk(c)
            d = self.chunk_dir(c)
            # datapipe.json last: it names what the BOP files hold
            for name in ("scene_camera", "scene_gt", "scene_gt_info"):
                write_json_lines_atomic(d / f"{name}.json", data[name])
            for name in SENSOR_FILES:             # the scanner's (renders with structured light only)
                if data[f"{name}_"]:
                    write_json_lines_atomic(d / f"{name}_{self.sensor}.json", data[f"{name}_"])
            write_json_lines_atomic(d / "scene_gt_coco.json", self._coco(data), compact=True)
            if self.amodal_coco:
                write_json_lines_atomic(d / AMODAL_COCO_FILE, self._coco(data, "coco_amodal"), compact=True)
            write_json_lines_atomic(d / "datapipe.json", data["datapipe"])

    # -- scenes -----------------------------------------------------------------------------------
    def add_scene(self, native_scene_dir: str | os.PathLike, scene: dict | None = None) -> list[int]:
        """Convert one complete native scene (its scene.json, or `scene` when given) and return the
        global image ids added."""
        scene_dir = Path(native_scene_dir)
        scene = _complete_scene(scene_dir) if scene is None else scene
        # models_eval/'s models_info.json is the last file set_models writes: a run stopped (disk
        # full, kill) anywhere in models/ or models_eval/ makes them again on --resume
        if not (self.root / MODELS_EVAL_DIR / layout.MODELS_INFO).is_file():
            self.set_models(scene_dir.parent / layout.MODELS_DIR)
        models = self.models()
        entries = [self._convert_render(scene_dir, scene, rd, models) for rd in scene.get("renders", [])]
        for e in entries:
            c = self._chunk(e.chunk)
            key = str(e.im_id)
            c["coco"][key] = e.coco
            if e.coco_amodal is not None:
                c["coco_amodal"][key] = e.coco_amodal
            c["scene_camera"][key] = e.camera
            c["scene_gt"][key] = e.gts
            c["scene_gt_info"][key] = e.infos
            c["datapipe"][key] = e.meta
            for name in SENSOR_FILES:
                if e.sensor is not None:
                    c[f"{name}_"][key] = e.sensor[name]
                else:                          # a re-added render that lost its scan: no stale entry
                    c[f"{name}_"].pop(key, None)
        touched = {e.chunk for e in entries}
        self._flush(touched)
        self._chunks_touched |= touched
        # a long run would otherwise hold every chunk (RLE masks included) in memory; the next
        # scene's images fall in the same chunk or a new one, and a dropped chunk is re-read from disk
        self._chunks = {c: d for c, d in self._chunks.items() if c in touched}
        self.images_written += len(entries)
        return [e.image_id for e in entries]

    def has_scene(self, native_scene_dir: str | os.PathLike, scene: dict | None = None) -> bool:
        """True when every render of the scene is already in this BOP folder (e.g. before a resume)."""
        scene = layout.read_scene(native_scene_dir) if scene is None else scene
        if scene is None:
            return False
        for rd in scene.get("renders", []):
            chunk, im_id = divmod(int(rd["image_id"]), self.chunk_size)
            meta = self._chunk(chunk)["datapipe"].get(str(im_id))
            if not meta or meta.get("image_id") != int(rd["image_id"]):
                return False
        return bool(scene.get("renders"))

    def _convert_render(self, scene_dir: Path, scene: dict, rd: dict, models: dict[int, Model]) -> _ImageEntry:
        """One native render -> its image files in the chunk and its JSON entries."""
        image_id = int(rd["image_id"])
        chunk, im_id = divmod(image_id, self.chunk_size)
        cdir = self.chunk_dir(chunk)
        W, H = (int(x) for x in rd["resolution"])
        K = _mat(rd["K"], (3, 3))
        for sub in ("rgb", "depth", "mask", "mask_visib"):
            make_dirs(cdir / sub)
        stem = f"{im_id:06d}"
        rgb_name = f"rgb/{stem}.{self.rgb_format}"
        self._write_rgb(_required(scene_dir, rd, "rgb"), cdir / rgb_name)
        depth_valid = self._write_depth(_required(scene_dir, rd, "depth"), cdir / "depth" / f"{stem}.png", W, H)
        sl_src = layout.render_file(scene_dir, rd, "sl_depth")
        has_sl = own_file_present(sl_src)
        if has_sl:
            make_dirs(cdir / "depth_sl")
            with own_file(sl_src) as p:
                sl_depth = read_depth(p)
            imwrite_atomic(cdir / "depth_sl" / f"{stem}.png", encode_depth(sl_depth, self.depth_scale, what=str(sl_src)))
        with own_file(_required(scene_dir, rd, "mask")) as p:
            inst = read_mask(p)
        gts, infos, coco_anns, sils, amodal_anns = self._annotate_objects(scene_dir, rd, models, inst, depth_valid,
                                                                          K, cdir, stem)
        sensor = self._write_sensor(scene_dir, rd, sl_src, cdir, stem, gts, sils) if has_sl else None
        if not self._camera_written:
            write_json_lines_atomic(self.root / "camera.json", {
                "cx": float(K[0, 2]), "cy": float(K[1, 2]), "fx": float(K[0, 0]), "fy": float(K[1, 1]),
                "width": W, "height": H, "depth_scale": self.depth_scale})
            self._camera_written = True
        meta = {"image_id": image_id, "scene": scene_dir.name, "render": rd["name"],
                "scene_id": int(scene.get("scene_id", -1)), "render_seed": rd.get("seed"),
                "depth_sl": has_sl}
        if sensor is not None:
            meta["sensor"] = self.sensor
        coords = layout.render_file(scene_dir, rd, "object_coords")
        if own_file_present(coords):
            self._write_object_coords(coords, cdir / OBJECT_COORDS_DIR / f"{stem}.exr", W, H)
        coco = {"image": {"id": im_id, "file_name": rgb_name, "width": W, "height": H},
                "annotations": coco_anns}
        coco_amodal = None
        if self.amodal_coco:
            coco_amodal = {"image": {**coco["image"], "depth_file_name": f"depth/{stem}.png"},
                           "annotations": amodal_anns}
        return _ImageEntry(image_id, chunk, im_id, self._camera_entry(K, rd), gts, infos, meta, coco,
                           sensor=sensor, coco_amodal=coco_amodal)

    def _write_sensor(self, scene_dir: Path, rd: dict, sl_src: Path, cdir: Path, stem: str, gts: list,
                      sils: list) -> dict:
        """The scanner as a BOP-Industrial sensor (docs/DATASETS.md): depth_S/ (its decoded depth, 0
        where invalid), gray_S/ (its grey image, when the run wrote sl_gray), mask_S/ and
        mask_visib_S/; returns its scene_camera / scene_gt / scene_gt_info entries. The scanner's
        camera is the render camera (same K, pose and pixels), so poses and masks are the classic
        ones; px_count_valid counts the silhouette's pixels with a valid scanner depth, as
        bop_toolkit's calc_gt_info does on depth_S/."""
        W, H = (int(x) for x in rd["resolution"])
        S = self.sensor
        for sub in ("depth", "mask", "mask_visib"):
            make_dirs(cdir / f"{sub}_{S}")
        with own_file(sl_src) as p:
            sl = read_depth(p)
        if sl.shape != (H, W):
            raise DataPipeError(f"{sl_src}: shape {sl.shape} but scene.json says {W}x{H}")
        imwrite_atomic(cdir / f"depth_{S}" / f"{stem}.png", encode_depth(sl, self.depth_scale, what=str(sl_src)))
        sl_valid = np.isfinite(sl) & (sl > 0)
        gray = layout.render_file(scene_dir, rd, "sl_gray")
        if own_file_present(gray):
            make_dirs(cdir / f"gray_{S}")
            with own_file(gray) as p:
                copy_atomic(p, cdir / f"gray_{S}" / f"{stem}.png")
        infos = []
        for gt_id, (sil, count, bbox, visib) in enumerate(sils):
            infos.append(gt_info(sil, count, bbox, visib, sl_valid))
            name = f"{stem}_{gt_id:06d}.png"
            for sub in ("mask", "mask_visib"):
                with own_file(cdir / sub / name) as p:
                    copy_atomic(p, cdir / f"{sub}_{S}" / name)
        K = _mat(rd["K"], (3, 3))
        return {"scene_camera": self._camera_entry(K, rd), "scene_gt": gts, "scene_gt_info": infos}

    def _write_rgb(self, src: Path, dst: Path) -> None:
        """The native rgb.png as JPEG (at jpg_quality), or as it is for PNG when it is 8-bit
        3-channel (the pipeline's), else converted."""
        with own_file(src) as p:
            rgb = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
            if rgb is None:
                raise DataPipeError(f"{src}: not a readable image")
            if rgb.ndim == 3 and rgb.shape[2] == 3 and rgb.dtype == np.uint8 and self.rgb_format == "png":
                copy_atomic(p, dst)
                return
        if rgb.dtype == np.uint16:
            rgb = (rgb.astype(np.float32) / 257.0 + 0.5).astype(np.uint8)
        if rgb.ndim == 2:
            rgb = cv2.cvtColor(rgb, cv2.COLOR_GRAY2BGR)
        elif rgb.shape[2] == 4:
            rgb = rgb[:, :, :3]
        imwrite_atomic(dst, np.ascontiguousarray(rgb), [cv2.IMWRITE_JPEG_QUALITY, self.jpg_quality])

    @staticmethod
    def _write_object_coords(src: Path, dst: Path, W: int, H: int) -> None:
        """The native object_coords.exr (m) as BOP's object_coords/IMID.exr: model X, Y, Z in mm in
        channels R, G, B (COORDS_CHANNELS), the names OpenCV reads as one 3-channel image."""
        with own_file(src) as p:
            xyz = read_object_coords(p) * np.float32(1000.0)
        if xyz.shape[:2] != (H, W):
            raise DataPipeError(f"{src}: shape {xyz.shape[:2]} but scene.json says {W}x{H}")
        make_dirs(dst.parent)
        write_exr(dst, {c: xyz[..., i] for i, c in enumerate(COORDS_CHANNELS)})

    def _write_depth(self, src: Path, dst: Path, W: int, H: int) -> np.ndarray:
        """Ground-truth z-buffer depth as BOP's uint16 PNG; returns where it has data."""
        with own_file(src) as p:
            depth = read_depth(p)
        if depth.shape != (H, W):
            raise DataPipeError(f"{src}: shape {depth.shape} but scene.json says {W}x{H}")
        imwrite_atomic(dst, encode_depth(depth, self.depth_scale, what=str(src)))
        return np.isfinite(depth) & (depth > 0)

    def _annotate_objects(self, scene_dir: Path, rd: dict, models: dict[int, Model], inst: np.ndarray,
                          depth_valid: np.ndarray, K: np.ndarray, cdir: Path, stem: str):
        """scene_gt, scene_gt_info and COCO entries of one render's objects; writes their masks."""
        W, H = (int(x) for x in rd["resolution"])
        gts, infos, coco_anns, sils, amodal_anns = [], [], [], [], []
        for gt_id, o in enumerate(rd.get("objects", [])):
            obj_id = int(o["obj_id"])
            T = _mat(o["T_cam_obj"], (4, 4))
            R, t_mm = T[:3, :3], T[:3, 3] * 1000.0
            gts.append({"cam_R_m2c": [float(x) for x in R.reshape(-1)],
                        "cam_t_m2c": [float(x) for x in t_mm], "obj_id": obj_id})
            if obj_id not in models:
                raise DataPipeError(f"{scene_dir.name}/{rd['name']}: object id {obj_id} has no model "
                                    f"{model_filename(obj_id)} in {self.models_dir}")
            m = models[obj_id]
            sil, count, bbox = rasterize_silhouette(m.verts_mm, m.faces, K, R, t_mm, W, H, dist=rd.get("distortion"))
            visib = inst == int(o["mask_index"])
            infos.append(gt_info(sil, count, bbox, visib, depth_valid))
            if infos[-1]["px_count_visib"] > 0:
                b = mask_bbox(sil | visib)
                coco_anns.append({"image_id": int(rd["image_id"]) % self.chunk_size, "category_id": obj_id,
                                  "iscrowd": 0, "area": infos[-1]["px_count_visib"],
                                  "bbox": [b[0], b[1], b[2] + 1, b[3] + 1],
                                  "segmentation": mask_to_rle(visib), "width": W, "height": H,
                                  "ignore": bool(infos[-1]["visib_fract"] < COCO_VISIB_MIN)})
                if self.amodal_coco:
                    amodal_anns.append(amodal_annotation(coco_anns[-1]["image_id"], obj_id, sil, visib, infos[-1]))
            if self.xyz_crop:
                xyz, hit = rasterize_xyz(m.verts_mm, m.faces, K, R, t_mm, W, H, dist=rd.get("distortion"))
                write_xyz_crop(xyz_file(cdir.parent, int(cdir.name), int(stem), gt_id), xyz_crop_info(xyz, hit))
            name = f"{stem}_{gt_id:06d}.png"
            imwrite_atomic(cdir / "mask" / name, ((sil | visib).astype(np.uint8) * 255))
            imwrite_atomic(cdir / "mask_visib" / name, visib.astype(np.uint8) * 255)
            sils.append((sil, count, bbox, visib))
        return gts, infos, coco_anns, sils, amodal_anns

    def _camera_entry(self, K: np.ndarray, rd: dict) -> dict:
        T_cw = np.linalg.inv(_mat(rd["T_world_cam"], (4, 4)))
        entry = {"cam_K": [float(x) for x in K.reshape(-1)], "depth_scale": self.depth_scale,
                 "cam_R_w2c": [float(x) for x in T_cw[:3, :3].reshape(-1)],
                 "cam_t_w2c": [float(x) for x in T_cw[:3, 3] * 1000.0]}
        if rd.get("distortion") is not None:      # OpenCV k1 k2 p1 p2 k3 beside cam_K (docs/DATASETS.md)
            entry = {"cam_K": entry.pop("cam_K"), DISTORTION_KEY: [float(x) for x in rd["distortion"]], **entry}
        return entry

    def finish(self) -> dict:
        """Flush everything (every add_scene already did) and return a summary."""
        self._flush(self._chunks)
        return {"bop_root": str(self.root), "images": self.images_written, "sensor": self.sensor,
                "chunks": sorted(self._chunks_touched | set(self._chunks)), "depth_scale": self.depth_scale}


def _coco_per_image(coco: dict) -> dict:
    """{image id: {"image", "annotations" (without their ids)}} of a chunk's COCO file read back."""
    per_image = {str(im["id"]): {"image": im, "annotations": []} for im in coco.get("images", [])}
    for ann in coco.get("annotations", []):
        a = {k: v for k, v in ann.items() if k != "id"}
        per_image.setdefault(str(ann["image_id"]), {"image": None, "annotations": []})["annotations"].append(a)
    return per_image


def _complete_scene(scene_dir: Path) -> dict:
    if not (scene_dir / layout.SCENE_FILE).is_file():
        raise DataPipeError(f"{scene_dir}: no scene.json (the scene is not complete); finish or resume the run")
    scene = read_json(scene_dir / layout.SCENE_FILE)
    if not scene.get("complete", False):
        raise DataPipeError(f"{scene_dir}: scene.json says the scene is not complete (a cancelled run); "
                            "resume the run to finish it")
    return scene


def _required(scene_dir: Path, rd: dict, kind: str) -> Path:
    p = layout.render_file(scene_dir, rd, kind)
    # in a run's own folder own_file says what stands there instead (removed, a link, not the run's)
    if guard.active_for(p) is None and not p.is_file():
        raise DataPipeError(f"{p}: missing (BOP needs the {kind!r} output)")
    return p


# ------------------------------------------------------------------------------------------------
# whole runs

def check_options(*, depth_scale: float = 0.1, chunk_size: int = 1000, split: str = SPLIT,
                  rgb_format: str = RGB_FORMAT, jpg_quality: int = JPG_QUALITY) -> None:
    """DataPipeError naming the option and the fix for a bad BOP export option."""
    if not (depth_scale > 0):
        raise DataPipeError(f"depth_scale must be > 0 mm, got {depth_scale}")
    if int(chunk_size) < 1:
        raise DataPipeError(f"chunk_size must be >= 1, got {chunk_size}")
    if not split or "/" in split or "\\" in split or split.startswith("."):
        raise DataPipeError(f"split: {split!r} is not a folder name (fix: e.g. {SPLIT!r})")
    if rgb_format not in RGB_FORMATS:
        raise DataPipeError(f"rgb_format: {rgb_format!r} (fix: one of {', '.join(RGB_FORMATS)})")
    if not 1 <= int(jpg_quality) <= 100:
        raise DataPipeError(f"jpg_quality: {jpg_quality} (fix: 1..100; the official datasets use {JPG_QUALITY})")


def export_bop(native_run_dir: str | os.PathLike, bop_root: str | os.PathLike, *, depth_scale: float = 0.1,
               chunk_size: int = 1000, split: str = SPLIT, rgb_format: str = RGB_FORMAT,
               jpg_quality: int = JPG_QUALITY, sensor: str | None = None, xyz_crop: bool = False,
               amodal_coco: bool = False) -> dict:
    """Convert every complete scene of a native run (OUT/) into a BOP dataset at `bop_root`. The
    scanner's folders are named `sensor`, else as the run's config says (io/bop_sensor.py);
    xyz_crop / amodal_coco: GDRNPP's and UOAIS' amodal targets (io/xyz_crop.py, io/amodal.py)."""
    check_options(depth_scale=depth_scale, chunk_size=chunk_size, split=split, rgb_format=rgb_format,
                  jpg_quality=jpg_quality)
    run = Path(native_run_dir)
    if not run.is_dir():
        raise DataPipeError(f"{run}: no such run folder")
    if sensor is None:
        sensor = sensor_for_config(read_json_or_empty(run / layout.RUN_FILE).get("config"))
    else:
        check_sensor_name(sensor, "sensor (--sensor)")
    scenes = list(layout.iter_scenes(run))
    if not scenes:
        raise DataPipeError(f"{run}: no complete scene (scene.*/scene.json) to export")
    writer = BopWriter(bop_root, depth_scale=depth_scale, chunk_size=chunk_size, split=split,
                       models_dir=run / layout.MODELS_DIR, rgb_format=rgb_format, jpg_quality=jpg_quality,
                       sensor=sensor, xyz_crop=xyz_crop, amodal_coco=amodal_coco)
    for scene_dir, scene in scenes:
        writer.add_scene(scene_dir, scene)
    summary = writer.finish()
    summary["scenes"] = len(scenes)
    return summary
