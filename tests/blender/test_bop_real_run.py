"""End to end on a tiny real Blender run: `python -m datapipe demo`, then the BOP export read back
with the independent readers of tests/bop_reference.py (moved here from tests/test_bop.py: it runs
the real pipeline, so it belongs beside the other Blender tests)."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from datapipe.io.bop import export_bop

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from bop_reference import iter_gt, ref_png, ref_read_ply  # noqa: E402


@pytest.mark.slow
def test_real_tiny_run_exports_to_bop(tmp_path):
    """End to end on a tiny real run: `python -m datapipe demo`, then BOP export read back.

    Without the demo's structured light (`--structured-light off`): everything read back here is the
    native layer's (depth/, masks, poses, models), and the fringes with their decode were 9.8 of the
    demo's 34 CPU seconds. The demo preset with structured light runs in test_snapshot.py, a real
    run's BOP scanner folders in test_scanner_outputs_real.py."""
    out = tmp_path / "demo"
    r = subprocess.run([sys.executable, "-m", "datapipe", "demo", "--out", str(out), "--force",
                        "--structured-light", "off"], capture_output=True, text=True, timeout=1800)
    assert r.returncode == 0, r.stderr[-3000:]
    root = tmp_path / "bop"
    summary = export_bop(out, root)
    assert summary["images"] >= 1
    checked = 0
    rng = np.random.default_rng(0)
    bary = np.vstack([[1 / 3, 1 / 3, 1 / 3], rng.dirichlet([2, 2, 2], size=12)])
    for image_id, cdir, im_id, cam_e, gts, infos in iter_gt(root):
        K = np.array(cam_e["cam_K"]).reshape(3, 3)
        depth_mm = ref_png(cdir / "depth" / f"{im_id:06d}.png").astype(np.float64) * cam_e["depth_scale"]
        H, W = depth_mm.shape
        for gt_id, (g, inf) in enumerate(zip(gts, infos)):
            mv = ref_png(cdir / "mask_visib" / f"{im_id:06d}_{gt_id:06d}.png") > 0
            mfull = ref_png(cdir / "mask" / f"{im_id:06d}_{gt_id:06d}.png") > 0
            assert inf["px_count_visib"] == mv.sum()
            assert 0.0 <= inf["visib_fract"] <= 1.0
            assert not (mv & ~mfull).any()
            V, F = ref_read_ply(root / "models" / f"obj_{g['obj_id']:06d}.ply")
            R = np.array(g["cam_R_m2c"]).reshape(3, 3)
            pc = V[:, :3] @ R.T + np.array(g["cam_t_m2c"])
            uv = pc @ K.T
            uv = uv[:, :2] / uv[:, 2:]
            # an independent silhouette: cv2.fillConvexPoly per triangle (1/16 px precision)
            sil = np.zeros((H, W), np.uint8)
            for tri in F:
                cv2.fillConvexPoly(sil, np.rint((uv[tri] - 0.0) * 16).astype(np.int32), 1, lineType=cv2.LINE_8,
                                   shift=4)
            sil = sil > 0
            # fillConvexPoly also fills pixels an edge only touches: compare with a 1-px tolerance
            if inf["px_count_visib"] > 100:
                assert (mv & sil).sum() / mv.sum() > 0.97, (image_id, gt_id)   # visible part inside the posed model
            core = cv2.erode(sil.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
            if core.sum() > 100:
                assert (core & ~mfull).sum() / core.sum() < 0.03, (image_id, gt_id)
            # points on the model's faces that the depth image sees (3x3 window within 2 mm) land on mask_visib
            tri = V[:, :3][F]                                             # (F,3,3)
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]) @ R.T
            pts = np.einsum("sk,fkd->fsd", bary, tri).reshape(-1, 3) @ R.T + np.array(g["cam_t_m2c"])
            n = np.repeat(n, len(bary), axis=0)
            grazing = np.abs((n * pts).sum(1)) < 0.3 * np.linalg.norm(n, axis=1) * np.linalg.norm(pts, axis=1)
            uvp = pts @ K.T
            px = np.rint(uvp[:, :2] / uvp[:, 2:]).astype(int)
            ok = ~grazing & (px[:, 0] >= 1) & (px[:, 0] < W - 1) & (px[:, 1] >= 1) & (px[:, 1] < H - 1)
            px, z = px[ok], pts[ok, 2]
            win = np.stack([depth_mm[px[:, 1] + dy, px[:, 0] + dx] for dy in (-1, 0, 1) for dx in (-1, 0, 1)])
            vis = np.abs(win - z).max(0) < 2.0
            if vis.sum() >= 10:
                checked += 1
                assert mv[px[vis, 1], px[vis, 0]].mean() > 0.9, (image_id, gt_id)
    assert checked >= 1
