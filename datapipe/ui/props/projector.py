"""`Scene.datapipe.projector`: the fringe projector's intrinsics and its pose relative to the camera
(`Config.projector`); the rotation is kept as Euler angles and as a quaternion, always equal."""
from bpy.props import BoolProperty, EnumProperty, FloatProperty, FloatVectorProperty, IntVectorProperty
from bpy.types import PropertyGroup
from mathutils import Euler, Quaternion

from ... import config as C
from .fields import default, sync_previews


_J = C.ProjectorConfig
_PROJ_ROT = default(_J, "rotation")
_PROJ_EULER = tuple(_PROJ_ROT) if len(_PROJ_ROT) == 3 else tuple(Quaternion(_PROJ_ROT).to_euler("XYZ"))
_PROJ_QUAT = tuple(_PROJ_ROT) if len(_PROJ_ROT) == 4 else tuple(Euler(_PROJ_ROT, "XYZ").to_quaternion())


def _euler_changed(self, context):
    """The Euler angles are the rotation: keep the quaternion equal (both always describe one pose)."""
    if self.rotation_mode == "XYZ":
        self.rotation_quaternion = Euler(self.rotation_euler, "XYZ").to_quaternion()
    sync_previews(self, context)


def _quaternion_changed(self, context):
    if self.rotation_mode == "QUATERNION":
        self.rotation_euler = Quaternion(self.rotation_quaternion).normalized().to_euler("XYZ")
    sync_previews(self, context)


class DATAPIPE_PG_projector(PropertyGroup):
    focal_length: FloatProperty(
        name="Focal Length", description="Projector lens focal length (millimetres)",
        subtype="DISTANCE_CAMERA", unit="CAMERA", min=1e-3, soft_min=1.0, soft_max=300.0,
        default=default(_J, "focal_length"), update=sync_previews)
    sensor_width: FloatProperty(
        name="Sensor Width", description="Projector image (DMD) width (millimetres)",
        subtype="DISTANCE_CAMERA", unit="CAMERA", min=C.MIN_POSITIVE["projector.sensor_width"], soft_min=1.0, soft_max=100.0,
        default=default(_J, "sensor_width"), update=sync_previews)
    resolution: IntVectorProperty(
        name="Resolution", description="Projector image size in pixels (width, height)", size=2,
        min=1, max=C.MAX_RESOLUTION, default=default(_J, "resolution"), update=sync_previews)
    use_intrinsics: BoolProperty(
        name="Calibrated K", description="Use fx, fy, cx, cy in projector pixels (a calibration) instead of "
        "the focal length and sensor width", default=False, update=sync_previews)
    intrinsics: FloatVectorProperty(
        name="K", description="fx, fy, cx, cy in projector pixels", size=4, precision=3,
        default=(1291.3, 1291.3, 455.5, 284.5), update=sync_previews)
    location: FloatVectorProperty(
        name="Location", description="Projector position relative to the camera, in the camera object's "
        "local axes", size=3, subtype="TRANSLATION", unit="LENGTH", default=default(_J, "location"),
        update=sync_previews)
    rotation_mode: EnumProperty(
        name="Rotation Mode", description="How the projector's rotation relative to the camera is given",
        items=[("XYZ", "XYZ Euler", "Euler angles, XYZ order"),
               ("QUATERNION", "Quaternion", "Quaternion (w, x, y, z)")],
        default="XYZ" if len(_PROJ_ROT) == 3 else "QUATERNION", update=sync_previews)
    rotation_euler: FloatVectorProperty(
        name="Rotation", description="Projector rotation relative to the camera (XYZ Euler)", size=3,
        subtype="EULER", unit="ROTATION", default=_PROJ_EULER, update=_euler_changed)
    rotation_quaternion: FloatVectorProperty(
        name="Rotation", description="Projector rotation relative to the camera (quaternion w, x, y, z)",
        size=4, subtype="QUATERNION", default=_PROJ_QUAT, update=_quaternion_changed)
    power: FloatProperty(name="Strength", description="Emission strength of the projector light's node tree",
                         min=C.MIN_POSITIVE["projector.power"], soft_max=100.0, default=default(_J, "power"))
