"""Object-coordinate maps (render output "object_coords"): per pixel, the object-frame XYZ (m) of
the part surface the pixel's centre ray hits; NaN where it hits no part.

Dense-correspondence pose networks train on them. They come from shader AOVs (Cycles' arbitrary
output variables), not from the z-buffer: every part material gets an AOV Output node fed by the
Texture Coordinate node's "Object" output (the instance's own coordinates = model coordinates in
metres: the template mesh holds the scaled model, the instance's matrix_world is its pose), and a
second AOV that is 1 on parts. A map built so is independent of the depth pass, and a test can
check one against the other.

Cycles averages AOVs over all samples of a pixel (the pixel filter's footprint), so at edges a
multi-sample value would mix two surfaces into a point on neither. The AOVs are therefore taken
from a layer rendered with one sample, whose sample is the pixel centre like the depth and object
index passes: the native layer itself when it renders one sample (no RGB output), else the view
layer COORDS_LAYER, rendered in the same render call with one sample, no denoising.

A part without a material gets DEFAULT_MATERIAL: a diffuse BSDF of 0.8 grey, what Cycles renders
for a surface without a material, so the RGB does not change.
"""
from __future__ import annotations

import bpy

COORDS_AOV = "dp_object_xyz"         # COLOR AOV: object coordinates (m)
HIT_AOV = "dp_object_hit"            # VALUE AOV: 1 on parts (0 where a material lacks the nodes)
COORDS_LAYER = "datapipe_coords"
DEFAULT_MATERIAL = "datapipe_default_surface"
_NODE_TAG = "datapipe_object_coords"  # name prefix of the nodes added to a material


def add_aovs(view_layer) -> None:
    """Declare the two AOVs on a view layer (their Render Layers sockets appear with them)."""
    have = {a.name for a in view_layer.aovs}
    for name, kind in ((COORDS_AOV, "COLOR"), (HIT_AOV, "VALUE")):
        if name not in have:
            aov = view_layer.aovs.add()
            aov.name, aov.type = name, kind


def coords_layer(scene):
    """The one-sample view layer for the AOVs (made once; kept out of every other render call by
    the structured-light calls, which switch off all layers but theirs)."""
    vl = scene.view_layers.get(COORDS_LAYER) or scene.view_layers.new(COORDS_LAYER)
    vl.use = True
    vl.samples = 1
    if hasattr(vl, "cycles"):
        vl.cycles.use_denoising = False
    for flag in ("use_pass_z", "use_pass_normal", "use_pass_object_index"):
        setattr(vl, flag, False)
    add_aovs(vl)
    return vl


def _default_material():
    mat = bpy.data.materials.get(DEFAULT_MATERIAL)
    if mat is None:
        mat = bpy.data.materials.new(DEFAULT_MATERIAL)
        nt = mat.node_tree
        nt.nodes.clear()
        out = nt.nodes.new("ShaderNodeOutputMaterial")
        diffuse = nt.nodes.new("ShaderNodeBsdfDiffuse")
        diffuse.inputs["Color"].default_value = (0.8, 0.8, 0.8, 1.0)
        nt.links.new(diffuse.outputs["BSDF"], out.inputs["Surface"])
    return mat


def _add_nodes(mat) -> None:
    nt = mat.node_tree
    if nt is None or nt.nodes.get(_NODE_TAG + "_xyz") is not None:
        return
    tc = nt.nodes.new("ShaderNodeTexCoord")
    tc.name = _NODE_TAG + "_coord"
    xyz = nt.nodes.new("ShaderNodeOutputAOV")
    xyz.name, xyz.aov_name = _NODE_TAG + "_xyz", COORDS_AOV
    nt.links.new(tc.outputs["Object"], xyz.inputs["Color"])
    hit = nt.nodes.new("ShaderNodeOutputAOV")
    hit.name, hit.aov_name = _NODE_TAG + "_hit", HIT_AOV
    hit.inputs["Value"].default_value = 1.0
    for k, n in enumerate((tc, xyz, hit)):
        n.location = (-900 + 200 * k, -600)


def prepare_parts(objects) -> None:
    """Give every material of the parts `objects` the AOV nodes (each material once; idempotent)."""
    for obj in objects:
        if obj.type != "MESH":
            continue
        if not obj.material_slots:
            obj.data.materials.append(_default_material())
        for slot in obj.material_slots:
            if slot.material is None:
                slot.material = _default_material()
            _add_nodes(slot.material)
