"""Materials in Blender: presets become Principled BSDF values, 'file' builds nothing, instances
sharing one mesh keep their own materials."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from datapipe.core import materials as M  # noqa: E402


def _bsdf(mat):
    return next(n for n in mat.node_tree.nodes if n.type == "BSDF_PRINCIPLED")


@pytest.mark.parametrize("name", sorted(M.PRESETS))
def test_presets_build_their_values(name):
    mat = M.build(name)
    b = _bsdf(mat)
    v = M.PRESETS[name]
    assert np.allclose(b.inputs["Base Color"].default_value[:3], v["base_color"], atol=1e-6)
    assert b.inputs["Metallic"].default_value == pytest.approx(v["metallic"])
    assert b.inputs["Roughness"].default_value == pytest.approx(v["roughness"])
    if "ior" in v:
        assert b.inputs["IOR"].default_value == pytest.approx(v["ior"])
    assert M.build(name) is mat                     # once per run, reused by name


def test_file_builds_nothing_and_variation_adds_noise():
    before = len(bpy.data.materials)
    assert M.build("file") is None and len(bpy.data.materials) == before
    mat = M.build({"name": "rough", "roughness": 0.4, "variation": 0.3})
    b = _bsdf(mat)
    assert b.inputs["Roughness"].is_linked and b.inputs["Base Color"].is_linked
    assert any(n.bl_idname == "ShaderNodeTexNoise" for n in mat.node_tree.nodes)
    assert mat.name.startswith(M.MATERIAL_PREFIX + "rough_")


def test_instances_sharing_a_mesh_keep_their_own_material():
    me = bpy.data.meshes.new("part")
    me.from_pydata([(0, 0, 0), (1, 0, 0), (0, 1, 0)], [], [(0, 1, 2)])
    own = bpy.data.materials.new("from_file")
    me.materials.append(own)
    a = bpy.data.objects.new("a", me)
    b = a.copy()
    c = a.copy()
    M.assign(a, M.build("steel"))
    M.assign(b, M.build("rubber"))
    M.assign(c, M.build("file"))
    assert a.material_slots[0].material.name == M.MATERIAL_PREFIX + "steel"
    assert b.material_slots[0].material.name == M.MATERIAL_PREFIX + "rubber"
    assert c.material_slots[0].material is own and me.materials[0] is own   # 'file': untouched
    bare = bpy.data.meshes.new("bare")
    d = bpy.data.objects.new("d", bare)
    M.assign(d, M.build("aluminium"))                # a mesh without slots gets one, overridden per object
    assert d.material_slots[0].material.name == M.MATERIAL_PREFIX + "aluminium"
