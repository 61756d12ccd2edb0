"""`Scene.datapipe.scene` (renders, drop zone, bin, seed) and `.simulation` (the rigid-body drop):
`Config.scene` and `Config.simulation`."""
from bpy.props import (BoolProperty, EnumProperty, FloatProperty, FloatVectorProperty, IntProperty,
                       PointerProperty, StringProperty)
from bpy.types import PropertyGroup

from ... import config as C
from .fields import default, enum_choices, keep_order, keep_range, material_search, range_property


_X = C.TexturesConfig


class DATAPIPE_PG_textures(PropertyGroup):
    """`Config.scene.textures`: textures drawn per scene (no target: off)."""
    targets: EnumProperty(
        name="Textured", description="What gets a texture drawn per scene (none: textures off)",
        items=[("bin", "Bin", "The bin's walls"), ("floor", "Floor", "The floor under the bin"),
               ("parts", "Parts", "Every part instance (on its own material's roughness and metallic)")],
        options={"ENUM_FLAG"}, default=set(default(_X, "targets")))
    kinds: EnumProperty(
        name="Kinds", description="The textures a draw picks from: Blender's procedural noise, Voronoi cells, "
        "waves, bricks, checker, or a texture set of the image folder",
        items=enum_choices(C.TEXTURE_KINDS, {"image": "A texture set (colour, roughness, normal maps) of the "
                                                      "image folder"}),
        options={"ENUM_FLAG"}, default=set(default(_X, "kinds")))
    image_folder: StringProperty(
        name="Image Folder", description="Texture sets (e.g. CC0 PBR sets): colour, roughness and normal maps "
        "recognised by file name (wood_Color.png, wood_Roughness.png, wood_NormalGL.png); needs Image in Kinds",
        subtype="DIR_PATH", default=default(_X, "image_folder"))
    feature_size: range_property("feature_size", "Feature Size", "Size of the texture's features", _X,
                                 unit="LENGTH", lo=1e-4, hi=10.0)
    contrast: range_property("contrast", "Contrast", "1 - dark albedo / bright albedo of the two colours", _X,
                             lo=0.0, hi=1.0)
    albedo: range_property("albedo", "Albedo", "Linear albedo of the bright colour", _X, lo=0.0, hi=1.0)
    saturation: range_property("saturation", "Saturation", "Saturation of the colours (hue drawn uniformly)", _X,
                               lo=0.0, hi=1.0)


_renders_lo, _renders_hi = keep_order("min_renders_per_scene", "max_renders_per_scene")
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
        size=3, subtype="XYZ_LENGTH", unit="LENGTH", min=C.MIN_POSITIVE["scene.drop_zone_scale"], soft_max=5.0,
        default=default(_S, "drop_zone_scale"))
    make_bin: BoolProperty(
        name="Bin Walls", description="Build a floor and walls around the drop zone (off: floor only)",
        default=default(_S, "make_bin"))
    bin_wall_thickness: FloatProperty(
        name="Wall Thickness", description="Thickness of the bin's floor and walls",
        subtype="DISTANCE", unit="LENGTH", min=C.MIN_POSITIVE["scene.bin_wall_thickness"], soft_max=0.1,
        default=default(_S, "bin_wall_thickness"))
    bin_size_scale: range_property("bin_size_scale", "Bin Size Scale", "Per scene, the drop zone's X and Y half "
                           "extents are each multiplied by a factor drawn from this range", _S, lo=0.05, hi=20.0)
    bin_wall_scale: range_property("bin_wall_scale", "Wall Height Scale", "Per scene, the wall height (the drop "
                           "zone's height) is multiplied by a factor drawn from this range", _S, lo=0.05, hi=20.0)
    use_fill: BoolProperty(
        name="Fill by Volume", description="Per scene, draw the part counts so that the parts' convex hulls "
        "fill a share of the bin's volume (within each object's Min/Max instances); off: each count is "
        "drawn from its Min..Max", default=False)
    fill: FloatVectorProperty(
        name="Fill", description="Share of the bin's inner volume the parts' convex hulls fill, drawn per "
        "scene (min, max; at most 0.5: more heaps over the walls)", size=2, min=0.0, max=0.5,
        default=(0.1, 0.2), precision=3, update=keep_range("fill"))
    use_picks: BoolProperty(
        name="Pick Sequences", description="After a pile's renders, remove parts as a robot picks, let the "
        "rest settle and render again, step by step: each step is a scene of its own (scene.picks)",
        default=False)
    picks_per_step: IntProperty(
        name="Parts per Step", description="Parts removed at each step of a pick sequence",
        default=C.PicksConfig().per_step, min=1, soft_max=50)
    picks_order: EnumProperty(
        name="Pick Order", description="Which parts a step removes: top (highest point first, as a robot "
        "picks), visible (largest visible fraction in the step's renders first), random",
        items=enum_choices(C.PICK_ORDERS), default=C.PicksConfig().order)
    picks_until: IntProperty(
        name="Until", description="The sequence stops when this many parts remain",
        default=C.PicksConfig().until, min=0, soft_max=500)
    blend_file: StringProperty(
        name="Blend File", description="Open this .blend as the base scene (empty: a fresh scene); its "
        "object 'drop_zone', when present, overrides the drop zone above",
        subtype="FILE_PATH", default=default(_S, "blend_file") or "")
    other_objects: EnumProperty(
        name="Other Objects", description="Objects of the open scene DataPipe did not make (e.g. the startup "
        "cube and light): hide them from the renders for the run (shown again afterwards), or keep them in; "
        "auto: keep with a Blend File, else hide", items=enum_choices(C.OTHER_OBJECTS),
        default=default(_S, "other_objects"))
    seed: IntProperty(
        name="Seed", description="Base seed of the run: scene i derives its own seed from it, so any scene "
        "can be re-made alone and shards match a single run",
        default=default(_S, "seed"), min=0, max=C.MAX_INT32)
    bin_material: StringProperty(
        name="Bin Material", description="Floor and walls: file (the built-in grey), a preset (matte_plastic, "
        "dark_plastic, painted, steel, aluminium, rubber) or Principled BSDF values as JSON, e.g. "
        "{\"base_color\": [0.5, 0.5, 0.5], \"roughness\": 0.2}; a comma-separated list draws one per scene",
        default=default(_S, "bin_material"),
        search=lambda self, context, text: material_search(text))
    textures: PointerProperty(type=DATAPIPE_PG_textures, name="Textures",
                              description="Textures drawn per scene on bin, floor and parts")


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
        unit="VELOCITY", min=C.MIN_POSITIVE["simulation.settle_speed"], soft_max=1.0, precision=4,
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
