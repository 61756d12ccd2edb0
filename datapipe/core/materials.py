"""Surface materials in Blender: the Principled BSDF node tree of a material spec, assigned per part
instance. What a spec may hold (names, keys, value ranges, presets, the per-instance draws) is
datapipe/materials_spec.py, which has no bpy; its names are re-exported here for the builder's
callers.
"""
from __future__ import annotations

import zlib

from ..materials_spec import FILE, MATERIAL_PREFIX, PRESETS, draw, label, values   # noqa: F401 (PRESETS: callers)

NOISE_SCALE = 100.0              # noise texture scale in object space (1/m): ~1 cm features


# ------------------------------------------------------------------------------------------------
# Blender side (bpy imported where used)

def build(spec):
    """The bpy material for a preset name or dict (made once per run, reused by name); None for
    'file' (nothing is built)."""
    import bpy

    if spec == FILE:
        return None
    v = values(spec)
    key = label(spec) if isinstance(spec, str) else f"{label(spec)}_{zlib.crc32(repr(sorted(v.items())).encode()):08x}"
    name = MATERIAL_PREFIX + key
    mat = bpy.data.materials.get(name)
    if mat is not None:
        return mat
    mat, nt, bsdf = principled(name, v)
    color = list(v["base_color"])[:3] + [1.0]
    bsdf.inputs["Base Color"].default_value = color
    mat.diffuse_color = color                     # the viewport colour
    mat.roughness = float(v["roughness"])
    mat.metallic = float(v["metallic"])
    if v["variation"] > 0:
        _add_variation(nt, bsdf, float(v["variation"]), color, float(v["roughness"]))
    return mat


def principled(name: str, v: dict):
    """A new bpy material `name` whose Principled BSDF has `v`'s metallic, roughness, anisotropy and
    (when given) IOR and specular; its base colour is the caller's (a value, or a texture). Returns
    (material, node tree, BSDF). Also used by core/textures.py."""
    import bpy

    mat = bpy.data.materials.new(name)
    if mat.node_tree is None:            # bpy 4.x
        mat.use_nodes = True
    nt = mat.node_tree
    bsdf = next(n for n in nt.nodes if n.type == "BSDF_PRINCIPLED")
    bsdf.inputs["Metallic"].default_value = float(v["metallic"])
    bsdf.inputs["Roughness"].default_value = float(v["roughness"])
    bsdf.inputs["Anisotropic"].default_value = float(v["anisotropic"])
    if "ior" in v:
        bsdf.inputs["IOR"].default_value = float(v["ior"])
    if "specular" in v:
        bsdf.inputs["Specular IOR Level"].default_value = float(v["specular"])
    mat["datapipe_roughness"] = float(v["roughness"])   # read by structured_light.has_shiny_surface
    return mat, nt, bsdf


def _add_variation(nt, bsdf, amount: float, color, roughness: float) -> None:
    """Roughness and base colour x (1 +- amount) by a noise texture in object space (~1 cm features:
    machining marks, moulding texture)."""
    coord = nt.nodes.new("ShaderNodeTexCoord")
    noise = nt.nodes.new("ShaderNodeTexNoise")
    noise.inputs["Scale"].default_value = NOISE_SCALE
    nt.links.new(coord.outputs["Object"], noise.inputs["Vector"])
    f = nt.nodes.new("ShaderNodeMapRange")                      # noise 0..1 -> 1 - a .. 1 + a
    f.inputs["To Min"].default_value = 1.0 - amount
    f.inputs["To Max"].default_value = 1.0 + amount
    nt.links.new(noise.outputs[0], f.inputs["Value"])
    r = nt.nodes.new("ShaderNodeMath")
    r.operation = "MULTIPLY"
    r.use_clamp = True
    r.inputs[1].default_value = roughness
    nt.links.new(f.outputs[0], r.inputs[0])
    nt.links.new(r.outputs[0], bsdf.inputs["Roughness"])
    c = nt.nodes.new("ShaderNodeMix")
    c.data_type = "RGBA"
    c.blend_type = "MULTIPLY"
    c.inputs[0].default_value = 1.0                             # Factor (float)
    c.clamp_result = True
    nt.links.new(f.outputs[0], c.inputs[6])                     # A (RGBA) <- the factor, as grey
    c.inputs[7].default_value = color                           # B (RGBA)
    nt.links.new(c.outputs[2], bsdf.inputs["Base Color"])


def assign(obj, mat) -> None:
    """Give `obj` (a linked copy sharing its mesh with other instances) the material `mat` on
    every slot, linked to the object so other instances keep theirs."""
    if mat is None:
        return
    if not obj.material_slots:
        obj.data.materials.append(None)       # one mesh slot; its content is overridden per object
    for slot in obj.material_slots:
        slot.link = "OBJECT"
        slot.material = mat


def instance_specs(cfg, instances, scene_seed: int) -> dict:
    """{instance name: its material spec} (a list drawn per instance from the material stream)."""
    by_entry: dict[int, list] = {}
    for inst in instances:
        by_entry.setdefault(inst.entry_index, []).append(inst)
    specs = {}
    for i, insts in by_entry.items():
        for inst, spec in zip(insts, draw(cfg.objects[i].material, len(insts), scene_seed, i)):
            specs[inst.name] = spec
    return specs


def apply_to_instances(cfg, instances, scene_seed: int) -> list[str]:
    """Materials of this scene's part instances (per the config); returns each one's label."""
    labels = []
    specs = instance_specs(cfg, instances, scene_seed)
    for inst in instances:
        spec = specs[inst.name]
        assign(inst.obj, build(spec))
        labels.append(label(spec))
    return labels
