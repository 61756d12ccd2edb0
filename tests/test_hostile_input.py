"""Hostile presets from issue 21 (a generated-preset run found them): each is refused with the field's
path and a fix, through the real loaders (a JSON file, an original-layout pickle) and the CLI
(`validate` and `run`: exit 2, no traceback, nothing written). Before, each was a traceback:
ValueError (NUL), UnicodeEncodeError (lone surrogate), OverflowError (10**400 in a material),
AssertionError (periods of a million), RecursionError (a material nested 950 deep)."""
import copy
import json
import os
import pickle
import struct
import subprocess
import sys

import pytest

from datapipe import config as C
from datapipe.errors import ConfigError
from datapipe.text_rules import MAX_ID_NAME_BYTES, name_problem, path_problem


def _base(assets_dir) -> dict:
    d = C.default_config().to_dict()
    for o in d["objects"]:                      # relative paths: resolved against the preset's folder
        o["filepath"] = str(assets_dir / o["filepath"].rsplit("/", 1)[-1])
    return d


def _nested(depth: int):
    v = "steel"
    for _ in range(depth):
        v = [v]
    return v


def _set(d: dict, dotted: str, value) -> dict:
    d = copy.deepcopy(d)
    keys = [int(k) if k.isdigit() else k for k in dotted.replace("[", ".").replace("]", "").split(".")]
    target = d
    for k in keys[:-1]:
        target = target[k]
    target[keys[-1]] = value
    return d


def _sl(d: dict, periods) -> dict:
    d = _set(d, "structured_light.enabled", True)
    return _set(d, "structured_light.periods", periods)


# (field set in the JSON preset, value, the path the error must name, a fragment of its message)
JSON_CASES = [
    ("scene.blend_file", "\u0000.blend", "scene.blend_file", "NUL"),
    ("objects[0].filepath", "a\u0000.obj", "objects[0].filepath", "NUL"),
    ("objects[0].filepath", "\ud800.obj", "objects[0].filepath", "surrogate"),
    ("output.path", "out\u0000put", "output.path", "NUL"),
    ("output.path", "out/{frame}", "output.path", "brace"),      # Blender 5 would skip every write
    ("objects[0].material", {"roughness": 10**400}, "objects[0].material", "roughness"),
    ("objects[0].material", {"ior": int("9" * 401)}, "objects[0].material", "ior"),
    ("scene.bin_material", _nested(950), "scene.bin_material", "nested"),
    ("objects[0].name", "\ud800", "objects[0].name", "surrogate"),
    ("objects[0].name", "peg\u0000x", "objects[0].name", "NUL"),
    ("objects[0].name", "peg\nx", "objects[0].name", "control character"),
    ("objects[0].name", "p" * (MAX_ID_NAME_BYTES - 3), "objects[0].name", "63 bytes"),
    ("objects[0].material", {"name": "\ud800"}, "objects[0].material", "surrogate"),
    ("objects[0].name", "datapipe_template_x", "objects[0].name", "prefix"),
]
PERIOD_CASES = [([1000003, 999983], "3 px per fringe"), ([2**62 + 1, 2**62 - 1], "3 px per fringe"),
                ([1, 8, 3000], "3 px per fringe")]


def _write_json(tmp_path, d) -> str:
    p = tmp_path / "preset.json"
    p.write_text(json.dumps(d))                 # ensure_ascii: NUL and lone surrogates as \u escapes
    return str(p)


def _assert_refused(path: str, expect_path: str, fragment: str):
    with pytest.raises(ConfigError) as ei:
        C.load(path).validate()
    assert expect_path in ei.value.paths(), str(ei.value)
    problem = next(p for p in ei.value.problems if p.path == expect_path)
    assert fragment in problem.message and problem.fix, problem


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "datapipe", *args], capture_output=True, text=True)


def _assert_cli_refuses(tmp_path, preset: str, expect_path: str):
    out = tmp_path / "out"
    for args in (("validate", preset), ("run", preset, "--out", str(out))):
        r = _cli(*args)
        assert r.returncode == 2, (args, r.stderr[-2000:])
        assert expect_path in r.stderr and "(fix:" in r.stderr, r.stderr
        assert "Traceback" not in r.stderr, r.stderr
    assert not out.exists()                     # refused before anything is written


@pytest.mark.parametrize("field,value,expect_path,fragment", JSON_CASES)
def test_json_preset_refused_naming_the_field(tmp_path, assets_dir, field, value, expect_path, fragment):
    preset = _write_json(tmp_path, _set(_base(assets_dir), field, value))
    _assert_refused(preset, expect_path, fragment)


@pytest.mark.parametrize("periods,fragment", PERIOD_CASES)
def test_periods_beyond_the_projector_are_refused(tmp_path, assets_dir, periods, fragment):
    """The real limit: 3 projector px per fringe; [2**62+1, 2**62-1] were 'duplicates' (float
    comparison), [1000003, 999983] an AssertionError in the lattice code."""
    preset = _write_json(tmp_path, _sl(_base(assets_dir), periods))
    _assert_refused(preset, "structured_light.periods", fragment)


@pytest.mark.parametrize("field,value,expect_path", [
    ("scene.blend_file", "\u0000.blend", "scene.blend_file"),
    ("objects[0].filepath", "\ud800.obj", "objects[0].filepath"),
    ("objects[0].material", {"roughness": 10**400}, "objects[0].material"),
    ("scene.bin_material", _nested(950), "scene.bin_material"),
    ("objects[0].name", "\ud800", "objects[0].name"),
])
def test_cli_refuses_without_traceback(tmp_path, assets_dir, field, value, expect_path):
    _assert_cli_refuses(tmp_path, _write_json(tmp_path, _set(_base(assets_dir), field, value)), expect_path)


def test_cli_refuses_huge_periods(tmp_path, assets_dir):
    _assert_cli_refuses(tmp_path, _write_json(tmp_path, _sl(_base(assets_dir), [1000003, 999983])),
                        "structured_light.periods")


def _legacy_file(tmp_path, filepath: str) -> str:
    cfg = C.Config(objects=[C.ObjectEntry(filepath="x.obj")])
    d = C.to_legacy_dict(cfg)
    d["objects"]["objects_list"][0]["filepath"] = filepath
    p = tmp_path / "inputs.pickle"
    p.write_bytes(pickle.dumps(d))
    return str(p)


@pytest.mark.parametrize("filepath,fragment", [("a\u0000.obj", "NUL"), ("\ud800.obj", "surrogate")])
def test_legacy_pickle_paths_refused(tmp_path, filepath, fragment):
    preset = _legacy_file(tmp_path, filepath)
    _assert_refused(preset, "objects[0].filepath", fragment)
    _assert_cli_refuses(tmp_path, preset, "objects[0].filepath")


def test_pickle_with_an_impossible_length_gives_the_reason(tmp_path):
    """A BINBYTES8 of 2^62 bytes: 'cannot read the pickle: ' with no reason before (a MemoryError)."""
    p = tmp_path / "huge.pickle"
    p.write_bytes(b"\x80\x04\x8e" + struct.pack("<Q", 2**62) + b"x")
    with pytest.raises(ConfigError, match="declares a value larger than the memory"):
        C.load(p)
    (tmp_path / "cut.pickle").write_bytes(pickle.dumps({"camera": {"focal_length": 16.0}})[:-4])
    with pytest.raises(ConfigError) as ei:
        C.load(tmp_path / "cut.pickle")
    assert "cannot read the pickle (" in str(ei.value) and "()" not in str(ei.value)
    r = _cli("validate", str(p))
    assert r.returncode == 2 and "<pickle>" in r.stderr and "Traceback" not in r.stderr


def test_json_integer_beyond_python_digit_limit(tmp_path):
    (tmp_path / "big.json").write_text('{"scene": {"seed": ' + "7" * 5000 + "}}")
    with pytest.raises(ConfigError, match="cannot read a number"):
        C.load(tmp_path / "big.json")


def test_blend_file_header_checked_without_blender(tmp_path, assets_dir):
    """A file named .blend that is no Blender file is refused by validate() itself; one with a
    Blender header but a broken body is the Blender preflight's (tests/blender/test_preflight_input.py)."""
    (tmp_path / "notes.blend").write_bytes(b"hello, not a blend file")
    d = _set(_base(assets_dir), "scene.blend_file", str(tmp_path / "notes.blend"))
    _assert_refused(_write_json(tmp_path, d), "scene.blend_file", "not a Blender file")
    (tmp_path / "ok.blend").write_bytes(b"BLENDER-v300" + bytes(100))     # the header passes here
    d = _set(_base(assets_dir), "scene.blend_file", str(tmp_path / "ok.blend"))
    assert "scene.blend_file" not in [p.path for p in C.load(_write_json(tmp_path, d)).problems()]


def test_name_rules():
    assert name_problem("peg") is None
    assert name_problem("é" * 29 + "a", suffix="_000") is None          # 59 + 4 = 63 bytes: fits
    assert name_problem("é" * 30, suffix="_000") is not None            # 60 + 4: Blender 4.x would cut it
    assert name_problem("bolt M6 (zinc)") is None
    assert path_problem("\udc80.obj") is None      # a surrogate escape: a non-UTF-8 byte of a real file name
    assert path_problem("dir/ part.obj") is None


def test_file_stem_too_long_for_a_name_says_to_set_name(tmp_path, assets_dir):
    long = tmp_path / ("x" * 70 + ".obj")
    long.write_text((assets_dir / "peg.obj").read_text())
    cfg = C.default_config()
    cfg.objects[0].filepath, cfg.objects[0].name = str(long), ""
    p = {q.path: q for q in cfg.problems()}["objects[0].name"]
    assert "taken from the file name" in p.message and "objects[0].name" in p.fix


def test_out_argument_with_braces_is_refused_before_anything_is_written(tmp_path):
    """validate said OK and `run --out 'o{x}'` wrote manifest.json, run.json, models/ and a scene
    folder before compat.set_file_output_path refused the path (Blender 5 path templates)."""
    out = tmp_path / "o{x}"
    r = _cli("run", str(C.presets_dir() / "default.json"), "--out", str(out))
    assert r.returncode == 2 and "--out" in r.stderr and "brace" in r.stderr and "Traceback" not in r.stderr
    assert not out.exists()


def test_validate_ok_on_a_file_name_that_is_not_utf8(tmp_path, assets_dir):
    """A preset named with a non-UTF-8 byte (Python: a surrogate escape) printed its OK line with a
    UnicodeEncodeError traceback on a strict UTF-8 terminal."""
    name = os.fsdecode(b"preset\xff.json")
    (tmp_path / name).write_text(json.dumps(_base(assets_dir)))
    r = subprocess.run([sys.executable, "-m", "datapipe", "validate", str(tmp_path / name)], capture_output=True,
                       env={**os.environ, "PYTHONIOENCODING": "utf-8:strict"})
    assert r.returncode == 0 and b"Traceback" not in r.stderr, r.stderr[-1500:]
    assert b"preset\\xff.json: OK" in r.stdout


def test_symlink_loops_are_a_field_error(tmp_path, assets_dir):
    """Path.resolve() raised RuntimeError('Symlink loop ...') from config.resolve_paths (Python 3.11)."""
    os.symlink("loop.obj", tmp_path / "loop.obj")
    os.symlink("b.blend", tmp_path / "a.blend")
    os.symlink("a.blend", tmp_path / "b.blend")
    d = _set(_set(_base(assets_dir), "objects[1].filepath", "loop.obj"), "scene.blend_file", "a.blend")
    preset = _write_json(tmp_path, d)
    _assert_refused(preset, "objects[1].filepath", "symbolic link to nothing")
    _assert_refused(preset, "scene.blend_file", "symbolic link to nothing")
    _assert_cli_refuses(tmp_path, preset, "objects[1].filepath")


def test_json_with_a_byte_order_mark_loads(tmp_path, assets_dir):
    """Windows editors save UTF-8 with a BOM; json.loads refused it ('Unexpected UTF-8 BOM')."""
    (tmp_path / "bom.json").write_bytes(b"\xef\xbb\xbf" + json.dumps(_base(assets_dir)).encode())
    C.load(tmp_path / "bom.json").validate()


def _deep_key_pickle(depth: int) -> bytes:
    """{((...(1,),...),): 2} with `depth` tuples, as opcodes (pickle.dumps itself refuses the depth)."""
    return b"\x80\x02}K\x01" + b"\x85" * depth + b"K\x02s."


def test_a_deep_tuple_key_in_a_pickle_is_refused_not_a_segfault(tmp_path):
    """Unpickling builds it in a loop, but hashing it as a dict key recursed in C: the process died
    with a segmentation fault (exit -11), no message. Run in a subprocess so a regression cannot take
    the test run down."""
    p = tmp_path / "deep.pickle"
    p.write_bytes(_deep_key_pickle(200_000))
    r = _cli("validate", str(p))
    assert r.returncode == 2, (r.returncode, r.stderr[-500:])
    assert "<pickle>" in r.stderr and "nested more than" in r.stderr and "Traceback" not in r.stderr
    with pytest.raises(ConfigError, match="unknown section"):          # shallow: the usual path
        C.load_legacy_pickle(_deep_key_pickle(3))


def test_pickle_depth_counts_what_the_unpickler_builds():
    from datapipe.config.pickle_depth import pickle_depth
    legacy = C.to_legacy_dict(C.default_config())
    assert {pickle_depth(pickle.dumps(legacy, protocol=p), 32) for p in range(6)} == {5}
    cyclic = []
    cyclic.append(cyclic)                                 # memo: the list fetched again and appended
    assert pickle_depth(pickle.dumps(cyclic), 32) == 2
    deep = leaf = []
    for _ in range(40):
        leaf.append([])
        leaf = leaf[0]
    assert pickle_depth(pickle.dumps(deep), 32) == 33     # stops one past the limit
    assert pickle_depth(_deep_key_pickle(200_000), C.MAX_PICKLE_NESTING) == C.MAX_PICKLE_NESTING + 1
    assert pickle_depth(b"\x80\x04\x8e" + struct.pack("<Q", 2**62) + b"x", 32) is None   # the unpickler's case


def test_a_camera_pose_far_away_is_blamed_on_the_pose(tmp_path, assets_dir):
    """A pose 2^63 m away passed validate and the mesh preflight blamed objects[i].scale ("0 px on
    the camera image"); the pose is the field at fault."""
    d = _base(assets_dir)
    d["camera"]["poses"][0]["location"] = [2.0**63, 0.0, 1.0]
    _assert_refused(_write_json(tmp_path, d), "camera.poses[0].location", "beyond camera.clip_end")
    cfg = C.load(_write_json(tmp_path, d))
    assert not [p for p in cfg.problems() if "scale" in p.path]
    d["camera"]["poses"][0]["location"] = [0.0, 0.0, 9.0]          # near enough: depth can reach the bin
    assert "camera.poses[0].location" not in [p.path for p in C.load(_write_json(tmp_path, d)).problems()]


@pytest.mark.parametrize("focal,sensor", [(1e-300, 1e308), (1e-300, 1e9)])
def test_absurd_lens_values_give_the_error_and_no_numpy_warning(tmp_path, assets_dir, focal, sensor):
    """A bin_view camera with these lenses printed a numpy RuntimeWarning (divide by zero / overflow
    in the sampler rules) before the field-of-view error."""
    d = _base(assets_dir)
    d["camera"].update(focal_length=focal, sensor_width=sensor)
    d["camera"]["sampler"]["kind"] = "bin_view"
    r = _cli("validate", _write_json(tmp_path, d))
    assert r.returncode == 2 and "camera.focal_length" in r.stderr and "(fix:" in r.stderr, r.stderr[-1500:]
    assert "Warning" not in r.stderr and "Traceback" not in r.stderr, r.stderr[-1500:]
