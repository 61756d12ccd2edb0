"""The sidebar's properties: one PropertyGroup tree registered as `bpy.types.Scene.datapipe`.

The tree mirrors `datapipe.config.Config` section by section and field by field (same names), so a
problem path such as `objects[1].min_instances` names the sidebar field too. Defaults are read from
the Config dataclasses (never restated here); `datapipe.ui.convert` is the one place that maps the
tree to and from a `Config`.

Properties carry units (metres, kilograms, camera millimetres, radians), hard limits matching
`Config.validate()`, and tooltips. Paired limits (min <= max, clip start < end) are kept consistent
by update callbacks, so the sidebar cannot hold an impossible pair.
"""

import dataclasses

import bpy
from bpy.props import (BoolProperty, CollectionProperty, EnumProperty, FloatProperty,
                       FloatVectorProperty, IntProperty, IntVectorProperty, PointerProperty,
                       StringProperty)
from bpy.types import PropertyGroup
from mathutils import Euler, Quaternion

from .. import config as C
from .convert import INT_MAX, format_factors, format_periods, parse_factors, parse_periods



def default(dc, name: str):
    """The Config dataclass default of `dc.name` (default or default_factory)."""
    for f in dataclasses.fields(dc):
        if f.name == name:
            if f.default is not dataclasses.MISSING:
                return f.default
            return f.default_factory()
    raise KeyError(f"{dc.__name__} has no field {name!r}")


def _items(values, descriptions=None):
    descriptions = descriptions or {}
    return [(v, v.replace("_", " ").title(), descriptions.get(v, v)) for v in values]


# ------------------------------------------------------------------------------------------------
# update callbacks

def _keep_order(lo: str, hi: str, *, strict: bool = False):
    """Two update callbacks keeping `lo <= hi` (or `lo < hi` when strict) by moving the other one."""
    def lo_changed(self, context):
        a, b = getattr(self, lo), getattr(self, hi)
        if a > b or (strict and a >= b):
            setattr(self, hi, a * 2 if strict else a)

    def hi_changed(self, context):
        a, b = getattr(self, lo), getattr(self, hi)
        if a > b or (strict and a >= b):
            setattr(self, lo, b / 2 if strict else b)

    return lo_changed, hi_changed


def _keep_range(name: str):
    """An update callback keeping a [min, max] vector property ordered (swaps an inverted pair)."""
    def changed(self, context):
        lo, hi = getattr(self, name)
        if lo > hi:
            setattr(self, name, (hi, lo))
    return changed


def _range(name: str, label: str, description: str, dc, *, unit="NONE", lo=None, hi=None, soft_max=None,
           precision=3):
    """A [min, max] FloatVectorProperty (size 2) for Config field `name` of dataclass `dc`."""
    kw = {"min": lo} if lo is not None else {}
    if hi is not None:
        kw["max"] = hi
    if soft_max is not None:
        kw["soft_max"] = soft_max
    return FloatVectorProperty(name=label, description=description + " (min, max)", size=2, unit=unit,
                               default=default(dc, name), precision=precision, update=_keep_range(name), **kw)


def _material_search(edit_text):
    """Preset names for the material fields (unknown text is reported by Config.validate())."""
    from ..materials_spec import NAMES
    return [n for n in NAMES if edit_text.lower() in n.lower()]


def _sync_previews(self, context):
    """Keep the viewport previews (camera, projector, object) in step with edited properties."""
    from . import preview
    preview.sync(context)


def _chain(*callbacks):
    def run(self, context):
        for cb in callbacks:
            cb(self, context)
    return run


# ------------------------------------------------------------------------------------------------
# scene

_renders_lo, _renders_hi = _keep_order("min_renders_per_scene", "max_renders_per_scene")
_S = C.SceneConfig


class DATAPIPE_PG_scene(PropertyGroup):
    num_renders: IntProperty(
        name="Renders", description="Total number of renders in the run (over all scenes)",
        default=default(_S, "num_renders"), min=1, soft_max=10000)
    min_renders_per_scene: IntProperty(
        name="Min per Scene", description="Fewest camera poses rendered per scene (one drop of parts per "
        "scene; poses are drawn without replacement). Raising it above Max raises Max",
        default=default(_S, "min_renders_per_scene"), min=1, soft_max=100, update=_renders_lo)
    max_renders_per_scene: IntProperty(
        name="Max per Scene", description="Most camera poses rendered per scene (at most the number of camera "
        "poses). Lowering it below Min lowers Min",
        default=default(_S, "max_renders_per_scene"), min=1, soft_max=100, update=_renders_hi)
    drop_zone_loc: FloatVectorProperty(
        name="Drop Zone Location", description="Centre of the bin's inner volume (world, metres)",
        size=3, subtype="TRANSLATION", unit="LENGTH", default=default(_S, "drop_zone_loc"))
    drop_zone_scale: FloatVectorProperty(
        name="Drop Zone Half Size", description="Half-extents of the drop zone box along X, Y, Z (metres)",
        size=3, subtype="XYZ_LENGTH", unit="LENGTH", min=1e-4, soft_max=5.0,
        default=default(_S, "drop_zone_scale"))
    make_bin: BoolProperty(
        name="Bin Walls", description="Build a floor and walls around the drop zone (off: floor only)",
        default=default(_S, "make_bin"))
    bin_wall_thickness: FloatProperty(
        name="Wall Thickness", description="Thickness of the bin's floor and walls",
        subtype="DISTANCE", unit="LENGTH", min=1e-5, soft_max=0.1, default=default(_S, "bin_wall_thickness"))
    bin_size_scale: _range("bin_size_scale", "Bin Size Scale", "Per scene, the drop zone's X and Y half "
                           "extents are each multiplied by a factor drawn from this range", _S, lo=0.05, hi=20.0)
    bin_wall_scale: _range("bin_wall_scale", "Wall Height Scale", "Per scene, the wall height (the drop "
                           "zone's height) is multiplied by a factor drawn from this range", _S, lo=0.05, hi=20.0)
    use_fill: BoolProperty(
        name="Fill by Volume", description="Per scene, draw the part counts so that the parts' convex hulls "
        "fill a share of the bin's volume (within each object's Min/Max instances); off: each count is "
        "drawn from its Min..Max", default=False)
    fill: FloatVectorProperty(
        name="Fill", description="Share of the bin's inner volume the parts' convex hulls fill, drawn per "
        "scene (min, max; at most 0.5: more heaps over the walls)", size=2, min=0.0, max=0.5,
        default=(0.1, 0.2), precision=3, update=_keep_range("fill"))
    blend_file: StringProperty(
        name="Blend File", description="Open this .blend as the base scene (empty: a fresh scene); its "
        "object 'drop_zone', when present, overrides the drop zone above",
        subtype="FILE_PATH", default=default(_S, "blend_file") or "")
    other_objects: EnumProperty(
        name="Other Objects", description="Objects of the open scene DataPipe did not make (e.g. the startup "
        "cube and light): hide them from the renders for the run (shown again afterwards), or keep them in; "
        "auto: keep with a Blend File, else hide", items=_items(C.OTHER_OBJECTS), default=default(_S, "other_objects"))
    seed: IntProperty(
        name="Seed", description="Base seed of the run: scene i derives its own seed from it, so any scene "
        "can be re-made alone and shards match a single run",
        default=default(_S, "seed"), min=0, max=INT_MAX)
    bin_material: StringProperty(
        name="Bin Material", description="Floor and walls: file (the built-in grey), a preset (matte_plastic, "
        "dark_plastic, painted, steel, aluminium, rubber) or Principled BSDF values as JSON, e.g. "
        "{\"base_color\": [0.5, 0.5, 0.5], \"roughness\": 0.2}; a comma-separated list draws one per scene",
        default=default(_S, "bin_material"),
        search=lambda self, context, text: _material_search(text))


# ------------------------------------------------------------------------------------------------
# simulation

_M = C.SimulationConfig


class DATAPIPE_PG_simulation(PropertyGroup):
    substeps: IntProperty(name="Substeps", description="Rigid-body substeps per frame, at least (more per scene "
                          "when a part could cross the thinnest part or wall in one substep)",
                          default=default(_M, "substeps"), min=1, soft_max=100)
    max_substeps: IntProperty(name="Max Substeps", description="Rigid-body substeps per frame, at most",
                              default=default(_M, "max_substeps"), min=1, soft_max=1000)
    solver_iterations: IntProperty(name="Solver Iterations", description="Rigid-body constraint solver iterations",
                                   default=default(_M, "solver_iterations"), min=1, soft_max=100)
    max_frames: IntProperty(name="Max Frames", description="Hard cap on simulated frames per scene (24 fps)",
                            default=default(_M, "max_frames"), min=1, soft_max=2000)
    settle_speed: FloatProperty(
        name="Settle Speed", description="A part moving slower than this is at rest",
        unit="VELOCITY", min=1e-6, soft_max=1.0, precision=4,
        default=default(_M, "settle_speed"))
    settle_frames: IntProperty(name="Settle Frames", description="Consecutive frames at rest before the drop "
                               "counts as settled", default=default(_M, "settle_frames"), min=1, soft_max=100)
    layer_gap: FloatProperty(name="Layer Gap", description="Vertical gap between spawn layers of parts",
                             subtype="DISTANCE", unit="LENGTH", min=0.0, soft_max=0.1, precision=4,
                             default=default(_M, "layer_gap"))
    redraw_lost_share: FloatProperty(
        name="Redraw Above Lost Share", description="Redraw a scene (from a derived seed) when more than this "
        "share of its parts left the bin or fell through the floor; 1 never redraws",
        min=0.0, max=1.0, precision=2, default=default(_M, "redraw_lost_share"))
    redraw_attempts: IntProperty(name="Redraw Attempts", description="Redraws per scene, at most",
                                 min=0, max=10, default=default(_M, "redraw_attempts"))


# ------------------------------------------------------------------------------------------------
# objects

_O = C.ObjectEntry
_inst_lo, _inst_hi = _keep_order("min_instances", "max_instances")


class DATAPIPE_PG_object(PropertyGroup):
    source: EnumProperty(
        name="Source", description="Where the entry's parts come from",
        items=[("FILE", "Mesh File", "One mesh file (any units: set Scale)"),
               ("BOP", "BOP Models", "Objects of a BOP dataset's models folder (obj_XXXXXX.ply in mm + "
                "models_info.json): their ids and symmetries go into the export")],
        default="FILE")
    bop_models: StringProperty(
        name="Models Folder", description="A BOP dataset's models folder (e.g. itodd/models)",
        subtype="DIR_PATH", default=default(_O, "bop_models"))
    bop_obj_ids: StringProperty(
        name="Object IDs", description="BOP object ids to drop, comma separated (empty: all of the folder); "
        "each gets the instance counts and settings of this entry", default="")
    obj_id: IntProperty(name="Object ID", description="The id exported for this part (0: its position in the "
                        "list + 1)", min=0, default=default(_O, "obj_id"))
    symmetries: StringProperty(
        name="Symmetries", description="Written to models_info.json: auto (BOP: the folder's; a mesh file: "
        "detected at 1% of the diameter), detect, none, {\"tolerance\": 0.02}, or JSON with "
        "symmetries_discrete / symmetries_continuous (mm)", default=default(_O, "symmetries"))
    filepath: StringProperty(
        name="File", description="Mesh file of the part (" + ", ".join(C.MESH_SUFFIXES) + ")",
        subtype="FILE_PATH", default=default(_O, "filepath"))
    name: StringProperty(name="Name", description="Name of the part in annotations (empty: the file name "
                         "without extension)", default=default(_O, "name"))
    scale: FloatProperty(
        name="Scale", description="File units to metres (e.g. 0.001 for a mesh modelled in millimetres)",
        min=1e-6, soft_max=100.0, precision=4, default=default(_O, "scale"), update=_sync_previews)
    mass: FloatProperty(name="Mass", description="Mass of each instance", unit="MASS",
                        min=1e-6, soft_max=100.0, precision=3, default=default(_O, "mass"))
    collision_shape: EnumProperty(
        name="Collision Shape", description="Rigid-body collision shape (Convex Hull is fast and stable; "
        "Mesh follows concave parts but is slower)",
        items=_items(C.COLLISION_SHAPES), default=default(_O, "collision_shape"))
    min_instances: IntProperty(
        name="Min Instances", description="Fewest copies of this part per scene. Raising it above Max "
        "raises Max", default=default(_O, "min_instances"), min=0, max=500, update=_inst_lo)
    max_instances: IntProperty(
        name="Max Instances", description="Most copies of this part per scene. Lowering it below Min "
        "lowers Min", default=default(_O, "max_instances"), min=0, max=500, update=_inst_hi)
    friction: FloatProperty(name="Friction", description="Rigid-body friction", min=0.0, soft_max=1.0,
                            default=default(_O, "friction"))
    restitution: FloatProperty(name="Restitution", description="Rigid-body bounciness (0..1)",
                               min=0.0, max=1.0, default=default(_O, "restitution"))
    material: StringProperty(
        name="Material", description="file (what the mesh carries), a preset (matte_plastic, dark_plastic, "
        "painted, steel, aluminium, rubber), several comma separated (one drawn per instance), or Principled "
        "BSDF values as JSON, e.g. {\"base_color\": [0.5, 0.5, 0.5], \"metallic\": 1, \"roughness\": 0.2}",
        default=default(_O, "material"), search=lambda self, context, text: _material_search(text))


# ------------------------------------------------------------------------------------------------
# camera

_P = C.CameraPose
_K = C.CameraConfig
_clip_lo, _clip_hi = _keep_order("clip_start", "clip_end", strict=True)


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
    distance: _range("distance", "Distance", "Camera centre to the look-at target", _CS, unit="LENGTH",
                     lo=1e-3, soft_max=5.0)
    tilt_deg: _range("tilt_deg", "Tilt", "Optical axis from straight down, degrees", _CS, lo=0.0, hi=89.0,
                     precision=1)
    azimuth_deg: _range("azimuth_deg", "Azimuth", "Direction from the target to the camera, degrees "
                        "counter-clockwise from world +X", _CS, precision=1)
    roll_deg: _range("roll_deg", "Roll", "Image rotation about the optical axis, degrees", _CS, precision=1)
    target_jitter: FloatProperty(
        name="Target Jitter", description="The look-at target is the bin floor's centre plus a random "
        "horizontal offset up to this far", subtype="DISTANCE", unit="LENGTH", min=0.0, soft_max=0.5,
        precision=3, default=default(_CS, "target_jitter"))


class DATAPIPE_PG_camera(PropertyGroup):
    focal_length: FloatProperty(
        name="Focal Length", description="Lens focal length (millimetres, as Blender's camera)",
        subtype="DISTANCE_CAMERA", unit="CAMERA", min=1e-3, soft_min=1.0, soft_max=300.0,
        default=default(_K, "focal_length"), update=_sync_previews)
    sensor_width: FloatProperty(
        name="Sensor Width", description="Sensor width (millimetres)",
        subtype="DISTANCE_CAMERA", unit="CAMERA", min=1e-3, soft_min=1.0, soft_max=100.0,
        default=default(_K, "sensor_width"), update=_sync_previews)
    sensor_fit: EnumProperty(
        name="Sensor Fit", description="Which image dimension the sensor width applies to",
        items=_items(C.SENSOR_FITS), default=default(_K, "sensor_fit"), update=_sync_previews)
    resolution: IntVectorProperty(
        name="Resolution", description="Image size in pixels (width, height)", size=2,
        min=1, max=C.MAX_RESOLUTION, default=default(_K, "resolution"), update=_sync_previews)
    clip_start: FloatProperty(
        name="Clip Start", description="Nearest rendered distance. Raising it past Clip End moves Clip End",
        subtype="DISTANCE", unit="LENGTH", min=1e-5, soft_max=10.0, precision=3,
        default=default(_K, "clip_start"), update=_chain(_clip_lo, _sync_previews))
    clip_end: FloatProperty(
        name="Clip End", description="Farthest rendered distance. Lowering it below Clip Start moves Clip Start",
        subtype="DISTANCE", unit="LENGTH", min=2e-5, soft_max=1000.0, precision=3,
        default=default(_K, "clip_end"), update=_chain(_clip_hi, _sync_previews))
    poses: CollectionProperty(type=DATAPIPE_PG_pose, name="Poses",
                              description="Pool of camera poses; each scene draws its renders' poses from it")
    poses_index: IntProperty(name="Active Pose", description="Selected camera pose", min=0)
    sampler: PointerProperty(type=DATAPIPE_PG_camera_sampler, name="Sampler",
                             description="Pose pool or look-at poses drawn around the bin")


# ------------------------------------------------------------------------------------------------
# projector

_J = C.ProjectorConfig
_PROJ_ROT = default(_J, "rotation")
_PROJ_EULER = tuple(_PROJ_ROT) if len(_PROJ_ROT) == 3 else tuple(Quaternion(_PROJ_ROT).to_euler("XYZ"))
_PROJ_QUAT = tuple(_PROJ_ROT) if len(_PROJ_ROT) == 4 else tuple(Euler(_PROJ_ROT, "XYZ").to_quaternion())


def _euler_changed(self, context):
    """The Euler angles are the rotation: keep the quaternion equal (both always describe one pose)."""
    if self.rotation_mode == "XYZ":
        self.rotation_quaternion = Euler(self.rotation_euler, "XYZ").to_quaternion()
    _sync_previews(self, context)


def _quaternion_changed(self, context):
    if self.rotation_mode == "QUATERNION":
        self.rotation_euler = Quaternion(self.rotation_quaternion).normalized().to_euler("XYZ")
    _sync_previews(self, context)


class DATAPIPE_PG_projector(PropertyGroup):
    focal_length: FloatProperty(
        name="Focal Length", description="Projector lens focal length (millimetres)",
        subtype="DISTANCE_CAMERA", unit="CAMERA", min=1e-3, soft_min=1.0, soft_max=300.0,
        default=default(_J, "focal_length"), update=_sync_previews)
    sensor_width: FloatProperty(
        name="Sensor Width", description="Projector image (DMD) width (millimetres)",
        subtype="DISTANCE_CAMERA", unit="CAMERA", min=1e-3, soft_min=1.0, soft_max=100.0,
        default=default(_J, "sensor_width"), update=_sync_previews)
    resolution: IntVectorProperty(
        name="Resolution", description="Projector image size in pixels (width, height)", size=2,
        min=1, max=C.MAX_RESOLUTION, default=default(_J, "resolution"), update=_sync_previews)
    location: FloatVectorProperty(
        name="Location", description="Projector position relative to the camera, in the camera object's "
        "local axes", size=3, subtype="TRANSLATION", unit="LENGTH", default=default(_J, "location"),
        update=_sync_previews)
    rotation_mode: EnumProperty(
        name="Rotation Mode", description="How the projector's rotation relative to the camera is given",
        items=[("XYZ", "XYZ Euler", "Euler angles, XYZ order"),
               ("QUATERNION", "Quaternion", "Quaternion (w, x, y, z)")],
        default="XYZ" if len(_PROJ_ROT) == 3 else "QUATERNION", update=_sync_previews)
    rotation_euler: FloatVectorProperty(
        name="Rotation", description="Projector rotation relative to the camera (XYZ Euler)", size=3,
        subtype="EULER", unit="ROTATION", default=_PROJ_EULER, update=_euler_changed)
    rotation_quaternion: FloatVectorProperty(
        name="Rotation", description="Projector rotation relative to the camera (quaternion w, x, y, z)",
        size=4, subtype="QUATERNION", default=_PROJ_QUAT, update=_quaternion_changed)
    power: FloatProperty(name="Strength", description="Emission strength of the projector light's node tree",
                         min=1e-6, soft_max=100.0, default=default(_J, "power"))


# ------------------------------------------------------------------------------------------------
# structured light

_L = C.StructuredLightConfig
_FIXED_EXPOSURE = 0.5        # the Exposure field's value while Auto Exposure is on (the former default)


def _list_text(name: str, parse, fmt, hint: str):
    """Getter and setter of a list typed as text (stored normalised in the hidden `<name>_text`)."""
    def get(self):
        return getattr(self, f"{name}_text")

    def set_(self, value):
        try:
            setattr(self, f"{name}_text", fmt(parse(value)))
        except ValueError as e:        # keep the last valid list; the field shows it again
            print(f"DataPipe: structured_light.{name}: ignored {value!r} ({e}); {hint}")
    return get, set_


_get_periods, _set_periods = _list_text("periods", parse_periods, format_periods, "give integers >= 1, e.g. '1, 8, 64'")
_get_hdr, _set_hdr = _list_text("hdr", parse_factors, format_factors,
                                "give factors > 0, e.g. '0.25, 1, 4', 'auto', or nothing for one exposure")


def _sensor_search(self, context, edit_text):
    """Suggestions for the sensor field, read when the field is edited (datapipe.sl imports scipy:
    too slow for add-on registration). Unknown names are reported by Config.validate()."""
    try:
        from ..sl.sensor import PRESETS
    except ImportError:
        return []
    return [name for name in sorted(PRESETS) if edit_text.lower() in name.lower()]


class DATAPIPE_PG_structured_light(PropertyGroup):
    enabled: BoolProperty(name="Structured Light", description="Render phase-shifted fringe images lit by "
                          "the projector and decode a structured-light depth map per render",
                          default=default(_L, "enabled"))
    periods_text: StringProperty(default=format_periods(default(_L, "periods")), options={"HIDDEN"})
    periods: StringProperty(
        name="Periods", description="Fringe periods across the projector width, coarse to fine, comma "
        "separated (e.g. '1, 8, 64' hierarchical, '8, 7' heterodyne, '13, 7' or '9, 10, 11' number-theoretic)",
        get=_get_periods, set=_set_periods)
    steps: IntProperty(name="Steps", description="Phase steps per period (4 or more avoids gamma errors)",
                       default=default(_L, "steps"), min=3, soft_max=16)
    unwrap: EnumProperty(name="Unwrapping", description="Temporal phase unwrapping method",
                         items=_items(C.UNWRAP_METHODS), default=default(_L, "unwrap"))
    fringe_mode: EnumProperty(name="Fringe Mode", description="fast: one render with the projector showing white, "
                              "every fringe image synthesised from it (exact direct light, bounce light as offset); "
                              "render: every fringe image path-traced (the reference, needed for mirrored fringes on shiny parts); "
                              "quadrature: a white, a cosine and a sine image per period path-traced, every phase step mixed "
                              "from them (the same light as render, 7 images instead of 12); "
                              "auto: quadrature when a configured material is shiny (render with a projector gamma), else fast",
                              items=_items(C.FRINGE_MODES), default=default(_L, "fringe_mode"))
    samples: IntProperty(name="Samples", description="Render paths per camera pixel for each fringe image (point-sampled at 2x2 per pixel; 4 is enough once bounce light is blurred, see README)",
                         default=default(_L, "samples"), min=1, soft_max=4096)
    sensor: StringProperty(name="Sensor Model", description="Camera noise model preset (datapipe.sl.sensor: "
                           "shot and read noise, ADC bits, saturation), e.g. ideal, industrial",
                           default=default(_L, "sensor"), search=_sensor_search)
    auto_exposure: BoolProperty(name="Auto Exposure", description="Meter each render's fringes and set the "
                                "exposure so the brightest lit pixels reach 80% of the full well (like a real "
                                "scanner's auto exposure); off: the fixed Exposure below",
                                default=default(_L, "exposure") == "auto")
    exposure: FloatProperty(name="Exposure", description="Fixed scale on the linear radiance before the sensor "
                            "model (used when Auto Exposure is off)", min=1e-6, soft_max=10.0,
                            default=_FIXED_EXPOSURE)
    hdr_text: StringProperty(default=format_factors(default(_L, "hdr")), options={"HIDDEN"})
    hdr: StringProperty(name="HDR Factors", description="Relative exposure factors fused per pixel, e.g. "
                        "'0.25, 1, 4' (metal parts); 'auto': shorter exposures added per render while "
                        "highlights clip; empty: one exposure", get=_get_hdr,
                        set=_set_hdr)
    reflection_filter: EnumProperty(name="Reflection Filter", description="local: drop pixels whose fringe "
                                    "frequencies disagree in modulation (light of two paths); global: also render a "
                                    "row code and drop mirror ghosts (+Steps path-traced images); auto: global on "
                                    "renders with shiny surfaces, else local; off",
                                    items=_items(C.REFLECTION_FILTERS), default=default(_L, "reflection_filter"))
    debug: BoolProperty(name="Debug Maps", description="Also write wrapped/absolute phase, modulation and "
                        "reason codes", default=default(_L, "debug"))
    projector_gamma: FloatProperty(name="Projector Gamma", description="Projector response exponent (it emits "
                                   "pattern ** gamma; 1 = linear); the decoder corrects the phase ripple",
                                   min=0.2, max=5.0, default=default(_L, "projector_gamma"))


# ------------------------------------------------------------------------------------------------
# render

_R = C.RenderConfig




class DATAPIPE_PG_render(PropertyGroup):
    engine: EnumProperty(name="Engine", description="Render engine", items=_items(C.ENGINES),
                         default=default(_R, "engine"))
    device: EnumProperty(name="Device", description="Cycles device (GPU uses the first available backend)",
                         items=_items(C.DEVICES), default=default(_R, "device"))
    samples: IntProperty(name="Samples", description="Cycles samples for the RGB / depth / normals / mask render",
                         default=default(_R, "samples"), min=1, soft_max=4096)
    threads: IntProperty(name="Threads", description="CPU threads (0: all cores)",
                         default=default(_R, "threads"), min=0, soft_max=256)
    denoise: BoolProperty(name="Denoise", description="Denoise the RGB render (OpenImageDenoise on the CPU, "
                          "albedo and normal guided)", default=default(_R, "denoise"))
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
    key_power: _range("key_power", "Key Power", "Power of the area light above the bin", _LI, unit="POWER",
                      lo=0.0, soft_max=1000.0, precision=1)
    key_color_temperature: _range("key_color_temperature", "Temperature", "Blackbody colour temperature "
                                  "of the key light, kelvin", _LI, lo=1000.0, hi=40000.0, precision=0)
    key_size: _range("key_size", "Key Size", "Side of the square area light", _LI, unit="LENGTH", lo=1e-3,
                     soft_max=5.0)
    key_position_jitter: FloatProperty(
        name="Key Jitter", description="Horizontal offset of the key light from above the bin, up to this far",
        subtype="DISTANCE", unit="LENGTH", min=0.0, soft_max=2.0, default=default(_LI, "key_position_jitter"))
    ambient: _range("ambient", "Ambient", "Strength of a white world background", _LI, lo=0.0, soft_max=2.0)


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


# ------------------------------------------------------------------------------------------------
# root

def _preset_items(self, context):
    from . import presets
    return presets.enum_items()


def _device_items():
    """'NONE' and every real-device preset (datapipe/devices.py: JSON read, no scipy)."""
    from ..devices import device, names
    return [("NONE", "None", "No device: the camera, projector and structured-light fields as they are")] + \
        [(n, device(n)["label"], f"{device(n)['label']}: fill the camera, projector and structured-light fields "
          f"from its data sheet ({device(n)['precision']['source']}); `python -m datapipe sensors` lists them")
         for n in names()]


def _device_changed(self, context):
    """Choosing a device (or its binning) fills the camera, projector and structured-light fields;
    not while a preset is being shown (its own fields win, as in a preset file)."""
    from . import convert
    if self.device != "NONE" and not convert.FILLING:
        convert.fill_device(self)


class DATAPIPE_PG_root(PropertyGroup):
    """`Scene.datapipe`: every sidebar setting (Config sections) plus a little UI state."""
    scene: PointerProperty(type=DATAPIPE_PG_scene, name="Scene", description="Renders, seed, drop zone, bin")
    objects: CollectionProperty(type=DATAPIPE_PG_object, name="Objects",
                                description="Parts to drop: one entry per mesh file")
    objects_index: IntProperty(name="Active Object", description="Selected object entry", min=0)
    camera: PointerProperty(type=DATAPIPE_PG_camera, name="Camera", description="Intrinsics and pose pool")
    projector: PointerProperty(type=DATAPIPE_PG_projector, name="Projector",
                               description="Fringe projector intrinsics and pose relative to the camera")
    structured_light: PointerProperty(type=DATAPIPE_PG_structured_light, name="Structured Light",
                                      description="Fringe patterns and decoding")
    render: PointerProperty(type=DATAPIPE_PG_render, name="Render", description="Cycles settings and outputs")
    lighting: PointerProperty(type=DATAPIPE_PG_lighting, name="Lighting",
                              description="Key and ambient light drawn per scene")
    simulation: PointerProperty(type=DATAPIPE_PG_simulation, name="Simulation",
                                description="Rigid-body drop settings")
    output: PointerProperty(type=DATAPIPE_PG_output, name="Output", description="Output folder and formats")
    device: EnumProperty(name="Device", description="A real structured-light scanner: choosing it fills the camera, "
                         "projector and structured-light fields (any field can be changed afterwards)",
                         items=_device_items(), default="NONE", update=_device_changed)
    binning: IntProperty(name="Binning", description="The device's camera binning (resolution / binning), one "
                         "it offers (`python -m datapipe sensors`)", min=1, max=4, default=1, update=_device_changed)

    # UI state (not part of the Config)
    preset: EnumProperty(name="Preset", description="Built-in (read-only) and user presets",
                         items=_preset_items)
    preset_name: StringProperty(name="Preset Name", description="Name to save the current settings under "
                                "(in the user presets folder)", default="my_preset")
    resume: BoolProperty(name="Resume", description="Continue an earlier run in the output folder (same "
                         "preset and seed); complete scenes are skipped", default=False)
    force: BoolProperty(name="Overwrite", description="Empty the output folder first if it holds an earlier "
                        "DataPipe run", default=False)
    status: StringProperty(name="Status", description="Last run status", default="")
    progress: FloatProperty(name="Progress", description="Share of the run's renders done",
                            subtype="PERCENTAGE", min=0.0, max=100.0, default=0.0)


CLASSES = (
    DATAPIPE_PG_scene,
    DATAPIPE_PG_simulation,
    DATAPIPE_PG_object,
    DATAPIPE_PG_pose,
    DATAPIPE_PG_camera_sampler,
    DATAPIPE_PG_camera,
    DATAPIPE_PG_projector,
    DATAPIPE_PG_structured_light,
    DATAPIPE_PG_render,
    DATAPIPE_PG_lighting,
    DATAPIPE_PG_output,
    DATAPIPE_PG_root,
)


def register_pointer() -> None:
    bpy.types.Scene.datapipe = PointerProperty(type=DATAPIPE_PG_root, name="DataPipe",
                                               description="DataPipe dataset settings")


def unregister_pointer() -> None:
    if hasattr(bpy.types.Scene, "datapipe"):
        del bpy.types.Scene.datapipe
