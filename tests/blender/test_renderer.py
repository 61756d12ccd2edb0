"""Renderer: real Cycles renders at 64x48, checked against analytic ground truth.

Ground truth never comes from the code under test: per-pixel rays are built here from K (pixel
centres at integers) and T_world_cam and intersected with the analytic plane / sphere; the 8-bit
sRGB image is compared with Blender's own Standard-view-transform PNG of the Render Result.

Tolerances: Cycles' depth and object-index passes come from the pixel centre (observed: the depth
of a slanted plane matches the pixel-centre ray to < 3e-6 m for any seed and sample count, while
the depth changes 4e-3 m per pixel there, so the sample is within 1e-3 px of the centre). Depth
is compared to 1e-5 m + 1e-5 relative (float32 has 6e-8 relative resolution; Cycles' ray-triangle
intersection gives ~2e-6 m at 1 m). On the sphere the mesh is a 64x32 UV sphere whose facets lie
up to r*(1 - cos(pi/64)) = 1.2e-4 m inside the analytic sphere, so depth is compared to 3e-4 m
there and the mask may differ only on pixels whose ray passes within 0.5 % of r of the silhouette.
"""
import math

import cv2
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from blender_probes import file_output_input_names  # noqa: E402
from datapipe.io import exr  # noqa: E402
from datapipe.config import CameraPose, Config  # noqa: E402
from datapipe.core import compat  # noqa: E402
from datapipe.core.camera import BlendCamera  # noqa: E402
from datapipe.core.renderer import NATIVE_LAYER, Renderer  # noqa: E402
from datapipe.errors import DataPipeError  # noqa: E402

W, H = 64, 48


def quat_axis_angle(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return [math.cos(angle / 2), *(math.sin(angle / 2) * axis)]


def make_cfg(outputs=("rgb", "depth", "normals", "mask"), poses=None, samples=4):
    cfg = Config()
    cfg.camera.resolution = [W, H]
    cfg.camera.poses = poses or [CameraPose([0.0, 0.0, 0.5], [1.0, 0.0, 0.0, 0.0])]
    cfg.render.samples = samples
    cfg.render.threads = 2
    cfg.render.denoise = False            # exact pixel values (test_denoise_... turns it on)
    cfg.render.outputs = list(outputs)
    return cfg


def setup(scene, cfg):
    cam = BlendCamera(cfg, scene).setup()
    ren = Renderer(cfg, scene, cam).setup()
    return cam, ren


def add_plane(size=4.0, location=(0, 0, 0), rotation=(0, 0, 0), pass_index=0, material=None):
    bpy.ops.mesh.primitive_plane_add(size=size, location=location, rotation=rotation)
    obj = bpy.context.active_object
    obj.pass_index = pass_index
    if material is not None:
        obj.data.materials.append(material)
    return obj


def add_sphere(radius, location, pass_index=0, material=None):
    bpy.ops.mesh.primitive_uv_sphere_add(segments=64, ring_count=32, radius=radius, location=location)
    obj = bpy.context.active_object
    bpy.ops.object.shade_smooth()
    obj.pass_index = pass_index
    if material is not None:
        obj.data.materials.append(material)
    return obj


def emission_material(color, strength=1.0):
    mat = bpy.data.materials.new("emit")
    if mat.node_tree is None:                        # bpy 4.2 (5.x: always has one; use_nodes deprecated)
        mat.use_nodes = True
    nt = mat.node_tree
    for n in list(nt.nodes):
        if n.type != "OUTPUT_MATERIAL":
            nt.nodes.remove(n)
    em = nt.nodes.new("ShaderNodeEmission")
    em.inputs["Color"].default_value = (*color, 1.0)
    em.inputs["Strength"].default_value = strength
    nt.links.new(em.outputs[0], nt.nodes["Material Output"].inputs["Surface"])
    return mat


def add_light():
    data = bpy.data.lights.new("key", "POINT")
    data.energy = 30.0
    obj = bpy.data.objects.new("key", data)
    obj.location = (0.3, -0.2, 0.8)
    bpy.context.scene.collection.objects.link(obj)


def pixel_rays(K, T_world_cam):
    """World-space ray directions through pixel centres, scaled so that their camera-z is 1."""
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    d_cam = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)
    return d_cam @ T_world_cam[:3, :3].T           # (H, W, 3); planar depth = ray parameter


def plane_depth(K, T_world_cam, point, normal):
    d = pixel_rays(K, T_world_cam)
    C = T_world_cam[:3, 3]
    return (np.dot(np.asarray(point) - C, normal)) / (d @ normal)


# ------------------------------------------------------------------------------------------------

def test_fronto_parallel_plane_depth_normals_mask(factory_scene, tmp_path):
    scene = factory_scene
    cfg = make_cfg()
    cam, ren = setup(scene, cfg)
    add_plane(size=4.0, pass_index=3)
    T = cam.set_pose(0)
    out = ren.render(tmp_path, seed=1)

    depth = exr.read_depth(tmp_path / "depth.exr")
    assert depth.shape == (H, W) and depth.dtype == np.float32
    np.testing.assert_allclose(depth, 0.5, atol=1e-5)
    np.testing.assert_array_equal(depth, out.depth)
    # a plane facing the camera: its normal points back at the camera = -z in the OpenCV frame
    normals = exr.read_normals(tmp_path / "normals.exr")
    np.testing.assert_allclose(normals, np.broadcast_to([0, 0, -1], (H, W, 3)), atol=1e-5)
    mask = exr.read_mask(tmp_path / "mask.exr")
    assert (mask == 3).all()
    np.testing.assert_allclose(out.T_world_cam, T)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["depth.exr", "mask.exr", "normals.exr", "rgb.png"]


def test_tilted_plane_tilted_camera_depth_and_normals(factory_scene, tmp_path):
    """Per-pixel analytic ray-plane planar depth; also shows row 0 is the image top (the plane
    recedes towards the top) and that the Z pass is planar depth, not ray length."""
    scene = factory_scene
    q = quat_axis_angle([1, 0.2, 0.1], 0.45)
    cfg = make_cfg(outputs=("depth", "normals"), poses=[CameraPose([0.1, -0.3, 0.6], q)])
    cam, ren = setup(scene, cfg)
    tilt = 0.2
    add_plane(size=8.0, rotation=(0, tilt, 0))
    n_world = np.array([math.sin(tilt), 0.0, math.cos(tilt)])
    T = cam.set_pose(0)
    out = ren.render(tmp_path, seed=3)

    expected = plane_depth(cam.K, T, [0, 0, 0], n_world)
    depth = exr.read_depth(tmp_path / "depth.exr")
    assert np.isfinite(depth).all()
    np.testing.assert_allclose(depth, expected, atol=1e-5, rtol=1e-5)
    assert expected[0].mean() > expected[-1].mean() + 0.05      # the test itself is orientation-sensitive
    ray_length = expected * np.linalg.norm(pixel_rays(cam.K, T), axis=-1)
    assert np.abs(ray_length - expected).max() > 100 * 1e-5      # ... and planar-vs-radial sensitive

    n_cam = T[:3, :3].T @ n_world                                 # world normal in the OpenCV frame
    normals = exr.read_normals(tmp_path / "normals.exr")
    np.testing.assert_allclose(normals, np.broadcast_to(n_cam, (H, W, 3)), atol=1e-4)
    assert n_cam[2] < 0 and abs(n_cam[1]) > 0.1                   # not trivially (0, 0, -1)


def test_sphere_mask_depth_and_centroid(factory_scene, tmp_path):
    scene = factory_scene
    cfg = make_cfg(outputs=("depth", "mask"), poses=[CameraPose([0.0, 0.0, 0.6], [1, 0, 0, 0])])
    cam, ren = setup(scene, cfg)
    centre, r = np.array([0.03, -0.02, 0.0]), 0.1
    add_sphere(r, centre, pass_index=7)
    T = cam.set_pose(0)
    out = ren.render(tmp_path, seed=0)

    # analytic first hit of each pixel-centre ray with the sphere
    d = pixel_rays(cam.K, T)
    oc = T[:3, 3] - centre
    a = (d * d).sum(-1)
    b = 2 * (d @ oc)
    c = oc @ oc - r * r
    disc = b * b - 4 * a * c
    hit = disc > 0
    t_hit = np.where(hit, (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a), np.nan)
    miss_dist = np.sqrt(np.maximum(c - b * b / (4 * a), 0) + r * r)    # ray's closest approach to centre
    boundary = np.abs(miss_dist - r) < 0.005 * r

    mask = exr.read_mask(tmp_path / "mask.exr")
    assert set(np.unique(mask)) == {0, 7}
    rendered = mask == 7
    iou = (rendered & hit).sum() / (rendered | hit).sum()
    assert iou > 0.95, iou
    assert not (rendered != hit)[~boundary].any()                    # differences only on the rim
    assert rendered.sum() > 500

    depth = exr.read_depth(tmp_path / "depth.exr")
    assert np.isnan(depth[~rendered]).all()                          # background 1e10 -> NaN
    both = rendered & hit & ~boundary
    np.testing.assert_allclose(depth[both], t_hit[both], atol=3e-4)

    # the sphere centre projects onto the mask centroid (here the perspective ellipse's own centroid
    # is 0.17 px off the projected centre); world y < 0 is below the image centre (row 0 = top)
    vs, us = np.nonzero(rendered)
    va, ua = np.nonzero(hit)
    assert abs(us.mean() - ua.mean()) < 0.05 and abs(vs.mean() - va.mean()) < 0.05
    pc = np.linalg.inv(T) @ np.append(centre, 1.0)
    uv = (cam.K @ pc[:3])[:2] / pc[2]
    assert abs(us.mean() - uv[0]) < 0.5 and abs(vs.mean() - uv[1]) < 0.5, (us.mean(), vs.mean(), uv)
    assert vs.mean() > cam.K[1, 2] + 2 and us.mean() > cam.K[0, 2] + 2
    np.testing.assert_array_equal(mask, out.mask)


def test_only_requested_outputs(factory_scene, tmp_path):
    scene = factory_scene
    cfg = make_cfg(outputs=("depth",))
    cam, ren = setup(scene, cfg)
    add_plane(pass_index=2)
    out = ren.render(tmp_path, seed=0)

    assert [p.name for p in tmp_path.iterdir()] == ["depth.exr"]     # no rgb/normals/mask, temp EXR gone
    assert set(out.files) == {"depth"}
    assert out.rgb is None and out.normals is None and out.mask is None
    vl = scene.view_layers[NATIVE_LAYER]
    assert vl.use_pass_z and not vl.use_pass_normal and not vl.use_pass_object_index
    assert file_output_input_names(ren.file_output) == ["Depth"]
    assert list(exr.read_exr(tmp_path / "depth.exr")) == ["Z"]
    np.testing.assert_allclose(out.depth, 0.5, atol=1e-5)


def test_compositor_built_once_same_seed_same_pixels_rgb_is_srgb8(factory_scene, tmp_path):
    scene = factory_scene
    cfg = make_cfg(samples=4)
    cam, ren = setup(scene, cfg)
    add_plane(size=4.0, pass_index=1)
    add_sphere(0.08, (0.0, 0.0, 0.05), pass_index=2)
    add_light()                                       # diffuse + point light: Monte-Carlo noise
    nodes = sorted(n.name for n in ren.tree.nodes)
    links = len(ren.tree.links)

    a = ren.render(tmp_path / "a", seed=11)
    # Blender's own 8-bit output of the same render (view transform Standard, dither 0)
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.image_settings.color_depth = "8"
    bpy.data.images["Render Result"].save_render(str(tmp_path / "blender.png"), scene=scene)
    b = ren.render(tmp_path / "b", seed=11)
    c = ren.render(tmp_path / "c", seed=12)

    assert sorted(n.name for n in ren.tree.nodes) == nodes and len(ren.tree.links) == links
    assert sorted(file_output_input_names(ren.file_output)) == ["Depth", "Image", "IndexOB", "Normal"]
    for kind in ("rgb", "depth", "normals", "mask"):
        x, y = getattr(a, kind), getattr(b, kind)
        np.testing.assert_array_equal(x, y, err_msg=kind)
    assert (a.rgb != c.rgb).any()                      # the seed reaches Cycles

    png = cv2.imread(str(tmp_path / "a" / "rgb.png"), cv2.IMREAD_UNCHANGED)
    assert png.dtype == np.uint8 and png.shape == (H, W, 3)
    np.testing.assert_array_equal(png[..., ::-1], a.rgb)
    ref = cv2.imread(str(tmp_path / "blender.png"), cv2.IMREAD_UNCHANGED)[..., ::-1]
    assert np.abs(ref.astype(int) - a.rgb.astype(int)).max() <= 1
    assert a.rgb.std() > 5                              # not a blank image
    assert 0 < a.seconds < 30


def test_linear_emission_gives_srgb_value(factory_scene, tmp_path):
    """An emitter of linear 0.18 must come out as sRGB 0.4613 -> 118 (Standard, exposure 0, gamma 1)."""
    scene = factory_scene
    cfg = make_cfg(outputs=("rgb",))
    cam, ren = setup(scene, cfg)
    add_plane(material=emission_material((0.18, 0.18, 0.18)))
    out = ren.render(tmp_path, seed=0)
    assert np.abs(out.rgb.astype(int) - 118).max() <= 1
    assert scene.view_settings.view_transform == "Standard" and scene.render.dither_intensity == 0


def test_denoise_and_adaptive_sampling_options(factory_scene, tmp_path):
    """render.denoise runs OpenImageDenoise on the RGB only (depth, mask untouched) and brings a
    2-sample render much closer to a 128-sample one; render.adaptive_threshold turns Cycles'
    adaptive sampling on with that threshold (and 0 leaves it off)."""
    scene = factory_scene
    add_plane(size=4.0, pass_index=1)
    add_sphere(0.08, (0.0, 0.0, 0.05), pass_index=2)
    add_light()
    results = {}
    for name, samples, denoise, thr in (("ref", 128, False, 0.0), ("noisy", 2, False, 0.0), ("clean", 2, True, 0.02)):
        cfg = make_cfg(samples=samples)
        cfg.render.denoise, cfg.render.adaptive_threshold = denoise, thr
        cam, ren = setup(scene, cfg)
        assert scene.cycles.use_denoising == denoise and scene.cycles.use_adaptive_sampling == (thr > 0)
        results[name] = ren.render(tmp_path / name, seed=3)
    assert scene.cycles.denoiser == "OPENIMAGEDENOISE" and scene.cycles.adaptive_threshold == pytest.approx(0.02)
    ref, noisy, clean = results["ref"], results["noisy"], results["clean"]
    np.testing.assert_array_equal(clean.depth, noisy.depth)
    np.testing.assert_array_equal(clean.mask, noisy.mask)
    err = lambda o: np.abs(o.rgb.astype(float) - ref.rgb.astype(float)).mean()  # noqa: E731
    assert err(clean) < 0.5 * err(noisy)


def test_denoiser_prefilter_and_quality_reach_cycles(factory_scene, tmp_path):
    """render.denoise_prefilter / denoise_quality are what Cycles reads back, and a config that does
    not set them renders the bytes of the settings the renderer hard-coded before they were fields
    (OIDN prefilter ACCURATE, quality HIGH, albedo + normal guides, set here on scene.cycles by hand);
    another prefilter and quality give another image (the fields reach the denoiser)."""
    scene = factory_scene
    add_plane(size=4.0, pass_index=1)
    add_sphere(0.08, (0.0, 0.0, 0.05), pass_index=2)
    add_light()
    rgb = {}
    for name, fields in (("unset", {}), ("cheap", {"denoise_prefilter": "FAST", "denoise_quality": "BALANCED"}),
                         ("none", {"denoise_prefilter": "NONE", "denoise_quality": "FAST"})):
        cfg = make_cfg(samples=2)
        cfg.render.denoise = True
        for k, v in fields.items():
            setattr(cfg.render, k, v)
        cam, ren = setup(scene, cfg)
        want = (fields.get("denoise_prefilter", "ACCURATE"), fields.get("denoise_quality", "HIGH"))
        assert (scene.cycles.denoising_prefilter, scene.cycles.denoising_quality) == want
        rgb[name] = ren.render(tmp_path / name, seed=3).rgb
    cy = scene.cycles                     # the former hard-coded settings, not through the config
    cy.denoiser, cy.denoising_input_passes = "OPENIMAGEDENOISE", "RGB_ALBEDO_NORMAL"
    cy.denoising_prefilter, cy.denoising_quality = "ACCURATE", "HIGH"
    old = ren.render(tmp_path / "old", seed=3).rgb
    np.testing.assert_array_equal(rgb["unset"], old)
    assert not np.array_equal(rgb["cheap"], old) and not np.array_equal(rgb["none"], old)


def test_sampling_pattern_reaches_the_native_render_only(factory_scene, tmp_path):
    """render.sampling_pattern is what Cycles reads during the native render (render_pre handler) and
    the scene's own pattern again after it (the fringe calls keep theirs); its default SCENE leaves
    the scene's pattern (a new scene's TABULATED_SOBOL, or any other a .blend carries) as the
    renderer did before the field, rendering the bytes of that pattern set by hand; BLUE_NOISE gives
    another image; a pattern this Blender lacks is refused naming the field."""
    from datapipe.errors import ConfigError
    scene = factory_scene
    add_plane(size=4.0, pass_index=1)
    add_sphere(0.08, (0.0, 0.0, 0.05), pass_index=2)
    add_light()
    seen = []
    probe = lambda *a: seen.append(scene.cycles.sampling_pattern)  # noqa: E731
    bpy.app.handlers.render_pre.append(probe)
    try:
        rgb = {}
        for name, pattern, own in (("unset", "SCENE", "TABULATED_SOBOL"), ("kept", "SCENE", "AUTOMATIC"),
                                   ("blue", "BLUE_NOISE", "TABULATED_SOBOL")):
            scene.cycles.sampling_pattern = own
            cfg = make_cfg(samples=2)
            cfg.render.sampling_pattern = pattern
            cam, ren = setup(scene, cfg)
            rgb[name] = ren.render(tmp_path / name, seed=3).rgb
            assert seen[-1] == (own if pattern == "SCENE" else pattern)
            assert scene.cycles.sampling_pattern == own
        ren.cfg.render.sampling_pattern = "SCENE"       # the former renderer: TABULATED_SOBOL set by hand
        np.testing.assert_array_equal(rgb["unset"], ren.render(tmp_path / "old", seed=3).rgb)
    finally:
        bpy.app.handlers.render_pre.remove(probe)
    assert not np.array_equal(rgb["blue"], rgb["unset"])
    with pytest.raises(ConfigError, match="render.sampling_pattern"):
        with compat.sampling_pattern(scene.cycles, "SOBOL_BURLEY"):
            pass


def test_gpu_device_falls_back_to_cpu_with_one_message(factory_scene, tmp_path, capsys, monkeypatch):
    """render.device GPU on a machine without a GPU (this one: Cycles' compute_device_type NONE)
    renders on the CPU and says so once per process on stderr; with a GPU it picks a backend."""
    monkeypatch.setattr(compat, "_gpu_fallback_reported", False)
    scene = factory_scene
    cfg = make_cfg(outputs=("rgb",), samples=1)
    cfg.render.device = "GPU"
    cam, ren = setup(scene, cfg)
    add_plane(material=emission_material((0.18, 0.18, 0.18)))
    err = capsys.readouterr().err
    if ren.device == "CPU":
        assert scene.cycles.device == "CPU"
        assert err.count("datapipe: render.device is GPU") == 1 and "rendering on the CPU" in err
        assert "OPTIX, CUDA" in err
    else:                                           # a machine with a usable GPU
        assert ren.device in compat.GPU_BACKENDS and scene.cycles.device == "GPU" and not err
    out = ren.render(tmp_path, seed=0)              # renders either way
    assert np.abs(out.rgb.astype(int) - 118).max() <= 1
    setup(scene, cfg)                               # a second run in the same process: no repeat
    assert "render.device" not in capsys.readouterr().err
    cfg.render.device = "CPU"
    setup(scene, cfg)
    assert scene.cycles.device == "CPU" and ren.device in ("CPU", *compat.GPU_BACKENDS)


def test_user_errors_are_datapipe_errors(factory_scene, tmp_path):
    scene = factory_scene
    cfg = make_cfg(outputs=("depth",))
    cam, ren = setup(scene, cfg)
    with pytest.raises(DataPipeError, match="no '{'"):
        ren.render(tmp_path / "a{frame}", seed=0)
