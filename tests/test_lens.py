"""Lens distortion (datapipe/lens.py) against OpenCV, the remap's two interpolations, and the decoder's
triangulation through undistorted pixel rays (sl.Triangulator(..., pixels=)). No bpy.

Ground truth: cv2.projectPoints (OpenCV's own implementation of the model), and closed-form ray-plane
intersections."""
import cv2
import numpy as np
import pytest

from datapipe import geometry, lens
from datapipe.sl.triangulate import Triangulator

K = np.array([[300.0, 0.0, 161.3], [0.0, 302.0, 118.7], [0.0, 0.0, 1.0]])
SIZE = (320, 240)
BARREL = np.array([-0.28, 0.09, 0.001, -0.0015, -0.01])
PINCUSHION = np.array([0.18, 0.02, -0.0008, 0.0012, 0.0])


@pytest.mark.parametrize("d", [BARREL, PINCUSHION])
def test_pixel_rays_reproject_through_opencv(d):
    """Each image pixel's ray, projected by cv2.projectPoints with the same K and d, lands on that
    pixel (to 1e-9 px: Newton converges to float64 round-off)."""
    grid = lens.render_grid(K, d, SIZE)
    x, y = grid.ideal_normalised()
    pts = np.stack([x.ravel(), y.ravel(), np.ones(x.size)], axis=1)
    uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, d)
    uu, vv = np.meshgrid(np.arange(SIZE[0]), np.arange(SIZE[1]))
    err = np.abs(uv.reshape(SIZE[1], SIZE[0], 2) - np.stack([uu, vv], axis=-1))
    assert err.max() < 1e-9


@pytest.mark.parametrize("d", [BARREL, PINCUSHION])
def test_render_grid_covers_the_image_at_least_as_finely(d):
    grid = lens.render_grid(K, d, SIZE)
    mx, my = grid.maps()
    wr, hr = grid.render_size
    # every lookup (and its bilinear neighbour) inside the render, MARGIN_PX - 1 pixels to spare
    assert mx.min() >= lens.MARGIN_PX - 1 and mx.max() <= wr - lens.MARGIN_PX
    assert my.min() >= lens.MARGIN_PX - 1 and my.max() <= hr - lens.MARGIN_PX
    # neighbouring image pixels are at least one render pixel apart: the render is nowhere coarser than
    # the image (1e-3: the grid's focal length comes from the lens's stretch on a 33 x 25 grid)
    assert np.hypot(np.diff(mx, axis=1), np.diff(my, axis=1)).min() >= 1.0 - 1e-3
    assert np.hypot(np.diff(mx, axis=0), np.diff(my, axis=0)).min() >= 1.0 - 1e-3
    # the Blender lens shift reproduces the render grid's principal point
    sx, sy = lens.blender_shift(grid)
    Kb = geometry.intrinsics_from_blender_camera(grid.K_render[0, 0] * 11.3 / max(wr, hr), 11.3, wr, hr, "AUTO",
                                                 shift_x=sx, shift_y=sy)
    assert np.allclose(Kb, grid.K_render, atol=1e-9)


def test_remap_spline_for_radiance_nearest_for_ids():
    """A smooth radiance field rendered on the grid comes out at each pixel's true ray within the
    cubic spline's interpolation error (5/384 h^4 max|f''''|, h = 1 render px); an id map comes out
    with ids only (no blend), each the id of the render pixel whose square holds the ray."""
    grid = lens.render_grid(K, BARREL, SIZE)
    wr, hr = grid.render_size
    Kr = grid.K_render
    ur, vr = np.meshgrid(np.arange(wr, dtype=np.float64), np.arange(hr, dtype=np.float64))
    xr, yr = (ur - Kr[0, 2]) / Kr[0, 0], (vr - Kr[1, 2]) / Kr[1, 1]
    w = 40.0                                                   # rad^-1: a period of 0.157 rad, ~47 render px
    radiance = (0.5 + 0.4 * np.sin(w * xr) * np.cos(0.7 * w * yr)).astype(np.float32)
    out = grid.remap(radiance, linear=True)
    x, y = grid.ideal_normalised()
    truth = 0.5 + 0.4 * np.sin(w * x) * np.cos(0.7 * w * y)
    k = np.hypot(w, 0.7 * w) / Kr[0, 0]                    # rad per render px along the steepest direction
    bound = 5 / 384 * 0.4 * k ** 4 * 4 + 1e-6                # x4: the 2-D tensor spline; 1e-6: float32 output
    err = np.abs(out - truth)
    assert out.shape == (SIZE[1], SIZE[0]) and err.max() < bound, (err.max(), bound)
    ids = (np.floor(ur / 7) + 1000 * np.floor(vr / 5)).astype(np.float32)
    got = grid.remap(ids, linear=False)
    assert set(np.unique(got)) <= set(np.unique(ids))
    xs, ys = Kr[0, 0] * x + Kr[0, 2], Kr[1, 1] * y + Kr[1, 2]      # the rays' render coordinates
    assert np.array_equal(got, ids[np.floor(ys + 0.5).astype(int), np.floor(xs + 0.5).astype(int)])


def test_no_distortion_square_pixels_is_the_camera_itself():
    Kc = geometry.intrinsics_from_sensor(16.0, 11.3, 320, 240)
    grid = lens.render_grid(Kc, None, SIZE)
    assert grid.identity and grid.render_size == SIZE
    img = np.arange(12.0).reshape(3, 4)
    assert grid.remap(img, linear=True) is img


def test_triangulation_through_undistorted_rays_finds_the_plane():
    """A tilted plane seen through a barrel lens: the projector column each pixel's true ray hits,
    triangulated with `pixels` = the ideal coordinates, gives the plane's depth (float32 evaluation:
    1e-5 relative); the same columns without `pixels` (rays of a pinhole) miss it by millimetres."""
    grid = lens.render_grid(K, BARREL, SIZE)
    x, y = grid.ideal_normalised()
    n, dist = np.array([0.1, -0.2, 1.0]), 0.8                # plane n . X = dist (camera frame, m)
    n = n / np.linalg.norm(n)
    z = dist / (n[0] * x + n[1] * y + n[2])
    X = np.stack([x * z, y * z, z], axis=-1)
    T_world_cam = np.eye(4)
    T_cam_proj = geometry.pose_matrix([0.12, 0.0, 0.0], geometry.euler_xyz_to_matrix([0.0, -0.15, 0.0]))
    Kp = np.array([[900.0, 0.0, 455.5], [0.0, 900.0, 284.5], [0.0, 0.0, 1.0]])
    P_proj = Kp @ np.linalg.inv(T_cam_proj)[:3]
    P_cam = geometry.projection_matrix(K, T_world_cam)
    xp = (X @ P_proj[:, :3].T + P_proj[:, 3])
    col = (xp[..., 0] / xp[..., 2]).astype(np.float32)
    tri = Triangulator(P_cam, P_proj, SIZE, (912, 570), pixels=grid.ideal_pixels())
    res = tri(col)
    ok = np.isfinite(res.depth)
    row = xp[..., 1] / xp[..., 2]
    inside = (row > 0) & (row < 569) & (col > 0) & (col < 911)       # lit by the projector (1 px inside)
    assert inside.mean() > 0.6 and ok[inside].all() and not ok[~inside & ((row < -1) | (row > 570))].any()
    assert np.nanmax(np.abs(res.depth - z) / z) < 1e-5
    assert np.nanmax(np.linalg.norm(res.points - X, axis=-1)[ok]) < 2e-5
    plain = Triangulator(P_cam, P_proj, SIZE, (912, 570))(col)
    assert np.nanmax(np.abs(plain.depth - z)) > 2e-3
    # depth_slope (the noise model's dZ/dx) follows the same rays: finite where the depth is
    assert np.all(np.isfinite(tri.depth_slope(res.depth)[ok]))


def test_silhouette_through_the_lens_matches_the_rays():
    """A square plate 0.6 m in front of the camera, tessellated 24 x 24: the rasterised silhouette
    with the lens equals the set of pixels whose true (undistorted) ray hits the plate, except pixels
    whose centre lies within a hair of its edge (< 1% of the outline); without the lens it is off by
    a band of pixels. visible_fractions and the BOP export use it (datapipe/visibility.py, io/bop.py)."""
    from datapipe.io.silhouette import rasterize_silhouette
    n, half, Z = 24, 150.0, 600.0                                  # mm
    g = np.linspace(-half, half, n + 1)
    gx, gy = np.meshgrid(g, g)
    verts = np.stack([gx.ravel() + 40.0, gy.ravel() - 25.0, np.zeros(gx.size)], -1)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d_ = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    faces = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d_], -1)])
    t = np.array([0.0, 0.0, Z])
    sil, count, _ = rasterize_silhouette(verts, faces, K, np.eye(3), t, *SIZE, dist=BARREL)
    x, y = lens.render_grid(K, BARREL, SIZE).ideal_normalised()
    X, Y = x * Z, y * Z
    truth = (np.abs(X - 40.0) <= half) & (np.abs(Y + 25.0) <= half)
    outline = np.count_nonzero(truth ^ np.roll(truth, 1, 0)) + np.count_nonzero(truth ^ np.roll(truth, 1, 1))
    assert truth.mean() > 0.2 and np.count_nonzero(sil ^ truth) <= 0.01 * outline
    plain, _, _ = rasterize_silhouette(verts, faces, K, np.eye(3), t, *SIZE)
    assert np.count_nonzero(plain ^ truth) > 0.5 * outline
