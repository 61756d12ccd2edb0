"""The render camera: one Blender camera object, its intrinsics K and its poses (OpenCV frame).

Conventions (docs/CONVENTIONS.md): metres; `T_world_cam` is the camera pose in the world in the OpenCV frame
(x right, y down, z forward); pixel centres at integers, so an unshifted camera has
cx = W/2 - 0.5, cy = H/2 - 0.5. The config's poses are Blender camera-object poses (location +
quaternion w, x, y, z; the camera looks down its local -Z); the Blender <-> OpenCV conversion is
`datapipe.geometry.blender_camera_to_opencv`, nowhere else.
"""
from __future__ import annotations

import numpy as np

import bpy

from .. import geometry, lens
from ..config import Config
from ..errors import DataPipeError

CAMERA_NAME = "datapipe_camera"


def apply_intrinsics(cam_data, scene, camera_cfg) -> None:
    """Set a Blender camera's lens and the scene's resolution from `cfg.camera` (also used by the
    UI's preview camera, so the preview frames exactly what renders)."""
    c = camera_cfg
    cam_data.type = "PERSP"
    cam_data.lens_unit = "MILLIMETERS"
    grid = render_grid(c)
    if grid is None:
        cam_data.lens = c.focal_length
        cam_data.sensor_fit = c.sensor_fit
        # With VERTICAL fit Blender uses sensor_height; the config's sensor_width is the size of the
        # fitted sensor dimension in every case (what intrinsics_from_sensor takes).
        cam_data.sensor_width = c.sensor_width
        if c.sensor_fit == "VERTICAL":
            cam_data.sensor_height = c.sensor_width
        cam_data.shift_x = cam_data.shift_y = 0.0
        size = tuple(int(v) for v in c.resolution)
    else:
        # a calibrated camera (any principal point, fx != fy) or a distorting lens: Blender renders the
        # ideal pinhole of the render grid (square pixels, principal point by lens shift, overscan for
        # the distortion) and the renderer remaps it into the camera's image (datapipe/lens.py)
        size = grid.render_size
        cam_data.sensor_fit = "AUTO"
        cam_data.sensor_width = c.sensor_width
        cam_data.lens = grid.K_render[0, 0] * c.sensor_width / max(size)
        cam_data.shift_x, cam_data.shift_y = lens.blender_shift(grid)
    cam_data.clip_start, cam_data.clip_end = c.clip_start, c.clip_end
    cam_data.dof.use_dof = False
    r = scene.render
    r.resolution_x, r.resolution_y = size
    r.resolution_percentage = 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.use_border = False


def render_grid(camera_cfg) -> "lens.RenderGrid | None":
    """The grid Blender renders when it is not the camera's own image (datapipe/lens.py), else None:
    a camera without `intrinsics` and `distortion` renders exactly as it always did."""
    c = camera_cfg
    if c.intrinsics is None and lens.coefficients(c.distortion) is None:
        return None
    return lens.render_grid(geometry.camera_intrinsics(c), c.distortion, tuple(int(v) for v in c.resolution))


class BlendCamera:
    """Creates and drives the scene's render camera.

    >>> cam = BlendCamera(cfg, scene); cam.setup()
    >>> T_world_cam = cam.set_pose(0)      # 4x4, OpenCV camera frame
    >>> cam.K, cam.resolution              # 3x3 intrinsics, (W, H)
    """

    def __init__(self, cfg: Config, scene):
        self.cfg = cfg
        self.scene = scene
        self.obj = None
        self.pose_index: int | None = None

    # -- setup ------------------------------------------------------------------------------------
    def setup(self) -> "BlendCamera":
        """Create (or reuse) the camera object "datapipe_camera", make it the scene camera and set
        the render resolution. Leaves the camera at pose 0."""
        c = self.cfg.camera
        obj = self.scene.objects.get(CAMERA_NAME)
        if obj is not None and obj.type != "CAMERA":
            raise DataPipeError(f"object {CAMERA_NAME!r} in the scene is a {obj.type}, not a camera "
                                f"(rename or delete it in the .blend file)")
        if obj is None:
            data = bpy.data.cameras.new(CAMERA_NAME)
            obj = bpy.data.objects.new(CAMERA_NAME, data)
            self.scene.collection.objects.link(obj)
        obj.parent = None
        apply_intrinsics(obj.data, self.scene, c)
        obj.rotation_mode = "QUATERNION"
        obj.scale = (1.0, 1.0, 1.0)
        self.scene.camera = obj
        self.obj = obj
        self.set_pose(0)
        return self

    # -- intrinsics -------------------------------------------------------------------------------
    @property
    def resolution(self) -> tuple[int, int]:
        w, h = self.cfg.camera.resolution
        return int(w), int(h)

    @property
    def K(self) -> np.ndarray:
        return geometry.camera_intrinsics(self.cfg.camera)

    @property
    def lens(self) -> "lens.RenderGrid | None":
        """The remap from Blender's render to the camera's image; None when they are the same."""
        c = self.cfg.camera
        key = (c.intrinsics and tuple(c.intrinsics), c.distortion and tuple(c.distortion), tuple(c.resolution),
               c.focal_length, c.sensor_width, c.sensor_fit)
        if getattr(self, "_grid_key", None) != key:          # the grid's rays are solved once per camera
            grid = render_grid(c)
            self._grid, self._grid_key = (None if grid is None or grid.identity else grid), key
        return self._grid

    @property
    def distortion(self) -> list[float] | None:
        """OpenCV k1 k2 p1 p2 k3 of the camera's lens, None without distortion."""
        d = lens.coefficients(self.cfg.camera.distortion)
        return None if d is None else [float(v) for v in d]

    # -- poses ------------------------------------------------------------------------------------
    def set_pose(self, pose_index: int) -> np.ndarray:
        """Move the camera to `cfg.camera.poses[pose_index]`; returns T_world_cam (4x4, OpenCV)."""
        self._require_setup()
        poses = self.cfg.camera.poses
        if not 0 <= pose_index < len(poses):
            raise DataPipeError(f"camera pose {pose_index} does not exist (camera.poses has {len(poses)})")
        p = poses[pose_index]
        T = self._place(p.location, p.rotation)
        self.pose_index = pose_index
        return T

    def set_view(self, view) -> np.ndarray:
        """Move the camera to a sampled pose (`datapipe.draws.camera_sampler.BinView`); returns T_world_cam.
        The projector, parented to the camera, moves with it."""
        self._require_setup()
        T = self._place(*view.blender_pose())
        self.pose_index = None
        return T

    def _place(self, location, quat_wxyz) -> np.ndarray:
        q = np.asarray(quat_wxyz, dtype=np.float64)
        q = q / np.linalg.norm(q)
        self.obj.location = [float(v) for v in location]
        self.obj.rotation_quaternion = [float(v) for v in q]
        # Evaluate so that matrix_world (and anything parented to the camera, e.g. the projector)
        # reflects the new pose now. This does not change the frame, so simulated parts stay put.
        self.scene.view_layers[0].update()
        return geometry.camera_pose_from_config(location, q)

    def T_world_cam(self) -> np.ndarray:
        """The camera's current pose from its matrix_world: 4x4, OpenCV frame, scale removed."""
        self._require_setup()
        M = np.array(self.obj.matrix_world, dtype=np.float64)
        R = M[:3, :3]
        M[:3, :3] = R / np.linalg.norm(R, axis=0, keepdims=True)
        return geometry.blender_camera_to_opencv(M)

    def draw_poses(self, rng, n: int) -> list[int]:
        """`n` distinct pose indices (without replacement), in draw order.

        `rng` is a numpy Generator (or a `random.Random`)."""
        total = len(self.cfg.camera.poses)
        if not 0 <= n <= total:
            raise DataPipeError(f"asked for {n} camera poses from a pool of {total} (drawn without "
                                f"replacement): add camera poses or lower scene.max_renders_per_scene")
        if isinstance(rng, np.random.Generator):
            return [int(i) for i in rng.choice(total, size=n, replace=False)]
        return [int(i) for i in rng.sample(range(total), n)]

    def _require_setup(self) -> None:
        if self.obj is None:
            raise DataPipeError("BlendCamera.setup() must run before poses are set")
