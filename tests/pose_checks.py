"""Independent checks of camera poses for the tests (not the package: no run needs them).

- `pose_parameters`: the inverse of `datapipe.draws.camera_sampler.look_at_pose`, read off the matrix
  by hand, so a drawn or recorded pose can be checked against the numbers it was drawn from;
- `pixels`: points through a 3x4 projection matrix (`datapipe.geometry.projection_matrix`, the one
  the scanner and the annotations use) to pixel coordinates."""
import math

import numpy as np


def pose_parameters(T_world_cam, target) -> dict:
    """Inverse of `look_at_pose`: distance, tilt, azimuth, roll (deg) of a pose around `target`, plus
    `miss` (m), how far the optical axis passes from the target (0 for a look-at pose).

    At tilt 0 the azimuth is undefined (camera straight above the target): it is reported as 0 and
    the whole in-plane rotation as roll."""
    T = np.asarray(T_world_cam, dtype=np.float64)
    c, x, z = T[:3, 3], T[:3, 0], T[:3, 2]
    v = c - np.asarray(target, dtype=np.float64)
    distance = float(np.linalg.norm(v))
    tilt = math.degrees(math.acos(float(np.clip(-z[2], -1.0, 1.0))))
    horizontal = math.hypot(-z[0], -z[1])
    azimuth = math.degrees(math.atan2(-z[1], -z[0])) if horizontal > 1e-9 else 0.0
    a = math.radians(azimuth)
    x0 = np.array([-math.sin(a), math.cos(a), 0.0])
    y0 = np.cross(z, x0)
    roll = math.degrees(math.atan2(float(x @ y0), float(x @ x0)))
    miss = float(np.linalg.norm(v - (v @ z) * z))
    return {"distance": distance, "tilt_deg": tilt, "azimuth_deg": azimuth % 360.0, "roll_deg": roll,
            "miss": miss}


def pixels(P, points) -> np.ndarray:
    """(N, 2) pixel coordinates of (N, 3) world points through the 3x4 projection matrix P."""
    pts = np.asarray(points, dtype=np.float64)
    uvw = pts @ np.asarray(P)[:, :3].T + np.asarray(P)[:, 3]
    return uvw[:, :2] / uvw[:, 2:3]
