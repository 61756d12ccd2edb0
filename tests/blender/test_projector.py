"""Projector: pure math, ground-truth geometry through Cycles, view-layer isolation, shadows, teardown.

The geometry test renders phase-shifted fringes on a tilted plane, decodes the projector column
(and row) per camera pixel with a plain N-step arctan + hierarchical unwrap written here, and
compares with the column that P_proj gives for the analytic plane point of each pixel.
"""
import math
import time

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from blender_probes import light_world_pose  # noqa: E402
from datapipe.config import Config  # noqa: E402
from datapipe.core import projector as pj  # noqa: E402
from datapipe.errors import DataPipeError  # noqa: E402
from datapipe.io.exr import read_exr  # noqa: E402
from datapipe.geometry import (blender_camera_to_opencv,  # noqa: E402
                               euler_xyz_to_matrix, intrinsics_from_sensor, matrix_to_quat)

CAM_W, CAM_H = 128, 96
CAM_F, CAM_SENSOR = 16.0, 11.3
TIMINGS = {}


# ------------------------------------------------------------------------------------------------
# scene helpers

def _cfg(samples=16, **proj):
    cfg = Config()
    cfg.structured_light.enabled = True
    cfg.structured_light.samples = samples
    for k, v in proj.items():
        setattr(cfg.projector, k, v)
    return cfg


def _setup_scene(world_strength=0.0):
    sc = bpy.context.scene
    sc.render.engine = "CYCLES"
    sc.cycles.device = "CPU"
    sc.cycles.samples = 4
    sc.cycles.use_denoising = False
    sc.cycles.seed = 0
    sc.render.threads_mode = "FIXED"
    sc.render.threads = 2
    sc.render.resolution_x, sc.render.resolution_y = CAM_W, CAM_H
    sc.render.resolution_percentage = 100
    sc.render.use_single_layer = False
    sc.view_settings.view_transform = "Standard"
    sc.view_settings.look = "None"
    sc.view_settings.exposure = 0.0
    sc.view_settings.gamma = 1.0
    sc.render.dither_intensity = 0.0
    sc.render.film_transparent = False
    world = bpy.data.worlds.new("datapipe_world")
    if world.node_tree is None:
        world.use_nodes = True
    bg = next(n for n in world.node_tree.nodes if n.bl_idname == "ShaderNodeBackground")
    bg.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    bg.inputs["Strength"].default_value = world_strength
    sc.world = world
    return sc


def _add_camera(sc, location=(0.0, 0.0, 0.0), quat=(1.0, 0.0, 0.0, 0.0)):
    from mathutils import Quaternion, Vector

    camd = bpy.data.cameras.new("cam")
    camd.lens, camd.sensor_width, camd.sensor_fit = CAM_F, CAM_SENSOR, "AUTO"
    camd.clip_start, camd.clip_end = 0.01, 100.0
    cam = bpy.data.objects.new("cam", camd)
    sc.collection.objects.link(cam)
    cam.location = Vector(location)
    cam.rotation_mode = "QUATERNION"
    cam.rotation_quaternion = Quaternion(quat)
    sc.camera = cam
    bpy.context.view_layer.update()
    return cam


def _mesh_object(sc, name, verts, faces, T_world):
    from mathutils import Matrix

    me = bpy.data.meshes.new(name)
    me.from_pydata([tuple(v) for v in verts], [], faces)
    me.update()
    ob = bpy.data.objects.new(name, me)
    sc.collection.objects.link(ob)
    ob.matrix_world = Matrix([list(r) for r in np.asarray(T_world, dtype=float)])
    return ob


def _add_plane(sc, T_world, half=2.0):
    """Square in its local xy plane (normal +z) - white diffuse by default material."""
    v = [(-half, -half, 0), (half, -half, 0), (half, half, 0), (-half, half, 0)]
    return _mesh_object(sc, "plane", v, [(0, 1, 2, 3)], T_world)


def _add_box(sc, lo, hi):
    (x0, y0, z0), (x1, y1, z1) = lo, hi
    v = [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0),
         (x0, y0, z1), (x1, y0, z1), (x1, y1, z1), (x0, y1, z1)]
    f = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]
    return _mesh_object(sc, "box", v, f, np.eye(4))


def _render(sc, tmp_path, layer_names, tag="r"):
    """Render all enabled view layers once; return {layer name: (H, W) red channel, row 0 = top}."""
    if bpy.app.version >= (5, 0, 0):
        tree = sc.compositing_node_group
        if tree is None:
            tree = bpy.data.node_groups.new("test_compositor", "CompositorNodeTree")
            sc.compositing_node_group = tree
    else:
        sc.use_nodes = True
        tree = sc.node_tree
    tree.nodes.clear()
    fo = tree.nodes.new("CompositorNodeOutputFile")
    fmt = fo.format
    if bpy.app.version >= (5, 0, 0):
        fo.directory, fo.file_name = str(tmp_path), f"{tag}_"
        fmt.media_type = "MULTI_LAYER_IMAGE"
        fmt.file_format = "OPEN_EXR_MULTILAYER"
        for name in layer_names:
            fo.file_output_items.new("RGBA", name)
        path = tmp_path / f"{tag}_.exr"
    else:
        fo.base_path = str(tmp_path / f"{tag}_")
        fmt.file_format = "OPEN_EXR_MULTILAYER"
        fo.layer_slots.clear()
        for name in layer_names:
            fo.layer_slots.new(name)
        path = tmp_path / f"{tag}_0001.exr"
    fmt.color_depth = "32"
    for name in layer_names:
        rl = tree.nodes.new("CompositorNodeRLayers")
        rl.layer = name
        tree.links.new(rl.outputs["Image"], fo.inputs[name])
    t = time.perf_counter()
    bpy.ops.render.render(write_still=False)
    TIMINGS[tag] = time.perf_counter() - t
    ch = read_exr(path)
    return {name: ch[f"{name}.R"].astype(np.float64) for name in layer_names}


def _fringes(width, height, periods, steps, axis="x", a=0.5, b=0.5):
    """docs/CONVENTIONS.md: I = a + b*cos(2*pi*K*x/Wp + 2*pi*n/N), frequency-major; axis 'y' uses rows/height."""
    length = width if axis == "x" else height
    coord = np.arange(length, dtype=np.float64)
    out = []
    for K in periods:
        for n in range(steps):
            line = a + b * np.cos(2 * np.pi * K * coord / length + 2 * np.pi * n / steps)
            out.append(np.broadcast_to(line[None, :] if axis == "x" else line[:, None], (height, width)))
    return np.asarray(out, dtype=np.float32)


def _decode(stack, periods, steps, length):
    """N-step least squares phase per frequency + hierarchical (coarse-to-fine) temporal unwrap.

    Returns (coordinate with pixel centres at integers, modulation of the finest frequency)."""
    shifts = 2 * np.pi * np.arange(steps) / steps
    coord = None
    for j, K in enumerate(periods):
        imgs = stack[j * steps:(j + 1) * steps]
        C = np.tensordot(np.cos(shifts), imgs, axes=1)
        S = np.tensordot(np.sin(shifts), imgs, axes=1)
        phi = np.mod(np.arctan2(-S, C), 2 * np.pi)           # I_n = a + b cos(phi + shift_n)
        T = length / K
        wrapped = phi / (2 * np.pi) * T
        coord = wrapped if coord is None else wrapped + T * np.round((coord - wrapped) / T)
        mod = 2.0 / steps * np.hypot(C, S)
    return coord, mod


def _camera_rays(K, T_world_cam):
    u, v = np.meshgrid(np.arange(CAM_W, dtype=np.float64), np.arange(CAM_H, dtype=np.float64))
    d_cam = np.linalg.inv(K) @ np.stack([u.ravel(), v.ravel(), np.ones(u.size)])
    d = (T_world_cam[:3, :3] @ d_cam).T
    return T_world_cam[:3, 3], d


def _erode(m, r=1):
    """Binary erosion with a (2r+1)^2 square (np.roll wraps, fine away from the border)."""
    out = m.copy()
    for dy_ in range(-r, r + 1):
        for dx_ in range(-r, r + 1):
            out &= np.roll(np.roll(m, dy_, 0), dx_, 1)
    return out


def _outside_image(gx, gy, W, H):
    """Camera pixels whose whole pixel-filter footprint sees no part of the projector image.

    Cycles' Blackman-Harris filter of width 1.5 px has a 3 px support (+-1.5 px): erode by 2."""
    return _erode((gx < -0.5) | (gx > W - 0.5) | (gy < -0.5) | (gy > H - 0.5), 2)


def _project(P, X):
    q = np.c_[X, np.ones(len(X))] @ P.T
    return q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]


def test_light_pose_matches_math():
    sc = _setup_scene()
    Twc_bl = np.eye(4)
    Twc_bl[:3, :3] = euler_xyz_to_matrix([0.4, -0.3, 1.2])
    Twc_bl[:3, 3] = [0.2, -0.5, 1.3]
    cam = _add_camera(sc, Twc_bl[:3, 3], matrix_to_quat(Twc_bl[:3, :3]))
    cam.scale = (1.5, 1.5, 1.5)                 # a scaled camera object must not scale the light
    bpy.context.view_layer.update()
    cfg = _cfg(rotation=[0.05, -0.15, 0.1], location=[-0.12, 0.03, 0.01])
    proj = pj.Projector(cfg, sc, cam)
    proj.build(np.ones((2, 570, 912), np.float32))
    Twc = blender_camera_to_opencv(Twc_bl)
    expect = Twc @ pj.T_cam_proj(cfg)
    assert np.allclose(light_world_pose(proj, 0), expect, atol=1e-6)        # composed
    proj.make_view_layers()
    for i in range(2):
        assert np.allclose(light_world_pose(proj, i), expect, atol=1e-6)    # evaluated in sl_0i
        M = np.array(proj.lights[i].evaluated_get(proj.view_layers[i].depsgraph).matrix_world)
        assert np.allclose(np.linalg.norm(M[:3, :3], axis=0), 1.0, atol=1e-6)
    assert np.allclose(proj.P_proj(), pj.projector_matrix(cfg, Twc), atol=1e-6)
    ld = proj.lights[0].data
    assert ld.type == "SPOT" and ld.shadow_soft_size == 0 and not ld.use_soft_falloff
    assert math.isclose(ld.spot_blend, pj.SPOT_BLEND, rel_tol=1e-6)      # soft edge outside the image, never 0 (NaN)
    assert ld.use_shadow and math.isclose(ld.spot_size, pj.spot_size(cfg), rel_tol=1e-6)
    img = proj.images[0]
    assert img.is_float and img.colorspace_settings.name == "Non-Color"
    assert proj.lights[0].parent == cam
    # rebuilding replaces everything (no duplicate lights, layers re-made on request)
    proj.build(np.ones((1, 570, 912), np.float32))
    assert len(proj.lights) == 1 and proj.layer_names == []
    assert [c.name for c in sc.collection.children] == ["datapipe_sl_00"]
    assert [vl.name for vl in sc.view_layers] == ["ViewLayer"]


# ------------------------------------------------------------------------------------------------
# the key test: decoded projector column/row == P_proj of the analytic surface point

PORTRAIT = {  # portrait DMD (AUTO sensor fit puts the sensor width on the height), odd width, another
    # focal length, a quaternion rotation and a general offset
    "resolution": [401, 640], "focal_length": 12.0, "sensor_width": 9.0, "location": [0.12, -0.05, 0.02],
    "rotation": list(matrix_to_quat(euler_xyz_to_matrix([0.04, 0.12, 0.3]))),
}
GEOMETRY_CASES = {
    # name: (interpolation, projector overrides, x periods, y periods, samples, point-sampled pixels)
    # point-sampled (filter width 0.01 px): each camera pixel is one ray through its centre, exactly
    # what the analytic ground truth computes, so the mapping itself is tested to ~0.001 px
    "exact-Linear": ("Linear", {}, [1, 4, 16], [1, 4, 16], 1, True),
    "exact-Closest": ("Closest", {}, [1, 4, 16], [1, 4, 16], 1, True),
    "exact-portrait": ("Linear", PORTRAIT, [1, 4, 12], [1, 4, 16], 1, True),
    # realistic: Cycles' default 1.5 px Blackman-Harris pixel filter, 16 samples
    "filtered-Linear": ("Linear", {}, [1, 4, 16], [1, 4], 16, False),
}


@pytest.mark.parametrize("case", list(GEOMETRY_CASES))
def test_decoded_columns_match_projection_matrix(tmp_path, case):
    interpolation, overrides, px, py, samples, point_sampled = GEOMETRY_CASES[case]
    sc = _setup_scene()
    if point_sampled:
        sc.cycles.filter_width = 0.01
    # a camera in a general pose, a plane ~0.9 m ahead, tilted 15 deg about the camera's y axis
    q = matrix_to_quat(euler_xyz_to_matrix([0.35, -0.25, 0.6]))
    cam = _add_camera(sc, (0.3, -0.2, 1.1), q)
    T_world_blcam = np.array(cam.matrix_world)
    Twc = blender_camera_to_opencv(T_world_blcam)
    T_plane = np.eye(4)
    T_plane[:3, :3] = euler_xyz_to_matrix([0.0, math.radians(15), 0.0])
    T_plane[:3, 3] = [0.0, 0.0, -0.9]
    T_plane = T_world_blcam @ T_plane
    _add_plane(sc, T_plane)

    cfg = _cfg(samples=samples, **overrides)
    W, H = cfg.projector.resolution
    N = 4
    pats = np.concatenate([_fringes(W, H, px, N, "x"), _fringes(W, H, py, N, "y")])
    proj = pj.Projector(cfg, sc, cam, interpolation=interpolation)
    proj.build(pats)
    layers = [vl.name for vl in proj.make_view_layers()]
    assert layers == [f"sl_{i:02d}" for i in range(len(pats))]
    img = _render(sc, tmp_path, layers, tag=f"geometry_{case}")
    stack = np.stack([img[n] for n in layers])
    nx = len(px) * N
    x_dec, _ = _decode(stack[:nx], px, N, W)
    y_dec, _ = _decode(stack[nx:], py, N, H)

    # ground truth: camera ray through the pixel centre -> plane -> P_proj
    K = intrinsics_from_sensor(CAM_F, CAM_SENSOR, CAM_W, CAM_H)
    C, d = _camera_rays(K, Twc)
    n, p0 = T_plane[:3, 2], T_plane[:3, 3]
    t = ((p0 - C) @ n) / (d @ n)
    X = C + t[:, None] * d
    gx, gy = _project(proj.P_proj(), X)
    gx, gy = gx.reshape(CAM_H, CAM_W), gy.reshape(CAM_H, CAM_W)
    margin = 25                                # projector px: away from the image edges
    inside = (gx > margin) & (gx < W - 1 - margin) & (gy > margin) & (gy < H - 1 - margin)
    assert inside.mean() > 0.3, "test setup: the projector image should cover most of the view"
    for axis, dec, gt in (("x", x_dec, gx), ("y", y_dec, gy)):
        err = (dec - gt)[inside]
        a = np.abs(err)
        med, p95, mx, bias = np.median(a), np.percentile(a, 95), a.max(), float(np.mean(err))
        TIMINGS[f"d{axis}_{case}"] = dict(median=round(float(med), 4), p95=round(float(p95), 4),
                                         max=round(float(mx), 4), mean=round(bias, 4), n=int(inside.sum()))
        msg = f"{case} {axis}: median |d{axis}| {med:.4f}, p95 {p95:.4f}, max {mx:.4f}, mean {bias:+.4f} px"
        if point_sampled and interpolation == "Linear":
            assert med < 0.01 and mx < 0.05 and abs(bias) < 0.005, msg
        elif point_sampled:                    # 'Closest': decoded = nearest texel centre
            assert mx < 0.51 and 0.2 < med < 0.3 and abs(bias) < 0.05, msg
        else:
            assert med < 0.2 and p95 < 0.5 and abs(bias) < 0.05, msg
    # outside the projector image nothing is lit (the image is the aperture, not the cone)
    outside = _outside_image(gx, gy, W, H)
    assert outside.sum() > 50
    assert np.abs(stack[:, outside]).max() == 0.0
    proj.teardown()


# ------------------------------------------------------------------------------------------------
# isolation: fringe layers see only their own projector, the native layer sees none

def test_view_layer_isolation_and_teardown(tmp_path):
    has_override = "world_override" in bpy.types.ViewLayer.bl_rna.properties
    # a bright world must not reach the fringe layers (where Blender has a view-layer world override)
    sc = _setup_scene(world_strength=0.5 if has_override else 0.0)
    cam = _add_camera(sc)
    _add_plane(sc, np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -0.9], [0, 0, 0, 1.0]]))
    lights = bpy.data.collections.new(pj.LIGHTS_COLLECTION)
    sc.collection.children.link(lights)
    key = bpy.data.objects.new("key", bpy.data.lights.new("key", "POINT"))
    key.data.energy = 30.0
    key.location = (0.3, 0.2, -0.3)
    lights.objects.link(key)
    native = sc.view_layers[0].name

    ref = _render(sc, tmp_path, [native], tag="native_before")[native]
    assert ref.min() > 0                         # key light + world light the plane everywhere

    before = {k: set(getattr(bpy.data, k).keys()) for k in
              ("objects", "lights", "images", "collections", "worlds", "node_groups", "meshes")}
    cfg = _cfg(samples=4)
    W, H = cfg.projector.resolution
    top_half = np.zeros((H, W), np.float32)
    top_half[: H // 2] = 1.0
    proj = pj.Projector(cfg, sc, cam)
    proj.build(np.stack([top_half, np.zeros((H, W), np.float32)]))
    layers = [vl.name for vl in proj.make_view_layers(exclude=[pj.LIGHTS_COLLECTION])]
    # the API-level view of isolation
    assert pj.fringe_layer_leaks(sc, proj.view_layers, proj.collections) == {}
    for vl in proj.view_layers:
        assert [o.name for o in vl.objects if o.type == "LIGHT"] == [proj.lights[layers.index(vl.name)].name]
        assert vl.samples == 4 and vl.use_pass_combined and not vl.use_pass_z
    assert [o.name for o in sc.view_layers[native].objects if o.type == "LIGHT"] == ["key"]
    if has_override:                             # without the override the bright world is a leak
        saved, proj.view_layers[0].world_override = proj.view_layers[0].world_override, None
        assert pj.fringe_layer_leaks(sc, proj.view_layers, proj.collections) == {"sl_00": ["world"]}
        proj.view_layers[0].world_override = saved

    out = _render(sc, tmp_path, [native] + layers, tag="isolation")
    # native RGB unchanged by the projectors (same seed, same scene otherwise)
    assert np.allclose(out[native], ref, rtol=1e-5, atol=1e-6)
    # zero pattern: black everywhere (no key light, world or other projector)
    assert np.abs(out["sl_01"]).max() == 0.0
    # top-half pattern: bright above the projected image's middle row, dark below (not flipped)
    K = intrinsics_from_sensor(CAM_F, CAM_SENSOR, CAM_W, CAM_H)
    C, d = _camera_rays(K, blender_camera_to_opencv(np.array(cam.matrix_world)))
    X = C + ((-0.9 - C[2]) / d[:, 2])[:, None] * d
    gx, gy = (g.reshape(CAM_H, CAM_W) for g in _project(proj.P_proj(), X))
    sl0 = out["sl_00"]
    in_x = (gx > 10) & (gx < W - 11)
    upper = in_x & (gy > 10) & (gy < H / 2 - 15)
    lower = _erode(gy > H / 2 - 0.5, 2) | _outside_image(gx, gy, W, H)
    assert upper.sum() > 100 and lower.sum() > 100
    assert sl0[upper].min() > 0.3 and sl0[lower].max() == 0.0

    proj.teardown()
    after = {k: set(getattr(bpy.data, k).keys()) for k in before}
    assert after == before
    assert [vl.name for vl in sc.view_layers] == [native]
    again = _render(sc, tmp_path, [native], tag="native_after")[native]
    assert np.allclose(again, ref, rtol=1e-5, atol=1e-6)


def test_leaking_light_is_refused():
    sc = _setup_scene()
    cam = _add_camera(sc)
    stray = bpy.data.objects.new("stray", bpy.data.lights.new("stray", "POINT"))
    sc.collection.objects.link(stray)             # master collection: cannot be excluded
    cfg = _cfg()
    W, H = cfg.projector.resolution
    proj = pj.Projector(cfg, sc, cam)
    proj.build(np.ones((1, H, W), np.float32))
    with pytest.raises(DataPipeError, match="stray"):
        proj.make_view_layers()


# ------------------------------------------------------------------------------------------------
# shadows: the projector is a point source that casts sharp shadows

def _ray_box(o, d, lo, hi):
    """Slab test, vectorised over rays (o: (3,) or (n,3), d: (n,3)); returns entry t (inf = miss)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (np.asarray(lo) - o) / d
        t2 = (np.asarray(hi) - o) / d
    tmin = np.nanmax(np.minimum(t1, t2), axis=-1)
    tmax = np.nanmin(np.maximum(t1, t2), axis=-1)
    hit = (tmax >= np.maximum(tmin, 0))
    return np.where(hit, np.maximum(tmin, 0), np.inf)


def test_box_casts_shadow(tmp_path):
    sc = _setup_scene()
    cam = _add_camera(sc)
    z_plane = -0.9
    _add_plane(sc, np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, z_plane], [0, 0, 0, 1.0]]))
    lo, hi = (0.0, -0.05, z_plane), (0.1, 0.05, z_plane + 0.3)       # a 10 x 10 x 30 cm post
    _add_box(sc, lo, hi)
    cfg = _cfg(samples=8)
    W, H = cfg.projector.resolution
    proj = pj.Projector(cfg, sc, cam)
    proj.build(np.ones((1, H, W), np.float32))
    layers = [vl.name for vl in proj.make_view_layers()]
    img = _render(sc, tmp_path, layers, tag="shadow")["sl_00"]

    K = intrinsics_from_sensor(CAM_F, CAM_SENSOR, CAM_W, CAM_H)
    Twc = blender_camera_to_opencv(np.array(cam.matrix_world))
    C, d = _camera_rays(K, Twc)
    t_plane = (z_plane - C[2]) / d[:, 2]
    sees_plane = t_plane < _ray_box(C, d, lo, hi)
    X = C + t_plane[:, None] * d
    Tproj = Twc @ proj.T_cam_proj
    to_proj = Tproj[:3, 3] - X
    t_occ = _ray_box(X + 1e-6 * to_proj, to_proj, lo, hi)     # in (0, 1): blocked before the projector
    shadow = (sees_plane & (t_occ < 1.0)).reshape(CAM_H, CAM_W)
    lit = (sees_plane & ~(t_occ < 1.0)).reshape(CAM_H, CAM_W)
    gx, gy = (g.reshape(CAM_H, CAM_W) for g in _project(proj.P_proj(), X))
    in_image = (gx > 5) & (gx < W - 6) & (gy > 5) & (gy < H - 6)

    core_shadow = _erode(shadow, 2) & in_image
    core_lit = _erode(lit, 2) & in_image
    assert core_shadow.sum() >= 20, f"test setup: only {core_shadow.sum()} shadow pixels"
    lit_level = np.median(img[core_lit])
    assert lit_level > 0.3
    # the box's lit faces bounce a little light into the shadow; direct light must be absent
    assert np.median(img[core_shadow]) < 0.02 * lit_level
    assert img[core_shadow].max() < 0.1 * lit_level
    TIMINGS["shadow_px"] = (int(core_shadow.sum()), float(np.median(img[core_shadow]) / lit_level))
    proj.teardown()


def test_sl_patterns_follow_the_convention_tested_here():
    """The decoder package's patterns are the ones whose geometry is verified above."""
    from datapipe.sl import fringe_patterns
    W, H = Config().projector.resolution
    for axis in ("x", "y"):
        ours = _fringes(W, H, [1, 8, 64], 4, axis)
        theirs = np.asarray(fringe_patterns(W, H, [1, 8, 64], 4, axis=axis))
        assert theirs.shape == ours.shape
        assert np.allclose(theirs, ours, atol=1e-5)


def test_report_timings():
    """Prints what the other tests measured (pytest -s), and checks the ranking across the geometry
    cases that no single case can: 'Linear' texture interpolation decodes the exact column where
    'Closest' quantises it to whole projector pixels (median ~0.25 px), and point-sampled pixels
    decode more exactly than Cycles' 1.5 px pixel filter (which mixes neighbouring columns)."""
    print()
    for k, v in TIMINGS.items():
        print(f"{k}: {v}")
    cases = ("exact-Linear", "exact-Closest", "filtered-Linear")
    if any(f"d{a}_{c}" not in TIMINGS for a in "xy" for c in cases):
        pytest.skip("needs the geometry cases of this file in the same session")
    for a in "xy":
        lin, closest, filtered = (TIMINGS[f"d{a}_{c}"]["median"] for c in cases)
        assert 10 * lin < closest, (a, lin, closest)
        assert lin < filtered, (a, lin, filtered)
