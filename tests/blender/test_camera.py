"""BlendCamera: camera object, intrinsics K against Blender's own projection, poses, pose draws.

Ground truth is Blender itself (bpy_extras.object_utils.world_to_camera_view, the object's
matrix_world) or plain quaternion algebra written out here, never the code under test.
"""
import math
import sys
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")
from bpy_extras.object_utils import world_to_camera_view  # noqa: E402
from mathutils import Vector  # noqa: E402

from blender_probes import light_world_pose  # noqa: E402
from datapipe import geometry  # noqa: E402
from datapipe.config import CameraPose, Config  # noqa: E402
from datapipe.core.camera import CAMERA_NAME, BlendCamera  # noqa: E402
from datapipe.errors import DataPipeError  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from pose_checks import pixels, pose_parameters  # noqa: E402


def quat_axis_angle(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    return [math.cos(angle / 2), *(math.sin(angle / 2) * axis)]


def make_cfg(res=(64, 48), fit="AUTO", poses=None, focal=16.0, sensor=11.3):
    cfg = Config()
    cfg.camera.resolution = list(res)
    cfg.camera.sensor_fit = fit
    cfg.camera.focal_length = focal
    cfg.camera.sensor_width = sensor
    cfg.camera.poses = poses or [
        CameraPose([0.0, 0.0, 1.0], [1.0, 0.0, 0.0, 0.0]),
        CameraPose([0.1, -0.3, 0.6], quat_axis_angle([1, 0.2, 0.1], 0.45)),
        CameraPose([-0.2, 0.25, 0.8], quat_axis_angle([-0.3, 1, 0.5], 0.6)),
    ]
    return cfg


def test_setup_creates_camera_and_resolution(factory_scene):
    scene = factory_scene
    cfg = make_cfg(res=(64, 48))
    cfg.camera.clip_start, cfg.camera.clip_end = 0.07, 7.5
    cam = BlendCamera(cfg, scene).setup()
    obj = scene.objects[CAMERA_NAME]
    assert cam.obj == obj and scene.camera == obj and obj.type == "CAMERA"
    d = obj.data
    assert d.type == "PERSP" and d.lens == pytest.approx(16.0) and d.sensor_width == pytest.approx(11.3)
    assert d.shift_x == 0 and d.shift_y == 0
    assert d.clip_start == pytest.approx(0.07) and d.clip_end == pytest.approx(7.5)
    r = scene.render
    assert (r.resolution_x, r.resolution_y, r.resolution_percentage) == (64, 48, 100)
    assert r.pixel_aspect_x == 1 and r.pixel_aspect_y == 1
    assert cam.resolution == (64, 48)
    f = 16.0 * 64 / 11.3
    np.testing.assert_allclose(cam.K, [[f, 0, 31.5], [0, f, 23.5], [0, 0, 1]])
    # setup twice reuses the object
    BlendCamera(cfg, scene).setup()
    assert len([o for o in scene.objects if o.type == "CAMERA"]) == 1


@pytest.mark.parametrize("res,fit", [((64, 48), "AUTO"), ((48, 64), "AUTO"), ((64, 48), "VERTICAL"),
                                     ((48, 64), "HORIZONTAL"), ((320, 240), "AUTO")])
def test_K_matches_blender_projection(factory_scene, res, fit):
    """world_to_camera_view gives normalised frame coordinates (0..1 from the bottom-left frame
    corner); with pixel centres at integers, u = x*W - 0.5 and v = (1 - y)*H - 0.5."""
    scene = factory_scene
    cfg = make_cfg(res=res, fit=fit)
    cam = BlendCamera(cfg, scene).setup()
    W, H = res
    rng = np.random.default_rng(1)
    for i in range(len(cfg.camera.poses)):
        T_world_cam = cam.set_pose(i)
        # points in front of the camera, spread across (and a bit beyond) the frame
        pc = np.column_stack([rng.uniform(-0.3, 0.3, 12), rng.uniform(-0.25, 0.25, 12), rng.uniform(0.3, 1.5, 12)])
        pw = pc @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
        ndc = np.array([world_to_camera_view(scene, cam.obj, Vector(p))[:] for p in pw])
        uv_blender = np.column_stack([ndc[:, 0] * W - 0.5, (1 - ndc[:, 1]) * H - 0.5])
        uv = pixels(geometry.projection_matrix(cam.K, T_world_cam), pw)
        np.testing.assert_allclose(uv, uv_blender, atol=1e-4)
        np.testing.assert_allclose(ndc[:, 2], pc[:, 2], atol=1e-6)   # Blender's z = planar depth


def test_set_pose_matches_matrix_world_and_blender_axes(factory_scene):
    scene = factory_scene
    cfg = make_cfg()
    cam = BlendCamera(cfg, scene).setup()
    for i, pose in enumerate(cfg.camera.poses):
        T = cam.set_pose(i)
        np.testing.assert_allclose(T, cam.T_world_cam(), atol=1e-6)
        M = np.array(cam.obj.matrix_world)                      # Blender's own evaluation
        np.testing.assert_allclose(T[:3, 3], pose.location, atol=1e-6)
        np.testing.assert_allclose(T[:3, 0], M[:3, 0], atol=1e-6)      # x right in both
        np.testing.assert_allclose(T[:3, 1], -M[:3, 1], atol=1e-6)     # OpenCV y = down = -Blender y
        np.testing.assert_allclose(T[:3, 2], -M[:3, 2], atol=1e-6)     # looks down Blender's -Z
        np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
    with pytest.raises(DataPipeError):
        cam.set_pose(len(cfg.camera.poses))


def test_T_world_cam_removes_scale(factory_scene):
    scene = factory_scene
    cam = BlendCamera(make_cfg(), scene).setup()
    T = cam.set_pose(2)
    cam.obj.scale = (2.0, 0.5, 3.0)
    scene.view_layers[0].update()
    np.testing.assert_allclose(cam.T_world_cam(), T, atol=1e-6)


def test_draw_poses_without_replacement(factory_scene):
    cfg = make_cfg()
    cam = BlendCamera(cfg, factory_scene).setup()
    a = cam.draw_poses(np.random.default_rng(5), 3)
    assert sorted(a) == [0, 1, 2]
    assert a == cam.draw_poses(np.random.default_rng(5), 3)        # seeded: reproducible
    assert len(set(cam.draw_poses(np.random.default_rng(6), 2))) == 2
    with pytest.raises(DataPipeError):
        cam.draw_poses(np.random.default_rng(0), 4)


def test_sampled_view_places_camera_and_parented_projector(factory_scene):
    """A bin_view draw moves the camera object to the drawn look-at pose (Blender's matrix_world is
    the ground truth) and the projector, parented to the camera, follows it (T_cam_proj fixed)."""
    from datapipe.draws.camera_sampler import draw_bin_view
    from datapipe.config import CameraSamplerConfig
    from datapipe.core import projector as pj
    from datapipe.draws.seeds import camera_rng
    cfg = make_cfg()
    cam = BlendCamera(cfg, factory_scene).setup()
    proj = pj.Projector(cfg, factory_scene, cam.obj)
    proj.build(np.ones((1, 570, 912), np.float32))
    sampler = CameraSamplerConfig(kind="bin_view", distance=[0.5, 0.9], tilt_deg=[10, 45], target_jitter=0.02)
    for r in range(3):
        view = draw_bin_view(sampler, [0.05, -0.02, 0.0], camera_rng(1, 0, r))
        T = cam.set_view(view)
        M = np.array(cam.obj.matrix_world)
        np.testing.assert_allclose(geometry.blender_camera_to_opencv(M), T, atol=1e-6)
        p = pose_parameters(cam.T_world_cam(), view.target)
        assert p["distance"] == pytest.approx(view.distance, abs=1e-6)
        assert p["tilt_deg"] == pytest.approx(view.tilt_deg, abs=1e-4) and p["miss"] < 1e-6
        np.testing.assert_allclose(light_world_pose(proj, 0), T @ pj.T_cam_proj(cfg), atol=1e-6)
        u, v, _ = world_to_camera_view(factory_scene, cam.obj, Vector(view.target))   # on the optical axis
        assert (u, v) == (pytest.approx(0.5, abs=1e-6), pytest.approx(0.5, abs=1e-6))
    proj.teardown()
