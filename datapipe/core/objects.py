"""Source meshes (imported once per run) and the per-scene instances dropped into the bin.

Templates
    `load_sources()` reads each distinct mesh file once (`import_count` counts the reads) with
    Blender's own importers, finding what an import created by diffing `bpy.data.objects` (never
    through the selection):

    - .obj  `wm.obj_import`, .ply `wm.ply_import`, .stl `wm.stl_import`, all with
      forward_axis='Y', up_axis='Z': no axis conversion, mesh coordinates = file coordinates;
    - .glb/.gltf `import_scene.gltf`: glTF is Y-up by specification and Blender converts it to
      Z-up, so for glTF the model frame is Blender's converted frame (x, -z, y of the file).

    A file holding several meshes is joined into one template (world transforms of the parts,
    parents included, are kept); non-mesh objects it brings (empties, cameras, lights) are deleted.
    A file with no mesh (or no vertices) is a DataPipeError naming the file. The entry's `scale`
    and any transform the importer put on the object are baked into the mesh data, so a
    template's matrix_world is the identity and its mesh coordinates are model coordinates in
    metres. Two entries naming the same file share one import; the second gets a copy of the
    mesh data with its own scale baked in.

    Templates live in the collection "datapipe_templates": excluded from every view layer that
    exists at load time and hidden from rendering (`hide_render`), so view layers made later
    (the renderer's fringe layers) do not show them either.

Instances
    `populate(rng)` makes, per entry, a random number in [min_instances, max_instances] (or, with
    `scene.fill`, the counts datapipe/draws/fill.py draws from the parts' hull volumes) of linked
    copies (`obj.copy()`: same mesh data, no re-import), named f"{entry_name}_{k:03d}" (k from 0
    within the scene), with unique pass_index 1..n (a distractor, `annotate: false`: 0, the mask's
    background; a procedural `shape`: its own mesh at a size drawn per instance, core/shape_parts.py),
    a uniformly random orientation, placed on a grid of bounding spheres inside the drop zone's
    footprint in layers from the zone's centre upward (spheres never overlap; `staged=True`: only the
    lowest STAGE_LAYERS layers at once, see simulation.drop_in_stages), and an ACTIVE rigid body
    (the entry's mass, friction, restitution and collision shape; a collision margin of 4% of the
    part's thinnest width, at most 0.5 mm: Blender's default 0.04 m is larger than small parts, a
    fixed 0.5 mm left a visible gap around a 2.4 mm peg), in "datapipe_objects". `populate()` first
    clears the previous scene's instances; `clear()` deletes them; the templates and meshes stay.

Collision shapes (see collision.py)
    AUTO (the default) is DECOMPOSED for a clearly concave mesh (it fills less than 70% of its
    convex hull), else CONVEX_HULL. DECOMPOSED, and MESH (Blender's triangle-mesh shape for moving
    parts threw concave parts out of the bin), simulate the part as a COMPOUND rigid body: one
    hidden, non-rendering child object per convex piece of the template's CoACD decomposition
    (cached on disk), parented to the instance, in the collection "datapipe_collision". Cost: the
    decomposition once per mesh (seconds, then cached) and one child body per piece.

Centre of mass
    Blender's rigid bodies put the centre of mass at the object origin. Each template mesh stores
    its volume centroid (custom property "datapipe_com"); when that is off the model origin, a
    re-centred copy of the mesh ("datapipe_sim_mesh") is what the simulation moves, and the pose
    is mapped back to the model frame afterwards (see core/simulation.py).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix, Quaternion, Vector

from ..config import Config
from ..errors import ConfigError, DataPipeError
from ..io.bop_models import entry_field
from .. import collision, shapes
from .shape_parts import make_shape
from .scene import BlendScene, add_rigid_bodies, add_rigid_body, find_layer_collection, remove_unused_data
from ..draws.fill import draw_share, fill_counts, hull_volume

TEMPLATES_COLLECTION = "datapipe_templates"
OBJECTS_COLLECTION = "datapipe_objects"
COLLISION_COLLECTION = "datapipe_collision"
TEMPLATE_PREFIX = "datapipe_template_"
COM_PROP = "datapipe_com"             # template mesh custom property: centre of mass, model coords
SIM_MESH_PROP = "datapipe_sim_mesh"   # template mesh custom property: copy re-centred on the COM
COM_TOLERANCE = 1e-5                  # m; closer than this the model origin is used as is
COLLISION_MARGIN = 0.0005  # m, the largest margin; Blender's default 0.04 m is larger than small parts
MARGIN_FRACTION = 0.04     # margin = this x the part's thinnest width (up to COLLISION_MARGIN)
DECOMPOSED_SHAPES = ("DECOMPOSED", "MESH")   # simulated as a compound of convex pieces
STAGE_LAYERS = 2           # spawn layers per drop stage: a deeper column drops in stages (core/simulation.py)

_IMPORTERS = {
    ".obj": "obj",
    ".ply": "ply",
    ".stl": "stl",
    ".glb": "gltf",
    ".gltf": "gltf",
}


@dataclass
class Instance:
    """One part in the current scene."""
    obj: bpy.types.Object
    entry_index: int           # index into cfg.objects (obj_id = cfg.obj_id(entry_index))
    name: str                  # f"{entry_name}_{k:03d}"
    filename: str              # the source mesh file (absolute path)
    mask_index: int            # = obj.pass_index, 1..n within the scene
    thin: float = 0.0          # thinnest width of its collision shape (m)
    size: float = 0.0          # largest bounding-box extent (m)
    shape: str = "CONVEX_HULL"  # the collision shape simulated (AUTO resolved; DECOMPOSED for MESH)
    layer: int = 0             # spawn layer (0: lowest); layers >= STAGE_LAYERS drop in later stages
    own: "_Template | None" = None   # a procedural shape's own mesh and pieces (its size is drawn per instance)

    @property
    def annotated(self) -> bool:
        """False for a distractor (objects[i].annotate: false): pass_index 0, in no ground truth."""
        return self.mask_index > 0


@dataclass
class _Template:
    obj: bpy.types.Object
    center: np.ndarray         # bounding-box centre, model coordinates (m)
    radius: float              # bounding-sphere radius about `center` (m)
    com: np.ndarray            # centre of mass (uniform density), model coordinates (m)
    shape: str = "CONVEX_HULL"  # resolved collision shape (AUTO -> DECOMPOSED or CONVEX_HULL)
    thin: float = 0.0          # thinnest width of the collision shape (m)
    size: float = 0.0          # largest bounding-box extent (m)
    pieces: tuple = ()         # DECOMPOSED: one mesh per convex piece, in the simulation frame
    hull_volume: float = 0.0   # m^3, of the convex hull (scene.fill counts parts by it)
    mesh: object = None        # a procedural shape's mesh data (deleted with its instance)


def _run_importer(kind: str, path: str) -> None:
    if kind == "obj":
        bpy.ops.wm.obj_import(filepath=path, forward_axis='Y', up_axis='Z')
    elif kind == "ply":
        bpy.ops.wm.ply_import(filepath=path, forward_axis='Y', up_axis='Z')
    elif kind == "stl":
        bpy.ops.wm.stl_import(filepath=path, forward_axis='Y', up_axis='Z')
    elif kind == "gltf":
        bpy.ops.import_scene.gltf(filepath=path)
    else:  # pragma: no cover - _IMPORTERS guards
        raise AssertionError(kind)


def remove_import_leftovers(before_objs, before_meshes, before_colls) -> None:
    """Delete every object, mesh and collection an import added (given what existed before it)."""
    for o in [o for o in bpy.data.objects if o not in before_objs]:
        data = o.data
        bpy.data.objects.remove(o, do_unlink=True)
        remove_unused_data(data)
    for m in set(bpy.data.meshes) - before_meshes:
        if m.users == 0:
            bpy.data.meshes.remove(m)
    for c in set(bpy.data.collections) - before_colls:
        bpy.data.collections.remove(c)


class ObjectManager:
    """Templates (one import per file per run) and the scene's instances."""

    def __init__(self, cfg: Config, blend_scene: BlendScene):
        self.cfg = cfg
        self.blend_scene = blend_scene
        self.import_count = 0
        self.templates: list[_Template] = []
        self.instances: list[Instance] = []
        self.templates_collection: bpy.types.Collection | None = None
        self.collection: bpy.types.Collection | None = None
        self.collision_collection: bpy.types.Collection | None = None
        self.decomposed_from_cache = 0    # decompositions read from the disk cache (rest computed)
        self.last_fill: dict | None = None  # scene.fill of the last populate: drawn share, share reached
        self._shape_meshes = 0              # procedural shape meshes made this run (their unique names)

    @property
    def scene(self) -> bpy.types.Scene:
        return self.blend_scene.scene

    # -- templates --------------------------------------------------------------------------------
    def load_sources(self) -> "ObjectManager":
        """Import every entry's file (each distinct file once). A second call is a no-op."""
        if self.templates:
            return self
        seen: dict[str, int] = {}
        for i in range(len(self.cfg.objects)):
            name = self.cfg.object_name(i)
            if name in seen:
                raise DataPipeError(f"objects[{i}].name: '{name}' is also the name of objects[{seen[name]}], so "
                                    "their instances would get the same names (fix: give each entry a unique "
                                    "'name')")
            seen[name] = i
        scene = self.scene
        self.templates_collection = self._collection(TEMPLATES_COLLECTION)
        self.templates_collection.hide_render = True
        self.collection = self._collection(OBJECTS_COLLECTION)
        self.collision_collection = self._collection(COLLISION_COLLECTION)
        self.collision_collection.hide_render = True
        self.templates = []
        by_file: dict[str, bpy.types.Object] = {}        # file -> its import, at the file's scale
        for i, entry in enumerate(self.cfg.objects):
            if entry.shape is not None:     # a procedural distractor: the template at its largest size
                self.templates.append(self._shape_template(i, shapes.largest(entry.shape, float(entry.scale)),
                                                           f"{TEMPLATE_PREFIX}{self.cfg.object_name(i)}",
                                                           self.templates_collection))
                continue
            path = os.path.abspath(entry.filepath)
            if path not in by_file:
                by_file[path] = self._import(i, path)
            self.templates.append(self._make_template(i, by_file[path].data))
        # drop the unscaled raw imports
        for obj in by_file.values():
            raw = obj.data
            bpy.data.objects.remove(obj, do_unlink=True)
            remove_unused_data(raw)
        for vl in scene.view_layers:
            lc = find_layer_collection(vl.layer_collection, self.templates_collection.name)
            if lc is not None:
                lc.exclude = True
        bpy.context.view_layer.update()
        return self

    def _collection(self, name: str) -> bpy.types.Collection:
        coll = bpy.data.collections.get(name)
        if coll is not None:                # left over from an earlier run saved in the .blend
            for obj in list(coll.all_objects):
                data = obj.data
                bpy.data.objects.remove(obj, do_unlink=True)
                if isinstance(data, bpy.types.Mesh) and data.users == 0:
                    sim = data.get(SIM_MESH_PROP)
                    bpy.data.meshes.remove(data)
                    if sim is not None and sim.users == 0:
                        bpy.data.meshes.remove(sim)
        else:
            coll = bpy.data.collections.new(name)
        if coll.name not in self.scene.collection.children:
            self.scene.collection.children.link(coll)
        return coll

    def _import(self, i: int, path: str) -> bpy.types.Object:
        """Read one file; return one mesh object (world transform baked, parent-free) in the scene."""
        field = f"{entry_field(self.cfg.objects[i], i)}.filepath"     # a BOP entry: the preset's field
        ext = Path(path).suffix.lower()
        kind = _IMPORTERS.get(ext)
        if kind is None:
            raise DataPipeError(f"{field}: unsupported mesh format '{ext or '(none)'}' for {path} "
                                f"(fix: give a {', '.join(_IMPORTERS)} file)")
        if not os.path.isfile(path):
            raise DataPipeError(f"{field}: file not found: {path} (fix: give the path of an existing mesh file)")
        before_objs = set(bpy.data.objects)
        before_meshes = set(bpy.data.meshes)
        before_colls = set(bpy.data.collections)
        layer = bpy.context.view_layer
        # import into the scene's top collection so the (visible) objects can be joined
        layer.active_layer_collection = layer.layer_collection
        try:
            _run_importer(kind, path)
        except RuntimeError as e:
            remove_import_leftovers(before_objs, before_meshes, before_colls)
            raise DataPipeError(f"{field}: cannot import {path}: {str(e).strip()} "
                                "(fix: check that the file is a valid mesh file of that format)") from None
        self.import_count += 1
        new = [o for o in bpy.data.objects if o not in before_objs]
        meshes = [o for o in new if o.type == 'MESH' and o.data is not None and len(o.data.vertices) > 0]
        if not meshes:
            remove_import_leftovers(before_objs, before_meshes, before_colls)
            raise DataPipeError(f"{field}: {path} holds no mesh with vertices (fix: export the part as a "
                                "triangle/polygon mesh, e.g. OBJ with 'v' and 'f' lines)")
        meshes.sort(key=lambda o: o.name)
        # make every part parent-free with its world transform, single-user mesh data
        mws = {o: o.matrix_world.copy() for o in meshes}
        for o in meshes:
            o.parent = None
            if o.data.users > 1:
                o.data = o.data.copy()
            o.matrix_world = mws[o]
        for o in new:
            if o not in meshes:
                data = o.data
                bpy.data.objects.remove(o, do_unlink=True)
                remove_unused_data(data)
        for o in meshes:
            for c in list(o.users_collection):
                c.objects.unlink(o)
            self.templates_collection.objects.link(o)
        # the templates collection is still part of the view layer here (excluded at the end)
        lc = find_layer_collection(layer.layer_collection, self.templates_collection.name)
        if lc is not None:
            lc.exclude = False
        layer.update()
        obj = meshes[0]
        if len(meshes) > 1:
            with bpy.context.temp_override(active_object=obj, object=obj, selected_objects=meshes,
                                           selected_editable_objects=meshes):
                bpy.ops.object.join()
        # bake the object transform into the mesh
        mw = obj.matrix_world.copy()
        obj.data.transform(mw)
        if mw.to_3x3().determinant() < 0:
            obj.data.flip_normals()
        obj.matrix_world = Matrix.Identity(4)
        obj.name = f"{TEMPLATE_PREFIX}raw_{Path(path).stem}"
        for m in set(bpy.data.meshes) - before_meshes:
            if m.users == 0:
                bpy.data.meshes.remove(m)
        for c in set(bpy.data.collections) - before_colls:
            if len(c.all_objects) == 0:
                bpy.data.collections.remove(c)
        return obj

    def _make_template(self, i: int, raw_mesh: bpy.types.Mesh) -> _Template:
        entry = self.cfg.objects[i]
        name = f"{TEMPLATE_PREFIX}{self.cfg.object_name(i)}"
        me = raw_mesh.copy()
        me.name = name
        s = float(entry.scale)
        me.transform(Matrix.Diagonal((s, s, s, 1.0)))   # (transform moves the vertices: _vertices reads them)
        if entry.origin == "bbox_center":   # BOP's model frame, the bounding box's centre (docs/DATASETS.md):
            pts = _vertices(me)              # the mesh data itself, so models, models_info and poses share it
            me.transform(Matrix.Translation(Vector((-(pts.min(axis=0) + pts.max(axis=0)) / 2).tolist())))
        me.update()
        obj = bpy.data.objects.new(name, me)
        self.templates_collection.objects.link(obj)
        pts = _vertices(me)
        lo, hi = pts.min(axis=0), pts.max(axis=0)
        center = (lo + hi) / 2
        radius = float(np.linalg.norm(pts - center, axis=1).max())
        # Blender's rigid bodies rotate about the object origin (= centre of mass). When the model
        # origin is off the part's centroid, the simulation uses a re-centred copy of the mesh
        # (see Simulation.run), found through these custom properties of the template mesh.
        com = _center_of_mass(me, pts, center)
        me[COM_PROP] = [float(x) for x in com]
        if np.linalg.norm(com) > COM_TOLERANCE:
            sim = me.copy()
            sim.name = f"{name}_com"
            for key in (COM_PROP, SIM_MESH_PROP):
                if key in sim:
                    del sim[key]
            sim.transform(Matrix.Translation(Vector((-com).tolist())))
            sim.update()
            me[SIM_MESH_PROP] = sim
        tpl = _Template(obj=obj, center=center, radius=radius, com=com, size=float(np.ptp(pts, axis=0).max()),
                        hull_volume=hull_volume(pts))
        self._collision_shape(i, tpl)
        return tpl

    def _shape_template(self, i: int, size, name: str, collection) -> _Template:
        """A procedural shape of this size as a mesh object in `collection` (core/shape_parts.py),
        centred on its centroid (no re-centred simulation copy). Its mesh gets a run-wide unique
        name: the simulation's check caches meshes by name, and each instance's size differs."""
        self._shape_meshes += 1
        obj, pieces, thin = make_shape(self.cfg.objects[i].shape, size, name,
                                       f"datapipe_shape_{self._shape_meshes:06d}", collection)
        pts = _vertices(obj.data)
        return _Template(obj=obj, center=np.zeros(3), radius=float(np.linalg.norm(pts, axis=1).max()),
                         com=np.zeros(3), shape="DECOMPOSED" if pieces else "CONVEX_HULL", thin=thin,
                         size=float(np.ptp(pts, axis=0).max()), pieces=pieces, hull_volume=hull_volume(pts),
                         mesh=obj.data)

    def _collision_shape(self, i: int, tpl: _Template) -> None:
        """Resolve AUTO, decompose concave parts (DECOMPOSED/MESH) and measure the thinnest width."""
        shape = self.cfg.objects[i].collision_shape
        me = tpl.obj.data
        verts, tris, _ = self.model_mesh_of(me)
        if shape == "AUTO":
            shape = "DECOMPOSED" if collision.is_clearly_concave(verts, tris) else "CONVEX_HULL"
        tpl.shape = "DECOMPOSED" if shape in DECOMPOSED_SHAPES else shape
        if tpl.shape == "DECOMPOSED":
            if not collision.coacd_available():       # preflight refuses it first; the add-on's run too
                raise ConfigError(collision.missing_coacd(f"objects[{i}].collision_shape"))
            pieces, cached = collision.decompose(verts, tris)
            self.decomposed_from_cache += int(cached)
            # the pieces move with the simulated mesh: re-centred on the centre of mass if that is
            shift = tpl.com if me.get(SIM_MESH_PROP) is not None else np.zeros(3)
            meshes = []
            for k, (pv, pf) in enumerate(pieces):
                pm = bpy.data.meshes.new(f"{tpl.obj.name}_piece{k:02d}")
                pm.from_pydata((pv - shift).tolist(), [], pf.tolist())
                pm.update()
                meshes.append(pm)
            tpl.pieces = tuple(meshes)
            tpl.thin = min(collision.min_width(pv) for pv, _ in pieces)
        elif tpl.shape == "CONVEX_HULL":
            tpl.thin = collision.min_width(verts)
        else:                                   # primitives fit the bounding box
            tpl.thin = float(np.ptp(verts, axis=0).min())

    # -- model data for annotations ---------------------------------------------------------------
    def model_mesh(self, entry_index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(verts (V,3) float64, triangles (F,3) int64, vertex normals (V,3) float64), model frame."""
        return self.model_mesh_of(self.templates[entry_index].obj.data)

    @staticmethod
    def model_mesh_of(me: bpy.types.Mesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        verts = _vertices(me)
        me.calc_loop_triangles()
        tris = np.zeros(len(me.loop_triangles) * 3, dtype=np.int32)
        me.loop_triangles.foreach_get("vertices", tris)
        normals = np.zeros(len(me.vertices) * 3, dtype=np.float32)
        me.vertices.foreach_get("normal", normals)
        return verts, tris.reshape(-1, 3).astype(np.int64), normals.reshape(-1, 3).astype(np.float64)

    # -- instances --------------------------------------------------------------------------------
    def populate(self, rng: np.random.Generator, *, staged: bool = False) -> list[Instance]:
        """Make this scene's instances (clears any left from an earlier populate). `staged`: only
        the first STAGE_LAYERS spawn layers get rigid bodies (core/simulation.drop_in_stages
        activates the others stage by stage); else every instance has one."""
        if not self.templates and self.cfg.objects:
            raise DataPipeError("ObjectManager.populate() before load_sources() "
                                "(fix: call load_sources() once per run first)")
        self.clear()
        plan: list[tuple[int, int]] = []            # (entry index, k)
        for i, n in enumerate(self._draw_counts(rng)):
            plan += [(i, k) for k in range(n)]
        rotations = [_random_rotation(rng) for _ in plan]
        centers, layers = self._place([self.templates[i].radius for i, _ in plan], rng)
        # procedural shapes draw their sizes last (placed by their largest size's sphere), so a
        # config without them draws exactly what it drew before
        sizes = [shapes.draw_sizes(rng, self.cfg.objects[i].shape, float(self.cfg.objects[i].scale), 1)[0]
                 if self.cfg.objects[i].shape is not None else None for i, _ in plan]

        instances: list[Instance] = []
        annotated = 0
        for (i, k), R, p, layer, size in zip(plan, rotations, centers, layers, sizes):
            entry = self.cfg.objects[i]
            tpl = self.templates[i]
            name = f"{self.cfg.object_name(i)}_{k:03d}"
            clash = bpy.data.objects.get(name)
            if clash is not None:
                raise DataPipeError(f"an object named '{name}' already exists in the scene, so instance "
                                    f"names would not be deterministic (fix: rename '{name}' in the .blend)")
            own = None
            if size is not None:                    # its own mesh, at the drawn size
                own = tpl = self._shape_template(i, size, name, self.collection)
                obj = tpl.obj
            else:
                obj = tpl.obj.copy()                # linked copy: shares tpl.obj.data
                obj.name = name
                self.collection.objects.link(obj)
            obj.hide_render = False
            obj.hide_viewport = False
            # annotated parts are numbered 1..n; a distractor is 0 in the object-index pass, the
            # mask's background (docs/DATASETS.md), so it is in no instance id
            annotated += int(entry.annotate)
            mask_index = annotated if entry.annotate else 0
            obj.pass_index = mask_index
            loc = p - R @ tpl.center                # the bounding sphere's centre goes to p
            obj.matrix_world = Matrix.Translation(Vector(loc)) @ Matrix(R.tolist()).to_4x4()
            instances.append(Instance(obj=obj, entry_index=i, name=name,
                                      filename=os.path.abspath(entry.filepath) if entry.filepath else "",
                                      mask_index=mask_index, layer=layer, own=own))
        bpy.context.view_layer.update()
        self.instances = instances
        self.activate([inst for inst in instances if not staged or inst.layer < STAGE_LAYERS])
        return list(instances)

    def _draw_counts(self, rng: np.random.Generator) -> list[int]:
        """Instances per entry: uniform in [min, max] each, or by scene.fill (datapipe/draws/fill.py)."""
        entries = self.cfg.objects
        fill = self.cfg.scene.fill
        self.last_fill = None
        if fill is None:
            return [int(rng.integers(e.min_instances, e.max_instances + 1)) for e in entries]
        bs = self.blend_scene
        half = bs.drop_zone_half
        volume = 4.0 * float(half[0] * half[1]) * float(bs.wall_top_z - bs.floor_z)
        share = draw_share(rng, fill)
        counts, reached = fill_counts(rng, share, volume, [t.hull_volume for t in self.templates],
                                      [e.min_instances for e in entries], [e.max_instances for e in entries])
        self.last_fill = {"share": round(share, 4), "reached": round(reached, 4),
                          "bin_litres": round(volume * 1e3, 4)}
        return counts

    def activate(self, instances: list[Instance]) -> None:
        """Give `instances` their ACTIVE rigid bodies (populate does it for the first stage's layers;
        core/simulation.py for the later stages, just before they drop)."""
        add_rigid_bodies([inst.obj for inst in instances], 'ACTIVE')
        for inst in instances:
            entry = self.cfg.objects[inst.entry_index]
            rb = inst.obj.rigid_body
            rb.mass = float(entry.mass)
            rb.friction = float(entry.friction)
            rb.restitution = float(entry.restitution)
            tpl = inst.own or self.templates[inst.entry_index]
            margin = part_margin(tpl.thin)
            rb.collision_shape = 'COMPOUND' if tpl.pieces else tpl.shape
            rb.mesh_source = 'BASE'
            rb.use_margin = True
            rb.collision_margin = margin
            inst.thin, inst.size, inst.shape = tpl.thin, tpl.size, tpl.shape
            for k, pm in enumerate(tpl.pieces):
                self._add_piece(inst, k, pm, margin)

    def _add_piece(self, inst: Instance, k: int, mesh: bpy.types.Mesh, margin: float) -> None:
        """One convex piece of a DECOMPOSED part: a hidden child whose local transform is the
        identity (its mesh is already in the parent's simulation frame)."""
        child = bpy.data.objects.new(f"{inst.name}_piece{k:02d}", mesh)
        child.hide_render = True
        child.display_type = 'WIRE'
        self.collision_collection.objects.link(child)
        child.parent = inst.obj
        child.matrix_parent_inverse = Matrix.Identity(4)
        bpy.context.view_layer.update()
        rb = add_rigid_body(child, 'ACTIVE')
        rb.collision_shape = 'CONVEX_HULL'
        rb.mesh_source = 'BASE'
        rb.use_margin = True
        rb.collision_margin = margin

    def _place(self, radii: list[float], rng: np.random.Generator) -> tuple[list[np.ndarray], list[int]]:
        """Sphere centres and their layers: a grid over the zone's footprint (minus the radius), layer
        upon layer from the zone's centre upward, jittered inside each cell; spheres of these radii
        never overlap."""
        n = len(radii)
        if n == 0:
            return [], []
        c, h = self.blend_scene.drop_zone_center, self.blend_scene.drop_zone_half
        gap = float(self.cfg.simulation.layer_gap)
        r_max = max(radii)
        cell = 2 * r_max + gap
        counts = []
        for ax in (0, 1):
            span = 2 * (h[ax] - r_max)              # range of sphere centres along the axis
            counts.append(int(math.floor(span / cell)) + 1 if span >= 0 else 1)
        nx, ny = counts
        per_layer = nx * ny
        layers = -(-n // per_layer)
        slots = np.concatenate([rng.permutation(per_layer) + L * per_layer for L in range(layers)])[:n]
        out, out_layers = [], []
        for r, slot in zip(radii, slots):
            L, rem = divmod(int(slot), per_layer)
            out_layers.append(L)
            ix, iy = divmod(rem, ny)
            base = np.array([c[0] + (ix - (nx - 1) / 2) * cell,
                             c[1] + (iy - (ny - 1) / 2) * cell,
                             c[2] + r_max + L * cell])
            jitter = max((cell - gap) / 2 - r, 0.0)
            out.append(base + rng.uniform(-jitter, jitter, size=3))
        return out, out_layers

    def clear(self) -> None:
        """Delete this scene's instances (their rigid bodies go with them; the mesh data stays)."""
        for inst in self.instances:
            try:
                obj = inst.obj
                obj.name  # raises ReferenceError if already removed (e.g. by the simulation)
            except ReferenceError:
                continue
            bpy.data.objects.remove(obj, do_unlink=True)
        owned = [inst.own for inst in self.instances if inst.own is not None]
        self.instances = []
        for coll in (self.collision_collection, self.collection):   # pieces, anything else left
            if coll is not None:
                for obj in list(coll.objects):
                    bpy.data.objects.remove(obj, do_unlink=True)
        for tpl in owned:                       # procedural shapes' own meshes (lost ones too)
            for me in (*tpl.pieces, tpl.mesh):
                if me is not None and me.users == 0:
                    bpy.data.meshes.remove(me)




def part_margin(thin: float) -> float:
    """Collision margin of a part whose thinnest width is `thin`: MARGIN_FRACTION of it, at most
    COLLISION_MARGIN, at least 0.01 mm (Bullet needs a non-zero margin)."""
    return float(min(COLLISION_MARGIN, max(1e-5, MARGIN_FRACTION * thin)))


def _vertices(me: bpy.types.Mesh) -> np.ndarray:
    co = np.zeros(len(me.vertices) * 3, dtype=np.float32)
    me.vertices.foreach_get("co", co)
    return co.reshape(-1, 3).astype(np.float64)


def _center_of_mass(me: bpy.types.Mesh, pts: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """Volume centroid of a closed mesh (signed tetrahedra); the bounding-box centre if the mesh
    encloses no volume (open or flat)."""
    me.calc_loop_triangles()
    tris = np.zeros(len(me.loop_triangles) * 3, dtype=np.int64)
    me.loop_triangles.foreach_get("vertices", tris)
    if len(tris) == 0:
        return np.asarray(fallback, dtype=np.float64)
    a, b, c = (pts[tris.reshape(-1, 3)[:, k]] for k in range(3))
    vol6 = np.einsum("ij,ij->i", a, np.cross(b, c))           # 6 x signed volume per tetrahedron
    total = vol6.sum()
    extent = float(np.ptp(pts, axis=0).max()) if len(pts) else 0.0
    if not np.isfinite(total) or abs(total) < 1e-9 * max(extent, 1e-12) ** 3:
        return np.asarray(fallback, dtype=np.float64)
    return (vol6[:, None] * (a + b + c)).sum(axis=0) / (4.0 * total)


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    """Uniformly random rotation (Haar measure) from a normalised 4D Gaussian quaternion."""
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return np.array(Quaternion(q.tolist()).to_matrix())
