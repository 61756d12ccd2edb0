"""Glossy light in the fringe render: a mirror-like plate beside a diffuse wall.

Geometry (world, m; camera 0.8 m above the floor looking down, projector 0.15 m to its -x side):
a 6 x 6 cm metal plate (metallic 1, roughness 0.05) centred at (0, 0, 0.05), its normal
(1, 0, 1)/sqrt(2), so camera rays reflect towards +x onto the face x = 0.10 of a diffuse wall
(0.10..0.12 x -0.1..0.1 x 0..0.15), which the projector lights directly. Ground truth is
analytic: for each camera pixel, the ray-plate hit P, the mirrored ray's hit W on the wall face,
W's projector column x_W (P_proj), and the ghost depth where the camera ray meets the projector's
column plane of x_W (what a decoder must triangulate from W's phase). The plate itself returns no
projector light towards the camera (a mirror), so its pixels can only be holes or ghosts: the
real-scanner artifact the issue asks for.
"""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from datapipe import sl  # noqa: E402
from datapipe.core import materials as M  # noqa: E402
from datapipe.core import structured_light as SLM  # noqa: E402
from datapipe.core.camera import BlendCamera  # noqa: E402
from datapipe.core.projector import projector_matrix  # noqa: E402
from datapipe.core.renderer import Renderer  # noqa: E402
from datapipe.core.scene import BlendScene  # noqa: E402

from test_structured_light import SEED, _add_box, plane_config  # noqa: E402

C_PLATE, N_PLATE = np.array([0.0, 0.0, 0.05]), np.array([1.0, 0.0, 1.0]) / np.sqrt(2)
U_PLATE, V_PLATE, HALF = np.array([1.0, 0.0, -1.0]) / np.sqrt(2), np.array([0.0, 1.0, 0.0]), 0.03
WALL_X, WALL_TOP, WALL_Y = 0.10, 0.15, 0.1


def _scene():
    cfg = plane_config(res=(160, 120))
    cfg.structured_light.periods = [1, 4, 32]            # ~5 camera px per finest period at 160 px
    cfg.structured_light.fringe_mode = "render"          # mirrored fringes need path-traced patterns; the
                                                         # plate is built here, not configured, so auto cannot see it
    blend = BlendScene(cfg).setup()
    corners = [tuple(C_PLATE + su * HALF * U_PLATE + sv * HALF * V_PLATE)
               for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
    me = bpy.data.meshes.new("plate")
    me.from_pydata(corners, [], [(0, 1, 2, 3)])
    me.update()
    plate = bpy.data.objects.new("plate", me)
    blend.scene.collection.objects.link(plate)
    M.assign(plate, M.build({"name": "mirror", "base_color": [0.9, 0.9, 0.9], "metallic": 1.0, "roughness": 0.05}))
    _add_box(blend.scene, (WALL_X, -WALL_Y, 0.0), (WALL_X + 0.02, WALL_Y, WALL_TOP))
    cam = BlendCamera(cfg, blend.scene).setup()
    ren = Renderer(cfg, blend.scene, cam).setup()
    slc = SLM.StructuredLightCamera(cfg, blend.scene, cam, ren)
    slc.setup()
    return cfg, cam, ren, slc, cam.set_pose(0)


def _mirror_geometry(cfg, K, T, shape):
    """Per pixel: on the plate (bool), mirrored ray hits the lit wall face (bool), plate depth and
    ghost depth (camera frame, m)."""
    H, W = shape
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    d = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], -1) @ T[:3, :3].T
    o = T[:3, 3]
    t = ((C_PLATE - o) @ N_PLATE) / (d @ N_PLATE)
    P = o + t[..., None] * d
    on_plate = (t > 0) & (np.abs((P - C_PLATE) @ U_PLATE) < HALF) & (np.abs((P - C_PLATE) @ V_PLATE) < HALF)
    dr = d - 2 * (d @ N_PLATE)[..., None] * N_PLATE
    with np.errstate(divide="ignore", invalid="ignore"):
        tw = (WALL_X - P[..., 0]) / dr[..., 0]
    Wpt = P + tw[..., None] * dr
    hits = on_plate & (tw > 0) & (Wpt[..., 2] > 0) & (Wpt[..., 2] < WALL_TOP) & (np.abs(Wpt[..., 1]) < WALL_Y)
    Pp = projector_matrix(cfg, T)
    ph = np.concatenate([Wpt, np.ones(shape + (1,))], -1) @ Pp.T
    x_w = ph[..., 0] / ph[..., 2]
    plane = Pp[0] - x_w[..., None] * Pp[2]                  # the projector's column plane of x_w
    s = -(plane[..., :3] @ o + plane[..., 3]) / np.einsum("hwk,hwk->hw", plane[..., :3], d)
    zdir = d @ T[:3, 2]
    return on_plate, hits, t * zdir, s * zdir


def test_mirror_plate_gives_ghosts_where_the_mirror_geometry_predicts(tmp_path):
    cfg, cam, ren, slc, T = _scene()
    assert SLM.has_shiny_surface(slc.scene)                # the plate: roughness 0.05
    slc.set_sharp_glossy(True)                             # what process() does for this scene
    rad, _ = slc.render_fringes(tmp_path / "f", SEED)
    on_plate, hits, z_plate, z_ghost = _mirror_geometry(cfg, cam.K, T, rad.shape[1:])
    assert hits.sum() > 150

    def scan(radiance, **kw):
        return sl.Scanner.from_config(cfg, **kw).scan(radiance, SEED, cam.K, T).result

    res = scan(rad, multipath_filter=False)
    valid = res.valid & hits
    ghost = valid & (np.abs(res.depth - z_ghost) < 5e-3)
    assert not (res.valid & on_plate & (np.abs(res.depth - z_plate) < 5e-3)).any()   # no true plate depth
    assert ghost.sum() >= 5                           # ghost points, where the mirror puts them ...
    assert ghost.sum() >= 0.8 * valid.sum()           # ... and almost nothing else: ghosts or holes
    assert (np.abs(z_ghost - z_plate)[ghost] > 0.1).all()     # floating > 10 cm above the plate

    # the filter removes ghosts whose pixel also sees another path, and keeps the floor
    filt = scan(rad)
    assert (filt.valid & ghost).sum() < ghost.sum()
    floor = np.abs(res.depth - 0.8) < 1e-3                  # the floor plane, 0.8 m below the camera
    assert (filt.valid & floor).sum() >= 0.98 * (res.valid & floor).sum()

    # with glossy bounces seeing the blurred pattern (as in a scene without shiny surfaces), the
    # mirror image has no fine fringe and the ghosts vanish: they come from the sharp glossy pattern
    slc.set_sharp_glossy(False)
    blurred = scan(slc.render_fringes(tmp_path / "b", SEED)[0], multipath_filter=False)
    assert (blurred.valid & hits & (np.abs(blurred.depth - z_ghost) < 5e-3)).sum() < 0.25 * ghost.sum()
