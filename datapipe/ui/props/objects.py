"""`Scene.datapipe.objects`: one entry per part to drop (`Config.objects`)."""
from bpy.props import BoolProperty, EnumProperty, FloatProperty, IntProperty, StringProperty
from bpy.types import PropertyGroup

from ... import config as C
from .fields import default, enum_choices, keep_order, material_search, sync_previews


_O = C.ObjectEntry
_inst_lo, _inst_hi = keep_order("min_instances", "max_instances")


class DATAPIPE_PG_object(PropertyGroup):
    source: EnumProperty(
        name="Source", description="Where the entry's parts come from",
        items=[("FILE", "Mesh File", "One mesh file (any units: set Scale)"),
               ("BOP", "BOP Models", "Objects of a BOP dataset's models folder (obj_XXXXXX.ply in mm + "
                "models_info.json): their ids and symmetries go into the export"),
               ("SHAPE", "Shape", "A procedural distractor (box, plate, cylinder, tube), its size drawn per "
                "instance: no file needed; never annotated")],
        default="FILE")
    bop_models: StringProperty(
        name="Models Folder", description="A BOP dataset's models folder (e.g. itodd/models)",
        subtype="DIR_PATH", default=default(_O, "bop_models"))
    bop_obj_ids: StringProperty(
        name="Object IDs", description="BOP object ids to drop, comma separated (empty: all of the folder); "
        "each gets the instance counts and settings of this entry", default="")
    obj_id: IntProperty(name="Object ID", description="The id exported for this part (0: its position in the "
                        "list + 1)", min=0, max=C.MAX_INT32, default=default(_O, "obj_id"))
    symmetries: StringProperty(
        name="Symmetries", description="Written to models_info.json: auto (BOP: the folder's; a mesh file: "
        "detected at 1% of the diameter), detect, none, {\"tolerance\": 0.02}, or JSON with "
        "symmetries_discrete / symmetries_continuous (mm)", default=default(_O, "symmetries"))
    filepath: StringProperty(
        name="File", description="Mesh file of the part (" + ", ".join(C.MESH_SUFFIXES) + ")",
        subtype="FILE_PATH", default=default(_O, "filepath"))
    shape: StringProperty(
        name="Shape", description="Procedural distractor as JSON, sizes in metres, a fixed list or [[min ...], "
        "[max ...]]: {\"kind\": \"box\"|\"plate\", \"size\": [x, y, z|thickness]}, {\"kind\": \"cylinder\", "
        "\"size\": [diameter, length]}, {\"kind\": \"tube\", \"size\": [outer diameter, wall, length]}",
        default='{"kind": "box", "size": [[0.01, 0.01, 0.01], [0.04, 0.03, 0.02]]}')
    annotate: BoolProperty(
        name="Annotate", description="Off: a distractor, which falls, collides, occludes and is rendered, but is in "
        "no ground truth (scene_gt, COCO, BOP, models; 0 in the mask)", default=default(_O, "annotate"))
    name: StringProperty(name="Name", description="Name of the part in annotations (empty: the file name "
                         "without extension)", default=default(_O, "name"))
    scale: FloatProperty(
        name="Scale", description="File units to metres (e.g. 0.001 for a mesh modelled in millimetres)",
        min=C.MIN_POSITIVE["objects.scale"], soft_max=100.0, precision=4, default=default(_O, "scale"),
        update=sync_previews)
    mass: FloatProperty(name="Mass", description="Mass of each instance", unit="MASS",
                        min=C.MIN_POSITIVE["objects.mass"], soft_max=100.0, precision=3, default=default(_O, "mass"))
    collision_shape: EnumProperty(
        name="Collision Shape", description="Rigid-body collision shape (Convex Hull is fast and stable; "
        "Mesh follows concave parts but is slower)",
        items=enum_choices(C.COLLISION_SHAPES), default=default(_O, "collision_shape"))
    origin: EnumProperty(
        name="Origin", description="The model frame's origin: the mesh file's own, or the centre of its 3D "
        "bounding box (BOP's convention; poses and exported models follow it)",
        items=enum_choices(C.ORIGINS), default=default(_O, "origin"))
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
        default=default(_O, "material"), search=lambda self, context, text: material_search(text))
