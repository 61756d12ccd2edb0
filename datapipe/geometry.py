"""Frames, rotations, pinhole intrinsics and projection matrices shared by core/ (Blender), sl/
(decoder) and io/. No bpy; imports nothing of DataPipe but its errors (sl/ builds on this, not
the other way round).

Blender's camera (and spot light) looks down its local -Z with +Y up; OpenCV's looks down +Z with
+Y down. The two differ by a 180-degree rotation about X: `BLENDER_TO_OPENCV`.
"""
from __future__ import annotations

import math

import numpy as np

from .errors import DataPipeError, bad_type, bad_value

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


def intrinsics_from_sensor(focal_mm: float, sensor_mm: float, width: int, height: int,
                           sensor_fit: str = "AUTO") -> np.ndarray:
    """Pinhole K of an unshifted camera given DataPipe's one sensor size; square pixels, pixel
    centres at integers.

    DataPipe's configs carry one sensor size: it is the sensor width, or with sensor_fit VERTICAL
    the sensor height (BlendCamera sets Blender's sensor_height from it then), so the one size
    applies to whichever dimension the fit selects. A real Blender camera with its own sensor
    height and lens shift is `intrinsics_from_blender_camera`.
    """
    return intrinsics_from_blender_camera(focal_mm, sensor_mm, int(width), int(height), sensor_fit,
                                          sensor_height_mm=sensor_mm)


def camera_intrinsics(camera_cfg) -> np.ndarray:
    """The camera's K: `camera.intrinsics` [fx, fy, cx, cy] when given (a calibration, any principal
    point), else the unshifted pinhole of its focal length and sensor size (`intrinsics_from_sensor`)."""
    c = getattr(camera_cfg, "camera", camera_cfg)
    if getattr(c, "intrinsics", None) is not None:
        return intrinsics_matrix(c.intrinsics)
    return intrinsics_from_sensor(c.focal_length, c.sensor_width, int(c.resolution[0]), int(c.resolution[1]),
                                  c.sensor_fit)


def intrinsics_matrix(fx_fy_cx_cy) -> np.ndarray:
    """[fx, fy, cx, cy] -> K (3x3 float64, zero skew)."""
    fx, fy, cx, cy = (float(v) for v in fx_fy_cx_cy)
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def intrinsics_from_blender_camera(focal_mm: float, sensor_width_mm: float, width: int, height: int,
                                   sensor_fit: str = "AUTO", *, sensor_height_mm: float = 24.0,
                                   shift_x: float = 0.0, shift_y: float = 0.0) -> np.ndarray:
    """OpenCV intrinsics ``K`` (3x3 float64) of a Blender perspective camera, square pixels.

    ``sensor_fit``: 'AUTO' (Blender's default: the sensor width applies to the larger image
    dimension), 'HORIZONTAL' (sensor width <-> image width) or 'VERTICAL' (``sensor_height_mm``
    <-> image height). Principal point ``cx = W/2 - 0.5``, ``cy = H/2 - 0.5`` (pixel centres at
    integers), moved by Blender's lens shift (in units of the fitted dimension; +shift_y moves the
    view up, i.e. the principal point down in the image).
    """
    for name, v in (("focal_mm", focal_mm), ("sensor_width_mm", sensor_width_mm),
                    ("sensor_height_mm", sensor_height_mm)):
        if not np.isfinite(v) or v <= 0:
            raise bad_value(name, f"must be a finite number > 0, got {v!r}", "give the length in millimetres")
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise bad_value(name, f"must be a positive int, got {v!r}", "give the resolution in pixels")
    fit = str(sensor_fit).upper()
    if fit == "AUTO":
        size_px, sensor = max(width, height), sensor_width_mm
    elif fit == "HORIZONTAL":
        size_px, sensor = width, sensor_width_mm
    elif fit == "VERTICAL":
        size_px, sensor = height, sensor_height_mm
    else:
        raise bad_value("sensor_fit", f"must be 'AUTO', 'HORIZONTAL' or 'VERTICAL', got {sensor_fit!r}",
                        "use Blender's camera.data.sensor_fit value")
    f = focal_mm * size_px / sensor
    cx = width / 2.0 - 0.5 - shift_x * size_px
    cy = height / 2.0 - 0.5 + shift_y * size_px
    return np.array([[f, 0.0, cx], [0.0, f, cy], [0.0, 0.0, 1.0]])


def projection_matrix(K, T_world_cam) -> np.ndarray:
    """``P = K @ inv(T_world_cam)[:3]`` (3x4, float64): world -> pixel for a camera whose pose in
    the world is ``T_world_cam`` (4x4, OpenCV camera frame: x right, y down, z forward)."""
    K = finite_matrix(K, (3, 3), "K")
    T = finite_matrix(T_world_cam, (4, 4), "T_world_cam")
    if not np.allclose(T[3], [0, 0, 0, 1], atol=1e-9):
        raise bad_value("T_world_cam", f"last row is {T[3].tolist()}, not [0, 0, 0, 1]",
                        "pass a rigid 4x4 pose matrix")
    R = T[:3, :3]
    if not np.allclose(R.T @ R, np.eye(3), atol=1e-6) or np.linalg.det(R) <= 0:
        raise bad_value("T_world_cam", "rotation part is not a proper rotation",
                        "pass a rigid pose (orthonormal rotation, det +1, no scale)")
    inv = np.eye(4)
    inv[:3, :3] = R.T
    inv[:3, 3] = -R.T @ T[:3, 3]
    return K @ inv[:3]


def finite_matrix(m, shape, name) -> np.ndarray:
    try:
        a = np.asarray(m, dtype=np.float64)
    except (TypeError, ValueError):
        raise bad_type(name, f"must be a numeric {shape[0]}x{shape[1]} matrix, got {type(m).__name__}",
                       f"pass a {shape[0]}x{shape[1]} numpy array") from None
    if a.shape != shape:
        raise bad_value(name, f"has shape {a.shape}, expected {shape}", f"pass a {shape[0]}x{shape[1]} matrix")
    if not np.all(np.isfinite(a)):
        raise bad_value(name, "contains NaN or inf", "check the calibration / pose that produced it")
    return a


# ------------------------------------------------------------------------------------------------
# the projector (a pinhole like the camera, realised in Blender as a spot light; derivations in
# core/projector.py's docstring)

SPOT_MARGIN = 1.05                          # cone half-angle tangent = 1.05 x the image corner's
MAX_CORNER_ANGLE = math.radians(80.0)       # image corner off-axis angle limit (cone < 180 deg)

def projector_cfg(cfg):
    """Accept a Config or a ProjectorConfig."""
    return getattr(cfg, "projector", cfg)


def projector_resolution(cfg) -> tuple[int, int]:
    w, h = projector_cfg(cfg).resolution
    return int(w), int(h)


def projector_intrinsics(cfg) -> np.ndarray:
    """K_p (3x3, pixel centres at integers) from focal length (mm), sensor width (mm), W x H, or
    `projector.intrinsics` [fx, fy, cx, cy] when given.

    The projector is an unshifted pinhole with square pixels and Blender's AUTO sensor fit (the
    sensor width applies to the larger image dimension) - the same rule as the camera."""
    pr = projector_cfg(cfg)
    if getattr(pr, "intrinsics", None) is not None:       # a calibration: any fx, fy, principal point
        return intrinsics_matrix(pr.intrinsics)
    w, h = projector_resolution(pr)
    return intrinsics_from_sensor(pr.focal_length, pr.sensor_width, w, h, "AUTO")


def projector_pose_blender(cfg) -> np.ndarray:
    """T_blcam_bllight: the light object's pose in the camera object's local (Blender) axes."""
    pr = projector_cfg(cfg)
    return pose_matrix(pr.location, rotation_from_config(pr.rotation))


def T_cam_proj(cfg) -> np.ndarray:
    """4x4 pose of the projector (OpenCV projector frame) in the OpenCV camera frame."""
    return BLENDER_TO_OPENCV @ projector_pose_blender(cfg) @ BLENDER_TO_OPENCV


def projector_matrix(cfg, T_world_cam) -> np.ndarray:
    """P_proj (3x4): homogeneous world points -> projector pixels (x column, y row; OpenCV).

    `T_world_cam` is the camera pose in the OpenCV frame (as BlendCamera returns it)."""
    T_world_proj = np.asarray(T_world_cam, dtype=np.float64) @ T_cam_proj(cfg)
    return projector_intrinsics(cfg) @ np.linalg.inv(T_world_proj)[:3]


def texture_mapping(cfg) -> tuple[tuple[float, float, float], tuple[float, float, float]]:
    """(scale, location) of the Mapping node that turns (N.x/N.z, N.y/N.z) into image (s, t)."""
    K = projector_intrinsics(cfg)
    w, h = projector_resolution(cfg)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    scale = (-fx / w, -fy / h, 1.0)
    location = ((cx + 0.5) / w, 1.0 - (cy + 0.5) / h, 0.0)
    return scale, location


def image_half_angle(cfg) -> float:
    """Angle between the optical axis and the ray through the image's farthest outer corner (rad)."""
    K = projector_intrinsics(cfg)
    w, h = projector_resolution(cfg)
    xs = (np.array([-0.5, w - 0.5]) - K[0, 2]) / K[0, 0]
    ys = (np.array([-0.5, h - 0.5]) - K[1, 2]) / K[1, 1]
    return math.atan(math.hypot(np.abs(xs).max(), np.abs(ys).max()))


def spot_size(cfg, margin: float = SPOT_MARGIN) -> float:
    """Full cone angle (rad) a little wider than the image, so the image is the aperture."""
    half = math.atan(margin * math.tan(image_half_angle(cfg)))
    corner = image_half_angle(cfg)
    if corner > MAX_CORNER_ANGLE:
        raise DataPipeError(
            f"projector field of view too wide: its image corner is {math.degrees(corner):.1f} deg off axis, "
            f"more than {math.degrees(MAX_CORNER_ANGLE):.0f} (a spot light cone is at most 180 deg) (fix: raise "
            "projector.focal_length or lower projector.sensor_width)")
    return 2.0 * half


def pattern_pixels(pattern: np.ndarray) -> np.ndarray:
    """(H, W) pattern (or (H, W, 3): one image per colour channel, sl.pack_basis), row 0 = top of
    the projected image -> flat RGBA float32 for Image.pixels.

    Blender images are stored bottom-up, so the rows are flipped; R = G = B = value, A = 1."""
    p = np.asarray(pattern, dtype=np.float32)
    h, w = p.shape[:2]
    rgba = np.empty((h, w, 4), dtype=np.float32)
    rgba[..., :3] = p[::-1, :, None] if p.ndim == 2 else p[::-1]
    rgba[..., 3] = 1.0
    return rgba.ravel()


def check_patterns(cfg, patterns) -> np.ndarray:
    """Validate a (P, H, W) stack (or (P, H, W, 3): an image per colour channel, sl.pack_basis)
    against the projector resolution; returns float32 array."""
    arr = np.asarray(patterns, dtype=np.float32)
    w, h = projector_resolution(cfg)
    if arr.ndim == 2:
        arr = arr[None]
    if arr.ndim not in (3, 4) or arr.shape[1:3] != (h, w) or (arr.ndim == 4 and arr.shape[3] != 3):
        raise DataPipeError(f"fringe patterns have shape {np.shape(patterns)}, the projector needs (P, {h}, {w}) "
                            f"or (P, {h}, {w}, 3) (fix: make the patterns at projector.resolution [width, height])")
    if arr.shape[0] < 1 or arr.shape[0] > 100:
        raise DataPipeError(f"{arr.shape[0]} fringe patterns: one view layer each, 1..100 supported "
                            "(fix: use fewer periods or steps)")
    if not np.all(np.isfinite(arr)) or arr.min() < 0:
        raise DataPipeError("fringe patterns must be finite and >= 0 (they are light intensities)")
    return arr
