"""Camera poses drawn around the bin, one per render ("bin_view" sampler). No bpy.

A pose is four numbers around a look-at target on the bin floor:

- `distance`  (m): from the camera centre to the target, along the optical axis;
- `tilt`    (deg): angle between the optical axis and straight down (0 = looking straight down);
- `azimuth` (deg): direction from the target to the camera, counter-clockwise from world +X;
- `roll`    (deg): rotation of the image about the optical axis.

The target is the centre of the bin floor plus a horizontal offset drawn uniformly in a disc of
radius `target_jitter`, so the optical axis always passes through the target.

Orientation at roll 0 (OpenCV frame: x right, y down, z forward): z points from the camera to the
target; x is horizontal, (-sin azimuth, cos azimuth, 0), i.e. perpendicular to the vertical plane
through camera and target; y = z x x then points "down the image" towards the camera's side of the
bin, so the far side of the bin is at the top of the image (how a person looks into a bin). Roll
turns (x, y) about z: x' = cos r x + sin r y. With tilt 0 the azimuth only sets the image's
in-plane rotation (as roll does).

Each of the four is drawn uniformly within its [min, max] (tilt uniform in degrees, not uniform on
the sphere: a range of tilts then gets equally many views of each tilt). All draws come from one
numpy Generator the caller seeds from (base seed, scene, render) (`datapipe.draws.seeds.camera_rng`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..geometry import BLENDER_TO_OPENCV, matrix_to_quat


@dataclass
class BinView:
    """One drawn pose: the parameters and the target they were drawn around."""
    distance: float              # m
    tilt_deg: float
    azimuth_deg: float
    roll_deg: float
    target: np.ndarray           # (3,) world, m: bin floor centre + jitter

    def T_world_cam(self) -> np.ndarray:
        return look_at_pose(self.target, self.distance, self.tilt_deg, self.azimuth_deg, self.roll_deg)

    def blender_pose(self) -> tuple[list[float], list[float]]:
        """The Blender camera object's (location, quaternion wxyz) for this pose."""
        T = self.T_world_cam() @ BLENDER_TO_OPENCV        # OpenCV -> Blender camera axes
        return [float(v) for v in T[:3, 3]], [float(v) for v in matrix_to_quat(T[:3, :3])]

    def record(self) -> dict:
        """What scene.json keeps of the draw (re-makes the pose with `look_at_pose`)."""
        return {"kind": "bin_view", "distance": self.distance, "tilt_deg": self.tilt_deg,
                "azimuth_deg": self.azimuth_deg, "roll_deg": self.roll_deg,
                "target": [float(v) for v in self.target]}


def look_at_pose(target, distance: float, tilt_deg: float, azimuth_deg: float, roll_deg: float) -> np.ndarray:
    """T_world_cam (4x4, OpenCV camera frame) of a camera `distance` from `target` (see module doc)."""
    t, a, r = (math.radians(v) for v in (tilt_deg, azimuth_deg, roll_deg))
    out = np.array([math.sin(t) * math.cos(a), math.sin(t) * math.sin(a), math.cos(t)])  # target -> camera
    z = -out
    x0 = np.array([-math.sin(a), math.cos(a), 0.0])
    y0 = np.cross(z, x0)
    x = math.cos(r) * x0 + math.sin(r) * y0
    y = -math.sin(r) * x0 + math.cos(r) * y0
    T = np.eye(4)
    T[:3, :3] = np.column_stack([x, y, z])
    T[:3, 3] = np.asarray(target, dtype=np.float64) + distance * out
    return T


def _uniform(rng: np.random.Generator, lo_hi) -> float:
    lo, hi = (float(v) for v in lo_hi)
    return lo if hi <= lo else float(rng.uniform(lo, hi))


def draw_bin_view(sampler, floor_center, rng: np.random.Generator) -> BinView:
    """One pose from `sampler` (a `config.CameraSamplerConfig` of kind "bin_view") around the bin
    floor centre `floor_center` (world, m). Draw order is fixed (jitter, distance, tilt, azimuth,
    roll), so a seed always gives the same pose."""
    target = np.asarray(floor_center, dtype=np.float64).copy()
    j = float(sampler.target_jitter)
    if j > 0:
        rho = j * math.sqrt(float(rng.uniform()))          # uniform over the disc's area
        phi = float(rng.uniform(0.0, 2 * math.pi))
        target[:2] += rho * np.array([math.cos(phi), math.sin(phi)])
    return BinView(distance=_uniform(rng, sampler.distance), tilt_deg=_uniform(rng, sampler.tilt_deg),
                   azimuth_deg=_uniform(rng, sampler.azimuth_deg), roll_deg=_uniform(rng, sampler.roll_deg),
                   target=target)


def view_problems(sampler, floor_half, wall_top: float, half_fov_deg: float) -> list[tuple[str, str, str]]:
    """(field, message, fix) for sampler ranges that can lose the bin from view.

    `floor_half` are the bin's inner half-extents in x, y; `wall_top` the height of the walls above
    the floor (m); `half_fov_deg` the camera's smaller half field of view. Checked at the worst
    corners of the ranges: the camera dipping to the walls' height (it would look through or from
    inside a wall), the bin's centre leaving the view when the target is jittered, and a target
    jittered beyond the bin's floor."""
    out = []
    d_lo, t_hi = float(min(sampler.distance)), float(max(sampler.tilt_deg))
    height = d_lo * math.cos(math.radians(t_hi))
    if height <= wall_top:
        out.append(("camera.sampler.tilt_deg",
                    f"at distance {d_lo:g} m and tilt {t_hi:g} deg the camera is {height:.3f} m above the bin "
                    f"floor, not above the walls ({wall_top:.3f} m): the bin can be out of view",
                    "lower the largest tilt or raise the smallest distance"))
    j = float(sampler.target_jitter)
    seen = d_lo * math.tan(math.radians(half_fov_deg))    # half width of the view at the target
    if j >= seen:
        out.append(("camera.sampler.target_jitter",
                    f"a target {j:g} m off the bin centre is beyond the view's half width ({seen:.3f} m at "
                    f"{d_lo:g} m): the bin's centre can leave the image",
                    f"use a jitter below {seen:.3f} m or raise the smallest distance"))
    if j > float(min(floor_half)):
        out.append(("camera.sampler.target_jitter",
                    f"{j:g} m jitter can aim beside the bin (its floor's half size is {min(floor_half):.3f} m)",
                    "use a jitter at most the bin's half size"))
    return out
