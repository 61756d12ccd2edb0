"""The pure geometry: projector intrinsics, pose, P_proj, the node-tree mapping, the cone, pattern
images (datapipe.geometry; the Blender side is tested in tests/blender/test_projector.py)."""
import math

import numpy as np
import pytest

from datapipe import geometry
from datapipe.config import Config
from datapipe.errors import DataPipeError
from datapipe.geometry import camera_pose_from_config, euler_xyz_to_matrix, intrinsics_from_sensor, matrix_to_quat


def _cfg(**proj):
    cfg = Config()
    for k, v in proj.items():
        setattr(cfg.projector, k, v)
    return cfg


def _project(P, X):
    q = np.c_[X, np.ones(len(X))] @ P.T
    return q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]



def test_projector_math():
    cfg = _cfg()
    W, H = cfg.projector.resolution
    K = geometry.projector_intrinsics(cfg)
    assert np.allclose(K, intrinsics_from_sensor(16.0, 11.3, W, H))
    assert K[0, 2] == W / 2 - 0.5 and K[1, 2] == H / 2 - 0.5
    T = geometry.T_cam_proj(cfg)
    # projector 15 cm to the camera's left (OpenCV -x), same height, optical axes converge ~1 m ahead
    assert np.allclose(T[:3, 3], [-0.15, 0.0, 0.0])
    z_axis = T[:3, 2]                         # projector's forward axis in the camera frame
    assert z_axis[0] > 0 and z_axis[2] > 0.98   # turned towards the camera axis
    t = 0.15 / z_axis[0]
    meet = T[:3, 3] + t * z_axis
    assert abs(meet[0]) < 1e-12 and 0.95 < meet[2] < 1.05
    # P_proj sends the projector centre's forward ray to the principal point, and the convergence
    # point (on the camera axis) to the principal point as well
    Twc = camera_pose_from_config([0.1, 0.2, 1.0], matrix_to_quat(euler_xyz_to_matrix([0.3, -0.2, 0.5])))
    P = geometry.projector_matrix(cfg, Twc)
    X = (Twc @ np.r_[meet, 1.0])[:3]
    x, y = _project(P, X[None])
    assert np.allclose([x[0], y[0]], [K[0, 2], K[1, 2]])
    # a point to the camera's right / below lands at larger projector x / y (no mirror)
    for d, (sx, sy) in (([0.1, 0, 0], (1, 0)), ([0, 0.1, 0], (0, 1))):
        Xd = (Twc @ np.r_[meet + d, 1.0])[:3]
        xd, yd = _project(P, Xd[None])
        assert np.sign(np.round(xd[0] - x[0], 6)) == sx and np.sign(np.round(yd[0] - y[0], 6)) == sy
    # Mapping values: s = (x + 0.5)/W, t = 1 - (y + 0.5)/H for u = -xn, v = yn
    scale, loc = geometry.texture_mapping(cfg)
    assert np.allclose(scale, [-16.0 / 11.3, -16.0 / 11.3 * W / H, 1.0])
    assert np.allclose(loc, [0.5, 0.5, 0.0])
    # spot cone wider than the image corner, < 180 deg
    assert 2 * geometry.image_half_angle(cfg) < geometry.spot_size(cfg) < math.pi
    # a quaternion rotation gives the same pose as the equivalent Euler
    cfg_q = _cfg(rotation=list(matrix_to_quat(euler_xyz_to_matrix(cfg.projector.rotation))))
    assert np.allclose(geometry.T_cam_proj(cfg_q), T)
    # pattern pixels: numpy row 0 (top) becomes Blender's last (top) stored row
    pix = geometry.pattern_pixels(np.array([[1.0, 2.0], [3.0, 4.0]])).reshape(2, 2, 4)
    assert pix[1, :, 0].tolist() == [1.0, 2.0] and pix[0, :, 0].tolist() == [3.0, 4.0]
    assert np.all(pix[..., 3] == 1)
    with pytest.raises(DataPipeError):
        geometry.check_patterns(cfg, np.zeros((2, H, W + 1)))
    with pytest.raises(DataPipeError):
        geometry.spot_size(_cfg(focal_length=1.0, sensor_width=36.0))
