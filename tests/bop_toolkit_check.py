"""A DataPipe BOP export judged by the official bop_toolkit (its `bop_toolkit_lib`, when installed).

Used by tests/test_bop_toolkit.py (asserts) and benchmarks/bench_bop.py (reports). Everything read
goes through the toolkit's loaders (`inout`); model points are projected with `misc.project_pts`;
visible masks are recomputed as its calc_gt_info does (`visibility.estimate_visib_mask_gt`, the
15 mm tolerance, "bop19" mode, on distance images from `misc.depth_im_to_dist_im_fast`) and boxes
with `misc.calc_2d_bbox`. calc_gt_info renders each model alone with an OpenGL renderer, which this
headless check may not have; the model's own depth is rasterised here instead (a z-buffer over the
projected triangles, pixel centres at integer coordinates as in BOP's K; OpenGL samples pixel
centres at +0.5, which is the half-pixel difference docs/DATASETS.md describes).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

DELTA_MM = 15.0        # calc_gt_info's visibility tolerance


def toolkit():
    """(inout, misc, visibility) of bop_toolkit_lib, or None when it is not importable."""
    try:
        from bop_toolkit_lib import inout, misc, visibility
    except Exception:           # not installed, or its own dependencies (imageio, pypng) missing
        return None
    return inout, misc, visibility


def model_depth(V, F, K, R, t, W, H):
    """Depth (mm) of a model alone in its pose, 0 where it does not cover a pixel centre."""
    F = np.asarray(F).astype(np.int64)
    pc = V @ R.T + t
    uv = pc @ K.T
    uv = uv[:, :2] / uv[:, 2:]
    depth = np.full((H, W), np.inf)
    for tri in F:
        p, z = uv[tri], pc[tri, 2]
        lo = np.maximum(np.floor(p.min(0)).astype(int), 0)
        hi = np.minimum(np.ceil(p.max(0)).astype(int), [W - 1, H - 1])
        if (hi < lo).any():
            continue
        xs, ys = np.meshgrid(np.arange(lo[0], hi[0] + 1), np.arange(lo[1], hi[1] + 1))
        q = np.stack([xs.ravel(), ys.ravel()], 1).astype(np.float64)
        d = (p[1, 0] - p[0, 0]) * (p[2, 1] - p[0, 1]) - (p[2, 0] - p[0, 0]) * (p[1, 1] - p[0, 1])
        if abs(d) < 1e-12:
            continue
        w1 = ((q[:, 0] - p[0, 0]) * (p[2, 1] - p[0, 1]) - (p[2, 0] - p[0, 0]) * (q[:, 1] - p[0, 1])) / d
        w2 = ((p[1, 0] - p[0, 0]) * (q[:, 1] - p[0, 1]) - (q[:, 0] - p[0, 0]) * (p[1, 1] - p[0, 1])) / d
        w0 = 1 - w1 - w2
        inside = (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
        if not inside.any():
            continue
        zz = 1.0 / (w0 / z[0] + w1 / z[1] + w2 / z[2])         # perspective-correct depth
        qi = q[inside].astype(int)
        np.minimum.at(depth, (qi[:, 1], qi[:, 0]), zz[inside])
    depth[~np.isfinite(depth)] = 0
    return depth


def obj_mesh(path: Path):
    """(vertices, triangles) of an OBJ file, parsed here (polygons fanned), independent of the
    importers DataPipe uses."""
    v, f = [], []
    for line in Path(path).read_text().splitlines():
        t = line.split()
        if t and t[0] == "v":
            v.append([float(x) for x in t[1:4]])
        elif t and t[0] == "f":
            idx = [int(x.split("/")[0]) - 1 for x in t[1:]]
            f += [(idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1)]
    return np.array(v), np.array(f)


def visible_part(V, F, K, T, depth, occluder):
    """(silhouette, visible pixels) of a model at pose T (4x4, the units of V and `depth`) against a
    rendered depth map (NaN where nothing was hit): a silhouette pixel is visible unless something
    lies more than `occluder` in front of the model there."""
    H, W = depth.shape
    own = model_depth(V, F, K, T[:3, :3], T[:3, 3], W, H)
    full = own > 0
    return full, full & ~(np.nan_to_num(depth, nan=np.inf) < own - occluder)


def _dilate(mask):
    out = mask.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            out |= np.roll(np.roll(mask, dy, axis=0), dx, axis=1)
    return out


TEMPLATE_DATASET = "xyzibd"       # an industrial dataset whose sensors include "photoneo" (gray + depth)


def classic_paths(root: Path, split: str) -> dict:
    """The toolkit's classic path templates ({scene_id}: the chunk), as dataset_params spells them."""
    c = str(root / split / "{scene_id:06d}")
    return {"scene_camera": c + "/scene_camera.json", "scene_gt": c + "/scene_gt.json",
            "scene_gt_info": c + "/scene_gt_info.json", "depth": c + "/depth/{im_id:06d}.png",
            "mask": c + "/mask/{im_id:06d}_{gt_id:06d}.png", "mask_visib": c + "/mask_visib/{im_id:06d}_{gt_id:06d}.png"}


def sensor_paths(root: Path, split: str, sensor: str, modality: str = "gray") -> dict:
    """The toolkit's own multi-sensor templates of `sensor` (dataset_params.get_split_params of
    TEMPLATE_DATASET, whose sensor list must hold it), moved from its split folder to ours."""
    from bop_toolkit_lib import dataset_params
    p = dataset_params.get_split_params(str(root / "_datasets"), TEMPLATE_DATASET, "val")
    assert sensor in p["im_modalities"], f"{TEMPLATE_DATASET} has no sensor {sensor!r}"
    keys = dataset_params.scene_tpaths_keys(modality, sensor)
    ours = str(root / split)

    def moved(key):
        t = p[key]
        assert t.startswith(p["split_path"]), t
        return ours + t[len(p["split_path"]):]
    out = {k: moved(keys[f"{k}_tpath"]) for k in ("scene_camera", "scene_gt", "scene_gt_info", "mask", "mask_visib")}
    out["depth"] = moved(f"depth_{sensor}_tpath")
    out[modality] = moved(f"{modality}_{sensor}_tpath")
    return out


def check(bop_root: str | Path, split: str = "train_pbr", sensor: str | None = None,
          delta_mm: float = DELTA_MM) -> dict:
    """Counts of what the toolkit recomputes and what agrees with the export: the classic folders,
    or with `sensor` the scanner's, read through the toolkit's multi-sensor templates. The visible
    masks are recomputed from the ground-truth depth/ (a PBR image's truth, as calc_gt_info does on
    the classic folders); px_count_valid from the paths' own depth (calc_gt_info's definition).
    `delta_mm`: the visibility tolerance (calc_gt_info's `delta`, 15 mm by default there and here)."""
    inout, misc, visibility = toolkit()
    root = Path(bop_root)
    P = sensor_paths(root, split, sensor) if sensor else classic_paths(root, split)
    C = classic_paths(root, split)
    info = inout.load_json(str(root / "models" / "models_info.json"), keys_to_int=True)
    models = {k: inout.load_ply(str(root / "models" / f"obj_{k:06d}.ply")) for k in info}
    evals = {k: inout.load_ply(str(root / "models_eval" / f"obj_{k:06d}.ply")) for k in info}
    s = {"instances": 0, "masks_visib_equal": 0, "visib_px_differing": 0, "visib_px": 0, "toolkit_only_px": 0,
         "gt_info_equal": 0, "bbox_obj_within_1_5px": 0, "points_on_mask": 0, "points": 0,
         "diameter_max_err_mm": 0.0, "images": 0, "px_count_valid_equal": 0, "modality_images": 0}
    for k, e in info.items():
        s["diameter_max_err_mm"] = max(s["diameter_max_err_mm"],
                                       abs(misc.calc_pts_diameter2(models[k]["pts"]) - e["diameter"]))
    for chunk in sorted((root / split).iterdir()):
        sid = int(chunk.name)
        cams = inout.load_scene_camera(P["scene_camera"].format(scene_id=sid))
        gts = inout.load_scene_gt(P["scene_gt"].format(scene_id=sid))
        infos = inout.load_json(P["scene_gt_info"].format(scene_id=sid), keys_to_int=True)
        for im_id, cam in cams.items():
            s["images"] += 1
            K = cam["cam_K"]
            depth = inout.load_depth(C["depth"].format(scene_id=sid, im_id=im_id)) * cam["depth_scale"]
            own_depth = inout.load_depth(P["depth"].format(scene_id=sid, im_id=im_id)) * cam["depth_scale"]
            H, W = depth.shape
            assert own_depth.shape == (H, W)
            if sensor:                          # the scanner's grey image, through its template and loader
                g = inout.load_im(P["gray"].format(scene_id=sid, im_id=im_id))
                s["modality_images"] += int(g.shape[:2] == (H, W))
            dist_test = misc.depth_im_to_dist_im_fast(depth, K)
            for gt_id, (gt, gi) in enumerate(zip(gts[im_id], infos[im_id])):
                s["instances"] += 1
                R, t = gt["cam_R_m2c"], gt["cam_t_m2c"].reshape(3)
                m = models[gt["obj_id"]]
                d_gt = model_depth(m["pts"], m["faces"], K, R, t, W, H)
                dist_gt = misc.depth_im_to_dist_im_fast(d_gt, K)
                visib = visibility.estimate_visib_mask_gt(dist_test, dist_gt, delta_mm, visib_mode="bop19")
                ours = inout.load_im(P["mask_visib"].format(scene_id=sid, im_id=im_id, gt_id=gt_id)) > 0
                diff = int((visib ^ ours).sum())
                s["visib_px_differing"] += diff
                s["toolkit_only_px"] += int((visib & ~ours).sum())     # its 15 mm: touching parts "visible"
                s["visib_px"] += int(ours.sum())
                s["masks_visib_equal"] += diff == 0
                # scene_gt_info from the toolkit's own mask, as calc_gt_info computes it
                px_visib = int(visib.sum())
                bbox_visib = [-1, -1, -1, -1]
                if px_visib:
                    ys, xs = visib.nonzero()
                    bbox_visib = [int(x) for x in misc.calc_2d_bbox(xs, ys, (W, H))]
                s["gt_info_equal"] += (px_visib == gi["px_count_visib"] and bbox_visib == gi["bbox_visib"])
                # model points projected by the toolkit: the box, and the points landing on the mask
                p = misc.project_pts(evals[gt["obj_id"]]["pts"], K, R, t.reshape(3, 1))
                if gi["px_count_visib"] > 0:       # box corners: continuous vs pixel centres
                    b, o = np.asarray(misc.calc_2d_bbox(p[:, 0], p[:, 1])), np.asarray(gi["bbox_obj"], float)
                    corners = np.r_[b[:2] - o[:2], b[:2] + b[2:] - o[:2] - o[2:]]
                    # (a sharp corner of the silhouette may miss the pixel centres next to it)
                    s["bbox_obj_within_1_5px"] += bool(np.abs(corners).max() <= 1.5)
                # points on the silhouette's outline may round to the pixel beside it: one pixel of slack
                full = inout.load_im(P["mask"].format(scene_id=sid, im_id=im_id, gt_id=gt_id)) > 0
                # calc_gt_info: px_count_valid = silhouette pixels with a depth in the image's own depth
                s["px_count_valid_equal"] += int(np.sum(own_depth[full] > 0)) == gi["px_count_valid"]
                full = _dilate(full)
                px = np.rint(p).astype(int)
                inside = (px[:, 0] >= 0) & (px[:, 0] < W) & (px[:, 1] >= 0) & (px[:, 1] < H)
                s["points"] += int(inside.sum())
                s["points_on_mask"] += int(full[px[inside, 1], px[inside, 0]].sum())
    return s
