"""BlendScene: bin, floor, walls, occlusion box, key light and drop zone, checked against the config
analytically (expected boxes are computed here from the numbers, not from the code under test)."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from datapipe.config import default_config  # noqa: E402
from datapipe.core.scene import INSIDE_MARGIN, BlendScene, remove_unused_data, world_bounds  # noqa: E402

TOL = 1e-6


def _cfg(loc=(0.3, -0.2, 0.5), half=(0.2, 0.12, 0.08), t=0.02, make_bin=True):
    cfg = default_config()
    cfg.scene.drop_zone_loc = list(loc)
    cfg.scene.drop_zone_scale = list(half)
    cfg.scene.bin_wall_thickness = t
    cfg.scene.make_bin = make_bin
    cfg.render.light_power = 123.0
    return cfg


def _bounds(obj):
    bpy.context.view_layer.update()
    return world_bounds(obj)


def _static():
    return {o.name: o for o in bpy.data.collections["datapipe_static"].objects}


def test_bin_matches_config_analytically():
    cx, cy, cz = 0.3, -0.2, 0.5
    hx, hy, hz = 0.2, 0.12, 0.08
    t = 0.02
    bs = BlendScene(_cfg()).setup()
    assert np.allclose(bs.drop_zone_center, [cx, cy, cz]) and np.allclose(bs.drop_zone_half, [hx, hy, hz])
    floor_z = cz - hz
    assert bs.floor_z == pytest.approx(floor_z)
    st = _static()
    # floor: a slab of thickness t, top at floor_z, the ground under the bin, wider than any view
    lo, hi = _bounds(st["datapipe_floor"])
    assert lo[2] == pytest.approx(floor_z - t, abs=TOL) and hi[2] == pytest.approx(floor_z, abs=TOL)
    assert np.all(lo[:2] <= [cx - 2.0, cy - 2.0]) and np.all(hi[:2] >= [cx + 2.0, cy + 2.0])
    # four walls, thickness t, outside the footprint, as high as the zone (floor_z .. cz + hz)
    expect = {
        "datapipe_wall_xneg": ([cx - hx - t, cy - hy - t], [cx - hx, cy + hy + t]),
        "datapipe_wall_xpos": ([cx + hx, cy - hy - t], [cx + hx + t, cy + hy + t]),
        "datapipe_wall_yneg": ([cx - hx, cy - hy - t], [cx + hx, cy - hy]),
        "datapipe_wall_ypos": ([cx - hx, cy + hy], [cx + hx, cy + hy + t]),
    }
    for name, (elo, ehi) in expect.items():
        lo, hi = _bounds(st[name])
        assert np.allclose(lo, [*elo, floor_z], atol=TOL), name
        assert np.allclose(hi, [*ehi, cz + hz], atol=TOL), name
    # all passive colliders in the scene's rigid-body world, grey material on what renders
    rbw = bs.scene.rigidbody_world
    assert rbw is not None
    members = set(rbw.collection.objects)
    for obj in st.values():
        assert obj.rigid_body is not None and obj.rigid_body.type == 'PASSIVE', obj.name
        assert obj.rigid_body.collision_shape in ('BOX', 'MESH'), obj.name
        assert obj in members, obj.name
    for name in ["datapipe_floor", *expect]:
        mat = st[name].data.materials[0]
        assert tuple(mat.diffuse_color)[:3] == pytest.approx((0.5, 0.5, 0.5))
        assert not st[name].hide_render


def test_units_world_and_key_light():
    bs = BlendScene(_cfg()).setup()
    sc = bs.scene
    assert sc.unit_settings.system == 'METRIC' and sc.unit_settings.scale_length == 1.0
    bg = next(n for n in sc.world.node_tree.nodes if n.type == 'BACKGROUND')
    assert bg.inputs["Strength"].default_value == 0.0
    assert tuple(bg.inputs["Color"].default_value)[:3] == (0.0, 0.0, 0.0)
    assert bs.lights.name == "datapipe_lights"
    lights = list(bs.lights.objects)
    assert len(lights) == 1 and lights[0].type == 'LIGHT' and lights[0].data.type == 'AREA'
    assert lights[0].data.energy == pytest.approx(123.0)
    loc = np.array(lights[0].matrix_world.translation)
    assert loc[2] > 0.5 + 0.08                      # above the bin's top
    assert np.allclose(loc[:2], [0.3, -0.2])
    assert lights[0] not in set(bpy.data.collections["datapipe_static"].objects)


def test_floor_only_without_bin():
    bs = BlendScene(_cfg(make_bin=False)).setup()
    names = set(_static())
    assert names == {"datapipe_floor", "datapipe_occlusion_box"}
    assert bs.walls == []


def test_occlusion_box_hidden_collider_below_floor():
    cfg = _cfg()
    bs = BlendScene(cfg).setup()
    occ = _static()["datapipe_occlusion_box"]
    assert occ.hide_render is True
    assert occ.rigid_body is not None and occ.rigid_body.type == 'PASSIVE'
    assert occ in set(bs.scene.rigidbody_world.collection.objects)
    lo, hi = _bounds(occ)
    floor_lo, _ = _bounds(_static()["datapipe_floor"])
    assert hi[2] <= bs.floor_z - cfg.scene.bin_wall_thickness + TOL    # under the floor slab
    assert hi[2] - lo[2] >= 0.05                                     # thick
    # covers the whole floor
    assert np.all(lo[:2] <= floor_lo[:2] + TOL)
    floor_hi = _bounds(_static()["datapipe_floor"])[1]
    assert np.all(hi[:2] >= floor_hi[:2] - TOL)


def test_drop_zone_object_in_blend_wins(tmp_path):
    # a unit cube (vertices at +-1) scaled (0.2, 0.3, 0.4) at (1, 2, 3): half extents = scale
    me = bpy.data.meshes.new("drop_zone")
    me.from_pydata([(x, y, z) for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], [],
                   [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)])
    zone = bpy.data.objects.new("drop_zone", me)
    bpy.context.scene.collection.objects.link(zone)
    zone.location = (1.0, 2.0, 3.0)
    zone.scale = (0.2, 0.3, 0.4)
    path = tmp_path / "zone.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_factory_settings(use_empty=True)

    cfg = _cfg()                                    # its own drop zone differs
    cfg.scene.blend_file = str(path)
    bs = BlendScene(cfg).setup()
    assert bs.drop_zone_source == "blend"
    assert np.allclose(bs.drop_zone_center, [1, 2, 3], atol=1e-6)
    assert np.allclose(bs.drop_zone_half, [0.2, 0.3, 0.4], atol=1e-6)
    assert bs.floor_z == pytest.approx(2.6, abs=1e-6)
    lo, hi = _bounds(_static()["datapipe_floor"])
    assert hi[2] == pytest.approx(2.6, abs=1e-6)
    lo, hi = _bounds(_static()["datapipe_wall_xneg"])
    assert np.allclose(lo, [1 - 0.2 - 0.02, 2 - 0.3 - 0.02, 2.6], atol=1e-6)
    assert np.allclose(hi, [1 - 0.2, 2 + 0.3 + 0.02, 3.4], atol=1e-6)
    assert bpy.data.objects["drop_zone"].hide_render      # a marker, never rendered


def test_reopening_a_saved_run_rebuilds_without_duplicates(tmp_path):
    cfg = _cfg()
    BlendScene(cfg).setup()
    path = tmp_path / "run.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    n_objects = len(bpy.data.objects)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    cfg.scene.blend_file = str(path)
    BlendScene(cfg).setup()
    assert len(bpy.data.objects) == n_objects
    assert not [o.name for o in bpy.data.objects if "." in o.name]          # no 'datapipe_floor.001'
    assert len([c for c in bpy.data.collections if c.name.startswith("datapipe_static")]) == 1


def test_inside_bin():
    """The simulation's test of a settled part (core/simulation.py: over the footprint, else LEFT_BIN;
    not under floor_z, else FELL_THROUGH; both within INSIDE_MARGIN)."""
    bs = BlendScene(_cfg()).setup()               # footprint x 0.1..0.5, y -0.32..-0.08, floor 0.42

    def inside(p, margin=INSIDE_MARGIN):
        return bs.inside_footprint(p, margin) and p[2] >= bs.floor_z - margin

    assert inside([0.3, -0.2, 0.45])
    assert inside([0.49, -0.09, 0.42])
    assert not inside([0.52, -0.2, 0.45])          # beyond a wall
    assert not inside([0.3, -0.35, 0.45])
    assert not inside([0.3, -0.2, 0.40])           # under the floor
    assert inside([0.3, -0.2, 0.418])              # within the default margin
    assert not inside([0.3, -0.2, 0.418], margin=0.0)


def test_apply_lighting_sets_key_light_and_ambient():
    from datapipe.draws.lighting import blackbody_rgb
    bs = BlendScene(_cfg()).setup()
    home = np.array(bs.key_light.matrix_world.translation)
    draw = {"key_power": 77.0, "key_color_temperature": 3200.0, "key_color": list(blackbody_rgb(3200.0)),
            "key_size": 0.7, "key_offset": [0.1, -0.2, 0.0], "ambient": 0.15}
    bs.apply_lighting(draw)
    ld = bs.key_light.data
    assert ld.energy == pytest.approx(77.0) and ld.size == pytest.approx(0.7)
    assert np.allclose(tuple(ld.color), blackbody_rgb(3200.0), atol=1e-6)
    assert np.allclose(np.array(bs.key_light.matrix_world.translation), home + [0.1, -0.2, 0.0], atol=1e-6)
    bg = next(n for n in bs.scene.world.node_tree.nodes if n.type == 'BACKGROUND')
    assert bg.inputs["Strength"].default_value == pytest.approx(0.15)
    assert tuple(bg.inputs["Color"].default_value)[:3] == (1.0, 1.0, 1.0)
    draw.update(key_offset=[0.0, 0.0, 0.0], ambient=0.0)         # offsets are from home, not cumulative
    bs.apply_lighting(draw)
    assert np.allclose(np.array(bs.key_light.matrix_world.translation), home, atol=1e-6)


def test_apply_bin_rebuilds_to_the_drawn_size():
    """After a drawn bin the boxes match the drawn half size and wall height analytically, old boxes
    are gone (no duplicates, no orphan meshes), and the floor stays put."""
    from datapipe.draws.bin_shape import draw_bin
    cfg = _cfg()
    cfg.scene.bin_size_scale, cfg.scene.bin_wall_scale = [0.7, 1.3], [0.5, 1.5]
    bs = BlendScene(cfg).setup()
    floor_z, t = bs.floor_z, cfg.scene.bin_wall_thickness
    n_meshes = len(bpy.data.meshes)
    for k in range(2):
        draw = draw_bin(cfg.scene, bs.base_half, np.random.default_rng(k))
        bs.apply_bin(draw)
        hx, hy = draw["half_size"][:2]
        assert 0.7 * 0.2 <= hx <= 1.3 * 0.2 and 0.5 * 0.16 <= draw["wall_height"] <= 1.5 * 0.16
        assert bs.floor_z == pytest.approx(floor_z)
        lo, hi = _bounds(_static()["datapipe_wall_xpos"])
        assert np.allclose(lo, [0.3 + hx, -0.2 - hy - t, floor_z], atol=TOL)
        assert np.allclose(hi, [0.3 + hx + t, -0.2 + hy + t, floor_z + draw["wall_height"]], atol=TOL)
        assert len(_static()) == 6 and len(bpy.data.meshes) == n_meshes
        assert bs.inside_footprint([0.3 + hx - 1e-3, -0.2, 0.5]) and not bs.inside_footprint([0.3 + hx + 2e-3, -0.2, 0.5])


def test_remove_unused_data_leaves_no_orphan_and_keeps_shared_data():
    """The one orphan cleanup: a mesh, camera, light and curve whose object is gone are removed;
    data another object still uses is kept; None and other kinds are a no-op."""
    made = {"mesh": bpy.data.meshes.new("m"), "camera": bpy.data.cameras.new("c"),
            "light": bpy.data.lights.new("l", "POINT"), "curve": bpy.data.curves.new("cu", "CURVE")}
    for name, data in made.items():
        obj = bpy.data.objects.new(name, data)
        bpy.context.scene.collection.objects.link(obj)
        bpy.data.objects.remove(obj, do_unlink=True)
        assert remove_unused_data(data)
    assert not (bpy.data.meshes or bpy.data.cameras or bpy.data.lights or bpy.data.curves)
    shared = bpy.data.meshes.new("shared")
    a, b = bpy.data.objects.new("a", shared), bpy.data.objects.new("b", shared)
    bpy.data.objects.remove(a, do_unlink=True)
    assert not remove_unused_data(shared) and shared.name in bpy.data.meshes    # b still uses it
    bpy.data.objects.remove(b, do_unlink=True)
    assert remove_unused_data(shared) and len(bpy.data.meshes) == 0
    assert not remove_unused_data(None)
