"""Frames, rotations and pinhole intrinsics shared by core/ (Blender) and sl/ (decoder). No bpy.

Blender's camera (and spot light) looks down its local -Z with +Y up; OpenCV's looks down +Z with
+Y down. The two differ by a 180-degree rotation about X: `BLENDER_TO_OPENCV`.
"""
from __future__ import annotations

import math

import numpy as np

from .sl.triangulate import intrinsics_from_blender as _sl_intrinsics
from .sl.triangulate import projection_matrix  # noqa: F401  (one source of truth, re-exported)

BLENDER_TO_OPENCV = np.diag([1.0, -1.0, -1.0, 1.0])   # T_blcam_cvcam (its own inverse)


def quat_to_matrix(q) -> np.ndarray:
    """Unit quaternion (w, x, y, z) -> 3x3 rotation. Normalises the input."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ])


def matrix_to_quat(R) -> np.ndarray:
    """3x3 rotation -> quaternion (w, x, y, z) with w >= 0."""
    R = np.asarray(R, dtype=np.float64)
    t = np.trace(R)
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    else:
        i = int(np.argmax(np.diag(R)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = math.sqrt(1.0 + R[i, i] - R[j, j] - R[k, k]) * 2
        q = [0.0] * 4
        q[0] = (R[k, j] - R[j, k]) / s
        q[1 + i] = 0.25 * s
        q[1 + j] = (R[j, i] + R[i, j]) / s
        q[1 + k] = (R[k, i] + R[i, k]) / s
    q = np.array(q)
    return q if q[0] >= 0 else -q


def euler_xyz_to_matrix(e) -> np.ndarray:
    """Blender 'XYZ' Euler (radians): R = Rz @ Ry @ Rx (X applied first)."""
    rx, ry, rz = e
    cx, sx, cy, sy, cz, sz = math.cos(rx), math.sin(rx), math.cos(ry), math.sin(ry), math.cos(rz), math.sin(rz)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def rotation_from_config(rot) -> np.ndarray:
    """3 numbers = XYZ Euler (rad), 4 numbers = quaternion (w, x, y, z)."""
    if len(rot) == 3:
        return euler_xyz_to_matrix(rot)
    if len(rot) == 4:
        return quat_to_matrix(rot)
    raise ValueError(f"rotation needs 3 (Euler XYZ) or 4 (quaternion wxyz) numbers, got {len(rot)}")


def pose_matrix(location, R) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = location
    return T


def blender_camera_to_opencv(T_world_blcam) -> np.ndarray:
    """World pose of a Blender camera/light object (no scale) -> T_world_cam in the OpenCV frame."""
    return np.asarray(T_world_blcam, dtype=np.float64) @ BLENDER_TO_OPENCV


def camera_pose_from_config(location, quat_wxyz) -> np.ndarray:
    """A config camera pose (Blender object location + quaternion) -> T_world_cam (OpenCV)."""
    return blender_camera_to_opencv(pose_matrix(location, quat_to_matrix(quat_wxyz)))


def sensor_fit_is_horizontal(sensor_fit: str, width: int, height: int) -> bool:
    if sensor_fit == "HORIZONTAL":
        return True
    if sensor_fit == "VERTICAL":
        return False
    return width >= height          # AUTO: the sensor size applies to the larger dimension


def intrinsics_from_blender(focal_mm: float, sensor_mm: float, width: int, height: int,
                            sensor_fit: str = "AUTO") -> np.ndarray:
    """Pinhole K of an unshifted Blender camera with square pixels; pixel centres at integers.

    DataPipe's configs carry one sensor size: it is the sensor width, or with sensor_fit VERTICAL
    the sensor height (BlendCamera sets Blender's sensor_height from it then). One implementation:
    `datapipe.sl.triangulate.intrinsics_from_blender`.
    """
    return _sl_intrinsics(focal_mm, sensor_mm, int(width), int(height), sensor_fit, sensor_height_mm=sensor_mm)


def project_points(K, T_cam_X, pts) -> np.ndarray:
    """Points in frame X (N,3) -> pixel coordinates (N,2) through T_cam_X (4x4) and K."""
    pts = np.asarray(pts, dtype=np.float64)
    pc = pts @ T_cam_X[:3, :3].T + T_cam_X[:3, 3]
    uv = pc @ np.asarray(K).T
    return uv[:, :2] / uv[:, 2:3]
