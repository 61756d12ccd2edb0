"""The Blender side of the procedural distractor shapes (the meshes and their rules: datapipe/shapes.py):
one mesh object per drawn size, with its convex collision pieces (core/objects.py makes one per
instance, and one at the largest size as the entry's template)."""
from __future__ import annotations

import bpy
import numpy as np

from .. import collision, shapes


def _mesh(name: str, verts: np.ndarray, faces: np.ndarray) -> bpy.types.Mesh:
    me = bpy.data.meshes.new(name)
    me.from_pydata(verts.tolist(), [], faces.tolist())
    me.update()
    return me


def make_shape(spec: dict, size, name: str, mesh_name: str, collection) -> tuple[bpy.types.Object, tuple, float]:
    """(object named `name` in `collection` with a new mesh `mesh_name`, the collision piece meshes
    (() for a convex kind: its own convex hull), the thinnest width of the collision shape in m)."""
    verts, faces = shapes.mesh(spec["kind"], size)
    obj = bpy.data.objects.new(name, _mesh(mesh_name, verts, faces))
    collection.objects.link(obj)
    pieces = shapes.convex_pieces(spec["kind"], size)
    thin = min(collision.min_width(pv) for pv, _ in pieces)
    if len(pieces) == 1:
        return obj, (), thin
    return obj, tuple(_mesh(f"{mesh_name}_piece{k:02d}", pv, pf) for k, (pv, pf) in enumerate(pieces)), thin
