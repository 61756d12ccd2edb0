"""BOP export (https://github.com/thodan/bop_toolkit/blob/master/docs/bop_datasets_format.md). No bpy.

Pure numpy / scipy / cv2 / json: reads the native output layout (docs/ARCHITECTURE.md) and writes
the BOP-scenewise layout BlenderProc's `write_bop` users know:

    BOP_ROOT/
      camera.json                    {cx, cy, fx, fy, width, height, depth_scale}
      models/obj_000001.ply          x y z nx ny nz (mm) + faces;  models_info.json (mm)
      train_pbr/000000/              chunk = image_id // chunk_size, im_id = image_id % chunk_size
        rgb/000000.png               the native rgb.png (8-bit, 3 channels)
        depth/000000.png             z-buffer depth, uint16, depth_mm = value * depth_scale, 0 = no data
        depth_sl/000000.png          structured-light depth, same encoding (when the run has it)
        mask/000000_000001.png       full (unoccluded) silhouette of annotation 1, 0/255
        mask_visib/000000_000001.png visible part of annotation 1 (native mask.exr == mask_index)
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

import json
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Mapping

import cv2
import numpy as np

from ...errors import DataPipeError
from ...exr import read_depth, read_mask

SPLIT = "train_pbr"
MAX_UINT16 = 65535
NEAR_MM = 1.0


# ------------------------------------------------------------------------------------------------
# models: PLY write / read, models_info

def write_ply(path: str | os.PathLike, verts: np.ndarray, faces: np.ndarray,
              normals: np.ndarray | None = None, *, binary: bool = True) -> None:
    """PLY with `x y z [nx ny nz]` (float32) and triangle faces (uchar count, int indices)."""
    path = Path(path)
    verts = np.asarray(verts, dtype=np.float32).reshape(-1, 3)
    faces = np.asarray(faces, dtype=np.int32).reshape(-1, 3)
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float32).reshape(-1, 3)
        if len(normals) != len(verts):
            raise ValueError(f"{len(normals)} normals for {len(verts)} vertices")
    if len(faces) and (faces.min() < 0 or faces.max() >= len(verts)):
        raise ValueError("face index out of range")
    props = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    header = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
              "comment DataPipe model, units: mm", f"element vertex {len(verts)}"]
    header += [f"property float {p}" for p in props]
    header += [f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    data = verts if normals is None else np.hstack([verts, normals])
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        if binary:
            f.write(np.ascontiguousarray(data, dtype="<f4").tobytes())
            rec = np.zeros(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
            rec["n"] = 3
            rec["i"] = faces
            f.write(rec.tobytes())
        else:
            np.savetxt(f, data, fmt="%.6f")
            np.savetxt(f, np.hstack([np.full((len(faces), 1), 3), faces]), fmt="%d")
    os.replace(tmp, path)


_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def read_ply(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V,3) float64 and triangle faces (F,3) of a PLY (ascii or binary little endian).

    Polygons with more than 3 corners are fanned into triangles."""
    raw = Path(path).read_bytes()
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise DataPipeError(f"{path}: not a PLY file")
    body_start = raw.index(b"\n", end) + 1
    lines = raw[:end].decode("ascii", "replace").splitlines()
    fmt = None
    elements: list[dict] = []
    for line in lines:
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "format":
            fmt = tok[1]
        elif tok[0] == "element":
            elements.append({"name": tok[1], "count": int(tok[2]), "props": []})
        elif tok[0] == "property":
            if tok[1] == "list":
                elements[-1]["props"].append((tok[4], "list", _PLY_TYPES[tok[2]], _PLY_TYPES[tok[3]]))
            else:
                elements[-1]["props"].append((tok[2], _PLY_TYPES[tok[1]]))
    if fmt not in ("ascii", "binary_little_endian"):
        raise DataPipeError(f"{path}: PLY format {fmt!r} not supported (use ascii or binary_little_endian)")
    verts = np.zeros((0, 3))
    polys: list[list[int]] = []
    tri = np.zeros((0, 3), dtype=np.int64)
    if fmt == "ascii":
        tokens = raw[body_start:].split()
        pos = 0
        for el in elements:
            if el["name"] == "vertex" and all(len(p) == 2 for p in el["props"]):
                n, k = el["count"], len(el["props"])
                arr = np.array(tokens[pos:pos + n * k], dtype=np.float64).reshape(n, k)
                pos += n * k
                names = [p[0] for p in el["props"]]
                verts = arr[:, [names.index("x"), names.index("y"), names.index("z")]]
                continue
            for _ in range(el["count"]):
                for p in el["props"]:
                    if len(p) == 4:
                        cnt = int(tokens[pos]); pos += 1
                        vals = [int(t) for t in tokens[pos:pos + cnt]]; pos += cnt
                        if el["name"] == "face" and p[0] in ("vertex_indices", "vertex_index"):
                            polys.append(vals)
                    else:
                        pos += 1
    else:
        pos = body_start
        for el in elements:
            if all(len(p) == 2 for p in el["props"]):
                dt = np.dtype([(p[0], "<" + p[1]) for p in el["props"]])
                arr = np.frombuffer(raw, dtype=dt, count=el["count"], offset=pos)
                pos += dt.itemsize * el["count"]
                if el["name"] == "vertex":
                    verts = np.stack([arr["x"], arr["y"], arr["z"]], axis=1).astype(np.float64)
                continue
            # fast path: faces that are all triangles with one list property
            if (el["name"] == "face" and len(el["props"]) == 1 and len(el["props"][0]) == 4):
                _, _, ct, it = el["props"][0]
                dt = np.dtype([("n", "<" + ct), ("i", "<" + it, (3,))])
                if pos + dt.itemsize * el["count"] <= len(raw):
                    arr = np.frombuffer(raw, dtype=dt, count=el["count"], offset=pos)
                    if np.all(arr["n"] == 3):
                        tri = arr["i"].astype(np.int64)
                        pos += dt.itemsize * el["count"]
                        continue
            for _ in range(el["count"]):
                for p in el["props"]:
                    if len(p) == 4:
                        cdt, idt = np.dtype("<" + p[2]), np.dtype("<" + p[3])
                        cnt = int(np.frombuffer(raw, cdt, 1, pos)[0]); pos += cdt.itemsize
                        vals = np.frombuffer(raw, idt, cnt, pos).tolist(); pos += idt.itemsize * cnt
                        if el["name"] == "face" and p[0] in ("vertex_indices", "vertex_index"):
                            polys.append(vals)
                    else:
                        pos += np.dtype(p[1]).itemsize
    if polys:
        tri = np.array([[p[0], p[k], p[k + 1]] for p in polys for k in range(1, len(p) - 1)], dtype=np.int64)
    return verts, tri.reshape(-1, 3)


def diameter(points: np.ndarray) -> float:
    """Largest distance between any two points, exact: convex-hull vertices, then all pairs."""
    pts = np.unique(np.asarray(points, dtype=np.float64).reshape(-1, 3), axis=0)
    if len(pts) < 2:
        return 0.0
    if len(pts) > 4:
        try:
            from scipy.spatial import ConvexHull
            pts = pts[ConvexHull(pts).vertices]
        except Exception:   # flat or degenerate point sets: fall back to all points (still exact)
            pass
    best = 0.0
    step = max(1, 4_000_000 // len(pts))
    for i in range(0, len(pts), step):
        d = ((pts[i:i + step, None, :] - pts[None, :, :]) ** 2).sum(-1)
        best = max(best, float(d.max()))
    return float(np.sqrt(best))


def model_info(verts_mm: np.ndarray) -> dict:
    v = np.asarray(verts_mm, dtype=np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    return {"diameter": diameter(v),
            "min_x": float(lo[0]), "min_y": float(lo[1]), "min_z": float(lo[2]),
            "size_x": float(hi[0] - lo[0]), "size_y": float(hi[1] - lo[1]), "size_z": float(hi[2] - lo[2])}


def model_filename(obj_id: int) -> str:
    return f"obj_{int(obj_id):06d}.ply"


def write_models(models_dir: str | os.PathLike, meshes: Mapping[int, tuple], *, binary: bool = True) -> dict:
    """Write `obj_XXXXXX.ply` (mm) and `models_info.json` for {obj_id: (verts_m, faces, normals)}.

    verts_m: (V,3) model coordinates in metres (scale baked, the frame of T_cam_obj); faces (F,3)
    triangles; normals (V,3) unit vertex normals or None. Returns the models_info dict."""
    models_dir = Path(models_dir)
    models_dir.mkdir(parents=True, exist_ok=True)
    info = {}
    for obj_id in sorted(meshes, key=int):
        verts_m, faces, normals = (tuple(meshes[obj_id]) + (None, None))[:3]
        if int(obj_id) < 1:
            raise DataPipeError(f"object id {obj_id}: BOP object ids start at 1")
        verts_mm = np.asarray(verts_m, dtype=np.float64).reshape(-1, 3) * 1000.0
        if len(verts_mm) == 0:
            raise DataPipeError(f"object {obj_id}: the mesh has no vertices")
        write_ply(models_dir / model_filename(obj_id), verts_mm, faces, normals, binary=binary)
        info[str(int(obj_id))] = model_info(verts_mm)
    _write_json_atomic(models_dir / "models_info.json", info)
    return info


@dataclass
class Model:
    verts_mm: np.ndarray    # (V,3) float64
    faces: np.ndarray       # (F,3) int64


def load_models(models_dir: str | os.PathLike) -> dict[int, Model]:
    models_dir = Path(models_dir)
    out = {}
    for p in sorted(models_dir.glob("obj_*.ply")):
        try:
            obj_id = int(p.stem.split("_")[1])
        except (IndexError, ValueError):
            continue
        v, f = read_ply(p)
        out[obj_id] = Model(v, f)
    return out


# ------------------------------------------------------------------------------------------------
# depth encoding, silhouettes, statistics

def depth_range_m(depth_scale: float) -> float:
    return MAX_UINT16 * depth_scale / 1000.0


def encode_depth(depth_m: np.ndarray, depth_scale: float, *, what: str = "depth") -> np.ndarray:
    """Planar depth in metres (NaN/inf/<=0 = no data) -> uint16 with depth_mm = value * depth_scale."""
    d = np.asarray(depth_m, dtype=np.float64)
    valid = np.isfinite(d) & (d > 0)
    q = np.zeros(d.shape, dtype=np.float64)
    q[valid] = np.rint(d[valid] * 1000.0 / depth_scale)
    if valid.any() and q.max() > MAX_UINT16:
        far = float(d[valid].max())
        need = far * 1000.0 / MAX_UINT16
        nice = next((s for s in (0.1, 0.2, 0.25, 0.5, 1.0, 2.0, 5.0, 10.0) if s >= need), need)
        raise DataPipeError(
            f"{what}: {far:.3f} m is beyond what 16-bit BOP depth holds with depth_scale {depth_scale} mm "
            f"(at most {depth_range_m(depth_scale):.4f} m); export with depth_scale={nice} "
            f"(BopWriter(..., depth_scale={nice}) or `export_bop(..., depth_scale={nice})`), or move the "
            "camera / clip_end closer")
    q[valid & (q < 1)] = 1          # a hit closer than half a step is still data, not "no data"
    return q.astype(np.uint16)


def rasterize_silhouette(verts_mm: np.ndarray, faces: np.ndarray, K, R, t_mm, width: int, height: int,
                         *, margin: tuple[int, int] | None = None):
    """Full silhouette of a posed mesh, pixel-centre coverage (edges inclusive).

    Returns (mask (H,W) bool inside the image, px_count_all, bbox_obj) where the count and the bbox
    cover a canvas extended by `margin` = (mx, my) pixels on each side (default: one image size)."""
    mx, my = margin if margin is not None else (width, height)
    K = np.asarray(K, dtype=np.float64)
    pc = np.asarray(verts_mm, dtype=np.float64) @ np.asarray(R, dtype=np.float64).T + np.asarray(t_mm, dtype=np.float64).reshape(3)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    empty = (np.zeros((height, width), bool), 0, [-1, -1, -1, -1])
    if len(faces) == 0:
        return empty
    z = pc[:, 2]
    ok = (z[faces] > NEAR_MM).all(axis=1)
    faces = faces[ok]
    if len(faces) == 0:
        return empty
    zs = np.where(z > NEAR_MM, z, 1.0)
    u = K[0, 0] * pc[:, 0] / zs + K[0, 1] * pc[:, 1] / zs + K[0, 2]
    v = K[1, 1] * pc[:, 1] / zs + K[1, 2]
    tu, tv = u[faces], v[faces]                                   # (F,3)
    x0 = np.maximum(np.ceil(tu.min(1)), -mx).astype(np.int64)
    x1 = np.minimum(np.floor(tu.max(1)), width - 1 + mx).astype(np.int64)
    y0 = np.maximum(np.ceil(tv.min(1)), -my).astype(np.int64)
    y1 = np.minimum(np.floor(tv.max(1)), height - 1 + my).astype(np.int64)
    # signed doubled area; degenerate triangles cover (almost) nothing
    area = (tu[:, 1] - tu[:, 0]) * (tv[:, 2] - tv[:, 0]) - (tu[:, 2] - tu[:, 0]) * (tv[:, 1] - tv[:, 0])
    keep = (x1 >= x0) & (y1 >= y0) & (np.abs(area) > 1e-12)
    if not keep.any():
        return empty
    tu, tv, x0, x1, y0, y1, area = tu[keep], tv[keep], x0[keep], x1[keep], y0[keep], y1[keep], area[keep]
    cx0, cy0 = int(x0.min()), int(y0.min())
    canvas = np.zeros((int(y1.max()) - cy0 + 1, int(x1.max()) - cx0 + 1), dtype=bool)
    bw, bh = x1 - x0 + 1, y1 - y0 + 1
    n = bw * bh
    sign = np.sign(area)
    # orient every triangle counter-clockwise in the image so one inequality tests "inside"
    a_u, a_v = tu[:, 0], tv[:, 0]
    b_u = np.where(sign > 0, tu[:, 1], tu[:, 2]); b_v = np.where(sign > 0, tv[:, 1], tv[:, 2])
    c_u = np.where(sign > 0, tu[:, 2], tu[:, 1]); c_v = np.where(sign > 0, tv[:, 2], tv[:, 1])
    eps = 1e-9
    order = np.argsort(n)
    starts = np.concatenate([[0], np.cumsum(n[order])])
    budget = 2_000_000
    i = 0
    while i < len(order):
        j = int(np.searchsorted(starts, starts[i] + budget, side="right")) - 1
        j = max(j, i + 1)
        sel = order[i:j]
        cnt = n[sel]
        tri = np.repeat(np.arange(len(sel)), cnt)
        local = np.arange(int(cnt.sum())) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        w = bw[sel][tri]
        px = x0[sel][tri] + local % w
        py = y0[sel][tri] + local // w
        s = sel[tri]
        e0 = (b_u[s] - a_u[s]) * (py - a_v[s]) - (b_v[s] - a_v[s]) * (px - a_u[s])
        e1 = (c_u[s] - b_u[s]) * (py - b_v[s]) - (c_v[s] - b_v[s]) * (px - b_u[s])
        e2 = (a_u[s] - c_u[s]) * (py - c_v[s]) - (a_v[s] - c_v[s]) * (px - c_u[s])
        inside = (e0 >= -eps) & (e1 >= -eps) & (e2 >= -eps)
        canvas[py[inside] - cy0, px[inside] - cx0] = True
        i = j
    count = int(canvas.sum())
    if count == 0:
        return empty
    bbox = _mask_bbox(canvas)
    bbox = [bbox[0] + cx0, bbox[1] + cy0, bbox[2], bbox[3]]
    mask = np.zeros((height, width), bool)
    ix0, iy0 = max(cx0, 0), max(cy0, 0)
    ix1, iy1 = min(cx0 + canvas.shape[1], width), min(cy0 + canvas.shape[0], height)
    if ix1 > ix0 and iy1 > iy0:
        mask[iy0:iy1, ix0:ix1] = canvas[iy0 - cy0:iy1 - cy0, ix0 - cx0:ix1 - cx0]
    return mask, count, bbox


def bbox_xywh(xs: np.ndarray, ys: np.ndarray) -> list[int]:
    """bop_toolkit's calc_2d_bbox: [x_min, y_min, x_max - x_min, y_max - y_min]."""
    if len(xs) == 0:
        return [-1, -1, -1, -1]
    x0, y0 = int(xs.min()), int(ys.min())
    return [x0, y0, int(xs.max()) - x0, int(ys.max()) - y0]


def _mask_bbox(mask: np.ndarray) -> list[int]:
    """bbox_xywh of a boolean image's True pixels (row/column projections: no full nonzero())."""
    cols = np.flatnonzero(mask.any(axis=0))
    if len(cols) == 0:
        return [-1, -1, -1, -1]
    rows = np.flatnonzero(mask.any(axis=1))
    return [int(cols[0]), int(rows[0]), int(cols[-1] - cols[0]), int(rows[-1] - rows[0])]


def mask_to_rle(mask: np.ndarray) -> dict:
    """COCO's uncompressed RLE (column-major runs, starting with a run of zeros), as bop_toolkit writes it."""
    flat = np.asarray(mask, dtype=bool).ravel(order="F")
    counts = [] if (len(flat) and not flat[0]) or not len(flat) else [0]
    if len(flat):
        change = np.flatnonzero(np.concatenate(([True], flat[:-1] != flat[1:], [True])))
        counts += np.diff(change).tolist()
    return {"counts": counts, "size": [int(mask.shape[0]), int(mask.shape[1])]}


def gt_info(sil_mask: np.ndarray, px_count_all: int, bbox_obj: list[int], visib: np.ndarray,
            depth_valid: np.ndarray) -> dict:
    """One scene_gt_info entry from the full silhouette (inside the image), the visible mask and
    the ground-truth depth's validity."""
    extra = int(np.count_nonzero(visib & ~sil_mask))     # visible pixels the rasteriser missed
    sil = sil_mask | visib
    px_all = int(px_count_all) + extra
    px_visib = int(np.count_nonzero(visib))
    px_valid = int(np.count_nonzero(sil & depth_valid))
    if px_visib > 0:
        bbox_visib = _mask_bbox(visib)
        if extra:
            b2 = _mask_bbox(sil)
            b = bbox_obj if bbox_obj[0] != -1 else b2
            lo_x, lo_y = min(b[0], b2[0]), min(b[1], b2[1])
            hi_x, hi_y = max(b[0] + b[2], b2[0] + b2[2]), max(b[1] + b[3], b2[1] + b2[3])
            bbox_obj = [lo_x, lo_y, hi_x - lo_x, hi_y - lo_y]
    else:
        bbox_visib = [-1, -1, -1, -1]
        bbox_obj = [-1, -1, -1, -1]
    return {"bbox_obj": [int(x) for x in bbox_obj], "bbox_visib": [int(x) for x in bbox_visib],
            "px_count_all": px_all, "px_count_valid": px_valid, "px_count_visib": px_visib,
            "visib_fract": float(px_visib / px_all) if px_all > 0 else 0.0}


# ------------------------------------------------------------------------------------------------
# JSON helpers (bop_toolkit's layout: one image per line, keys sorted numerically)

def _write_json_atomic(path: Path, data, *, compact: bool = False) -> None:
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    if compact:
        text = json.dumps(data, separators=(",", ":")) + "\n"
    elif isinstance(data, dict) and data and all(str(k).lstrip("-").isdigit() for k in data):
        keys = sorted(data, key=lambda k: int(k))
        body = ",\n".join(f'  "{int(k)}": {json.dumps(data[k], sort_keys=True)}' for k in keys)
        text = "{\n" + body + "\n}\n"
    else:
        text = json.dumps(data, indent=2, sort_keys=True) + "\n"
    with open(tmp, "w") as f:
        f.write(text)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _read_json(path: Path) -> dict:
    try:
        with open(path) as f:
            return json.load(f)
    except FileNotFoundError:
        return {}
    except json.JSONDecodeError as e:
        raise DataPipeError(f"{path} is not valid JSON ({e}); delete the chunk folder and export again") from None


def _imwrite_atomic(path: Path, img: np.ndarray) -> None:
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    if not cv2.imwrite(str(tmp), img):
        raise DataPipeError(f"could not write {path}")
    os.replace(tmp, path)


def _mat(x, shape) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.shape != shape:
        raise DataPipeError(f"expected a {shape} matrix in scene.json, got shape {a.shape}")
    return a


# ------------------------------------------------------------------------------------------------
# the writer

CHUNK_FILES = ("scene_camera", "scene_gt", "scene_gt_info", "datapipe")
COCO_VISIB_MIN = 0.1      # bop_toolkit's calc_gt_coco: annotations less visible than this are "ignore"


class BopWriter:
    """Add native scenes one at a time to a BOP dataset; safe to call after every scene.

    Images are written first, then each touched chunk's JSON files are re-written atomically (write
    a temporary file, rename), so a crash loses nothing written before, and re-adding a scene (a
    resumed run) overwrites its own entries. One writer per BOP folder at a time."""

    def __init__(self, bop_root: str | os.PathLike, *, depth_scale: float = 0.1, chunk_size: int = 1000,
                 split: str = SPLIT, models_dir: str | os.PathLike | None = None):
        if not (depth_scale > 0):
            raise DataPipeError(f"depth_scale must be > 0 mm, got {depth_scale}")
        if int(chunk_size) < 1:
            raise DataPipeError(f"chunk_size must be >= 1, got {chunk_size}")
        self.root = Path(bop_root)
        self.depth_scale = float(depth_scale)
        self.chunk_size = int(chunk_size)
        self.split = split
        self.root.mkdir(parents=True, exist_ok=True)
        self._models: dict[int, Model] | None = None
        self._chunks: dict[int, dict[str, dict]] = {}
        self._camera_written = (self.root / "camera.json").is_file()
        self.images_written = 0
        if models_dir is not None:
            self.set_models(models_dir)

    # -- models -----------------------------------------------------------------------------------
    @property
    def models_dir(self) -> Path:
        return self.root / "models"

    def set_models(self, source: str | os.PathLike | Mapping[int, tuple]) -> None:
        """Copy a native models/ folder (obj_*.ply + models_info.json), or write {obj_id: mesh}."""
        if isinstance(source, Mapping):
            write_models(self.models_dir, source)
        else:
            src = Path(source)
            if not (src / "models_info.json").is_file():
                raise DataPipeError(f"{src}: no models_info.json (the run's models/ folder is written at the "
                                    "start of a run by datapipe.core.writers.bop.write_models)")
            if src.resolve() != self.models_dir.resolve():
                self.models_dir.mkdir(parents=True, exist_ok=True)
                for p in sorted(src.iterdir()):
                    if p.is_file() and (p.suffix == ".ply" or p.name == "models_info.json"):
                        shutil.copyfile(p, self.models_dir / (p.name + ".tmp"))
                        os.replace(self.models_dir / (p.name + ".tmp"), self.models_dir / p.name)
        self._models = None

    def models(self) -> dict[int, Model]:
        if self._models is None:
            self._models = load_models(self.models_dir)
        return self._models

    # -- chunks -----------------------------------------------------------------------------------
    def chunk_dir(self, chunk: int) -> Path:
        return self.root / self.split / f"{chunk:06d}"

    def _chunk(self, chunk: int) -> dict[str, dict]:
        if chunk not in self._chunks:
            d = self.chunk_dir(chunk)
            data = {name: _read_json(d / f"{name}.json") for name in CHUNK_FILES}
            coco = _read_json(d / "scene_gt_coco.json")
            per_image = {str(im["id"]): {"image": im, "annotations": []} for im in coco.get("images", [])}
            for ann in coco.get("annotations", []):
                a = {k: v for k, v in ann.items() if k != "id"}
                per_image.setdefault(str(ann["image_id"]), {"image": None, "annotations": []})["annotations"].append(a)
            data["coco"] = per_image
            self._chunks[chunk] = data
        return self._chunks[chunk]

    def _coco(self, data: dict) -> dict:
        """scene_gt_coco.json of a chunk (bop_toolkit's calc_gt_coco layout, amodal boxes, RLE masks)."""
        obj_ids = sorted(self.models()) or sorted({a["category_id"] for e in data["coco"].values()
                                                   for a in e["annotations"]})
        images, anns = [], []
        for key in sorted(data["coco"], key=int):
            e = data["coco"][key]
            if e["image"] is not None:
                images.append(e["image"])
            for a in e["annotations"]:
                anns.append({"id": len(anns) + 1, **a})
        return {"info": {"description": f"DataPipe {self.split}", "url": "", "version": "0.1.0",
                         "contributor": "DataPipe"},
                "licenses": [],
                "categories": [{"id": i, "name": str(i), "supercategory": "datapipe"} for i in obj_ids],
                "images": images, "annotations": anns}

    def _flush(self, chunks: Iterable[int]) -> None:
        for c in sorted(set(chunks)):
            data = self._chunk(c)
            d = self.chunk_dir(c)
            # datapipe.json last: it names what the BOP files hold
            for name in ("scene_camera", "scene_gt", "scene_gt_info"):
                _write_json_atomic(d / f"{name}.json", data[name])
            _write_json_atomic(d / "scene_gt_coco.json", self._coco(data), compact=True)
            _write_json_atomic(d / "datapipe.json", data["datapipe"])

    # -- scenes -----------------------------------------------------------------------------------
    def add_scene(self, native_scene_dir: str | os.PathLike) -> list[int]:
        """Convert one complete native scene (its scene.json) and return the global image ids added."""
        scene_dir = Path(native_scene_dir)
        sj = scene_dir / "scene.json"
        if not sj.is_file():
            raise DataPipeError(f"{scene_dir}: no scene.json (the scene is not complete); finish or resume the run")
        with open(sj) as f:
            scene = json.load(f)
        if not scene.get("complete", False):
            raise DataPipeError(f"{scene_dir}: scene.json says the scene is not complete (a cancelled run); "
                                "resume the run to finish it")
        if not (self.models_dir / "models_info.json").is_file():
            self.set_models(scene_dir.parent / "models")
        models = self.models()
        touched = []
        entries = []
        for rd in scene.get("renders", []):
            entries.append(self._convert_render(scene_dir, scene, rd, models))
        for image_id, chunk, im_id, cam, gts, infos, meta, coco in entries:
            c = self._chunk(chunk)
            key = str(im_id)
            c["coco"][key] = coco
            c["scene_camera"][key] = cam
            c["scene_gt"][key] = gts
            c["scene_gt_info"][key] = infos
            c["datapipe"][key] = meta
            touched.append(chunk)
        self._flush(touched)
        self.images_written += len(entries)
        return [e[0] for e in entries]

    def has_scene(self, native_scene_dir: str | os.PathLike) -> bool:
        """True when every render of the scene is already in this BOP folder (e.g. before a resume)."""
        try:
            with open(Path(native_scene_dir) / "scene.json") as f:
                scene = json.load(f)
        except (OSError, json.JSONDecodeError):
            return False
        for rd in scene.get("renders", []):
            chunk, im_id = divmod(int(rd["image_id"]), self.chunk_size)
            meta = self._chunk(chunk)["datapipe"].get(str(im_id))
            if not meta or meta.get("image_id") != int(rd["image_id"]):
                return False
        return bool(scene.get("renders"))

    def _convert_render(self, scene_dir: Path, scene: dict, rd: dict, models: dict[int, Model]):
        image_id = int(rd["image_id"])
        chunk, im_id = divmod(image_id, self.chunk_size)
        cdir = self.chunk_dir(chunk)
        W, H = (int(x) for x in rd["resolution"])
        K = _mat(rd["K"], (3, 3))
        files = rd.get("files", {})
        rdir = scene_dir / rd["name"]

        def native(kind, default):
            rel = files.get(kind)
            p = scene_dir / rel if rel else rdir / default
            return p

        for sub in ("rgb", "depth", "mask", "mask_visib"):
            (cdir / sub).mkdir(parents=True, exist_ok=True)
        stem = f"{im_id:06d}"

        # rgb
        rgb_src = native("rgb", "rgb.png")
        if not rgb_src.is_file():
            raise DataPipeError(f"{rgb_src}: missing (BOP needs the 'rgb' output)")
        rgb = cv2.imread(str(rgb_src), cv2.IMREAD_UNCHANGED)
        if rgb is None:
            raise DataPipeError(f"{rgb_src}: not a readable image")
        if rgb.ndim == 3 and rgb.shape[2] == 3 and rgb.dtype == np.uint8:
            shutil.copyfile(rgb_src, cdir / "rgb" / f"{stem}.png.tmp")
            os.replace(cdir / "rgb" / f"{stem}.png.tmp", cdir / "rgb" / f"{stem}.png")
        else:
            if rgb.dtype == np.uint16:
                rgb = (rgb.astype(np.float32) / 257.0 + 0.5).astype(np.uint8)
            if rgb.ndim == 2:
                rgb = cv2.cvtColor(rgb, cv2.COLOR_GRAY2BGR)
            elif rgb.shape[2] == 4:
                rgb = rgb[:, :, :3]
            _imwrite_atomic(cdir / "rgb" / f"{stem}.png", np.ascontiguousarray(rgb))

        # depth (z-buffer, ground truth)
        depth_src = native("depth", "depth.exr")
        if not depth_src.is_file():
            raise DataPipeError(f"{depth_src}: missing (BOP needs the 'depth' output)")
        depth = read_depth(depth_src)
        if depth.shape != (H, W):
            raise DataPipeError(f"{depth_src}: shape {depth.shape} but scene.json says {W}x{H}")
        _imwrite_atomic(cdir / "depth" / f"{stem}.png",
                        encode_depth(depth, self.depth_scale, what=str(depth_src)))
        depth_valid = np.isfinite(depth) & (depth > 0)

        # structured-light depth, beside
        sl_src = native("sl_depth", "sl_depth.exr")
        if sl_src.is_file():
            (cdir / "depth_sl").mkdir(exist_ok=True)
            _imwrite_atomic(cdir / "depth_sl" / f"{stem}.png",
                            encode_depth(read_depth(sl_src), self.depth_scale, what=str(sl_src)))

        # masks + gt
        mask_src = native("mask", "mask.exr")
        if not mask_src.is_file():
            raise DataPipeError(f"{mask_src}: missing (BOP needs the 'mask' output)")
        inst = read_mask(mask_src)
        gts, infos, coco_anns = [], [], []
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
            sil, count, bbox = rasterize_silhouette(m.verts_mm, m.faces, K, R, t_mm, W, H)
            visib = inst == int(o["mask_index"])
            infos.append(gt_info(sil, count, bbox, visib, depth_valid))
            if infos[-1]["px_count_visib"] > 0:
                b = _mask_bbox(sil | visib)
                coco_anns.append({"image_id": im_id, "category_id": obj_id, "iscrowd": 0,
                                  "area": infos[-1]["px_count_visib"], "bbox": [b[0], b[1], b[2] + 1, b[3] + 1],
                                  "segmentation": mask_to_rle(visib), "width": W, "height": H,
                                  "ignore": bool(infos[-1]["visib_fract"] < COCO_VISIB_MIN)})
            name = f"{stem}_{gt_id:06d}.png"
            _imwrite_atomic(cdir / "mask" / name, ((sil | visib).astype(np.uint8) * 255))
            _imwrite_atomic(cdir / "mask_visib" / name, visib.astype(np.uint8) * 255)

        T_wc = _mat(rd["T_world_cam"], (4, 4))
        T_cw = np.linalg.inv(T_wc)
        cam = {"cam_K": [float(x) for x in K.reshape(-1)], "depth_scale": self.depth_scale,
               "cam_R_w2c": [float(x) for x in T_cw[:3, :3].reshape(-1)],
               "cam_t_w2c": [float(x) for x in T_cw[:3, 3] * 1000.0]}
        meta = {"image_id": image_id, "scene": scene_dir.name, "render": rd["name"],
                "scene_id": int(scene.get("scene_id", -1)), "render_seed": rd.get("seed"),
                "depth_sl": sl_src.is_file()}
        if not self._camera_written:
            _write_json_atomic(self.root / "camera.json", {
                "cx": float(K[0, 2]), "cy": float(K[1, 2]), "fx": float(K[0, 0]), "fy": float(K[1, 1]),
                "width": W, "height": H, "depth_scale": self.depth_scale})
            self._camera_written = True
        coco = {"image": {"id": im_id, "file_name": f"rgb/{stem}.png", "width": W, "height": H},
                "annotations": coco_anns}
        return image_id, chunk, im_id, cam, gts, infos, meta, coco

    def finish(self) -> dict:
        """Flush everything (every add_scene already did) and return a summary."""
        self._flush(self._chunks)
        return {"bop_root": str(self.root), "images": self.images_written,
                "chunks": sorted(self._chunks), "depth_scale": self.depth_scale}


# ------------------------------------------------------------------------------------------------
# whole runs

def scene_is_complete(scene_dir: str | os.PathLike) -> bool:
    """A native scene is complete when its scene.json exists and says "complete": true."""
    try:
        with open(Path(scene_dir) / "scene.json") as f:
            return bool(json.load(f).get("complete", False))
    except (OSError, json.JSONDecodeError):
        return False


def complete_scenes(native_run_dir: str | os.PathLike) -> list[Path]:
    """Scene folders of a native run that are complete, in order."""
    run = Path(native_run_dir)
    return sorted(p for p in run.glob("scene.*") if p.is_dir() and scene_is_complete(p))


def export_bop(native_run_dir: str | os.PathLike, bop_root: str | os.PathLike, *, depth_scale: float = 0.1,
               chunk_size: int = 1000, split: str = SPLIT) -> dict:
    """Convert every complete scene of a native run (OUT/) into a BOP dataset at `bop_root`."""
    run = Path(native_run_dir)
    if not run.is_dir():
        raise DataPipeError(f"{run}: no such run folder")
    scenes = complete_scenes(run)
    if not scenes:
        raise DataPipeError(f"{run}: no complete scene (scene.*/scene.json) to export")
    writer = BopWriter(bop_root, depth_scale=depth_scale, chunk_size=chunk_size, split=split,
                       models_dir=run / "models")
    for s in scenes:
        writer.add_scene(s)
    summary = writer.finish()
    summary["scenes"] = len(scenes)
    return summary
