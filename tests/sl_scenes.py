"""Structured-light scenes as a user of the original add-on makes them, and their independent
ground truth, for the Blender tests (tests/blender/test_sl_working_distance.py, test_sl_truth.py) and
the benchmarks (benchmarks/sl_bench_scenes.py, bench_sl_truth.py): `direct_mask` (the pixels the
projector lights directly: a ray cast, needs bpy, imported inside it) and `depth_edges` (the
pixels near a z-buffer step).

A rig is where the projector sits relative to the camera: 'default' (the preset: 0.15 m baseline,
8.5 deg toe-in) or 'gui' (where the original DataPipe GUI puts it: 0.12 m, 8.5 deg). The preset is
an original-layout pickle (camera pose, projector pose, is_structured_light) loaded with
`config.load_legacy_pickle`, everything else default: structured light as it ships.
"""
from __future__ import annotations

import math
import pickle

import numpy as np

from datapipe import config as C

EDGE_STEP = 5e-3           # m: z-buffer second difference that marks a depth edge
EDGE_PX = 2                # px either side of it (the "away from depth edges (+-2 px)")

RIGS = {"default": ([-0.15, 0.0, 0.0], [0.0, math.radians(-8.5), 0.0]),
        "gui": ([-0.12, 0.0, 0.0], [0.0, math.radians(-8.5), 0.0])}


def rig_config(rig: str, height: float, res=(320, 240)) -> C.Config:
    """The original-layout pickle preset: camera straight down from `height` m above the bin floor,
    the projector of `rig`, structured light on with its defaults. Only the native layer is made
    cheap (8 samples, 2 threads, rgb/depth/mask): its z-buffer depth and mask are ground truth,
    exact at any sample count."""
    base = C.default_config()
    d = C.to_legacy_dict(base)
    d["camera"]["world2cam_pose_list"] = [{"location": [0.0, 0.0, float(height)], "rotation": [1.0, 0.0, 0.0, 0.0]}]
    d["camera"]["resolution"] = [int(res[1]), int(res[0])]
    d["camera"]["is_structured_light"] = True
    loc, rot = RIGS[rig]
    d["projector"]["proj2cam_pose"] = {"location": list(loc), "rotation": list(rot)}
    cfg = C.load_legacy_pickle(pickle.dumps(d), base_dir=C.presets_dir())
    cfg.render.samples = 8
    cfg.render.threads = 2
    cfg.render.outputs = ["rgb", "depth", "mask"]
    return cfg


def direct_mask(bscene, cfg, T_world_cam, K, depth, where=None) -> np.ndarray:
    """Pixels whose z-buffer point is inside the projector image with a free line to the projector
    centre (Blender ray cast from the point towards the projector): lit directly and seen, known
    without the fringe render. `where`: an optional (H, W) bool mask of the pixels to test."""
    import bpy
    from mathutils import Vector

    from datapipe.core.projector import projector_matrix

    H, W = depth.shape
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    Xc = np.stack([(u - K[0, 2]) / K[0, 0] * depth, (v - K[1, 2]) / K[1, 1] * depth, depth], -1)
    Xw = Xc @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
    P = projector_matrix(cfg, T_world_cam)
    p = np.concatenate([Xw, np.ones((H, W, 1))], -1) @ P.T
    x, y = p[..., 0] / p[..., 2], p[..., 1] / p[..., 2]
    Wp, Hp = cfg.projector.resolution
    inside = np.isfinite(depth) & (p[..., 2] > 0) & (x > 0.5) & (x < Wp - 1.5) & (y > 0.5) & (y < Hp - 1.5)
    if where is not None:
        inside &= where
    centre = -np.linalg.solve(P[:, :3], P[:, 3])
    dg = bpy.context.evaluated_depsgraph_get()
    out = np.zeros((H, W), bool)
    for i, j in zip(*np.nonzero(inside)):
        d = centre - Xw[i, j]
        dist = float(np.linalg.norm(d))
        d /= dist
        o = Xw[i, j] + d * 1e-4
        hit = bscene.ray_cast(dg, Vector(o.tolist()), Vector(d.tolist()), distance=dist - 2e-4)[0]
        out[i, j] = not hit
    return out


def depth_edges(z: np.ndarray, step: float = EDGE_STEP, px: int = EDGE_PX) -> np.ndarray:
    """Pixels within `px` of a depth discontinuity of the z-buffer: |second difference| > `step`
    along a row or a column (a slanted plane, however steep, has none; a step or a crease has),
    or a missing neighbour (background)."""
    from scipy.ndimage import binary_dilation

    zz = np.where(np.isfinite(z), z, np.nan).astype(np.float64)
    e = ~np.isfinite(zz)
    with np.errstate(invalid="ignore"):
        for ax in (0, 1):
            d2 = np.abs(np.diff(zz, 2, axis=ax))
            hit = ~(d2 <= step)                       # NaN counts as an edge
            sl_mid = [slice(None)] * 2
            sl_mid[ax] = slice(1, -1)
            e[tuple(sl_mid)] |= hit
    return binary_dilation(e, iterations=px)
