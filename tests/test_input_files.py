"""Inputs that could hang or exhaust the machine, or end in a traceback (issue 33): each is refused by
`validate` with exit 2, naming the field, the file and (models_info.json) the object id, before a
byte of a FIFO or device is read. Before: a glTF buffer of /dev/zero grew `validate` to 22 GiB (killed,
exit 137), a FIFO buffer hung it forever, a FIFO preset or .blend was "not found", and a
models_info.json entry that is a number, null, 200,000 levels deep or with bad symmetries gave a
TypeError / RecursionError traceback, or passed validate to be refused by run under the wrong name."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from datapipe import config as C
from datapipe.errors import ConfigError
from datapipe.io.models import write_ply

CLI_TIMEOUT_S = 60        # a hang would be forever; the refusals take ~2 s (interpreter start-up)


def _preset(tmp_path, assets_dir, objects=None, **scene) -> str:
    d = C.default_config().to_dict()
    for o in d["objects"]:
        o["filepath"] = str(assets_dir / o["filepath"].rsplit("/", 1)[-1])
    if objects is not None:
        d["objects"] = objects
    d["scene"].update(scene)
    p = tmp_path / "preset.json"
    p.write_text(json.dumps(d))
    return str(p)


def _validate(preset: str) -> tuple[subprocess.CompletedProcess, float]:
    t = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "datapipe", "validate", preset], capture_output=True, text=True,
                       timeout=CLI_TIMEOUT_S)
    return r, time.perf_counter() - t


def _refused(preset: str, *fragments: str) -> str:
    r, _ = _validate(preset)
    assert r.returncode == 2 and "Traceback" not in r.stderr, (r.returncode, r.stderr[-2000:])
    for f in fragments:
        assert f in r.stderr, (f, r.stderr[-2000:])
    return r.stderr


def _gltf(tmp_path, uri: str, byte_length) -> str:
    p = tmp_path / "part.gltf"
    p.write_text(json.dumps({"asset": {"version": "2.0"}, "buffers": [{"uri": uri, "byteLength": byte_length}]}))
    return str(p)


def _in_process_seconds(preset: str, field: str, fragment: str) -> float:
    """Seconds load + validate take to refuse `preset` (after a first validate has imported the rules)."""
    C.default_config().problems(check_files=False)
    t = time.perf_counter()
    with pytest.raises(ConfigError) as e:
        C.load(preset).validate()
    seconds = time.perf_counter() - t
    hit = [p for p in e.value.problems if p.path == field]
    assert hit and fragment in hit[0].message and hit[0].fix, str(e.value)
    return seconds


@pytest.mark.skipif(not os.path.exists("/dev/zero"), reason="needs /dev/zero")
def test_gltf_buffer_on_dev_zero_is_refused_at_once(tmp_path, assets_dir):
    gltf = _gltf(tmp_path, "/dev/zero", 1e9)
    preset = _preset(tmp_path, assets_dir, objects=[{"filepath": gltf}])
    assert _in_process_seconds(preset, "objects[0].filepath", "character device, not a regular file") < 1.0
    _refused(preset, "objects[0].filepath", "buffers[0].uri", "/dev/zero", gltf)


def test_gltf_buffer_that_is_a_fifo_is_refused_at_once(tmp_path, assets_dir):
    os.mkfifo(tmp_path / "buf.bin")
    gltf = _gltf(tmp_path, "buf.bin", 1024)
    preset = _preset(tmp_path, assets_dir, objects=[{"filepath": gltf}])
    assert _in_process_seconds(preset, "objects[0].filepath", "FIFO (named pipe), not a regular file") < 1.0
    _refused(preset, "objects[0].filepath", "buffers[0].uri 'buf.bin'", "FIFO")


def test_gltf_buffer_shorter_than_its_byte_length(tmp_path, assets_dir):
    (tmp_path / "buf.bin").write_bytes(bytes(10))
    preset = _preset(tmp_path, assets_dir, objects=[{"filepath": _gltf(tmp_path, "buf%2Ebin", 1000)}])
    _in_process_seconds(preset, "objects[0].filepath", "holds 10 bytes, fewer than its byteLength 1,000")


def test_glb_json_chunk_buffers_are_checked(tmp_path, assets_dir):
    os.mkfifo(tmp_path / "ext.bin")
    doc = json.dumps({"asset": {"version": "2.0"}, "buffers": [{"byteLength": 0}, {"uri": "ext.bin",
                                                                                 "byteLength": 4}]}).encode()
    doc += b" " * (-len(doc) % 4)
    glb = tmp_path / "part.glb"
    glb.write_bytes(b"glTF" + (2).to_bytes(4, "little") + (20 + len(doc)).to_bytes(4, "little")
                    + len(doc).to_bytes(4, "little") + b"JSON" + doc)
    preset = _preset(tmp_path, assets_dir, objects=[{"filepath": str(glb)}])
    _in_process_seconds(preset, "objects[0].filepath", "buffers[1].uri 'ext.bin'")


def test_obj_material_library_or_texture_that_is_a_fifo(tmp_path, assets_dir):
    """Blender's OBJ importer hung (bpy 5.0.1) on a FIFO as the .mtl or as a texture the .mtl names."""
    tri = "v 0 0 0\nv 0.02 0 0\nv 0 0.02 0\nf 1 2 3\n"
    os.mkfifo(tmp_path / "fifo.mtl")
    os.mkfifo(tmp_path / "wood.png")
    (tmp_path / "ok.mtl").write_text("newmtl a\nmap_Kd -s 1 1 1 wood.png\n")
    (tmp_path / "a.obj").write_text("mtllib fifo.mtl\n" + tri)
    (tmp_path / "b.obj").write_text("mtllib ok.mtl\nusemtl a\n" + tri)
    (tmp_path / "c.obj").write_text("mtllib missing.mtl\n" + tri)       # missing: the importer goes on
    preset = _preset(tmp_path, assets_dir, objects=[{"filepath": str(tmp_path / n)} for n in ("a.obj", "b.obj",
                                                                                               "c.obj")])
    assert _in_process_seconds(preset, "objects[0].filepath", "mtllib 'fifo.mtl'") < 1.0
    problems = {p.path: p.message for p in C.load(preset).problems()}
    assert "map_Kd 'wood.png'" in problems["objects[1].filepath"] and "FIFO" in problems["objects[1].filepath"]
    assert "objects[2].filepath" not in problems


def test_mesh_preset_and_blend_fifos_are_not_regular_files(tmp_path, assets_dir):
    os.mkfifo(tmp_path / "part.obj")
    os.mkfifo(tmp_path / "scene.blend")
    preset = _preset(tmp_path, assets_dir, objects=[{"filepath": str(tmp_path / "part.obj")}],
                     blend_file=str(tmp_path / "scene.blend"))
    stderr = _refused(preset, "objects[0].filepath", "scene.blend_file")
    assert stderr.count("FIFO (named pipe), not a regular file") == 2 and "not found" not in stderr
    os.mkfifo(tmp_path / "fifo.json")
    stderr = _refused(str(tmp_path / "fifo.json"), "FIFO (named pipe), not a regular file")
    assert "not found" not in stderr


def test_read_regular_refuses_before_reading(tmp_path):
    from datapipe.errors import DataPipeError
    from datapipe.io.input_files import read_regular
    os.mkfifo(tmp_path / "f")
    t = time.perf_counter()
    with pytest.raises(DataPipeError, match="FIFO"):
        read_regular(tmp_path / "f", 100)                 # would block forever with a plain open()
    assert time.perf_counter() - t < 1.0
    (tmp_path / "big").write_bytes(bytes(101))
    with pytest.raises(DataPipeError, match="101 bytes, more than the 100"):
        read_regular(tmp_path / "big", 100)
    assert read_regular(tmp_path / "big", 200, head=7) == bytes(7)


# ------------------------------------------------------------------ BOP models_info.json

def _models(tmp_path, info_text: str):
    d = tmp_path / "models"
    d.mkdir()
    V = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]], float)
    write_ply(d / "obj_000001.ply", V, np.array([[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]))
    (d / "models_info.json").write_text(info_text)
    return d


GOOD = {"diameter": 14.2, "min_x": 0, "min_y": 0, "min_z": 0, "size_x": 10, "size_y": 10, "size_z": 10}
DEEP = "[" * 200_000 + "]" * 200_000


@pytest.mark.parametrize("info,fragment", [
    ('{"1": 5}', "object 1: the entry is 5"),
    ('{"1": null}', "object 1: the entry is null"),
    ('{"1": {"diameter": "big"}}', "object 1: diameter"),
    ('[1, 2]', "a JSON list"),
    ('{"one": {}}', "key 'one' is not an object id"),
    ('{"1": ' + DEEP + "}", "nested too deeply"),
    (json.dumps({"1": {**GOOD, "symmetries_discrete": "garbage"}}), "object 1.symmetries_discrete: expected a list"),
    (json.dumps({"1": {**GOOD, "symmetries_continuous": [{"axis": [math.nan, 0, 1], "offset": [0, 0, 0]}]}}),
     "object 1.symmetries_continuous[0]"),
    (json.dumps({"1": {**GOOD, "symmetries_discrete": [[1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, "x"]]}}),
     "object 1.symmetries_discrete[0]"),
])
def test_models_info_problems_are_found_by_validate(tmp_path, assets_dir, info, fragment):
    models = _models(tmp_path, info)
    preset = _preset(tmp_path, assets_dir, objects=[{"bop_models": str(models), "bop_obj_ids": []}])
    _in_process_seconds(preset, "objects[0].bop_models", str(models / "models_info.json"))
    _in_process_seconds(preset, "objects[0].bop_models", fragment)


@pytest.mark.parametrize("info,fragment", [
    ('{"1": 5}', "object 1: the entry is 5"),
    ('{"1": ' + DEEP + "}", "nested too deeply"),
    (json.dumps({"1": {**GOOD, "symmetries_discrete": "garbage"}}), "object 1.symmetries_discrete: expected a list"),
])
def test_models_info_problems_exit_2_from_the_cli(tmp_path, assets_dir, info, fragment):
    """The command a user runs: exit 2, the field, the file, the object id; no TypeError or
    RecursionError traceback, and bad symmetries no longer pass (exit 0 before)."""
    models = _models(tmp_path, info)
    preset = _preset(tmp_path, assets_dir, objects=[{"bop_models": str(models), "bop_obj_ids": []}])
    _refused(preset, "objects[0].bop_models", str(models / "models_info.json"), fragment, "(fix:")


def test_a_good_models_info_still_passes(tmp_path, assets_dir):
    sym = {"symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 0]}]}
    models = _models(tmp_path, json.dumps({"1": {**GOOD, **sym}}))
    cfg = C.load(_preset(tmp_path, assets_dir, objects=[{"bop_models": str(models), "bop_obj_ids": []}]))
    assert not [p for p in cfg.problems() if p.path.startswith("objects")]
