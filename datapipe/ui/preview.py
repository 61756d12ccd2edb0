"""Viewport helpers of the sidebar: previews (object entry, camera, projector) and the drop zone box.

Previews live in the collection "datapipe_preview"; each preview object is tagged with the custom
property "datapipe_preview" = "object" | "camera" | "projector", and removing a preview removes its
objects together with the data they alone used (meshes, cameras, lights, materials, images), so a
toggle on + off leaves `bpy.data` as it was. The drop zone is the object "drop_zone" (a wire cube
of half-extents `scene.drop_zone_scale` at `scene.drop_zone_loc`), the same object a .blend may
carry for the pipeline (`core.scene` reads its world bounding box).

Geometry comes from core so the previews show what a run will do: the importers and axis
conventions of `core.objects`, the projector pose and cone of `core.projector`.
"""
from __future__ import annotations

import math
import os
from pathlib import Path

import bpy
from mathutils import Matrix, Quaternion, Vector

from ..config import CameraPose, MESH_SUFFIXES
from ..core.scene import remove_unused_data
from ..errors import DataPipeError

COLLECTION = "datapipe_preview"
TAG = "datapipe_preview"
CAMERA_NAME = "datapipe_preview_camera"        # never "datapipe_camera": that one is the pipeline's
PROJECTOR_NAME = "datapipe_preview_projector"
DROP_ZONE_NAME = "drop_zone"                   # == core.scene.DROP_ZONE_NAME (checked by the tests)

_BOX_VERTS = [(sx, sy, sz) for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]
_BOX_FACES = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]


# ------------------------------------------------------------------------------------------------
# bookkeeping

def tagged(kind: str) -> list:
    return [o for o in bpy.data.objects if o.get(TAG) == kind]


def is_on(kind: str) -> bool:
    return any(o.get(TAG) == kind for o in bpy.data.objects)


def _collection(scene) -> bpy.types.Collection:
    coll = bpy.data.collections.get(COLLECTION)
    if coll is None:
        coll = bpy.data.collections.new(COLLECTION)
        coll.hide_render = True               # previews never appear in (or light) a run's renders
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    return coll


def _remove_data(data) -> None:
    """Remove an ID that nothing uses any more, and the materials/images only it used."""
    if data is None or data.users > 0:
        return
    materials = list(getattr(data, "materials", []) or [])
    remove_unused_data(data)
    for mat in materials:
        if mat is not None and mat.users == 0:
            images = []
            if mat.node_tree is not None:
                images = [n.image for n in mat.node_tree.nodes if getattr(n, "image", None) is not None]
            bpy.data.materials.remove(mat)
            for img in images:
                if img.users == 0:
                    bpy.data.images.remove(img)


def remove_objects(objects) -> None:
    for obj in list(objects):
        data = obj.data
        for child in list(obj.children):       # children of a preview are previews too
            remove_objects([child])
        bpy.data.objects.remove(obj, do_unlink=True)
        _remove_data(data)


def remove(kind: str) -> None:
    """Remove every preview object of `kind` and its data; drop the collection when it is empty."""
    if kind == "camera":
        remove("projector")                    # the projector preview hangs off the camera preview
    remove_objects(tagged(kind))
    coll = bpy.data.collections.get(COLLECTION)
    if coll is not None and len(coll.all_objects) == 0 and len(coll.children) == 0:
        bpy.data.collections.remove(coll)


def remove_all() -> None:
    for kind in ("object", "projector", "camera"):
        remove(kind)


# ------------------------------------------------------------------------------------------------
# object entry preview

def _preview_scale(entry) -> float:
    return float(entry.scale) * (0.001 if entry.source == "BOP" else 1.0)


def _first_bop_model(entry, index: int) -> str:
    from ..config import ObjectEntry
    from ..io.bop_models import bop_ids, ply_path
    ids = [int(t) for t in entry.bop_obj_ids.replace(",", " ").split() if t.isdigit()]
    probe = ObjectEntry(bop_models=bpy.path.abspath(entry.bop_models), bop_obj_ids=ids)
    return str(ply_path(probe.bop_models, bop_ids(probe, f"objects[{index}]")[0]))


def show_object(context, props, index: int) -> list:
    """Import object entry `index` into "datapipe_preview" at its scale; replaces an earlier one."""
    from ..core import objects as core_objects        # the pipeline's importers and axis conventions
    remove("object")
    if not 0 <= index < len(props.objects):
        raise DataPipeError("objects: no object entry selected (fix: add an entry and select it)")
    entry = props.objects[index]
    field = f"objects[{index}].filepath"
    path = bpy.path.abspath(entry.filepath) if entry.filepath else ""
    if entry.source == "BOP":          # the entry's first object (its PLY is in mm)
        path, field = _first_bop_model(entry, index), f"objects[{index}].bop_models"
    suffix = Path(path).suffix.lower()
    if not path:
        raise DataPipeError(f"{field}: empty (fix: choose a mesh file, {', '.join(MESH_SUFFIXES)})")
    kind = core_objects._IMPORTERS.get(suffix)
    if kind is None:
        raise DataPipeError(f"{field}: not a mesh file: {path} (fix: use one of {', '.join(MESH_SUFFIXES)})")
    if not os.path.isfile(path):
        raise DataPipeError(f"{field}: file not found: {path} (fix: check the path)")
    before = set(bpy.data.objects)
    before_data = {pool: set(pool) for pool in (bpy.data.meshes, bpy.data.materials, bpy.data.images,
                                                bpy.data.cameras, bpy.data.lights, bpy.data.collections)}
    layer = context.view_layer
    active = layer.active_layer_collection
    layer.active_layer_collection = layer.layer_collection
    try:
        core_objects._run_importer(kind, path)
    except RuntimeError as e:
        _remove_new(before, before_data)
        raise DataPipeError(f"{field}: cannot import {path}: {str(e).strip()} (fix: check the file)") from None
    finally:
        layer.active_layer_collection = active
    new = [o for o in bpy.data.objects if o not in before]
    if not any(o.type == "MESH" and len(o.data.vertices) > 0 for o in new):
        _remove_new(before, before_data)
        raise DataPipeError(f"{field}: {path} holds no mesh with vertices (fix: export the part as a mesh)")
    coll = _collection(context.scene)
    roots = [o for o in new if o.parent not in new]
    # importer-made collections (glTF scenes) are dropped; the objects move to the preview collection
    for o in new:
        for c in list(o.users_collection):
            c.objects.unlink(o)
        coll.objects.link(o)
        o.hide_render = True
        o[TAG] = "object"
        o["datapipe_entry"] = index
    for c in set(bpy.data.collections) - before_data[bpy.data.collections]:
        if c.name != COLLECTION and len(c.all_objects) == 0:
            bpy.data.collections.remove(c)
    s = _preview_scale(entry)
    centre = Vector(props.scene.drop_zone_loc)
    for o in roots:
        o.matrix_world = Matrix.Translation(centre) @ Matrix.Diagonal((s, s, s, 1.0)) @ o.matrix_world
    return new


def _remove_new(before, before_data) -> None:
    remove_objects([o for o in bpy.data.objects if o not in before])
    for pool, old in before_data.items():
        for idb in set(pool) - old:
            if idb.users == 0:
                pool.remove(idb)


def sync_object_scale(props) -> None:
    """Follow edits of the previewed entry's scale without re-importing."""
    objs = tagged("object")
    if not objs:
        return
    index = int(objs[0].get("datapipe_entry", -1))
    if not 0 <= index < len(props.objects):
        return
    s = _preview_scale(props.objects[index])
    for o in objs:
        if o.parent is None or o.parent.get(TAG) != "object":
            o.scale = (s, s, s)


# ------------------------------------------------------------------------------------------------
# camera and projector previews

def _apply_intrinsics(cam_data, scene, cfg) -> None:
    from ..core.camera import apply_intrinsics
    apply_intrinsics(cam_data, scene, cfg.camera)


def camera_object():
    objs = tagged("camera")
    return objs[0] if objs else None


def show_camera(context, props, pose: CameraPose | None = None):
    """Create (or update) the preview camera from the camera properties, at `pose` (default: the
    selected pose, else the Config's default pose)."""
    from .convert import props_to_config
    cfg = props_to_config(props)
    obj = camera_object()
    if obj is None:
        data = bpy.data.cameras.new(CAMERA_NAME)
        obj = bpy.data.objects.new(CAMERA_NAME, data)
        obj[TAG] = "camera"
        obj.hide_render = True
        _collection(context.scene).objects.link(obj)
        if context.scene.camera is None:
            context.scene.camera = obj
    _apply_intrinsics(obj.data, context.scene, cfg)
    if pose is None:
        poses = cfg.camera.poses
        i = props.camera.poses_index
        pose = poses[i] if 0 <= i < len(poses) else CameraPose()
    obj.rotation_mode = "QUATERNION"
    obj.location = pose.location
    obj.rotation_quaternion = Quaternion(pose.rotation).normalized()
    obj.scale = (1.0, 1.0, 1.0)
    return obj


def camera_pose(obj) -> CameraPose:
    """The object's world pose as a Config pose: location + unit quaternion (w, x, y, z)."""
    loc, rot, _ = obj.matrix_world.decompose()
    return CameraPose(location=list(loc), rotation=list(rot.normalized()))


def show_projector(context, props):
    """A spot light parented to the preview camera at the projector's pose, cone = projector image."""
    from .. import geometry                             # the pose and cone a run uses
    from .convert import props_to_config
    cam = camera_object()
    if cam is None:
        raise DataPipeError("projector preview: the camera preview is off (fix: turn on the camera preview "
                            "first, in the Camera panel)")
    cfg = props_to_config(props)
    objs = tagged("projector")
    if objs:
        obj = objs[0]
    else:
        data = bpy.data.lights.new(PROJECTOR_NAME, "SPOT")
        obj = bpy.data.objects.new(PROJECTOR_NAME, data)
        obj[TAG] = "projector"
        obj.hide_render = True
        _collection(context.scene).objects.link(obj)
    data = obj.data
    data.spot_blend = 0.0
    data.shadow_soft_size = 0.0
    data.show_cone = True
    try:
        data.spot_size = geometry.spot_size(cfg.projector)
    except DataPipeError:
        data.spot_size = math.radians(179.0)
    obj.parent = cam
    obj.matrix_parent_inverse = Matrix.Identity(4)
    obj.matrix_basis = Matrix([list(row) for row in geometry.projector_pose_blender(cfg.projector)])
    return obj


def sync(context) -> None:
    """Update callback target: bring live previews in line with the properties (cheap, no imports)."""
    scene = getattr(context, "scene", None)
    if scene is None or not hasattr(scene, "datapipe"):
        return
    props = scene.datapipe
    try:
        cam = camera_object()
        if cam is not None:
            from .convert import props_to_config
            _apply_intrinsics(cam.data, scene, props_to_config(props))
            if is_on("projector"):
                show_projector(context, props)
        sync_object_scale(props)
    except (DataPipeError, ValueError, ReferenceError):
        pass                                  # a half-edited value: the next edit syncs again


# ------------------------------------------------------------------------------------------------
# drop zone

def place_drop_zone(context, props):
    """Create or move the wire cube "drop_zone" to the drop zone properties."""
    s = props.scene
    obj = bpy.data.objects.get(DROP_ZONE_NAME)
    if obj is not None and obj.type != "MESH":
        raise DataPipeError(f"drop zone: the object {DROP_ZONE_NAME!r} is a {obj.type}, not a mesh (fix: "
                            "rename or delete it)")
    if obj is None:
        mesh = bpy.data.meshes.new(DROP_ZONE_NAME)
        mesh.from_pydata(_BOX_VERTS, [], _BOX_FACES)
        mesh.update()
        obj = bpy.data.objects.new(DROP_ZONE_NAME, mesh)
        context.scene.collection.objects.link(obj)
    elif context.scene not in obj.users_scene:
        context.scene.collection.objects.link(obj)
    obj.display_type = "WIRE"
    obj.hide_render = True
    obj.show_in_front = True
    # the unit cube spans [-1, 1]: object scale = half-extents; a foreign mesh is fitted by its bounds
    if len(obj.data.vertices) == 0:
        raise DataPipeError(f"drop zone: the mesh of {DROP_ZONE_NAME!r} is empty (fix: delete the object; "
                            "Place creates a new box)")
    lo = Vector([min(v.co[k] for v in obj.data.vertices) for k in range(3)])
    hi = Vector([max(v.co[k] for v in obj.data.vertices) for k in range(3)])
    half_mesh = (hi - lo) / 2
    centre_mesh = (hi + lo) / 2
    if min(half_mesh) <= 0:
        raise DataPipeError(f"drop zone: the mesh of {DROP_ZONE_NAME!r} is flat (fix: delete the object; "
                            "Place creates a new box)")
    scale = Vector([h / m for h, m in zip(s.drop_zone_scale, half_mesh)])
    obj.rotation_mode = "XYZ"
    obj.rotation_euler = (0.0, 0.0, 0.0)
    obj.scale = scale
    obj.location = Vector(s.drop_zone_loc) - Vector([c * k for c, k in zip(centre_mesh, scale)])
    return obj


def read_drop_zone(props) -> tuple[list[float], list[float], bool]:
    """Set the drop zone properties from the "drop_zone" object's world bounding box (as a run reads
    it). Returns (location, half-extents, rotated) - rotated: the box is not axis-aligned."""
    from ..core.scene import world_bounds
    obj = bpy.data.objects.get(DROP_ZONE_NAME)
    if obj is None:
        raise DataPipeError(f"drop zone: no object named {DROP_ZONE_NAME!r} (fix: click Place Drop Zone first, "
                            "or name a box object 'drop_zone')")
    bpy.context.view_layer.update()
    lo, hi = world_bounds(obj)
    half = [float(v) for v in (hi - lo) / 2]
    if min(half) <= 0:
        raise DataPipeError(f"drop zone: {DROP_ZONE_NAME!r} has a flat bounding box (half extents {half}) "
                            "(fix: give it size along x, y and z)")
    centre = [float(v) for v in (hi + lo) / 2]
    props.scene.drop_zone_loc = centre
    props.scene.drop_zone_scale = half
    rot = obj.matrix_world.to_quaternion()
    rotated = abs(abs(rot.w) - 1.0) > 1e-6
    return centre, half, rotated
