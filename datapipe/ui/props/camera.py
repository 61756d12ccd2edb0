"""`Scene.datapipe.camera`: intrinsics, the pose pool and the look-at pose sampler (`Config.camera`)."""
from bpy.props import (BoolProperty, CollectionProperty, EnumProperty, FloatProperty, FloatVectorProperty,
                       IntProperty, IntVectorProperty, PointerProperty)
from bpy.types import PropertyGroup

from ... import config as C
from .fields import chain, default, enum_choices, keep_order, range_property, sync_previews


_P = C.CameraPose
_K = C.CameraConfig
_clip_lo, _clip_hi = keep_order("clip_start", "clip_end", strict=True)


class DATAPIPE_PG_pose(PropertyGroup):
    location: FloatVectorProperty(
        name="Location", description="World location of the Blender camera object",
        size=3, subtype="TRANSLATION", unit="LENGTH", default=default(_P, "location"))
    rotation: FloatVectorProperty(
        name="Rotation", description="World rotation of the Blender camera object as a quaternion (w, x, y, z); "
        "the camera looks down its local -Z", size=4, subtype="QUATERNION", default=default(_P, "rotation"))


_CS = C.CameraSamplerConfig


class DATAPIPE_PG_camera_sampler(PropertyGroup):
    kind: EnumProperty(
        name="Sampler", description="How each render's camera pose is chosen",
        items=[("pool", "Pose Pool", "Draw from the pose list below (without replacement within a scene)"),
               ("bin_view", "Bin View", "Draw a look-at pose around the bin floor's centre per render "
                "from the ranges below (the projector moves with the camera)")],
        default=default(_CS, "kind"))
    distance: range_property("distance", "Distance", "Camera centre to the look-at target", _CS, unit="LENGTH",
                     lo=1e-3, soft_max=5.0)
    tilt_deg: range_property("tilt_deg", "Tilt", "Optical axis from straight down, degrees", _CS, lo=0.0, hi=89.0,
                     precision=1)
    azimuth_deg: range_property("azimuth_deg", "Azimuth", "Direction from the target to the camera, degrees "
                        "counter-clockwise from world +X", _CS, precision=1)
    roll_deg: range_property("roll_deg", "Roll", "Image rotation about the optical axis, degrees", _CS, precision=1)
    target_jitter: FloatProperty(
        name="Target Jitter", description="The look-at target is the bin floor's centre plus a random "
        "horizontal offset up to this far", subtype="DISTANCE", unit="LENGTH", min=0.0, soft_max=0.5,
        precision=3, default=default(_CS, "target_jitter"))


class DATAPIPE_PG_camera(PropertyGroup):
    focal_length: FloatProperty(
        name="Focal Length", description="Lens focal length (millimetres, as Blender's camera)",
        subtype="DISTANCE_CAMERA", unit="CAMERA", min=1e-3, soft_min=1.0, soft_max=300.0,
        default=default(_K, "focal_length"), update=sync_previews)
    sensor_width: FloatProperty(
        name="Sensor Width", description="Sensor width (millimetres)",
        subtype="DISTANCE_CAMERA", unit="CAMERA", min=C.MIN_POSITIVE["camera.sensor_width"], soft_min=1.0, soft_max=100.0,
        default=default(_K, "sensor_width"), update=sync_previews)
    sensor_fit: EnumProperty(
        name="Sensor Fit", description="Which image dimension the sensor width applies to",
        items=enum_choices(C.SENSOR_FITS), default=default(_K, "sensor_fit"), update=sync_previews)
    resolution: IntVectorProperty(
        name="Resolution", description="Image size in pixels (width, height)", size=2,
        min=1, max=C.MAX_RESOLUTION, default=default(_K, "resolution"), update=sync_previews)
    clip_start: FloatProperty(
        name="Clip Start", description="Nearest rendered distance. Raising it past Clip End moves Clip End",
        subtype="DISTANCE", unit="LENGTH", min=C.MIN_POSITIVE["camera.clip_start"], soft_max=10.0, precision=3,
        default=default(_K, "clip_start"), update=chain(_clip_lo, sync_previews))
    clip_end: FloatProperty(
        name="Clip End", description="Farthest rendered distance. Lowering it below Clip Start moves Clip Start",
        subtype="DISTANCE", unit="LENGTH", min=C.MIN_POSITIVE["camera.clip_end"], soft_max=1000.0, precision=3,
        default=default(_K, "clip_end"), update=chain(_clip_hi, sync_previews))
    # a calibrated camera (docs/CALIBRATION.md): K and OpenCV lens distortion, each off = the config's null
    use_intrinsics: BoolProperty(
        name="Calibrated K", description="Use fx, fy, cx, cy in pixels (a calibration) instead of the focal "
        "length and sensor width", default=False, update=sync_previews)
    intrinsics: FloatVectorProperty(
        name="K", description="fx, fy, cx, cy in pixels at the resolution above", size=4, precision=3,
        default=(453.1, 453.1, 159.5, 119.5), update=sync_previews)
    use_distortion: BoolProperty(
        name="Lens Distortion", description="Render through OpenCV's lens model (k1 k2 p1 p2 k3)",
        default=False, update=sync_previews)
    distortion: FloatVectorProperty(
        name="Distortion", description="OpenCV k1, k2, p1, p2, k3", size=5, precision=5,
        default=(0.0, 0.0, 0.0, 0.0, 0.0), update=sync_previews)
    poses: CollectionProperty(type=DATAPIPE_PG_pose, name="Poses",
                              description="Pool of camera poses; each scene draws its renders' poses from it")
    poses_index: IntProperty(name="Active Pose", description="Selected camera pose", min=0)
    sampler: PointerProperty(type=DATAPIPE_PG_camera_sampler, name="Sampler",
                             description="Pose pool or look-at poses drawn around the bin")
