"""The scanner's own outputs (issue #30 item 2): its grey image (render output `sl_gray`) and its
organised point cloud (`point_cloud`, a binary PLY), from a synthetic plane scan.

The PLY is read back by a parser written here from the PLY format (header lines, then one numpy
structured record per vertex), and by plyfile where it is importable; points are checked against
the depth back-projected with K here (float64), to 1e-6 m."""
from __future__ import annotations

import numpy as np
import pytest
from sl_helpers import PERIODS, STEPS

from datapipe import sl
from datapipe.io.point_cloud import write_point_cloud
from datapipe.sl.gray_image import fringe_mean


def _scanner(cam, proj, **kw):
    return sl.Scanner(PERIODS, STEPS, proj.size, proj.K, np.linalg.inv(cam.T) @ proj.T, **kw)


@pytest.fixture(scope="module")
def scan(rig, plane_render):
    cam, proj = rig
    return _scanner(cam, proj, sensor="industrial").scan(plane_render.images.astype(np.float32), 11, cam.K, cam.T)


def test_gray_is_the_fringe_mean_with_the_sensor_noise(rig, plane_render, scan):
    """Expected grey = mean radiance of the F x N frames x DN per radiance unit at the scan's
    exposure; its noise is the sensor's at that signal divided by sqrt(F x N) (independent frames),
    plus rounding to whole DN (1/12 DN^2)."""
    model = sl.SensorModel.preset("industrial")
    g = scan.gray()
    assert g.dtype == np.uint16 and g.shape == plane_render.images.shape[1:]
    assert g.max() <= 4095                                     # 12-bit DN, not scaled to 16 bits
    dn = scan.exposure * model.electrons_per_unit / model.gain
    expected = plane_render.images[:len(PERIODS) * STEPS].astype(np.float64).mean(axis=0) * dn
    lit = plane_render.lit & (expected > 50)
    n = len(PERIODS) * STEPS
    sigma = np.sqrt(model.noise_sigma(expected) ** 2 / n + 1 / 12)
    z = (g[lit] - expected[lit]) / sigma[lit]
    assert abs(z.mean()) < 0.1                                  # unbiased (tens of thousands of pixels)
    assert 0.85 < z.std() < 1.15, z.std()                       # the sensor's noise, averaged over n frames
    assert np.abs(z).max() < 6


def test_gray_bit_depth_follows_the_sensor():
    frames = np.full((4, 2, 3), 300.7)
    assert fringe_mean(frames, 4, 8).dtype == np.uint8 and fringe_mean(frames, 4, 8).max() == 255   # clipped
    assert fringe_mean(frames, 4, 12).dtype == np.uint16 and fringe_mean(frames, 4, 12)[0, 0] == 301
    assert fringe_mean(np.full((2, 1, 1), 1e6), 2, None)[0, 0] == 65535                 # no ADC: 16-bit range


PLY_TYPES = {"float": "<f4", "uchar": "u1", "ushort": "<u2"}


def read_ply_ref(path):
    """Header fields and the vertex records, parsed from the PLY format itself."""
    data = path.read_bytes()
    end = data.index(b"end_header\n") + len(b"end_header\n")
    lines = data[:end].decode("ascii").splitlines()
    assert lines[0] == "ply" and lines[1] == "format binary_little_endian 1.0"
    organised = [ln.split()[2:] for ln in lines if ln.startswith("obj_info organised")]
    count = next(int(ln.split()[2]) for ln in lines if ln.startswith("element vertex"))
    props = [(ln.split()[2], PLY_TYPES[ln.split()[1]]) for ln in lines if ln.startswith("property")]
    v = np.frombuffer(data[end:], dtype=np.dtype(props), count=count)
    assert len(data) == end + count * np.dtype(props).itemsize     # nothing after the vertices
    return [int(x) for x in organised[0]], v


def check_cloud(v, W, H, depth, K, gray, conf):
    assert len(v) == W * H
    assert {"x", "y", "z", "grey", "confidence", "nx", "ny", "nz"} <= set(v.dtype.names)
    vv, uu = np.mgrid[0:H, 0:W]
    z = depth.astype(np.float64)
    valid = np.isfinite(z)
    X = (uu - K[0, 2]) * z / K[0, 0]
    Y = (vv - K[1, 2]) * z / K[1, 1]
    got = np.stack([v["x"], v["y"], v["z"]], -1).reshape(H, W, 3).astype(np.float64)
    ref = np.stack([X, Y, z], -1)
    assert np.abs(got[valid] - ref[valid]).max() < 1e-6                  # metres
    assert np.isnan(got[~valid]).all()                                    # invalid pixels: NaN
    np.testing.assert_array_equal(np.asarray(v["grey"]).reshape(H, W), gray)
    c = np.asarray(v["confidence"]).reshape(H, W)
    np.testing.assert_allclose(c[valid], conf[valid], rtol=0, atol=0)
    assert (c[~valid] == 0).all()
    n = np.stack([v["nx"], v["ny"], v["nz"]], -1).reshape(H, W, 3).astype(np.float64)
    return valid, n


def test_point_cloud_round_trip(rig, scan, tmp_path):
    cam, _ = rig
    res = scan.result
    H, W = res.depth.shape
    gray = scan.gray()
    path = tmp_path / "point_cloud.ply"
    write_point_cloud(path, res.depth, cam.K, gray, res.confidence)
    (w, h), v = read_ply_ref(path)
    assert (w, h) == (W, H)
    valid, n = check_cloud(v, W, H, res.depth, cam.K, gray, res.confidence)
    assert valid.mean() > 0.5
    # the plane z = 0 of the world, seen from 1 m above: its normal in the camera frame, towards the camera
    n_true = np.linalg.inv(cam.T)[:3, :3] @ np.array([0.0, 0.0, 1.0])
    n_true = n_true if n_true[2] < 0 else -n_true
    inner = valid.copy()
    inner[1:-1, 1:-1] &= valid[:-2, 1:-1] & valid[2:, 1:-1] & valid[1:-1, :-2] & valid[1:-1, 2:]
    ok = inner & np.isfinite(n).all(-1)
    assert ok.mean() > 0.4
    # central differences over 2 px of a 0.13 mm-noise surface: a few degrees per pixel
    ang = np.degrees(np.arccos(np.clip(n[ok] @ n_true, -1, 1)))
    assert np.median(ang) < 5, np.median(ang)
    assert (n[ok][:, 2] < 0).all()                              # every normal faces the camera


@pytest.fixture
def scan_cloud(rig, scan, tmp_path):
    """The scan's point cloud written as the pipeline writes it: (its path, its number of points, the
    check of a reader's vertex records against the scan)."""
    cam, _ = rig
    res = scan.result
    H, W = res.depth.shape
    path = tmp_path / "point_cloud.ply"
    write_point_cloud(path, res.depth, cam.K, scan.gray(), res.confidence)
    return path, W * H, lambda v: check_cloud(v, W, H, res.depth, cam.K, scan.gray(), res.confidence)


def test_point_cloud_with_plyfile(scan_cloud):
    plyfile = pytest.importorskip("plyfile", reason="plyfile not installed (the numpy reader above still runs)")
    path, _, check = scan_cloud
    check(plyfile.PlyData.read(str(path))["vertex"].data)


def test_point_cloud_8bit_grey(tmp_path):
    K = np.array([[100.0, 0, 1.5], [0, 100.0, 1.0], [0, 0, 1]])
    depth = np.array([[1.0, np.nan, 1.0, 1.0], [1.0, 1.0, 1.0, 1.0], [1.0, 1.0, 1.0, 1.0]], np.float32)
    gray = np.arange(12, dtype=np.uint8).reshape(3, 4)
    write_point_cloud(tmp_path / "p.ply", depth, K, gray)
    (w, h), v = read_ply_ref(tmp_path / "p.ply")
    assert (w, h) == (4, 3) and v.dtype["grey"] == np.uint8
    valid, n = check_cloud(v, 4, 3, depth, K, gray, np.zeros((3, 4), np.float32))
    has = np.isfinite(n).all(-1)
    # (0, 0): the border on its left, a hole on its right -- no row difference, so no normal
    np.testing.assert_array_equal(has, valid & ~((np.arange(12) == 0).reshape(3, 4)))
    np.testing.assert_allclose(n[has], np.tile([0, 0, -1.0], (has.sum(), 1)), atol=1e-6)   # a fronto-parallel plane


def test_point_cloud_with_trimesh(scan_cloud):
    trimesh = pytest.importorskip("trimesh", reason="trimesh not installed (the numpy reader above still runs)")
    path, n_points, check = scan_cloud
    cloud = trimesh.load(str(path))
    assert isinstance(cloud, trimesh.PointCloud) and len(cloud.vertices) == n_points     # NaN points kept
    check(cloud.metadata["_ply_raw"]["vertex"]["data"])


def test_point_cloud_of_a_distorting_lens_projects_back_onto_its_pixels(tmp_path):
    """With camera.distortion each point lies on its pixel's undistorted ray (datapipe/lens.py), so
    OpenCV's own projectPoints with K and the distortion maps it back onto that pixel; the pinhole
    back-projection misses by pixels at the corners of a barrel lens."""
    import cv2
    from datapipe.lens import render_grid
    K = np.array([[220.0, 0, 80.3], [0, 215.0, 59.6], [0, 0, 1]])
    d = [-0.25, 0.08, 0.001, -0.0015, 0.0]
    W, H = 160, 120
    grid = render_grid(K, d, (W, H))
    depth = np.full((H, W), 0.8, np.float32)
    depth[:10, :10] = np.nan
    gray = np.zeros((H, W), np.uint8)
    path = tmp_path / "p.ply"
    write_point_cloud(path, depth, K, gray, rays=grid.ideal_normalised())
    (w, h), v = read_ply_ref(path)
    pts = np.stack([v["x"], v["y"], v["z"]], -1).astype(np.float64).reshape(H, W, 3)
    valid = np.isfinite(pts[..., 2])
    assert (~valid).sum() == 100 and np.isnan(pts[~valid]).all()
    np.testing.assert_allclose(pts[valid][:, 2], 0.8, rtol=1e-6)
    uv, _ = cv2.projectPoints(pts[valid].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.asarray(d))
    vv, uu = np.nonzero(valid)
    # float32 points at 0.8 m: 6e-8 m of rounding is ~2e-5 px at f = 220 px
    err = np.hypot(uv[:, 0, 0] - uu, uv[:, 0, 1] - vv)
    assert err.max() < 1e-3, err.max()
    pin = write_point_cloud(tmp_path / "q.ply", depth, K, gray) or read_ply_ref(tmp_path / "q.ply")[1]
    p2 = np.stack([pin["x"], pin["y"], pin["z"]], -1).astype(np.float64).reshape(H, W, 3)
    uv2, _ = cv2.projectPoints(p2[valid].reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, np.asarray(d))
    assert np.hypot(uv2[:, 0, 0] - uu, uv2[:, 0, 1] - vv).max() > 2.0     # the check can fail
