"""Glossy light in the fringe render: a mirror-like plate beside a diffuse wall.

Geometry (world, m; camera 0.8 m above the floor looking down, projector 0.15 m to its -x side):
a 6 x 6 cm metal plate (metallic 1, roughness 0.05) centred at (0, 0, 0.05), tilted 45 deg so
that camera rays reflect onto the inner face of a diffuse wall 10 cm away, which the projector
lights directly. Two orientations (MIRRORS):

- "along": normal (1, 0, 1)/sqrt(2), wall face x = 0.10. The mirrored light stays in each pixel's
  epipolar plane (the baseline is along x): the ghost lies on the wall point's projector ray.
- "across": normal (1/2, 1/2, 1/sqrt(2)), the same wall face, longer. Rays reflect diagonally:
  the mirrored light leaves the epipolar plane, and the projector sees the ghost 100-215 rows
  away from the wall point's row.

Ground truth is analytic: for each camera pixel, the ray-plate hit P, the mirrored ray's hit W on
the wall face, W's projector column x_W and row y_W (P_proj), and the ghost where the camera ray
meets the projector's column plane of x_W (what a decoder must triangulate from W's phase), with
the row the projector sees the ghost at. The plate itself returns no projector light towards the
camera (a mirror), so its pixels can only be holes or ghosts: the real-scanner artifact the issue
asks for. The global reflection filter (a row code) must remove the "across" ghosts; the "along"
ghosts agree with the row code (no single projector-camera check can see them).
"""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from datapipe import sl  # noqa: E402
from datapipe.core import materials as M  # noqa: E402
from datapipe.core import structured_light as SLM  # noqa: E402
from datapipe.core.projector import projector_matrix  # noqa: E402

from test_structured_light import SEED, _add_box, build, plane_config  # noqa: E402

C_PLATE, HALF, WALL_X, WALL_TOP = np.array([0.0, 0.0, 0.05]), 0.03, 0.10, 0.15
S2 = np.sqrt(0.5)
MIRRORS = {   # plate normal, its in-plane axes, the wall's y extent (its lit face is x = WALL_X)
    "along": (np.array([S2, 0.0, S2]), np.array([S2, 0.0, -S2]), np.array([0.0, 1.0, 0.0]), (-0.1, 0.1)),
    "across": (np.array([0.5, 0.5, S2]), np.array([S2, -S2, 0.0]), np.array([0.5, 0.5, -S2]), (-0.1, 0.2)),
}


def _scene(kind):
    n, u_ax, v_ax, (y0, y1) = MIRRORS[kind]
    cfg = plane_config(res=(160, 120))
    cfg.structured_light.periods = [1, 4, 32]            # ~5 camera px per finest period at 160 px
    cfg.structured_light.fringe_mode = "render"          # mirrored fringes need path-traced patterns; the
                                                         # plate is built here, not configured, so auto cannot see it

    def add_plate_and_wall(scene):
        corners = [tuple(C_PLATE + su * HALF * u_ax + sv * HALF * v_ax) for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        me = bpy.data.meshes.new("plate")
        me.from_pydata(corners, [], [(0, 1, 2, 3)])
        me.update()
        plate = bpy.data.objects.new("plate", me)
        scene.collection.objects.link(plate)
        M.assign(plate, M.build({"name": "mirror", "base_color": [0.9, 0.9, 0.9], "metallic": 1.0, "roughness": 0.05}))
        _add_box(scene, (WALL_X, y0, 0.0), (WALL_X + 0.02, y1, WALL_TOP))

    _, cam, ren, slc, T = build(None, cfg, add=add_plate_and_wall)
    return cfg, cam, ren, slc, T


def _mirror_geometry(cfg, K, T, shape, kind):
    """Per pixel: on the plate (bool), mirrored ray hits the lit wall face (bool), plate depth and
    ghost depth (camera frame, m), and the projector rows of the wall point and of the ghost."""
    n, u_ax, v_ax, (y0, y1) = MIRRORS[kind]
    H, W = shape
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1) @ T[:3, :3].T
    o = T[:3, 3]
    t = ((C_PLATE - o) @ n) / (d @ n)
    P = o + t[..., None] * d
    on_plate = (t > 0) & (np.abs((P - C_PLATE) @ u_ax) < HALF) & (np.abs((P - C_PLATE) @ v_ax) < HALF)
    dr = d - 2 * (d @ n)[..., None] * n
    with np.errstate(divide="ignore", invalid="ignore"):
        tw = (WALL_X - P[..., 0]) / dr[..., 0]
    Wpt = P + tw[..., None] * dr
    hits = on_plate & (tw > 0) & (Wpt[..., 2] > 0) & (Wpt[..., 2] < WALL_TOP) & (Wpt[..., 1] > y0) & (Wpt[..., 1] < y1)
    Pp = projector_matrix(cfg, T)

    def proj(X):
        ph = np.concatenate([X, np.ones(shape + (1,))], -1) @ Pp.T
        return ph[..., 0] / ph[..., 2], ph[..., 1] / ph[..., 2]

    x_w, y_w = proj(Wpt)
    plane = Pp[0] - x_w[..., None] * Pp[2]                  # the projector's column plane of x_w
    s = -(plane[..., :3] @ o + plane[..., 3]) / np.einsum("hwk,hwk->hw", plane[..., :3], d)
    _, y_ghost = proj(o + s[..., None] * d)
    zdir = d @ T[:3, 2]
    return on_plate, hits, t * zdir, s * zdir, y_w, y_ghost


def _render(tmp_path, kind, sharp=True, rows=True):
    cfg, cam, ren, slc, T = _scene(kind)
    assert SLM.has_shiny_surface(slc.scene)                # the plate: roughness 0.05
    slc.set_sharp_glossy(sharp)                            # what process() does for this scene
    rad, _ = slc.render_fringes(tmp_path / kind, SEED, rows=rows)
    geo = _mirror_geometry(cfg, cam.K, T, rad.shape[1:], kind)

    def scan(radiance, **kw):
        return sl.Scanner.from_config(cfg, **kw).scan(radiance, SEED, cam.K, T).result

    return cfg, slc, rad, geo, scan


def test_mirror_plate_gives_ghosts_where_the_mirror_geometry_predicts(tmp_path):
    cfg, slc, rad, (on_plate, hits, z_plate, z_ghost, y_w, y_ghost), scan = _render(tmp_path, "along")
    assert rad.shape[0] == len(cfg.structured_light.periods) * cfg.structured_light.steps + cfg.structured_light.steps
    assert hits.sum() > 150

    res = scan(rad, multipath_filter=False, row_check=False)
    valid = res.valid & hits
    ghost = valid & (np.abs(res.depth - z_ghost) < 5e-3)
    assert not (res.valid & on_plate & (np.abs(res.depth - z_plate) < 5e-3)).any()   # no true plate depth
    assert ghost.sum() >= 5                           # ghost points, where the mirror puts them ...
    assert ghost.sum() >= 0.8 * valid.sum()           # ... and almost nothing else: ghosts or holes
    assert (np.abs(z_ghost - z_plate)[ghost] > 0.1).all()     # floating > 10 cm above the plate
    assert (np.abs(y_ghost - y_w)[hits] < 8).all()    # in the epipolar plane: the row code agrees

    # the filter removes ghosts whose pixel also sees another path, and keeps the floor
    filt = scan(rad, row_check=False)
    assert (filt.valid & ghost).sum() < ghost.sum()
    floor = np.abs(res.depth - 0.8) < 1e-3                  # the floor plane, 0.8 m below the camera
    assert (filt.valid & floor).sum() >= 0.98 * (res.valid & floor).sum()

    # with glossy bounces seeing the blurred pattern (as in a scene without shiny surfaces), the
    # mirror image has no fine fringe and the ghosts vanish: they come from the sharp glossy pattern
    slc.set_sharp_glossy(False)
    blurred = scan(slc.render_fringes(tmp_path / "b", SEED, rows=False)[0], multipath_filter=False)
    assert (blurred.valid & hits & (np.abs(blurred.depth - z_ghost) < 5e-3)).sum() < 0.25 * ghost.sum()


def test_global_reflection_filter_removes_ghosts_that_leave_the_epipolar_plane(tmp_path):
    """The "across" mirror: ghosts the decoder trusts (every frequency sharp, one path, so the local
    filter keeps them), removed by the row code because the projector sees each ghost 100-215 rows
    from where its light left. The row code repeats every H_proj / 8 = 71 rows and is unwrapped by
    the prediction, so a ghost whose mismatch is within a few rows of a whole period is an alias
    and stays (sl.filters.reflection_filter); the analytic geometry says which. The directly lit
    floor keeps its depth."""
    from datapipe.sl.filters import row_residual
    from datapipe.sl.scanner import ROW_PERIODS

    cfg, slc, rad, (on_plate, hits, z_plate, z_ghost, y_w, y_ghost), scan = _render(tmp_path, "across")
    assert hits.sum() > 150
    assert (np.abs(y_ghost - y_w)[hits] > 100).all()             # analytic: far off the epipolar plane
    local = scan(rad, row_check=False)
    ghost = local.valid & hits & (np.abs(local.depth - z_ghost) < 5e-3) & (np.abs(z_ghost - z_plate) > 5e-3)
    assert ghost.sum() >= 20                                      # the local filter leaves them
    period = cfg.projector.resolution[1] / ROW_PERIODS[0]
    alias = np.abs(row_residual(y_w, y_ghost, period)) < 6.0      # within 6 rows of a whole period
    glob = scan(rad)
    assert (glob.valid & ghost & ~alias).sum() <= 0.05 * (ghost & ~alias).sum()
    assert (glob.reason[ghost & ~alias] == sl.Reason.REFLECTION).mean() >= 0.95
    assert (ghost & alias).sum() <= 0.25 * ghost.sum()            # 12 of 71 rows: the filter's blind share
    floor = np.abs(local.depth - 0.8) < 1e-3                      # the floor plane, 0.8 m below the camera
    assert (glob.valid & floor).sum() >= 0.98 * (local.valid & floor).sum()
    # the product's path: "auto" renders the row code on this shiny scene, filters, records it
    assert cfg.structured_light.reflection_filter == "auto"
    _, info = slc.process(tmp_path / "p", SEED, slc.camera.T_world_cam())
    assert info["reflection_filter"] == "global" and info["glossy_fringes"] == "sharp"
    assert info["reasons"]["REFLECTION"] == int((glob.reason == sl.Reason.REFLECTION).sum()) >= 0.9 * (ghost & ~alias).sum()
