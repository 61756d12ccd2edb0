"""`Scene.datapipe.render` (Cycles settings and outputs), `.lighting` (key and ambient light drawn per
scene) and `.output` (folder and formats): `Config.render`, `Config.lighting`, `Config.output`."""
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty
from bpy.types import PropertyGroup

from ... import config as C
from .fields import default, enum_choices, range_property


_R = C.RenderConfig


class DATAPIPE_PG_render(PropertyGroup):
    engine: EnumProperty(name="Engine", description="Render engine", items=enum_choices(C.ENGINES),
                         default=default(_R, "engine"))
    device: EnumProperty(name="Device", description="Cycles device (GPU uses the first available backend)",
                         items=enum_choices(C.DEVICES), default=default(_R, "device"))
    samples: IntProperty(name="Samples", description="Cycles samples for the RGB / depth / normals / mask render",
                         default=default(_R, "samples"), min=1, soft_max=4096)
    sampling_pattern: EnumProperty(name="Sampling Pattern", description="Cycles' sampling pattern of the RGB / "
                                   "depth / normals / mask render (Scene: as the scene has it; the fringe renders "
                                   "always keep the scene's)", items=enum_choices(C.SAMPLING_PATTERNS),
                                   default=default(_R, "sampling_pattern"))
    threads: IntProperty(name="Threads", description="CPU threads (0: all cores)",
                         default=default(_R, "threads"), min=0, soft_max=256)
    denoise: BoolProperty(name="Denoise", description="Denoise the RGB render (OpenImageDenoise on the CPU, "
                          "albedo and normal guided)", default=default(_R, "denoise"))
    denoise_prefilter: EnumProperty(name="Denoise Prefilter", description="OpenImageDenoise's albedo and "
                                    "normal guides: denoised first (ACCURATE), with the image (FAST), or as "
                                    "rendered (NONE)", items=enum_choices(C.DENOISE_PREFILTERS),
                                    default=default(_R, "denoise_prefilter"))
    denoise_quality: EnumProperty(name="Denoise Quality", description="OpenImageDenoise's network: HIGH, "
                                  "BALANCED or FAST", items=enum_choices(C.DENOISE_QUALITIES),
                                  default=default(_R, "denoise_quality"))
    adaptive_threshold: FloatProperty(name="Noise Threshold", description="Adaptive sampling: stop sampling a "
                                      "pixel once its noise is below this (0: off, every pixel gets Samples)",
                                      min=0.0, max=0.999, soft_max=0.1, precision=3,
                                      default=default(_R, "adaptive_threshold"))
    persistent_data: BoolProperty(name="Persistent Data", description="Keep Cycles' scene data between the "
                                  "renders of a scene", default=default(_R, "persistent_data"))
    max_bounces: IntProperty(name="Max Bounces", description="Cycles light bounces",
                             default=default(_R, "max_bounces"), min=0, soft_max=32)
    light_power: FloatProperty(name="Key Light", description="Power of the area light above the bin",
                               unit="POWER", min=0.0, soft_max=1000.0,
                               default=default(_R, "light_power"))
    outputs: EnumProperty(
        name="Outputs", description="What to write for each render",
        items=[(k, k.title(), f"Write the {k} image of each render") for k in C.OUTPUT_KINDS],
        options={"ENUM_FLAG"}, default=set(default(_R, "outputs")))


# ------------------------------------------------------------------------------------------------
# lighting

_LI = C.LightingConfig


class DATAPIPE_PG_lighting(PropertyGroup):
    """`Config.lighting`: `enabled` off is a config without a lighting section (the fixed key light)."""
    enabled: BoolProperty(name="Random Lighting", description="Draw the key light and ambient light per "
                          "scene from the ranges below (off: the fixed Key Light of the render settings)",
                          default=False)
    key_power: range_property("key_power", "Key Power", "Power of the area light above the bin", _LI, unit="POWER",
                      lo=0.0, soft_max=1000.0, precision=1)
    key_color_temperature: range_property("key_color_temperature", "Temperature", "Blackbody colour temperature "
                                  "of the key light, kelvin", _LI, lo=1000.0, hi=40000.0, precision=0)
    key_size: range_property("key_size", "Key Size", "Side of the square area light", _LI, unit="LENGTH", lo=1e-3,
                     soft_max=5.0)
    key_position_jitter: FloatProperty(
        name="Key Jitter", description="Horizontal offset of the key light from above the bin, up to this far",
        subtype="DISTANCE", unit="LENGTH", min=0.0, soft_max=2.0, default=default(_LI, "key_position_jitter"))
    ambient: range_property("ambient", "Ambient", "Strength of a white world background", _LI, lo=0.0, soft_max=2.0)
    per_render: BoolProperty(name="Per Render", description="Draw the lighting for every render (off: once per "
                             "scene)", default=default(_LI, "per_render"))
    environment: StringProperty(name="Environment Map", description="An .hdr/.exr environment map, or a folder "
                                "of them (one drawn per draw); empty: none. The fringe images see it only with "
                                "structured light's Ambient 'scene'", subtype="FILE_PATH",
                                default=default(_LI, "environment"))
    environment_strength: range_property("environment_strength", "Environment Strength", "World strength of the "
                                         "environment map", _LI, lo=0.0, hi=1e4, soft_max=5.0)
    environment_rotation_deg: range_property("environment_rotation_deg", "Environment Rotation", "Rotation of the "
                                             "environment map about the world's Z axis, degrees", _LI,
                                             precision=1)


# ------------------------------------------------------------------------------------------------
# output

_T = C.OutputConfig


def _formats_changed(self, context):
    if not self.formats:                    # at least one format: an empty set is never a valid run
        self.formats = {C.FORMATS[0]}


class DATAPIPE_PG_output(PropertyGroup):
    path: StringProperty(name="Folder", description="Output folder of the dataset (must be empty, or an "
                         "earlier run's folder with Resume)", subtype="DIR_PATH", default=default(_T, "path"))
    formats: EnumProperty(
        name="Formats", description="Dataset formats to write",
        items=[("native", "Native", "DataPipe's scene.NNNN/render.NNNN layout"),
               ("bop", "BOP", "BOP toolkit layout (needs RGB, depth and mask)")],
        options={"ENUM_FLAG"}, default=set(default(_T, "formats")), update=_formats_changed)
    legacy_pickle: BoolProperty(name="Legacy Pickle", description="Also write the original DataPipe's "
                                "output_dict.pickle", default=default(_T, "legacy_pickle"))
    overview: BoolProperty(name="Overview Sheet", description="Write an overview sheet of the run at the end",
                           default=default(_T, "overview"))
    bop_sensor: StringProperty(name="BOP Sensor", description="BOP-Industrial name of the scanner's folders "
                               "(gray_NAME, depth_NAME ...); empty: after the device's maker, 'sl' without one",
                               default="")
    xyz_crop: BoolProperty(name="GDRNPP xyz_crop", description="BOP: also write each instance's amodal object "
                           "coordinates in GDRNPP's xyz_crop format", default=default(_T, "xyz_crop"))
    amodal_coco: BoolProperty(name="Amodal COCO", description="BOP: also write scene_gt_coco_amodal.json (full "
                              "silhouettes, UOAIS' fields)", default=default(_T, "amodal_coco"))
