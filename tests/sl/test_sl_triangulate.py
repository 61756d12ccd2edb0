"""Camera helpers and closed-form triangulation against analytic geometry."""
import re
from pathlib import Path

import numpy as np
import pytest

import datapipe
import synth
from datapipe.errors import DataPipeError
from datapipe.geometry import intrinsics_from_sensor
from datapipe.sl import Triangulator, intrinsics_from_blender, intrinsics_from_blender_camera, projection_matrix


@pytest.mark.parametrize("w, h, fit, f", [
    (640, 480, "AUTO", 50 * 640 / 36), (480, 640, "AUTO", 50 * 640 / 36),
    (480, 640, "HORIZONTAL", 50 * 480 / 36), (640, 480, "VERTICAL", 50 * 480 / 24),
])
def test_intrinsics_from_blender_camera(w, h, fit, f):
    K = intrinsics_from_blender_camera(50, 36, w, h, fit)
    np.testing.assert_allclose(K, [[f, 0, w / 2 - 0.5], [0, f, h / 2 - 0.5], [0, 0, 1]])
    # the deprecated sl name is the same function in behaviour, defaults included
    with pytest.warns(DeprecationWarning):
        np.testing.assert_array_equal(intrinsics_from_blender(50, 36, w, h, fit), K)


def test_the_deprecated_name_says_the_version_that_removes_it():
    """scikit-image's rule: a deprecation names the release that removes it, and that release is still
    ahead (when the package reaches it, this fails: remove the alias, its export and this test)."""
    with pytest.warns(DeprecationWarning, match="intrinsics_from_blender_camera") as caught:
        intrinsics_from_blender(50, 36, 640, 480)
    assert caught[0].filename == __file__                      # the warning points at the caller's line
    found = re.search(r"removed in DataPipe (\d+)\.(\d+)\.(\d+)", str(caught[0].message))
    assert found, str(caught[0].message)
    removed = tuple(int(v) for v in found.groups())
    assert removed > tuple(int(v) for v in datapipe.__version__.split("."))
    api = (Path(__file__).resolve().parents[2] / "docs" / "API.md").read_text()
    assert re.search(r"`sl\.intrinsics_from_blender`.*\| " + re.escape(".".join(found.groups())) + r" \|", api)


@pytest.mark.parametrize("w, h, fit, f", [
    (640, 480, "AUTO", 50 * 640 / 36), (480, 640, "HORIZONTAL", 50 * 480 / 36),
    (640, 480, "VERTICAL", 50 * 480 / 36),     # one sensor size: 36 mm is the height here
])
def test_intrinsics_from_sensor_one_size(w, h, fit, f):
    K = intrinsics_from_sensor(50, 36, w, h, fit)
    np.testing.assert_allclose(K, [[f, 0, w / 2 - 0.5], [0, f, h / 2 - 0.5], [0, 0, 1]])
    np.testing.assert_array_equal(K, intrinsics_from_blender_camera(50, 36, w, h, fit, sensor_height_mm=36))


def test_intrinsics_lens_shift_and_errors():
    K = intrinsics_from_blender_camera(50, 36, 640, 480, shift_x=0.1, shift_y=-0.05)
    assert K[0, 2] == pytest.approx(319.5 - 64) and K[1, 2] == pytest.approx(239.5 - 32)
    with pytest.raises(ValueError, match="sensor_fit"):
        intrinsics_from_blender_camera(50, 36, 640, 480, "DIAGONAL")
    with pytest.raises(ValueError, match="focal_mm"):
        intrinsics_from_sensor(0, 36, 640, 480)


def test_projection_matrix_matches_pose():
    cam, _ = synth.make_rig()
    P = projection_matrix(cam.K, cam.T)
    X = np.array([0.1, -0.2, 0.05, 1.0])
    p = P @ X
    uv, z = cam.project(X[:3])
    np.testing.assert_allclose(p[:2] / p[2], uv, atol=1e-9)
    assert p[2] == pytest.approx(z)           # third row gives the camera-frame depth
    bad = cam.T.copy()
    bad[:3, :3] *= 2
    with pytest.raises(ValueError, match="rotation"):
        projection_matrix(cam.K, bad)
    with pytest.raises(ValueError, match="NaN"):
        projection_matrix(cam.K * np.nan, cam.T)


def _random_points(cam, n, rng, zmin=0.6, zmax=1.2):
    w, h = cam.size
    idx = rng.choice(w * h, n, replace=False)
    u, v = idx % w, idx // w
    z = rng.uniform(zmin, zmax, n)
    d = np.stack([u, v, np.ones(n)], -1) @ np.linalg.inv(cam.K).T
    return u, v, z, z[:, None] * d           # camera frame points


@pytest.mark.parametrize("axis", ["x", "y"])
def test_roundtrip_depth_and_points(axis):
    """Project camera-frame points into the projector (analytic, float64), triangulate back from
    the projector coordinate: error = |dZ/dx| * ulp(x)/2 from storing x in float32 plus the
    float32 evaluation (~1 ulp of x and of Z): bound 3 * slope * ulp(x) + 4 ulp(Z)."""
    off = (0.15, 0.0, 0.0) if axis == "x" else (0.0, 0.15, 0.0)
    cam, proj = synth.make_rig(proj_offset=off)
    tri = Triangulator(cam.P, proj.P, cam.size, proj.size, axis=axis)
    rng = np.random.default_rng(0)
    u, v, z, Xc = _random_points(cam, 5000, rng)
    Xw = Xc @ cam.T[:3, :3].T + cam.T[:3, 3]
    pxy, _ = proj.project(Xw)
    x = pxy[:, 0] if axis == "x" else pxy[:, 1]
    xmap = np.full((cam.size[1], cam.size[0]), np.nan, np.float32)
    xmap[v, u] = x
    res = tri(xmap, check_other_axis=False)
    zz = res.depth[v, u].astype(float)
    zmap = np.full(xmap.shape, np.nan)
    zmap[v, u] = z
    slope = tri.depth_slope(zmap)[v, u].astype(float)
    bound = 3 * slope * np.spacing(np.abs(x).astype(np.float32)) + 4 * np.spacing(z.astype(np.float32))
    assert np.all(np.abs(zz - z) <= bound)
    np.testing.assert_allclose(res.points[v, u], Xc, atol=5e-6)
    np.testing.assert_allclose(tri.project(Xc), pxy, atol=1e-9)


def test_scaled_and_negated_matrices_give_same_depth(rig):
    cam, proj = rig
    x = np.full((cam.size[1], cam.size[0]), 250.0, np.float32)
    a = Triangulator(cam.P, proj.P, cam.size, proj.size)(x).depth
    b = Triangulator(-3.7 * cam.P, 0.01 * proj.P, cam.size, proj.size)(x).depth
    np.testing.assert_allclose(a, b, rtol=1e-6)


def test_depth_slope_matches_analytic(rig):
    cam, proj = rig
    r = synth.render(synth.plane_scene(), cam, proj, (1,), 3)
    tri = Triangulator(cam.P, proj.P, cam.size, proj.size)
    np.testing.assert_allclose(tri.depth_slope(r.depth), synth.depth_slope(cam, proj, r.depth), rtol=1e-4)


def test_ray_in_projector_column_plane_is_flagged_without_inf():
    """Projector 0.3 m behind the camera on its optical axis, axes parallel: the camera's centre
    column (u = cx = 80 for W = 161) lies exactly in the projector column plane x = cx_p
    (q = 0: no depth information); neighbouring columns exceed the default cap |dZ/dx| <= Z."""
    cam, proj = synth.make_rig(cam_size=(161, 121), proj_offset=(0, 0, -0.3), converge=False)
    tri = Triangulator(cam.P, proj.P, cam.size, proj.size)
    r = synth.render(synth.plane_scene(), cam, proj, (1,), 3)
    x = np.where(np.isfinite(r.proj_x), r.proj_x, 0).astype(np.float32)
    res = tri(x)
    assert np.all(res.ill_conditioned[:, 80])
    assert not np.isinf(res.depth).any() and not np.isinf(res.points).any()
    slope = synth.depth_slope(cam, proj, r.depth)
    np.testing.assert_array_equal(res.ill_conditioned, ~(slope <= r.depth))
    ok = ~res.ill_conditioned
    assert np.isfinite(res.depth[ok]).all()


@pytest.mark.parametrize("kw, exc, msg", [
    (dict(P_cam=np.full((3, 4), np.nan)), ValueError, "P_cam: contains NaN"),
    (dict(P_proj=np.zeros((4, 4))), ValueError, "P_proj: has shape"),
    (dict(P_cam=np.zeros((3, 4))), ValueError, "singular"),
    (dict(proj_size=(0, 10)), ValueError, "proj_size"),
    (dict(cam_size="big"), TypeError, "cam_size"),
])
def test_bad_geometry(rig, kw, exc, msg):
    cam, proj = rig
    args = dict(P_cam=cam.P, P_proj=proj.P, cam_size=cam.size, proj_size=proj.size)
    args.update(kw)
    with pytest.raises(exc, match=msg) as ei:
        Triangulator(**args)
    assert isinstance(ei.value, DataPipeError)


@pytest.mark.parametrize("lens", [False, True])
def test_at_pixels_matches_analytic_depth_and_the_slab(lens):
    """`Triangulator.at` (the neighbour pass re-triangulates only the pixels it decided): depth of
    analytic points within the round trip's float32 bound, and the same depth / flags as the
    whole-row evaluation at those pixels (per-pixel coefficients too: a distorting lens' ideal
    pixel coordinates, here the pixel grid moved by up to 2 px)."""
    cam, proj = synth.make_rig(proj_offset=(0.15, 0.0, 0.0))
    w, h = cam.size
    pixels = None
    if lens:
        vv, uu = np.mgrid[0:h, 0:w].astype(np.float64)
        pixels = np.stack([uu + 2 * np.sin(vv / h), vv - 2 * np.cos(uu / w)], -1)
    tri = Triangulator(cam.P, proj.P, cam.size, proj.size, pixels=pixels)
    rng = np.random.default_rng(1)
    u, v, z, Xc = _random_points(cam, 3000, rng)
    if lens:                                 # the pixel sees the ray through its ideal coordinates
        uv = pixels[v, u]
        Xc = z[:, None] * (np.stack([uv[:, 0], uv[:, 1], np.ones(u.size)], -1) @ np.linalg.inv(cam.K).T)
    Xw = Xc @ cam.T[:3, :3].T + cam.T[:3, 3]
    x = proj.project(Xw)[0][:, 0]
    flat = v * w + u
    zz, ill, out = tri.at(x.astype(np.float32), flat)
    zmap = np.full((h, w), np.nan)
    zmap[v, u] = z
    slope = tri.depth_slope(zmap)[v, u].astype(float)
    bound = 3 * slope * np.spacing(np.abs(x).astype(np.float32)) + 4 * np.spacing(z.astype(np.float32))
    assert np.all(np.abs(zz - z) <= bound)
    xmap = np.full((h, w), 250.0, np.float32)
    xmap[v, u] = x
    zs, ills, outs = tri.slab(xmap, 0, h)
    # the same IEEE float32 operations on the same operands: equal, not merely close (the decoder's
    # "same outputs" rests on it)
    np.testing.assert_array_equal(zz, zs[v, u])
    np.testing.assert_array_equal(ill, ills[v, u])
    np.testing.assert_array_equal(out, outs[v, u])
