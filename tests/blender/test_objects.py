"""ObjectManager: one import per file per run, linked instances, deterministic names and pass
indices, non-overlapping placement, clean-up, model geometry, importers and their errors.

Ground truth comes from parsing the mesh files here, not from the code under test."""
import base64
import json
import subprocess
import sys
from itertools import combinations
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from datapipe.config import ObjectEntry, assets_dir, default_config  # noqa: E402
from datapipe.core.objects import ObjectManager  # noqa: E402
from datapipe.core.scene import BlendScene  # noqa: E402
from datapipe.errors import DataPipeError  # noqa: E402

ASSETS = assets_dir()


def parse_obj(path):
    """(vertices (V,3), faces [list of 0-based indices]) of a plain OBJ file."""
    verts, faces = [], []
    for line in Path(path).read_text().splitlines():
        t = line.split()
        if t and t[0] == "v":
            verts.append([float(x) for x in t[1:4]])
        elif t and t[0] == "f":
            faces.append([int(x.split("/")[0]) - 1 for x in t[1:]])
    return np.array(verts), faces


def setup(cfg):
    bs = BlendScene(cfg).setup()
    om = ObjectManager(cfg, bs).load_sources()
    return bs, om


def sphere_of(path, scale):
    """Bounding sphere (centre, radius) about the bounding-box centre, model coordinates."""
    v, _ = parse_obj(path)
    v = v * scale
    c = (v.min(0) + v.max(0)) / 2
    return c, np.linalg.norm(v - c, axis=1).max()


def test_each_file_imported_once_and_instances_share_mesh():
    cfg = default_config()
    cfg.objects.append(ObjectEntry(filepath=str(ASSETS / "peg.obj"), scale=2.0, name="bigpeg",
                                   min_instances=1, max_instances=1))   # same file, another entry
    bs, om = setup(cfg)
    assert om.import_count == 3                      # peg, nut, bracket: the peg file read once
    meshes = len(bpy.data.meshes)
    for seed in range(4):                            # several scenes
        insts = om.populate(np.random.default_rng(seed))
        assert om.import_count == 3
        assert len(bpy.data.meshes) == meshes        # no new mesh data per scene
        for inst in insts:
            tpl = om.templates[inst.entry_index].obj
            assert inst.obj.data == tpl.data          # linked copy of its template
            assert inst.obj.type == 'MESH' and inst.obj.rigid_body.type == 'ACTIVE'
            entry = cfg.objects[inst.entry_index]
            assert inst.obj.rigid_body.mass == pytest.approx(entry.mass)
            want = {"AUTO": "CONVEX_HULL"}.get(entry.collision_shape, entry.collision_shape)  # convex peg
            assert inst.shape == want and inst.obj.rigid_body.collision_shape == want
        om.clear()
    om.load_sources()                                # a second call does not re-import
    assert om.import_count == 3


def test_counts_names_pass_indices():
    cfg = default_config()
    bs, om = setup(cfg)
    seen_counts = set()
    for seed in range(6):
        insts = om.populate(np.random.default_rng(seed))
        by_entry = {}
        for inst in insts:
            by_entry.setdefault(inst.entry_index, []).append(inst)
        for i, entry in enumerate(cfg.objects):
            got = by_entry.get(i, [])
            assert entry.min_instances <= len(got) <= entry.max_instances
            seen_counts.add((i, len(got)))
            assert [x.name for x in got] == [f"{cfg.object_name(i)}_{k:03d}" for k in range(len(got))]
            assert all(x.obj.name == x.name for x in got)
            assert all(x.filename == str((ASSETS / Path(entry.filepath).name).resolve()) for x in got)
        idx = sorted(inst.obj.pass_index for inst in insts)
        assert idx == list(range(1, len(insts) + 1))
        assert all(inst.mask_index == inst.obj.pass_index for inst in insts)
        om.clear()
    assert len(seen_counts) > len(cfg.objects)       # counts do vary between scenes


def test_populate_is_deterministic():
    cfg = default_config()
    bs, om = setup(cfg)

    def snap(seed):
        insts = om.populate(np.random.default_rng(seed))
        out = {i.name: np.array(i.obj.matrix_world) for i in insts}
        om.clear()
        return out

    a, b, a2 = snap(11), snap(12), snap(11)
    assert a.keys() == a2.keys()
    assert all(np.allclose(a[k], a2[k], atol=1e-9) for k in a)
    assert a.keys() != b.keys() or any(not np.allclose(a[k], b[k]) for k in a)


def test_model_points_equal_file_vertices_times_scale():
    cfg = default_config()
    cfg.objects[0].scale = 2.5                       # peg, scale baked into the mesh
    bs, om = setup(cfg)
    for i, entry in enumerate(cfg.objects):
        v, faces = parse_obj(entry.filepath)
        pts = om.model_mesh(i)[0]
        assert pts.dtype == np.float64 and pts.shape == v.shape
        assert np.allclose(pts, v * entry.scale, atol=1e-6)
        assert np.allclose(np.array(om.templates[i].obj.matrix_world), np.eye(4))
        verts, tris, normals = om.model_mesh(i)
        assert np.allclose(verts, v * entry.scale, atol=1e-6)
        n_tris = sum(len(f) - 2 for f in faces)
        assert tris.shape == (n_tris, 3) and tris.dtype.kind == "i"
        assert {tuple(sorted(t)) for t in tris.tolist()} == {tuple(sorted(f)) for f in faces if len(f) == 3}
        assert np.allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-4)


def test_templates_hidden_and_out_of_view_layer():
    bs, om = setup(default_config())
    coll = bpy.data.collections["datapipe_templates"]
    assert coll.hide_render
    assert {o.name for o in coll.objects} == {"datapipe_template_peg", "datapipe_template_nut",
                                              "datapipe_template_bracket"}
    vl = bpy.context.view_layer
    assert not any(o.name.startswith("datapipe_template_") for o in vl.objects)
    assert all(o.rigid_body is None for o in coll.objects)


def test_initial_placement_does_not_overlap():
    cfg = default_config()
    cfg.objects[1].min_instances = cfg.objects[1].max_instances = 30     # nuts: several layers
    bs, om = setup(cfg)
    spheres = {i: sphere_of(e.filepath, e.scale) for i, e in enumerate(cfg.objects)}
    c, h = np.array(cfg.scene.drop_zone_loc), np.array(cfg.scene.drop_zone_scale)
    for seed in range(3):
        insts = om.populate(np.random.default_rng(seed))
        bpy.context.view_layer.update()
        centres, radii = [], []               # (float32 matrices: 1e-6 m tolerances)
        for inst in insts:
            sc, r = spheres[inst.entry_index]
            M = np.array(inst.obj.matrix_world)
            assert np.allclose(M[:3, :3] @ M[:3, :3].T, np.eye(3), atol=1e-5)   # a rotation, no scale
            p = M[:3, :3] @ sc + M[:3, 3]
            centres.append(p)
            radii.append(r)
            assert np.all(np.abs(p[:2] - c[:2]) <= h[:2] - r + 1e-6)       # inside the footprint
            assert p[2] - r >= c[2] - 1e-6                                 # above the zone's centre
        for a, b in combinations(range(len(insts)), 2):
            assert np.linalg.norm(centres[a] - centres[b]) >= radii[a] + radii[b] - 1e-6
        layers = {round(float(p[2]), 3) for p in centres}
        assert max(p[2] for p in centres) - min(p[2] for p in centres) > 0.03   # stacked upward
        assert len(layers) > 1
        om.clear()


def test_orientations_are_random():
    bs, om = setup(default_config())
    insts = om.populate(np.random.default_rng(3))
    z_axes = np.array([np.array(i.obj.matrix_world)[:3, 2] for i in insts])
    assert np.std(z_axes, axis=0).min() > 0.1


def test_clear_leaves_nothing_and_nothing_grows():
    bs, om = setup(default_config())
    counts = None
    for seed in range(5):
        insts = om.populate(np.random.default_rng(seed))
        names = [i.name for i in insts]
        om.clear()
        assert not [n for n in names if n in bpy.data.objects]
        assert len(bpy.data.collections["datapipe_objects"].objects) == 0
        now = (len(bpy.data.objects), len(bpy.data.meshes), len(bpy.data.collections),
               len(bpy.data.materials), len(bs.scene.rigidbody_world.collection.objects))
        if counts is None:
            counts = now
        assert now == counts


def _entry(path, **kw):
    return ObjectEntry(filepath=str(path), **kw)


def _load_error(path) -> str:
    """The DataPipeError that loading `path` as the only object entry raises, as text."""
    cfg = default_config()
    cfg.objects = [_entry(path)]
    bs = BlendScene(cfg).setup()
    with pytest.raises(DataPipeError) as e:
        ObjectManager(cfg, bs).load_sources()
    return str(e.value)


def test_file_without_mesh_is_an_error(tmp_path):
    p = tmp_path / "empty.obj"
    p.write_text("# nothing here\n")
    msg = _load_error(p)
    assert str(p) in msg and "fix" in msg
    assert "empty" not in {o.name for o in bpy.data.objects}


@pytest.mark.parametrize("name", ["part.fbx", "part.txt", "missing.obj"])
def test_unsupported_or_missing_file_is_an_error(tmp_path, name):
    p = tmp_path / name
    if not name.startswith("missing"):
        p.write_text("v 0 0 0\n")
    msg = _load_error(p)
    assert str(p) in msg and "objects[0].filepath" in msg


TET = np.array([[0.0, 0.0, 0.0], [0.02, 0.0, 0.0], [0.0, 0.03, 0.0], [0.0, 0.0, 0.04]])
TET_FACES = [(0, 2, 1), (0, 1, 3), (0, 3, 2), (1, 2, 3)]


def _write_ply(p):
    lines = ["ply", "format ascii 1.0", f"element vertex {len(TET)}", "property float x", "property float y",
             "property float z", f"element face {len(TET_FACES)}", "property list uchar int vertex_indices",
             "end_header"]
    lines += [" ".join(f"{x:.6f}" for x in v) for v in TET]
    lines += ["3 " + " ".join(map(str, f)) for f in TET_FACES]
    p.write_text("\n".join(lines) + "\n")


def _write_stl(p):
    lines = ["solid tet"]
    for f in TET_FACES:
        a, b, c = TET[list(f)]
        n = np.cross(b - a, c - a)
        n /= np.linalg.norm(n)
        lines += [f"facet normal {n[0]:.6f} {n[1]:.6f} {n[2]:.6f}", "outer loop"]
        lines += [f"vertex {x:.6f} {y:.6f} {z:.6f}" for x, y, z in (a, b, c)]
        lines += ["endloop", "endfacet"]
    p.write_text("\n".join(lines + ["endsolid tet"]) + "\n")


def _write_gltf(p):
    V = TET.astype(np.float32)
    idx = np.array(TET_FACES, dtype=np.uint16).ravel()
    buf = V.tobytes() + idx.tobytes()
    g = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0]}],
         "nodes": [{"mesh": 0, "translation": [0.1, 0.0, 0.0]}],
         "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
         "buffers": [{"byteLength": len(buf),
                      "uri": "data:application/octet-stream;base64," + base64.b64encode(buf).decode()}],
         "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": V.nbytes},
                         {"buffer": 0, "byteOffset": V.nbytes, "byteLength": idx.nbytes}],
         "accessors": [{"bufferView": 0, "componentType": 5126, "count": len(V), "type": "VEC3",
                        "min": V.min(0).tolist(), "max": V.max(0).tolist()},
                       {"bufferView": 1, "componentType": 5123, "count": len(idx), "type": "SCALAR"}]}
    p.write_text(json.dumps(g))


def _rows(a):
    return sorted(map(tuple, np.round(np.asarray(a), 6).tolist()))


@pytest.mark.parametrize("ext,writer", [(".ply", _write_ply), (".stl", _write_stl)])
def test_ply_and_stl_import_without_axis_change(tmp_path, ext, writer):
    p = tmp_path / f"tet{ext}"
    writer(p)
    cfg = default_config()
    cfg.objects = [_entry(p, scale=2.0, min_instances=2, max_instances=2)]
    bs, om = setup(cfg)
    assert om.import_count == 1
    assert _rows(om.model_mesh(0)[0]) == _rows(TET * 2.0)
    insts = om.populate(np.random.default_rng(0))
    assert [i.name for i in insts] == ["tet_000", "tet_001"]


def test_gltf_import_converts_y_up(tmp_path):
    p = tmp_path / "tet.gltf"
    _write_gltf(p)
    cfg = default_config()
    cfg.objects = [_entry(p, scale=2.0)]
    bs, om = setup(cfg)
    # glTF is Y-up: Blender maps file (x, y, z) to (x, -z, y); the node's translation is baked in
    expect = (TET + [0.1, 0.0, 0.0]) @ np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]]) * 2.0
    assert _rows(om.model_mesh(0)[0]) == _rows(expect)
    assert np.allclose(np.array(om.templates[0].obj.matrix_world), np.eye(4))


def test_obj_with_several_meshes_is_joined(tmp_path):
    p = tmp_path / "two.obj"
    p.write_text("o a\nv 0 0 0\nv 0.01 0 0\nv 0 0.01 0\nf 1 2 3\n"
                 "o b\nv 0 0 0.05\nv 0.01 0 0.05\nv 0 0.01 0.05\nf 4 5 6\n")
    cfg = default_config()
    cfg.objects = [_entry(p)]
    bs, om = setup(cfg)
    v, _ = parse_obj(p)
    assert _rows(om.model_mesh(0)[0]) == _rows(v)
    assert len(bpy.data.collections["datapipe_templates"].objects) == 1
    assert om.model_mesh(0)[1].shape == (2, 3)


def test_off_centre_origin_gets_a_centred_simulation_mesh(tmp_path):
    # a 2 cm cube whose vertices sit at 0..0.02: centre of mass (0.01, 0.01, 0.01), not the origin
    p = tmp_path / "cube.obj"
    v = [(x, y, z) for x in (0, 0.02) for y in (0, 0.02) for z in (0, 0.02)]
    faces = [(1, 2, 4, 3), (5, 7, 8, 6), (1, 5, 6, 2), (3, 4, 8, 7), (1, 3, 7, 5), (2, 6, 8, 4)]
    p.write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v) + "".join(
        "f " + " ".join(map(str, f)) + "\n" for f in faces))
    cfg = default_config()
    cfg.objects = [_entry(p)]
    bs, om = setup(cfg)
    me = om.templates[0].obj.data
    assert np.allclose(me["datapipe_com"], [0.01, 0.01, 0.01], atol=1e-6)
    sim = me["datapipe_sim_mesh"]
    co = np.array([tuple(x.co) for x in sim.vertices])
    assert np.allclose(co.min(0), -0.01, atol=1e-6) and np.allclose(co.max(0), 0.01, atol=1e-6)
    assert np.allclose(om.model_mesh(0)[0].min(0), 0.0, atol=1e-7)     # model frame unchanged


def test_duplicate_entry_names_are_an_error():
    cfg = default_config()
    cfg.objects.append(ObjectEntry(filepath=str(ASSETS / "peg.obj")))      # name defaults to 'peg' again
    bs = BlendScene(cfg).setup()
    with pytest.raises(DataPipeError, match=r"objects\[3\]\.name"):
        ObjectManager(cfg, bs).load_sources()


def test_reopening_a_saved_run_leaves_no_duplicates(tmp_path):
    cfg = default_config()
    bs, om = setup(cfg)
    om.populate(np.random.default_rng(0))               # saved mid-scene, instances and all
    path = tmp_path / "run.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bs, om = setup(cfg)
    clean = (len(bpy.data.objects), len(bpy.data.meshes))
    bpy.ops.wm.read_factory_settings(use_empty=True)
    cfg.scene.blend_file = str(path)
    bs, om = setup(cfg)
    assert (len(bpy.data.objects), len(bpy.data.meshes)) == clean
    assert not [x.name for x in [*bpy.data.objects, *bpy.data.meshes] if "." in x.name]
    insts = om.populate(np.random.default_rng(0))
    assert all(i.obj.name == i.name for i in insts)


# -- coacd missing (no wheel on some platforms, e.g. Intel macOS): a clear error, never ModuleNotFoundError

def _bracket_index(cfg) -> int:
    return next(i for i, o in enumerate(cfg.objects) if o.filepath.endswith("bracket.obj"))


def test_without_coacd_a_concave_part_is_refused_naming_the_field_and_the_fix(monkeypatch):
    from datapipe.core.preflight import check_meshes
    from datapipe.errors import ConfigError
    cfg = default_config()
    cfg.objects[_bracket_index(cfg)].collision_shape = "AUTO"    # clearly concave: convex pieces
    cfg.objects[0].collision_shape = "AUTO"                      # the peg is convex: a hull, no coacd
    field = f"objects[{_bracket_index(cfg)}].collision_shape"
    monkeypatch.setitem(sys.modules, "coacd", None)          # `import coacd` raises ImportError
    problems = check_meshes(cfg)
    assert [p.path for p in problems] == [field]
    assert "coacd" in problems[0].message and "CONVEX_HULL" in problems[0].fix
    bs = BlendScene(cfg).setup()
    with pytest.raises(ConfigError) as e:                    # the add-on's run reaches the objects directly
        ObjectManager(cfg, bs).load_sources()
    assert e.value.paths() == [field]
    cfg.objects[_bracket_index(cfg)].collision_shape = "CONVEX_HULL"     # the fix the message names
    assert check_meshes(cfg) == []


def test_cli_validate_without_coacd_exits_2_with_the_fix(tmp_path):
    from datapipe import config
    cfg = default_config()
    cfg.objects[_bracket_index(cfg)].collision_shape = "DECOMPOSED"
    config.save(cfg, tmp_path / "preset.json")
    code = ("import sys; sys.modules['coacd'] = None\n"
            "from datapipe import cli\n"
            f"raise SystemExit(cli.main(['validate', {str(tmp_path / 'preset.json')!r}]))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2, r.stdout + r.stderr
    assert ".collision_shape: the part is simulated as convex pieces" in r.stderr and "pip install coacd" in r.stderr
    assert "Traceback" not in r.stderr and "ModuleNotFoundError" not in r.stderr
