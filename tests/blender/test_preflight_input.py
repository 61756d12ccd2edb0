"""Issue 21: what `validate` accepts, `run` can start. The Blender preflight reads scene.blend_file with
Blender's own reader and refuses part counts whose convex hulls cannot fit the bin, before anything is
written; names at the byte limit validate accepts come out of a real run whole.

In-process `cli.main` calls, as tests/blender/test_cli_safety.py does (one message, exit 2, no
traceback, no output folder)."""
import copy
import json
import math
import os

import bpy
import pytest

from datapipe import cli, config as C
from datapipe.core.preflight import check_blend, check_meshes
from datapipe.checks.part_fit import RANDOM_PACKING_MAX, bin_volume
from datapipe.text_rules import MAX_ID_NAME_BYTES


def main(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, out, err


def _refused_by_both(capsys, tmp_path, cfg, field, fragment):
    p = tmp_path / "p.json"
    C.save(cfg, p)
    for cmd in (["validate", p], ["run", p, "--out", tmp_path / "o"]):
        code, out, err = main(capsys, *cmd)
        assert code == 2 and field in err and fragment in err, err
        assert "OK" not in out
    assert not (tmp_path / "o").exists()


def test_garbage_blend_is_refused_before_anything_is_written(tmp_path, capsys):
    """`BLENDER-v300` + random bytes: validate said OK, and `run` wrote manifest.json and run.json
    before Blender failed with 'Missing DNA block'."""
    blend = tmp_path / "broken.blend"
    blend.write_bytes(b"BLENDER-v300" + os.urandom(4096))
    cfg = C.default_config()
    cfg.scene.blend_file = str(blend)
    assert not cfg.problems()                     # the header is a Blender one: only Blender can tell
    _refused_by_both(capsys, tmp_path, cfg, "scene.blend_file", "Missing DNA block")
    code, _, err = main(capsys, "run", tmp_path / "p.json", "--out", tmp_path / "o", "--ray")   # Ray or not
    assert code == 2 and "Missing DNA block" in err and not (tmp_path / "o").exists()


def test_a_real_blend_passes_and_the_open_scene_stays(tmp_path):
    bpy.ops.mesh.primitive_cube_add()
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_uv_sphere_add()
    cfg = C.default_config()
    cfg.scene.blend_file = str(blend)
    assert check_blend(cfg) == []
    assert [o.name for o in bpy.data.objects] == ["Sphere"]           # nothing opened or linked
    assert len(bpy.data.libraries) == 0 and bpy.data.filepath == ""


def test_an_object_with_an_instance_name_in_the_blend_is_refused(tmp_path):
    """populate() stops at an existing 'peg_001' (instance names must be deterministic): found by
    the preflight now, from the .blend's object list or the open scene's."""
    bpy.ops.mesh.primitive_cube_add()
    bpy.context.active_object.name = "peg_001"
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    cfg = C.default_config()
    problems = check_blend(cfg)                                      # the open scene has it
    assert [p.path for p in problems] == ["objects[0].name"] and "'peg_001'" in problems[0].message
    bpy.ops.wm.read_factory_settings(use_empty=True)
    assert check_blend(cfg) == []
    cfg.scene.blend_file = str(blend)
    assert [p.path for p in check_blend(cfg)] == ["objects[0].name"]
    cfg.objects[0].max_instances = 1                                 # only peg_000 is made: no clash
    assert check_blend(cfg) == []


def _crowded(n_entries: int, max_instances: int) -> C.Config:
    cfg = C.default_config()
    cfg.objects = [copy.deepcopy(cfg.objects[i % 3]) for i in range(n_entries)]
    for i, o in enumerate(cfg.objects):
        o.name, o.min_instances, o.max_instances = f"part{i:02d}", 1, max_instances
    return cfg


def test_part_counts_that_cannot_fit_the_bin_are_refused(tmp_path, capsys):
    """40 entries x 500 instances (20,000 parts in the 30 x 20 x 20 cm bin) passed validate."""
    cfg = _crowded(40, 500)
    assert not cfg.problems()
    _refused_by_both(capsys, tmp_path, cfg, "objects[", "max_instances")
    code, _, err = main(capsys, "validate", tmp_path / "p.json")
    assert "20000 parts" in err and "lower" in err


def test_the_volume_bound_is_the_packing_limit():
    """Refused just above RANDOM_PACKING_MAX of the bin's volume, accepted at it. The peg is a
    24-gon prism (radius 12 mm, 50 mm long: its OBJ), hull volume 22.4 cm^3 (its box: 28.8)."""
    cfg = C.default_config()
    cfg.objects = [cfg.objects[0]]                 # the peg
    v = 24 / 2 * 0.012 ** 2 * math.sin(2 * math.pi / 24) * 0.05
    fits = int(RANDOM_PACKING_MAX * bin_volume(cfg.scene) / v)       # 0.74 x 12 litres: 397 pegs
    assert bin_volume(cfg.scene) == pytest.approx(0.3 * 0.2 * 0.2)
    cfg.objects[0].max_instances = fits
    assert check_meshes(cfg) == []                 # (over MAX_INSTANCES is validate's, not this check's)
    cfg.objects[0].max_instances = fits + 1
    problems = check_meshes(cfg)
    assert [p.path for p in problems] == ["objects[0].max_instances"]
    assert f"to {fits} or less" in problems[0].fix
    cfg.scene.bin_size_scale = [0.5, 1.0]          # the smallest bin a scene can draw counts: 1/4 the floor
    cfg.objects[0].max_instances = fits // 4 + 1
    assert [p.path for p in check_meshes(cfg)] == ["objects[0].max_instances"]
    cfg.objects[0].max_instances = fits // 4 - 1
    assert check_meshes(cfg) == []


def test_a_huge_scale_is_refused_with_or_without_a_blend(tmp_path):
    """scale 1e308: the bin check raised OverflowError (scale ** 3; found by benchmarks/fuzz_presets.py),
    and with a .blend (no drop zone size check) a 3.5e306 m nut passed."""
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"), copy=True)
    cfg = C.default_config()
    for scale, blend, expect in ((1e308, None, ("objects[1].scale", "drop zone's diagonal")),
                                 (1e308, "scene.blend", ("objects[1].scale", "camera sees")),
                                 (1000.0, "scene.blend", ("objects[1].scale", "camera sees")),
                                 (100.0, "scene.blend", None),      # a 3.5 m nut: the .blend's zone is unknown here
                                 (10.0, None, ("objects[1].max_instances", "litres"))):   # 4 x 9.4 litres
        cfg.objects[1].scale = scale
        cfg.scene.blend_file = str(tmp_path / blend) if blend else None
        problems = check_meshes(cfg)                 # (1e308: no OverflowError from the bin check)
        assert [(p.path, expect[1] in p.message) for p in problems] == ([(expect[0], True)] if expect else [])


def test_names_at_the_byte_limit_come_out_of_a_run_whole(tmp_path, capsys):
    """validate accepts names up to 63 bytes of UTF-8 with the instance suffix; the run must
    give exactly those names to the objects and the annotations (no cut, no '.001')."""
    name = "é" * ((MAX_ID_NAME_BYTES - 4) // 2) + "a" * ((MAX_ID_NAME_BYTES - 4) % 2)
    assert len(name.encode()) == MAX_ID_NAME_BYTES - 4
    cfg = C.default_config()
    cfg.objects = [cfg.objects[0]]
    cfg.objects[0].name, cfg.objects[0].min_instances, cfg.objects[0].max_instances = name, 2, 2
    cfg.scene.num_renders = cfg.scene.max_renders_per_scene = cfg.scene.min_renders_per_scene = 1
    cfg.camera.resolution = [32, 24]
    cfg.render.samples = 1
    cfg.render.denoise = False
    cfg.structured_light.enabled = False
    cfg.output.overview = False
    p = tmp_path / "p.json"
    C.save(cfg, p)
    code, out, err = main(capsys, "validate", p)
    assert code == 0, err
    code, out, err = main(capsys, "run", p, "--out", tmp_path / "o", "--quiet")
    assert code == 0, err
    scene = json.loads((tmp_path / "o" / "scene.0001" / "scene.json").read_text())
    assert sorted(o["name"] for o in scene["objects"]) == [f"{name}_000", f"{name}_001"]


def test_the_add_on_checks_and_runs_through_the_same_preflight(ui_props, tmp_path):
    """Check Settings said 'ready to run' without the Blender checks; Run then failed in its first
    scene. Both refuse now, naming the field, and write nothing."""
    d = ui_props
    bpy.ops.datapipe.initialize(preset="builtin:default")
    d.output.path = str(tmp_path / "out")
    for o in d.objects:
        o.max_instances = 500                # 1,500 parts, 24 litres of hulls, in a 12 litre bin
    for op in (bpy.ops.datapipe.check, lambda: bpy.ops.datapipe.run(blocking=True)):
        with pytest.raises(RuntimeError, match=r"objects\[0\]\.max_instances: a scene may hold 1500 parts"):
            op()
    for o in d.objects:
        o.max_instances = 2
    blend = tmp_path / "broken.blend"
    blend.write_bytes(b"BLENDER-v300" + os.urandom(4096))
    d.scene.blend_file = str(blend)
    for op in (bpy.ops.datapipe.check, lambda: bpy.ops.datapipe.run(blocking=True)):
        with pytest.raises(RuntimeError, match=r"scene\.blend_file: Blender cannot read .*Missing DNA block"):
            op()
    assert not (tmp_path / "out").exists()
