"""Drawn textures in Blender (`scene.textures`): the material of one draw of draws/textures.py, built
on the target's own Principled BSDF values (its material spec's roughness, metallic, IOR), with the
base colour (and for an image set roughness and normal) from the texture.

Coordinates: the bin's walls and the floor use world position (one continuous texture over the
bin); parts use object coordinates (the texture moves with the part). Either is scaled by
1 / feature_size, so Blender's texture scale of 1 is one feature per feature_size metres. Image
sets are box-projected (parts have no UVs that DataPipe could trust), blended over 0.2 at the
box's edges.

The RGB and the fringe renders see the same material: they are view layers of one scene. Each
scene's textured materials replace the last scene's (`remove_unused`), so a long run does not
collect them.
"""
from __future__ import annotations

import zlib

from . import materials

PREFIX = "datapipe_tex_"
BIN_DEFAULT = {"base_color": [0.5, 0.5, 0.5], "roughness": 0.6}   # = scene.py's built-in bin grey
PART_DEFAULT = {"base_color": [0.8, 0.8, 0.8], "roughness": 0.5}  # a part's "file": Principled defaults
BOX_BLEND = 0.2


def build(spec, draw: dict, *, world_space: bool, default: dict, tag: str):
    """A new bpy material: `spec`'s Principled values (`default` for "file") with `draw`'s texture."""
    import bpy

    v = materials.values(default if spec == materials.FILE else spec)
    key = zlib.crc32(repr((sorted(v.items()), sorted((k, repr(x)) for k, x in draw.items()), world_space)).encode())
    name = f"{PREFIX}{tag}_{key:08x}"
    mat = bpy.data.materials.get(name)
    if mat is not None:
        return mat
    mat, nt, bsdf = materials.principled(name, v)
    bright = list(draw["colors"][0])[:3] + [1.0]
    mat.diffuse_color = bright
    vec = _coordinates(nt, world_space, float(draw["feature_size"]))
    if draw["kind"] == "image":
        _image_set(nt, bsdf, vec, draw["set"])
    else:
        color = _procedural(nt, vec, draw)
        nt.links.new(color, bsdf.inputs["Base Color"])
    return mat


def _coordinates(nt, world_space: bool, feature_size: float):
    """The texture vector: world position or object coordinates (m) / feature_size."""
    if world_space:
        src = nt.nodes.new("ShaderNodeNewGeometry").outputs["Position"]
    else:
        src = nt.nodes.new("ShaderNodeTexCoord").outputs["Object"]
    sc = nt.nodes.new("ShaderNodeVectorMath")
    sc.operation = "SCALE"
    sc.inputs["Scale"].default_value = 1.0 / feature_size
    nt.links.new(src, sc.inputs[0])
    return sc.outputs["Vector"]


def _mix(nt, fac, a, b):
    """Colour a where fac = 0, b where fac = 1 (RGBA mix, clamped factor)."""
    m = nt.nodes.new("ShaderNodeMix")
    m.data_type = "RGBA"
    m.clamp_factor = True
    nt.links.new(fac, m.inputs[0])
    m.inputs[6].default_value = a
    m.inputs[7].default_value = b
    return m.outputs[2]


def _procedural(nt, vec, draw: dict):
    """The base colour socket of a procedural draw: its texture between the two drawn colours."""
    bright = list(draw["colors"][0])[:3] + [1.0]
    dark = list(draw["colors"][1])[:3] + [1.0]
    q, kind = float(draw["param"]), draw["kind"]
    N = nt.nodes
    if kind == "noise":               # blotches: detail 1..9 octaves, the value stretched to use both colours
        t = N.new("ShaderNodeTexNoise")
        t.inputs["Scale"].default_value = 1.0
        t.inputs["Detail"].default_value = 1.0 + 8.0 * q
        nt.links.new(vec, t.inputs["Vector"])
        r = N.new("ShaderNodeMapRange")          # noise Fac clusters around 0.5: 0.3..0.7 -> 0..1
        r.inputs["From Min"].default_value = 0.3
        r.inputs["From Max"].default_value = 0.7
        nt.links.new(t.outputs["Fac"], r.inputs["Value"])
        return _mix(nt, r.outputs["Result"], bright, dark)
    if kind == "voronoi":             # cells, each one shade between the colours; randomness = param
        t = N.new("ShaderNodeTexVoronoi")
        t.inputs["Scale"].default_value = 1.0
        t.inputs["Randomness"].default_value = q
        nt.links.new(vec, t.inputs["Vector"])
        sep = N.new("ShaderNodeSeparateColor")
        nt.links.new(t.outputs["Color"], sep.inputs[0])
        return _mix(nt, sep.outputs[0], bright, dark)
    if kind == "wave":                # bands (wood, brushed stripes): distortion 0..10
        t = N.new("ShaderNodeTexWave")
        t.inputs["Scale"].default_value = 1.0
        t.inputs["Distortion"].default_value = 10.0 * q
        nt.links.new(vec, t.inputs["Vector"])
        return _mix(nt, t.outputs["Fac"], bright, dark)
    if kind == "brick":               # bricks in the bright colour, mortar in the dark, mortar 2..12%
        t = N.new("ShaderNodeTexBrick")
        t.inputs["Scale"].default_value = 1.0
        t.inputs["Color1"].default_value = bright
        t.inputs["Color2"].default_value = bright
        t.inputs["Mortar"].default_value = dark
        t.inputs["Mortar Size"].default_value = 0.02 + 0.1 * q
        nt.links.new(vec, t.inputs["Vector"])
        return t.outputs["Color"]
    if kind == "checker":
        t = N.new("ShaderNodeTexChecker")
        t.inputs["Scale"].default_value = 1.0
        t.inputs["Color1"].default_value = bright
        t.inputs["Color2"].default_value = dark
        nt.links.new(vec, t.inputs["Vector"])
        return t.outputs["Color"]
    raise ValueError(f"unknown texture kind {kind!r}")


def _image(nt, vec, path: str, colour: bool):
    img = load_image(path)
    if not colour:
        img.colorspace_settings.name = "Non-Color"
    t = nt.nodes.new("ShaderNodeTexImage")
    t.image = img
    t.projection = "BOX"
    t.projection_blend = BOX_BLEND
    nt.links.new(vec, t.inputs["Vector"])
    return t


def _image_set(nt, bsdf, vec, s: dict) -> None:
    """A texture set: colour -> base colour, roughness -> roughness, normal -> a tangent-space
    normal map (a DirectX map's green flipped to OpenGL's convention)."""
    nt.links.new(_image(nt, vec, s["color"], True).outputs["Color"], bsdf.inputs["Base Color"])
    if "roughness" in s:
        nt.links.new(_image(nt, vec, s["roughness"], False).outputs["Color"], bsdf.inputs["Roughness"])
    if "normal" in s:
        col = _image(nt, vec, s["normal"], False).outputs["Color"]
        if s.get("normal_dx_green"):
            sep = nt.nodes.new("ShaderNodeSeparateColor")
            inv = nt.nodes.new("ShaderNodeMath")
            inv.operation = "SUBTRACT"
            inv.inputs[0].default_value = 1.0
            comb = nt.nodes.new("ShaderNodeCombineColor")
            nt.links.new(col, sep.inputs[0])
            nt.links.new(sep.outputs[1], inv.inputs[1])
            nt.links.new(sep.outputs[0], comb.inputs[0])
            nt.links.new(inv.outputs[0], comb.inputs[1])
            nt.links.new(sep.outputs[2], comb.inputs[2])
            col = comb.outputs[0]
        nm = nt.nodes.new("ShaderNodeNormalMap")
        nt.links.new(col, nm.inputs["Color"])
        nt.links.new(nm.outputs["Normal"], bsdf.inputs["Normal"])


IMAGE_TAG = "datapipe_loaded"      # on the images DataPipe loaded: only those are ever removed


def load_image(path: str):
    """The bpy image of `path`: one already loaded is reused (and left alone by `remove_unused`
    when it was not ours), a new one is tagged as DataPipe's."""
    import bpy
    before = set(bpy.data.images)
    img = bpy.data.images.load(str(path), check_existing=True)
    if img not in before:
        img[IMAGE_TAG] = True
    return img


def remove_unused() -> None:
    """Remove the textured materials no object uses any more (the last scene's) and the images
    DataPipe loaded that nothing uses (never one of the open file's own)."""
    import bpy
    for mat in [m for m in bpy.data.materials if m.name.startswith(PREFIX) and m.users == 0]:
        bpy.data.materials.remove(mat)
    for img in [i for i in bpy.data.images if i.users == 0 and i.get(IMAGE_TAG)]:
        bpy.data.images.remove(img)
