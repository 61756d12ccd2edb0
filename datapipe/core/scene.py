"""The Blender scene a run works in: units, black world, key light, drop zone, bin and occlusion box.

`BlendScene(cfg).setup()` runs once per run. It either opens `cfg.scene.blend_file` or works in the
current (factory-empty) scene, then builds, in metres:

- the drop zone: the world bounding box of an object named ``drop_zone`` in the open .blend if there
  is one (that object is then hidden from rendering and is not a collider), else the box with
  half-extents `cfg.scene.drop_zone_scale` centred at `cfg.scene.drop_zone_loc`;
- the bin: a floor whose top is the zone's bottom (``floor_z = centre.z - half.z``) and, when
  `cfg.scene.make_bin`, four walls of thickness `bin_wall_thickness` around the zone's footprint,
  as high as the zone; all PASSIVE rigid bodies with BOX shapes (exact for boxes), neutral grey.
  The floor is the ground the bin stands on: it reaches at least 2 m (and 10x the bin's half
  size) from the zone's centre, so it fills the camera view and parts that jump out land beside
  the bin (and are then removed as "left the bin");
- the occlusion box: a thick passive box right under the floor so fast small parts cannot tunnel
  through; it collides but never renders (``hide_render``);
- the key light: a 1 m square AREA light 2.5 m above the floor (ceiling-like, above any camera
  pose of the presets) with power `cfg.render.light_power` (50 W: a grey floor renders ~0.4
  linear), invisible to camera rays, in the collection ``datapipe_lights`` (the renderer
  excludes it from fringe layers);
- the rigid-body world (the simulation configures and steps it).

Everything static that DataPipe creates lives in the collection ``datapipe_static``. A .blend saved
after an earlier run may already hold these collections: setup() deletes and rebuilds them.
"""
from __future__ import annotations

import bpy
import numpy as np
from mathutils import Vector

from ..config import Config
from ..errors import DataPipeError

STATIC_COLLECTION = "datapipe_static"
LIGHTS_COLLECTION = "datapipe_lights"
DROP_ZONE_NAME = "drop_zone"
BIN_MATERIAL = "datapipe_bin_grey"
LIGHT_HEIGHT = 2.5          # m, key light above the floor. Cycles gives an AREA light of power P
                            # an on-axis irradiance of about P / (pi^2 h^2): 50 W -> 0.8 W/m^2, so a
                            # grey (0.5) floor renders near 0.4 linear under the Standard view transform
LIGHT_SIZE = 1.0            # m, a soft box: soft shadows
INSIDE_MARGIN = 0.005       # m, how far a settled part may be outside the footprint or under floor_z (simulation)
STATIC_MARGIN = 0.0005      # m, collision margin of the bin's boxes
GROUND_HALF_SIZE = 2.0      # m, the floor reaches at least this far from the zone's centre ...
GROUND_FACTOR = 10.0        # ... and at least 10x the bin's half size

RENDERED_TYPES = {"MESH", "CURVE", "SURFACE", "META", "FONT", "VOLUME", "POINTCLOUD", "CURVES", "LIGHT",
                  "GPENCIL", "GREASEPENCIL", "EMPTY"}   # EMPTY: only collection instances render
_BOX_FACES = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]


def _remove_collection(name: str) -> None:
    """Delete a collection DataPipe made earlier (e.g. saved into the .blend) with its objects."""
    coll = bpy.data.collections.get(name)
    if coll is None:
        return
    for obj in list(coll.all_objects):
        data = obj.data
        bpy.data.objects.remove(obj, do_unlink=True)
        remove_unused_data(data)
    for child in list(coll.children):
        _remove_collection(child.name)
    bpy.data.collections.remove(coll)


def remove_unused_data(data) -> bool:
    """Remove an object's data block (mesh, camera, light or curve) once nothing uses it - call it
    after removing the object that held it, so no orphan stays in the .blend. True if removed."""
    if data is None or data.users > 0:
        return False
    for kind, pool in ((bpy.types.Mesh, bpy.data.meshes), (bpy.types.Camera, bpy.data.cameras),
                       (bpy.types.Light, bpy.data.lights), (bpy.types.Curve, bpy.data.curves)):
        if isinstance(data, kind):
            pool.remove(data)
            return True
    return False


def _new_collection(scene: bpy.types.Scene, name: str) -> bpy.types.Collection:
    coll = bpy.data.collections.new(name)
    scene.collection.children.link(coll)
    return coll


def add_rigid_body(obj: bpy.types.Object, kind: str) -> bpy.types.RigidBodyObject:
    """Give `obj` a rigid body ('ACTIVE' or 'PASSIVE') without relying on the selection."""
    if obj.rigid_body is None:
        with bpy.context.temp_override(object=obj, active_object=obj, selected_objects=[obj],
                                       selected_editable_objects=[obj]):
            bpy.ops.rigidbody.object_add(type=kind)
    obj.rigid_body.type = kind
    return obj.rigid_body


def add_rigid_bodies(objs: list[bpy.types.Object], kind: str) -> None:
    """`add_rigid_body` for many objects in one operator call: each call updates the whole view
    layer, so one call per part cost O(parts^2) (1.5 CPU s of a 120-part drop)."""
    new = [o for o in objs if o.rigid_body is None]
    if new:
        with bpy.context.temp_override(object=new[0], active_object=new[0], selected_objects=new,
                                       selected_editable_objects=new):
            bpy.ops.rigidbody.objects_add(type=kind)
    for o in objs:
        o.rigid_body.type = kind


def remove_rigid_bodies(objs: list[bpy.types.Object]) -> None:
    """`remove_rigid_body` for many objects in one operator call (see add_rigid_bodies)."""
    old = [o for o in objs if o.rigid_body is not None]
    if old:
        with bpy.context.temp_override(object=old[0], active_object=old[0], selected_objects=old,
                                       selected_editable_objects=old):
            bpy.ops.rigidbody.objects_remove()


def remove_rigid_body(obj: bpy.types.Object) -> None:
    if obj.rigid_body is not None:
        with bpy.context.temp_override(object=obj, active_object=obj, selected_objects=[obj],
                                       selected_editable_objects=[obj]):
            bpy.ops.rigidbody.object_remove()


def ensure_rigidbody_world(scene: bpy.types.Scene):
    if scene.rigidbody_world is None:
        with bpy.context.temp_override(scene=scene):
            bpy.ops.rigidbody.world_add()
    scene.rigidbody_world.enabled = True
    return scene.rigidbody_world


def world_bounds(obj: bpy.types.Object) -> tuple[np.ndarray, np.ndarray]:
    """(min, max) of the object's bounding box corners in world coordinates."""
    mw = obj.matrix_world
    pts = np.array([tuple(mw @ Vector(c)) for c in obj.bound_box])
    return pts.min(axis=0), pts.max(axis=0)


class BlendScene:
    """The run's scene: drop zone, bin, occlusion box, key light, rigid-body world."""

    def __init__(self, cfg: Config):
        self.cfg = cfg
        self.scene: bpy.types.Scene | None = None
        self.drop_zone_center = np.asarray(cfg.scene.drop_zone_loc, dtype=np.float64).copy()
        self.drop_zone_half = np.asarray(cfg.scene.drop_zone_scale, dtype=np.float64).copy()
        self.drop_zone_source = "config"      # or "blend" when the .blend's drop_zone object is used
        self.hidden_others: list[str] = []     # objects of the open scene hidden from the renders (restored)
        self.static: bpy.types.Collection | None = None
        self.lights: bpy.types.Collection | None = None
        self.floor: bpy.types.Object | None = None
        self.walls: list[bpy.types.Object] = []
        self.occlusion_box: bpy.types.Object | None = None
        self.key_light: bpy.types.Object | None = None
        self.wall_height: float | None = None  # None: as high as the drop zone (apply_bin draws it)
        self.textured: dict = {}               # {"bin"/"floor": a drawn textured material} (core/textures.py)
        self._env_nodes = None                 # the world's environment map nodes, made on first use
        m = cfg.scene.bin_material           # a list is drawn per scene (core/variety.py); its first
        self.bin_material_spec = m[0] if isinstance(m, list) else m     # item until the first draw

    # -- derived geometry -------------------------------------------------------------------------
    @property
    def floor_z(self) -> float:
        return float(self.drop_zone_center[2] - self.drop_zone_half[2])

    @property
    def floor_center(self) -> np.ndarray:
        """Centre of the bin floor (world, m): what the bin_view camera sampler aims at."""
        return np.array([self.drop_zone_center[0], self.drop_zone_center[1], self.floor_z])

    @property
    def top_z(self) -> float:
        """Top of the drop zone (and of the walls)."""
        return float(self.drop_zone_center[2] + self.drop_zone_half[2])

    @property
    def wall_top_z(self) -> float:
        return self.top_z if self.wall_height is None else self.floor_z + self.wall_height

    def inside_footprint(self, location, margin: float = 0.0) -> bool:
        p = np.asarray(location, dtype=np.float64)
        d = np.abs(p[:2] - self.drop_zone_center[:2])
        return bool(np.all(d <= self.drop_zone_half[:2] + margin))

    # -- other objects of the open scene ----------------------------------------------------------
    def hide_other_objects(self, scene) -> list[str]:
        """Hide from rendering the render-visible objects of `scene` that DataPipe did not make (not
        in a `datapipe_*` collection), per `scene.other_objects`; returns their names. In the add-on
        the run renders into the user's open scene: Blender's startup cube encloses the camera (every
        render black) and its light lights the bin and leaks into the fringe layers. Nothing is
        deleted; `restore_other_objects` shows them again when the run ends."""
        mode = self.cfg.scene.other_objects
        if mode == "keep" or (mode == "auto" and self.cfg.scene.blend_file):
            return []
        hidden = []
        for obj in scene.objects:
            if obj.hide_render or obj.name.startswith("datapipe") or obj.type not in RENDERED_TYPES:
                continue
            if obj.type == "EMPTY" and obj.instance_type != "COLLECTION":
                continue
            if any(c.name.startswith("datapipe") for c in obj.users_collection):
                continue
            obj.hide_render = True
            hidden.append(obj.name)
        self.hidden_others = hidden
        return hidden

    def restore_other_objects(self) -> None:
        """Render again what `hide_other_objects` hid (objects deleted meanwhile are skipped)."""
        for name in self.hidden_others:
            obj = bpy.data.objects.get(name)
            if obj is not None:
                obj.hide_render = False
        self.hidden_others = []

    # -- setup ------------------------------------------------------------------------------------
    def setup(self) -> "BlendScene":
        sc_cfg = self.cfg.scene
        if sc_cfg.blend_file:
            try:
                bpy.ops.wm.open_mainfile(filepath=str(sc_cfg.blend_file))
            except RuntimeError as e:
                raise DataPipeError(f"scene.blend_file: cannot open {sc_cfg.blend_file}: {e} "
                                    "(fix: give the path of a readable .blend file)") from None
        scene = bpy.context.scene
        self.scene = scene
        for name in (STATIC_COLLECTION, LIGHTS_COLLECTION):
            _remove_collection(name)
        self.hide_other_objects(scene)

        us = scene.unit_settings
        us.system = 'METRIC'
        us.scale_length = 1.0
        us.length_unit = 'METERS'
        self._setup_world(scene)
        self._setup_drop_zone(scene)
        self.base_half = self.drop_zone_half.copy()     # what per-scene bin draws scale

        self.static = _new_collection(scene, STATIC_COLLECTION)
        self.lights = _new_collection(scene, LIGHTS_COLLECTION)
        ensure_rigidbody_world(scene)
        self._build_bin(scene)
        self._build_light()
        bpy.context.view_layer.update()
        return self

    def _setup_world(self, scene) -> None:
        world = scene.world
        if world is None:
            world = bpy.data.worlds.new("datapipe_world")
            scene.world = world
        world.color = (0.0, 0.0, 0.0)
        if world.node_tree is None:          # bpy 4.x: worlds get a node tree on use_nodes
            world.use_nodes = True
        bg = next((n for n in world.node_tree.nodes if n.type == 'BACKGROUND'), None)
        if bg is None:
            bg = world.node_tree.nodes.new("ShaderNodeBackground")
            out = next((n for n in world.node_tree.nodes if n.type == 'OUTPUT_WORLD'), None)
            if out is None:
                out = world.node_tree.nodes.new("ShaderNodeOutputWorld")
            world.node_tree.links.new(bg.outputs["Background"], out.inputs["Surface"])
        bg.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
        bg.inputs["Strength"].default_value = 0.0

    def _setup_drop_zone(self, scene) -> None:
        zone = bpy.data.objects.get(DROP_ZONE_NAME)
        if zone is not None and scene in zone.users_scene:
            lo, hi = world_bounds(zone)
            half = (hi - lo) / 2
            if np.any(half <= 0):
                raise DataPipeError(f"the object '{DROP_ZONE_NAME}' in {self.cfg.scene.blend_file} has a flat "
                                    f"bounding box (half extents {half.tolist()}) (fix: make it a box with "
                                    "non-zero size along x, y and z, e.g. a scaled cube)")
            self.drop_zone_center = (lo + hi) / 2
            self.drop_zone_half = half
            self.drop_zone_source = "blend"
            zone.hide_render = True          # a marker, not a part of the picture ...
            remove_rigid_body(zone)          # ... nor a collider
        else:
            self.drop_zone_center = np.asarray(self.cfg.scene.drop_zone_loc, dtype=np.float64).copy()
            self.drop_zone_half = np.asarray(self.cfg.scene.drop_zone_scale, dtype=np.float64).copy()
            self.drop_zone_source = "config"

    def _material(self) -> bpy.types.Material:
        """The bin's material: the current `bin_material_spec` (`scene.bin_material`, or one scene's
        draw from a list of them; core/materials.py), or for "file" the built-in grey (0.5,
        roughness 0.6)."""
        from . import materials
        spec = self.bin_material_spec
        if spec != materials.FILE:
            return materials.build(spec)
        mat = bpy.data.materials.get(BIN_MATERIAL)
        if mat is None:
            mat = bpy.data.materials.new(BIN_MATERIAL)
            if mat.node_tree is None:        # bpy 4.x
                mat.use_nodes = True
        mat.diffuse_color = (0.5, 0.5, 0.5, 1.0)
        bsdf = next((n for n in mat.node_tree.nodes if n.type == 'BSDF_PRINCIPLED'), None)
        if bsdf is not None:
            bsdf.inputs["Base Color"].default_value = (0.5, 0.5, 0.5, 1.0)
            bsdf.inputs["Roughness"].default_value = 0.6
        return mat

    def _box(self, name: str, lo, hi, material=None) -> bpy.types.Object:
        """A passive BOX rigid body spanning [lo, hi] (world). Origin at its centre: Blender's BOX
        collision shape is centred on the object origin."""
        lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
        c, h = (lo + hi) / 2, (hi - lo) / 2
        verts = [(sx * h[0], sy * h[1], sz * h[2]) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
        me = bpy.data.meshes.new(name)
        me.from_pydata(verts, [], _BOX_FACES)
        me.update()
        if material is not None:
            me.materials.append(material)
        obj = bpy.data.objects.new(name, me)
        obj.location = tuple(c)
        self.static.objects.link(obj)
        bpy.context.view_layer.update()
        rb = add_rigid_body(obj, 'PASSIVE')
        rb.collision_shape = 'BOX'
        # Blender's default margin (0.04 m) exceeds a thin wall's half thickness; Bullet would then
        # shrink the box to negative size and parts pass through. Use a small explicit margin.
        rb.use_margin = True
        rb.collision_margin = float(min(STATIC_MARGIN, 0.1 * h.min()))
        # Bullet multiplies the two bodies' friction (and restitution): 1.0 on the bin makes a part's
        # configured friction/restitution the effective part-bin value.
        rb.friction = 1.0
        rb.restitution = 1.0
        return obj

    def _build_bin(self, scene) -> None:
        c, h = self.drop_zone_center, self.drop_zone_half
        t = float(self.cfg.scene.bin_wall_thickness)
        fz = self.floor_z
        mat = self._material()
        # the floor is the ground the bin stands on: wide enough to fill any sensible camera view
        # (depth and structured light everywhere, parts that jump out land beside the bin)
        g = max(GROUND_HALF_SIZE, GROUND_FACTOR * float(max(h[0], h[1]) + t))
        outer_lo = np.array([c[0] - g, c[1] - g])
        outer_hi = np.array([c[0] + g, c[1] + g])
        self.floor = self._box("datapipe_floor", [*outer_lo, fz - t], [*outer_hi, fz], self.textured.get("floor", mat))
        self.walls = []
        if self.cfg.scene.make_bin:
            x0, x1, y0, y1 = c[0] - h[0], c[0] + h[0], c[1] - h[1], c[1] + h[1]
            spans = {
                "datapipe_wall_xneg": ([x0 - t, y0 - t], [x0, y1 + t]),
                "datapipe_wall_xpos": ([x1, y0 - t], [x1 + t, y1 + t]),
                "datapipe_wall_yneg": ([x0, y0 - t], [x1, y0]),
                "datapipe_wall_ypos": ([x0, y1], [x1, y1 + t]),
            }
            for name, (lo, hi) in spans.items():
                self.walls.append(self._box(name, [*lo, fz], [*hi, self.wall_top_z], self.textured.get("bin", mat)))
        # the occlusion box: thick, right under the floor, a collider that never renders
        depth = max(2.0 * float(h[2]), 0.05)
        self.occlusion_box = self._box("datapipe_occlusion_box", [*outer_lo, fz - t - depth], [*outer_hi, fz - t])
        self.occlusion_box.hide_render = True
        self.occlusion_box.display_type = 'WIRE'
        for obj in [self.floor, *self.walls, self.occlusion_box]:
            obj.visible_shadow = obj is not self.occlusion_box

    def _build_light(self) -> None:
        c, h = self.drop_zone_center, self.drop_zone_half
        ld = bpy.data.lights.new("datapipe_key_light", 'AREA')
        ld.energy = float(self.cfg.render.light_power)
        ld.shape = 'SQUARE'
        ld.size = LIGHT_SIZE
        obj = bpy.data.objects.new("datapipe_key_light", ld)
        obj.location = self._key_light_home()     # looks down -Z
        obj.visible_camera = False           # lights the scene without showing up in the picture
        self.lights.objects.link(obj)
        self.key_light = obj

    def _key_light_home(self) -> tuple[float, float, float]:
        c = self.drop_zone_center
        return float(c[0]), float(c[1]), max(self.floor_z + LIGHT_HEIGHT, self.top_z + 0.5, self.wall_top_z + 0.5)

    def set_bin_material(self, spec) -> None:
        """Give floor and walls the material `spec` (one scene's draw from a `scene.bin_material` list)."""
        self.bin_material_spec = spec
        mat = self._material()
        for obj in [self.floor, *self.walls]:
            if obj is not None:
                obj.data.materials.clear()
                obj.data.materials.append(self.textured.get("floor" if obj is self.floor else "bin", mat))

    def set_textures(self, draws: dict) -> None:
        """Give the walls ("bin") and the floor ("floor") one scene's drawn textures
        (datapipe.draws.textures.draw_static), on the bin material's own Principled values."""
        from . import textures
        spec = self.bin_material_spec
        self.textured = {t: textures.build(spec, d, world_space=True, default=textures.BIN_DEFAULT, tag=t)
                         for t, d in draws.items()}
        self.set_bin_material(spec)
        textures.remove_unused()

    def apply_bin(self, draw: dict) -> None:
        """Rebuild floor, walls and occlusion box for one scene's `datapipe.draws.bin_shape.draw_bin`: the
        zone's x, y half extents (placement and the "left the bin" test follow them) and the wall
        height change; the floor and the zone's centre stay."""
        for obj in [self.floor, *self.walls, self.occlusion_box]:
            if obj is not None:
                mesh = obj.data
                bpy.data.objects.remove(obj, do_unlink=True)
                remove_unused_data(mesh)
        self.drop_zone_half = np.asarray(draw["half_size"], dtype=np.float64).copy()
        self.wall_height = float(draw["wall_height"])
        self._build_bin(self.scene)
        self.key_light.location = self._key_light_home()
        bpy.context.view_layer.update()

    def apply_lighting(self, draw: dict) -> None:
        """Set the key light and the ambient world from one scene's `datapipe.draws.lighting.draw_lighting`.
        The ambient is a white world background (the fringe layers override it with a black world,
        so the projector alone lights the patterns)."""
        ld = self.key_light.data
        ld.energy = float(draw["key_power"])
        ld.color = tuple(float(v) for v in draw["key_color"])
        ld.size = float(draw["key_size"])
        self.key_light.location = tuple(h + float(o) for h, o in zip(self._key_light_home(), draw["key_offset"]))
        bg = next(n for n in self.scene.world.node_tree.nodes if n.type == 'BACKGROUND')
        bg.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        bg.inputs["Strength"].default_value = float(draw["ambient"])
        if "environment" in draw:
            self.apply_environment(draw["environment"])
        bpy.context.view_layer.update()

    def apply_environment(self, draw: dict) -> None:
        """Add the environment map of one draw (datapipe.draws.environment.draw_environment) to the world:
        a second Background node, its image rotated about world Z and of the drawn strength, added to
        the white ambient. The fringe layers keep their black world override (the projector alone
        lights them); the projector-off layer of structured_light.ambient "scene" sees it."""
        from ..draws.environment import rotation_rad
        nt = self.scene.world.node_tree
        if self._env_nodes is None:
            out = next(n for n in nt.nodes if n.type == 'OUTPUT_WORLD')
            bg = next(n for n in nt.nodes if n.type == 'BACKGROUND')
            coord = nt.nodes.new("ShaderNodeTexCoord")
            mapping = nt.nodes.new("ShaderNodeMapping")
            tex = nt.nodes.new("ShaderNodeTexEnvironment")
            env_bg = nt.nodes.new("ShaderNodeBackground")
            add = nt.nodes.new("ShaderNodeAddShader")
            nt.links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
            nt.links.new(mapping.outputs["Vector"], tex.inputs["Vector"])
            nt.links.new(tex.outputs["Color"], env_bg.inputs["Color"])
            nt.links.new(bg.outputs["Background"], add.inputs[0])
            nt.links.new(env_bg.outputs["Background"], add.inputs[1])
            nt.links.new(add.outputs["Shader"], out.inputs["Surface"])
            self._env_nodes = (mapping, tex, env_bg)
        mapping, tex, env_bg = self._env_nodes
        from .textures import IMAGE_TAG, load_image
        old = tex.image
        tex.image = load_image(draw["map"])
        if old is not None and old is not tex.image and old.users == 0 and old.get(IMAGE_TAG):
            bpy.data.images.remove(old)                               # one map of ours held at a time
        mapping.inputs["Rotation"].default_value = (0.0, 0.0, rotation_rad(draw))
        env_bg.inputs["Strength"].default_value = float(draw["strength"])


def find_layer_collection(layer_collection, name: str):
    """The LayerCollection of collection `name` anywhere below `layer_collection` (None if absent);
    what a view layer's per-collection `exclude` flag hangs on."""
    if layer_collection.collection.name == name:
        return layer_collection
    for child in layer_collection.children:
        found = find_layer_collection(child, name)
        if found is not None:
            return found
    return None
