"""The bin_view camera sampler without bpy: the drawn parameters come back out of the produced pose,
the optical axis hits the target, draws stay in their ranges, and the seed fixes the draw."""
import math

import numpy as np
import pytest

from datapipe import config as C
from datapipe.draws.camera_sampler import draw_bin_view, look_at_pose, view_problems
from datapipe.geometry import BLENDER_TO_OPENCV, camera_pose_from_config, projection_matrix
from datapipe.draws.seeds import camera_rng
from pose_checks import pixels, pose_parameters


def _sampler(**kw):
    s = C.CameraSamplerConfig(kind="bin_view", distance=[0.5, 0.9], tilt_deg=[5.0, 40.0],
                              azimuth_deg=[0.0, 360.0], roll_deg=[-180.0, 180.0], target_jitter=0.03)
    for k, v in kw.items():
        setattr(s, k, v)
    return s


@pytest.mark.parametrize("d,t,a,r", [(0.7, 30.0, 45.0, 10.0), (0.5, 5.0, 200.0, -170.0),
                                     (1.2, 60.0, 300.0, 90.0), (0.8, 0.0, 0.0, 0.0)])
def test_parameters_round_trip_through_the_pose(d, t, a, r):
    target = np.array([0.1, -0.05, 0.02])
    T = look_at_pose(target, d, t, a, r)
    R = T[:3, :3]
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-12) and np.isclose(np.linalg.det(R), 1.0)
    p = pose_parameters(T, target)
    assert p["distance"] == pytest.approx(d, abs=1e-12)
    assert p["tilt_deg"] == pytest.approx(t, abs=1e-9)
    assert p["miss"] == pytest.approx(0.0, abs=1e-12)
    if t > 0:
        assert p["azimuth_deg"] == pytest.approx(a % 360.0, abs=1e-9)
        assert p["roll_deg"] == pytest.approx(r, abs=1e-9)


def test_tilt_and_azimuth_by_hand():
    """Independent geometry: 30 deg tilt towards +X puts the camera at (d sin 30, 0, d cos 30) above
    the target; the target projects onto the principal point; the image's bottom points to +X."""
    target = np.array([0.0, 0.0, 0.0])
    T = look_at_pose(target, 1.0, 30.0, 0.0, 0.0)
    assert np.allclose(T[:3, 3], [0.5, 0.0, math.sqrt(3) / 2])
    K = np.array([[500.0, 0, 319.5], [0, 500.0, 239.5], [0, 0, 1]])
    uv = pixels(projection_matrix(K, T), [target, [0.1, 0, 0], [-0.1, 0, 0]])
    assert np.allclose(uv[0], [319.5, 239.5])
    assert uv[1, 1] > 239.5 > uv[2, 1]          # the near side (+X) is lower in the image
    # roll +90 deg turns the camera's x onto its former y: the +X point moves from below the centre
    # to its right, on the centre row
    uv90 = pixels(projection_matrix(K, look_at_pose(target, 1.0, 30.0, 0.0, 90.0)), [[0.1, 0, 0]])
    assert uv90[0, 0] > 319.5 and uv90[0, 1] == pytest.approx(239.5)


def test_blender_pose_matches_opencv_pose():
    v = draw_bin_view(_sampler(), [0.0, 0.0, 0.0], camera_rng(3, 1, 2))
    loc, q = v.blender_pose()
    assert np.allclose(camera_pose_from_config(loc, q), v.T_world_cam(), atol=1e-12)
    assert np.allclose(v.T_world_cam() @ BLENDER_TO_OPENCV @ BLENDER_TO_OPENCV, v.T_world_cam())


def test_draws_stay_in_ranges_and_hit_the_target():
    s = _sampler()
    floor = np.array([0.02, 0.01, 0.0])
    for r in range(200):
        v = draw_bin_view(s, floor, camera_rng(7, 0, r))
        p = pose_parameters(v.T_world_cam(), v.target)
        assert 0.5 <= p["distance"] <= 0.9 and 5.0 <= p["tilt_deg"] <= 40.0 and p["miss"] < 1e-12
        assert -180.0 <= p["roll_deg"] <= 180.0
        assert np.linalg.norm(v.target[:2] - floor[:2]) <= 0.03 and v.target[2] == floor[2]
        # from the bin floor centre itself: within distance +- jitter
        assert 0.5 - 0.03 - 1e-12 <= np.linalg.norm(v.T_world_cam()[:3, 3] - floor) <= 0.9 + 0.03 + 1e-12


def test_same_seed_same_pose_and_poses_differ():
    s = _sampler()
    a = [draw_bin_view(s, [0, 0, 0], camera_rng(11, 2, r)).record() for r in range(5)]
    b = [draw_bin_view(s, [0, 0, 0], camera_rng(11, 2, r)).record() for r in range(5)]
    assert a == b
    assert len({(x["distance"], x["tilt_deg"]) for x in a}) == 5


def test_fixed_ranges_give_exactly_those_values():
    s = _sampler(distance=[0.7, 0.7], tilt_deg=[20.0, 20.0], azimuth_deg=[90.0, 90.0], roll_deg=[0.0, 0.0],
                 target_jitter=0.0)
    v = draw_bin_view(s, [0, 0, 0.1], camera_rng(0, 0, 0))
    assert (v.distance, v.tilt_deg, v.azimuth_deg, v.roll_deg) == (0.7, 20.0, 90.0, 0.0)
    assert np.allclose(v.target, [0, 0, 0.1])


def test_view_problems_flag_low_cameras_and_wild_jitter():
    assert view_problems(_sampler(), [0.15, 0.1], 0.2, 19.0) == []
    low = view_problems(_sampler(distance=[0.3, 0.9], tilt_deg=[0.0, 80.0]), [0.15, 0.1], 0.2, 19.0)
    assert [p[0] for p in low] == ["camera.sampler.tilt_deg"]
    wild = view_problems(_sampler(target_jitter=0.5), [0.15, 0.1], 0.2, 19.0)
    assert {p[0] for p in wild} == {"camera.sampler.target_jitter"} and len(wild) == 2


def test_config_validates_the_sampler():
    cfg = C.default_config()
    cfg.camera.sampler = _sampler()
    assert cfg.problems() == []
    cfg.camera.poses = []                     # the pool is not used by bin_view
    cfg.scene.max_renders_per_scene = 50
    assert cfg.problems() == []
    cfg.camera.sampler.kind = "orbit"
    assert [p.path for p in cfg.problems()] == ["camera.sampler.kind"]
    cfg.camera.sampler = _sampler(distance=[0.9, 0.5], tilt_deg=[0.0, 95.0], target_jitter=-1.0)
    assert {p.path for p in cfg.problems()} == {"camera.sampler.distance", "camera.sampler.tilt_deg",
                                                "camera.sampler.target_jitter"}
    cfg.camera.sampler = _sampler(distance=[0.5, 20.0])
    assert [p.path for p in cfg.problems()] == ["camera.sampler.distance"]
    cfg.camera.sampler = _sampler(distance=[0.3, 0.9], tilt_deg=[0.0, 85.0])
    assert [p.path for p in cfg.problems()] == ["camera.sampler.tilt_deg"]


def test_sampler_json_round_trip(tmp_path):
    cfg = C.default_config()
    cfg.camera.sampler = _sampler()
    C.save(cfg, tmp_path / "p.json")
    assert C.load(tmp_path / "p.json").to_dict() == cfg.to_dict()
    d = cfg.to_dict()
    d["camera"]["sampler"] = {"kind": "bin_view", "distance": [0.6, 0.7]}    # the rest defaults
    back = C.Config.from_dict(d)
    assert back.camera.sampler.distance == [0.6, 0.7] and back.camera.sampler.tilt_deg == [0.0, 25.0]
    d["camera"]["sampler"]["dist"] = 1
    with pytest.raises(C.ConfigError) as e:
        C.Config.from_dict(d)
    assert "camera.sampler.dist" in e.value.paths()
