"""What BOP's files hold, entry by entry: 16-bit depth PNGs (depth_mm = value * depth_scale), COCO's
uncompressed RLE as bop_toolkit writes it, and one scene_gt_info entry (bounding boxes, pixel counts,
visible fraction). The writer that puts them into a dataset is :mod:`datapipe.io.bop`."""
from __future__ import annotations

import numpy as np

from ..errors import DataPipeError
from .silhouette import mask_bbox

MAX_UINT16 = 65535


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
        bbox_visib = mask_bbox(visib)
        if extra:
            b2 = mask_bbox(sil)
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
