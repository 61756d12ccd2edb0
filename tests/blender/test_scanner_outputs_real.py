"""The scanner's outputs from a real (tiny) run: `sl_gray` and `point_cloud` in the native layout,
and the scanner as a BOP-Industrial sensor in the run's own BOP output (issue #30 items 1, 2)."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from datapipe import config as C  # noqa: E402
from datapipe.engine.pipeline import Pipeline  # noqa: E402
from datapipe.io.exr import read_depth  # noqa: E402


def _ply(path):
    """Header and vertices, parsed from the PLY format (tests/sl/test_sl_scanner_outputs.py's reader)."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    lines = data[:end].decode("ascii").splitlines()
    types = {"float": "<f4", "uchar": "u1", "ushort": "<u2"}
    props = [(ln.split()[2], types[ln.split()[1]]) for ln in lines if ln.startswith("property")]
    n = next(int(ln.split()[2]) for ln in lines if ln.startswith("element vertex"))
    return lines, np.frombuffer(data[end:], dtype=np.dtype(props), count=n)


def test_sl_gray_point_cloud_and_bop_sensor(tmp_path):
    cfg = C.default_config()
    cfg.scene.num_renders = 1
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 1
    for o in cfg.objects:
        o.min_instances = o.max_instances = 1
    cfg.camera.resolution = [64, 48]
    cfg.structured_light.enabled = True
    cfg.structured_light.periods = [1, 4, 12]       # ~5 camera px per finest period at 64 px
    cfg.render.samples = 2
    cfg.render.threads = 2
    cfg.render.outputs = ["rgb", "depth", "mask", "sl_gray", "point_cloud"]
    cfg.output.formats = ["native", "bop"]
    out = tmp_path / "o"
    events = list(Pipeline(cfg, out).run())
    assert events[-1].stage == "done"
    sdir = next(out.glob("scene.*"))
    r = json.loads((sdir / "scene.json").read_text())["renders"][0]
    gray = cv2.imread(str(sdir / r["files"]["sl_gray"]), cv2.IMREAD_UNCHANGED)
    assert gray.dtype == np.uint16 and gray.shape == (48, 64) and 0 < gray.max() <= 4095   # 12-bit sensor DN
    depth = read_depth(sdir / r["files"]["sl_depth"]).astype(np.float64)
    valid = np.isfinite(depth)
    assert valid.any()
    lines, v = _ply(sdir / r["files"]["point_cloud"])
    assert "obj_info organised 64 48" in lines and len(v) == 64 * 48
    K = np.array(r["K"])
    vv, uu = np.mgrid[0:48, 0:64]
    ref = np.stack([(uu - K[0, 2]) * depth / K[0, 0], (vv - K[1, 2]) * depth / K[1, 1], depth], -1)
    got = np.stack([v["x"], v["y"], v["z"]], -1).reshape(48, 64, 3).astype(np.float64)
    assert np.abs(got[valid] - ref[valid]).max() < 1e-6 and np.isnan(got[~valid]).all()
    np.testing.assert_array_equal(v["grey"].reshape(48, 64), gray)
    # the run's BOP output: the scanner as sensor "sl" (no device)
    chunk = out / "bop" / "train_pbr" / "000000"
    np.testing.assert_array_equal(cv2.imread(str(chunk / "gray_sl" / "000000.png"), cv2.IMREAD_UNCHANGED), gray)
    d = cv2.imread(str(chunk / "depth_sl" / "000000.png"), cv2.IMREAD_UNCHANGED).astype(np.float64)
    cam = json.loads((chunk / "scene_camera_sl.json").read_text())["0"]
    np.testing.assert_array_equal(d > 0, valid)
    assert np.abs(d[valid] * cam["depth_scale"] - depth[valid] * 1000).max() <= cam["depth_scale"] / 2 + 1e-3
    for name in ("scene_gt_sl.json", "scene_gt_info_sl.json"):
        assert (chunk / name).is_file()
    assert len(list((chunk / "mask_visib_sl").glob("000000_*.png"))) == len(r["objects"])
