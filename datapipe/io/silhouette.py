"""Full silhouettes of posed meshes (pixel-centre coverage) and mask bounding boxes. No bpy.

The renders give only the visible mask; the BOP export (`mask/`, px_count_all, visib_fract) and
the overview sheet rasterise the full silhouette from the model posed with K and T_cam_obj.
"""
from __future__ import annotations

import numpy as np

from ..lens import coefficients, distort, turning_radius

NEAR_MM = 1.0       # triangles with a vertex closer than this to the camera plane are skipped


def rasterize_silhouette(verts_mm: np.ndarray, faces: np.ndarray, K, R, t_mm, width: int, height: int,
                         *, margin: tuple[int, int] | None = None, dist=None):
    """Full silhouette of a posed mesh, pixel-centre coverage (edges inclusive).

    Returns (mask (H,W) bool inside the image, px_count_all, bbox_obj) where the count and the bbox
    cover a canvas extended by `margin` = (mx, my) pixels on each side (default: one image size).

    `dist` (OpenCV k1 k2 p1 p2 k3, datapipe/lens.py): the vertices go through the lens; edges stay
    straight between them (a part's triangles span a few pixels: the bend of an edge across one is
    far below a pixel). Faces with a vertex beyond the radius where the lens polynomial turns
    (outside the frame: validate refuses a lens that turns inside it) are left out."""
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
    xn, yn = pc[:, 0] / zs, pc[:, 1] / zs
    d = coefficients(dist)
    if d is not None:
        ok = (np.hypot(xn, yn)[faces] < turning_radius(d)).all(axis=1)
        faces = faces[ok]
        if len(faces) == 0:
            return empty
        xn, yn = distort(xn, yn, d)
    u = K[0, 0] * xn + K[0, 1] * yn + K[0, 2]
    v = K[1, 1] * yn + K[1, 2]
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
    for px, py, _ in covered_pixels(tu, tv, x0, y0, bw, bh, area):
        canvas[py - cy0, px - cx0] = True
    count = int(canvas.sum())
    if count == 0:
        return empty
    bbox = mask_bbox(canvas)
    bbox = [bbox[0] + cx0, bbox[1] + cy0, bbox[2], bbox[3]]
    mask = np.zeros((height, width), bool)
    ix0, iy0 = max(cx0, 0), max(cy0, 0)
    ix1, iy1 = min(cx0 + canvas.shape[1], width), min(cy0 + canvas.shape[0], height)
    if ix1 > ix0 and iy1 > iy0:
        mask[iy0:iy1, ix0:ix1] = canvas[iy0 - cy0:iy1 - cy0, ix0 - cx0:ix1 - cx0]
    return mask, count, bbox



def mask_bbox(mask: np.ndarray) -> list[int]:
    """bop_toolkit's calc_2d_bbox [x_min, y_min, x_max - x_min, y_max - y_min] of a boolean image's True pixels (row/column projections: no full nonzero())."""
    cols = np.flatnonzero(mask.any(axis=0))
    if len(cols) == 0:
        return [-1, -1, -1, -1]
    rows = np.flatnonzero(mask.any(axis=1))
    return [int(cols[0]), int(rows[0]), int(cols[-1] - cols[0]), int(rows[-1] - rows[0])]


def covered_pixels(tu, tv, x0, y0, bw, bh, area, budget: int = 2_000_000):
    """Yield (px, py, triangle index) of every integer pixel centre inside each projected triangle
    (corners `tu`, `tv` (F, 3), pixel box x0, y0 and its size bw, bh, signed doubled `area`), in
    chunks of about `budget` candidate pixels (smallest boxes first). Edges count as inside (1e-9
    px), so a shared edge's pixels belong to both triangles: a silhouette has no cracks.
    The rasteriser of the silhouettes here and of io/xyz_crop.py's object coordinates."""
    sign = np.sign(area)
    # orient every triangle counter-clockwise in the image so one inequality tests "inside"
    a_u, a_v = tu[:, 0], tv[:, 0]
    b_u = np.where(sign > 0, tu[:, 1], tu[:, 2]); b_v = np.where(sign > 0, tv[:, 1], tv[:, 2])
    c_u = np.where(sign > 0, tu[:, 2], tu[:, 1]); c_v = np.where(sign > 0, tv[:, 2], tv[:, 1])
    eps = 1e-9
    n = bw * bh
    order = np.argsort(n)
    starts = np.concatenate([[0], np.cumsum(n[order])])
    i = 0
    while i < len(order):
        j = max(int(np.searchsorted(starts, starts[i] + budget, side="right")) - 1, i + 1)
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
        yield px[inside], py[inside], s[inside]
        i = j
