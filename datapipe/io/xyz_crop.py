"""Amodal object coordinates of one posed model, rasterised in numpy, and GDRNPP's `xyz_crop` files. No bpy.

GDRN-family methods (GDRNPP) train on per-instance `xyz_crop` targets: the object rendered alone
(amodal: not cut by occluders), its model coordinates cropped to the box of its silhouette. GDRNPP
makes them with its own generation scripts, e.g.
shanice-l/gdrnpp_bop2022@b80383bd7b0ea9f165bb019ecf846f261e60e56f:core/gdrn_modeling/tools/itodd/itodd_pbr_1_gen_xyz.py:
the model is rendered alone with `vertex_scale=0.001` and `t = cam_t_m2c / 1000` (metres), the
rendered depth back-projected to model coordinates (`misc.calc_xyz_bp_torch`, 0 where the depth is
0), cropped to the rendered mask's box and dumped as
`xyz_info = {"xyz_crop": xyz_crop.astype("float16"), "xyxy": [x1, y1, x2, y2]}` to
`train_pbr/xyz_crop/{scene:06d}/{im_id:06d}_{anno_i:06d}-xyz.pkl` (mmcv.dump: a pickle); an
instance with no pixel in the image gets `np.zeros((IM_H, IM_W, 3), dtype=np.float16)` and
`"xyxy": [0, 0, IM_W - 1, IM_H - 1]`. GDRNPP's loader (core/gdrn_modeling/datasets/data_loader.py,
same commit) pastes it back with `xyz[y1 : y2 + 1, x1 : x2 + 1, :] = xyz_crop` and takes the
non-zero pixels as the full mask, so x2, y2 are inclusive and the background is exactly 0.

Here the model is rasterised directly instead of rendered: each pixel centre (integer coordinates,
BOP's K; the same coverage test as io/silhouette.py, so the crop's mask equals `mask/`) takes the
nearest triangle along its ray, and its model point is the ray's exact intersection with that
triangle's plane (no depth-buffer quantisation). With lens distortion the vertices go through the
lens for coverage and each pixel's ray is undistorted (datapipe/lens.py) for the intersection.

float16 in metres keeps a coordinate to half a unit in the last place: <= 0.03 mm below 0.125 m,
<= 0.06 mm below 0.25 m (GDRNPP's own choice: "float16 does not affect performance").
"""
from __future__ import annotations

import os
import pickle

import numpy as np

from ..lens import coefficients, distort, turning_radius, undistort
from .files import make_dirs, write_bytes_atomic
from .silhouette import NEAR_MM, covered_pixels

XYZ_CROP_DIR = "xyz_crop"      # beside the chunks in train_pbr/, as GDRNPP's xyz_root
PICKLE_PROTOCOL = 2            # readable by every Python 3 pickle / mmcv.load


def xyz_file(split_dir: str | os.PathLike, chunk: int, im_id: int, gt_id: int):
    """GDRNPP's path of one instance's file: SPLIT/xyz_crop/CHUNK/IMID_GTID-xyz.pkl."""
    from pathlib import Path
    return Path(split_dir) / XYZ_CROP_DIR / f"{chunk:06d}" / f"{im_id:06d}_{gt_id:06d}-xyz.pkl"


def rasterize_xyz(verts_mm, faces, K, R, t_mm, width: int, height: int, *, dist=None):
    """The model alone at pose (R, t_mm) seen with K: (xyz_mm (H,W,3) float64 model coordinates in mm,
    0 off the model; hit (H,W) bool). Pixel centres at integer coordinates; nearest surface wins."""
    K = np.asarray(K, dtype=np.float64)
    R = np.asarray(R, dtype=np.float64)
    t = np.asarray(t_mm, dtype=np.float64).reshape(3)
    V = np.asarray(verts_mm, dtype=np.float64)
    pc = V @ R.T + t
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    xyz = np.zeros((height, width, 3))
    hit = np.zeros((height, width), bool)
    z = pc[:, 2]
    faces = faces[(z[faces] > NEAR_MM).all(axis=1)] if len(faces) else faces
    if len(faces) == 0:
        return xyz, hit
    zs = np.where(z > NEAR_MM, z, 1.0)
    xn, yn = pc[:, 0] / zs, pc[:, 1] / zs
    d = coefficients(dist)
    if d is not None:
        faces = faces[(np.hypot(xn, yn)[faces] < turning_radius(d)).all(axis=1)]
        if len(faces) == 0:
            return xyz, hit
        xn, yn = distort(xn, yn, d)
    u = K[0, 0] * xn + K[0, 1] * yn + K[0, 2]
    v = K[1, 1] * yn + K[1, 2]
    tu, tv = u[faces], v[faces]
    x0 = np.maximum(np.ceil(tu.min(1)), 0).astype(np.int64)
    x1 = np.minimum(np.floor(tu.max(1)), width - 1).astype(np.int64)
    y0 = np.maximum(np.ceil(tv.min(1)), 0).astype(np.int64)
    y1 = np.minimum(np.floor(tv.max(1)), height - 1).astype(np.int64)
    area = (tu[:, 1] - tu[:, 0]) * (tv[:, 2] - tv[:, 0]) - (tu[:, 2] - tu[:, 0]) * (tv[:, 1] - tv[:, 0])
    keep = (x1 >= x0) & (y1 >= y0) & (np.abs(area) > 1e-12)
    if not keep.any():
        return xyz, hit
    faces, tu, tv = faces[keep], tu[keep], tv[keep]
    x0, x1, y0, y1, area = x0[keep], x1[keep], y0[keep], y1[keep], area[keep]
    # each triangle's plane in the camera frame: n . p = c; a ray p = s * (rx, ry, 1) meets it at s = c / (n . r)
    P0, P1, P2 = pc[faces[:, 0]], pc[faces[:, 1]], pc[faces[:, 2]]
    n = np.cross(P1 - P0, P2 - P0)
    c = (n * P0).sum(1)
    # the ray of every pixel centre (undistorted when the lens distorts)
    gx, gy = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    ry = (gy - K[1, 2]) / K[1, 1]
    rx = (gx - K[0, 2] - K[0, 1] * ry) / K[0, 0]
    if d is not None:
        rx, ry, _ = undistort(rx, ry, d)
    rx, ry = rx.ravel(), ry.ravel()
    zbuf = np.full(width * height, np.inf)
    bw, bh = x1 - x0 + 1, y1 - y0 + 1
    for px, py, s in covered_pixels(tu, tv, x0, y0, bw, bh, area):
        pix = py * width + px
        denom = n[s, 0] * rx[pix] + n[s, 1] * ry[pix] + n[s, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = c[s] / denom
        ok = np.isfinite(depth) & (depth > 0)
        pix, depth = pix[ok], depth[ok]
        np.minimum.at(zbuf, pix, depth)
    hit_flat = np.isfinite(zbuf)
    pix = np.flatnonzero(hit_flat)
    p_cam = np.stack([rx[pix] * zbuf[pix], ry[pix] * zbuf[pix], zbuf[pix]], axis=1)
    xyz.reshape(-1, 3)[pix] = (p_cam - t) @ R          # R^T (p - t), row vectors
    hit.reshape(-1)[pix] = True
    return xyz, hit


def xyz_crop_info(xyz_mm: np.ndarray, hit: np.ndarray) -> dict:
    """GDRNPP's per-instance dict: {"xyz_crop": (y2-y1+1, x2-x1+1, 3) float16 in metres, 0 off the
    model; "xyxy": [x1, y1, x2, y2] inclusive}; no pixel: the whole image of zeros."""
    H, W = hit.shape
    if not hit.any():
        return {"xyz_crop": np.zeros((H, W, 3), dtype=np.float16), "xyxy": [0, 0, W - 1, H - 1]}
    cols = np.flatnonzero(hit.any(axis=0))
    rows = np.flatnonzero(hit.any(axis=1))
    x1, x2, y1, y2 = int(cols[0]), int(cols[-1]), int(rows[0]), int(rows[-1])
    crop = np.where(hit[y1:y2 + 1, x1:x2 + 1, None], xyz_mm[y1:y2 + 1, x1:x2 + 1] / 1000.0, 0.0)
    return {"xyz_crop": crop.astype(np.float16), "xyxy": [x1, y1, x2, y2]}


def write_xyz_crop(path: str | os.PathLike, info: dict) -> None:
    """One instance's pickle, written atomically."""
    from pathlib import Path
    make_dirs(Path(path).parent)
    write_bytes_atomic(path, pickle.dumps(info, protocol=PICKLE_PROTOCOL))
