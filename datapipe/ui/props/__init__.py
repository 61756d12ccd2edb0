"""The sidebar's properties: one PropertyGroup tree registered as `bpy.types.Scene.datapipe`.

The tree mirrors `datapipe.config.Config` section by section and field by field (same names), so a
problem path such as `objects[1].min_instances` names the sidebar field too. Defaults are read from
the Config dataclasses (never restated here); `datapipe.ui.convert` is the one place that maps the
tree to and from a `Config`.

Properties carry units (metres, kilograms, camera millimetres, radians), hard limits matching
`Config.validate()`, and tooltips. Paired limits (min <= max, clip start < end) are kept consistent
by update callbacks, so the sidebar cannot hold an impossible pair.

One module per part of the tree, named for the Config sections it holds: `scene` (scene,
simulation), `objects`, `camera`, `projector`, `structured_light`, `render` (render, lighting,
output); `fields` holds what they share. The root group, the class tuple in registration order and
the `Scene.datapipe` pointer are here.
"""
import bpy
from bpy.props import (BoolProperty, CollectionProperty, EnumProperty, FloatProperty, IntProperty,
                       PointerProperty, StringProperty)
from bpy.types import PropertyGroup

from .camera import DATAPIPE_PG_camera, DATAPIPE_PG_camera_sampler, DATAPIPE_PG_pose
from .objects import DATAPIPE_PG_object
from .projector import DATAPIPE_PG_projector
from .render import DATAPIPE_PG_lighting, DATAPIPE_PG_output, DATAPIPE_PG_render
from .scene import DATAPIPE_PG_scene, DATAPIPE_PG_simulation, DATAPIPE_PG_textures
from .structured_light import DATAPIPE_PG_structured_light

__all__ = ["CLASSES", "register_pointer", "unregister_pointer", "DATAPIPE_PG_root", "DATAPIPE_PG_scene",
           "DATAPIPE_PG_simulation", "DATAPIPE_PG_object", "DATAPIPE_PG_pose", "DATAPIPE_PG_camera_sampler",
           "DATAPIPE_PG_camera", "DATAPIPE_PG_projector", "DATAPIPE_PG_structured_light", "DATAPIPE_PG_render",
           "DATAPIPE_PG_lighting", "DATAPIPE_PG_output", "DATAPIPE_PG_textures"]


def _preset_items(self, context):
    from .. import presets
    return presets.enum_items()


def _device_items():
    """'NONE' and every real-device preset (datapipe/devices.py: JSON read, no scipy)."""
    from ...devices import device, names
    return [("NONE", "None", "No device: the camera, projector and structured-light fields as they are")] + \
        [(n, device(n)["label"], f"{device(n)['label']}: fill the camera, projector and structured-light fields "
          f"from its sourced figures (docs/DEVICES.md; precision: {device(n)['precision']['source'].split(':')[0]}); "
          "`python -m datapipe sensors` lists them")
         for n in names()]


def _device_changed(self, context):
    """Choosing a device (or its binning) fills the camera, projector and structured-light fields;
    not while a preset is being shown (its own fields win, as in a preset file)."""
    from .. import convert
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
    warnings: StringProperty(name="Warnings", description="The last check's warnings, one per line (as "
                             "`datapipe validate` prints them)", default="")
    progress: FloatProperty(name="Progress", description="Share of the run's renders done",
                            subtype="PERCENTAGE", min=0.0, max=100.0, default=0.0)


# registration order: a group before the groups whose PointerProperty / CollectionProperty name it
# (Blender refuses a pointer to an unregistered type); unregistered in reverse
CLASSES = (
    DATAPIPE_PG_textures,
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
