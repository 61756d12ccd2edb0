"""Object entries from a BOP models folder (made here in BOP's layout: mm PLY + models_info.json
with symmetries): expansion, validation with the field and the fix, exported symmetries."""
from __future__ import annotations

import json

import numpy as np
import pytest

from datapipe import config as C
from datapipe.errors import ConfigError
from datapipe.io.bop_models import expand_bop_objects, models_symmetries, planned_obj_ids
from datapipe.io.models import diameter, write_ply

from test_symmetry import load_obj_mm

# BOP ids as a dataset might number them (ITODD-like: not 1..n)
BOP_PARTS = {7: "nut", 12: "peg", 30: "bracket"}
FLIP_Z = [1.0, 0, 0, 0, 0, -1.0, 0, 0, 0, 0, -1.0, 0, 0, 0, 0, 1.0]


def make_bop_models(folder):
    """A BOP models folder of the three shipped parts, in mm, with hand-written symmetries."""
    folder.mkdir(parents=True, exist_ok=True)
    info = {}
    for obj_id, name in BOP_PARTS.items():
        V, F = load_obj_mm(name)
        write_ply(folder / f"obj_{obj_id:06d}.ply", V, F, binary=False)
        lo, hi = V.min(0), V.max(0)
        info[str(obj_id)] = {"diameter": diameter(V), "min_x": lo[0], "min_y": lo[1], "min_z": lo[2],
                             "size_x": hi[0] - lo[0], "size_y": hi[1] - lo[1], "size_z": hi[2] - lo[2]}
    info["7"]["symmetries_discrete"] = [FLIP_Z]
    info["12"]["symmetries_continuous"] = [{"axis": [0, 0, 1], "offset": [0, 0, 0]}]
    (folder / "models_info.json").write_text(json.dumps(info))
    return folder


def bop_config(models, **entry):
    cfg = C.default_config()
    cfg.objects = [C.ObjectEntry(bop_models=str(models), **entry)]
    return cfg


def test_expansion_keeps_ids_symmetries_and_settings(tmp_path):
    models = make_bop_models(tmp_path / "models")
    cfg = bop_config(models, bop_obj_ids=[30, 7], max_instances=3, mass=0.02)
    cfg.objects.append(C.ObjectEntry(filepath=str(models / "obj_000012.ply"), scale=0.001))
    cfg.validate()
    assert planned_obj_ids(cfg) == [("objects[0] (obj_id 30)", 30), ("objects[0] (obj_id 7)", 7), ("objects[1]", 3)]
    x = expand_bop_objects(cfg)
    assert [cfg.objects[0].bop_models] == [str(models)]                 # the original is unchanged
    assert [x.obj_id(i) for i in range(3)] == [30, 7, 3]
    assert [x.object_name(i) for i in range(3)] == ["obj_000030", "obj_000007", "obj_000012"]
    assert x.objects[0].filepath == str(models / "obj_000030.ply") and x.objects[0].scale == 0.001
    assert x.objects[1].max_instances == 3 and x.objects[1].mass == 0.02
    assert x.objects[1].symmetries == {"symmetries_discrete": [FLIP_Z]}
    assert x.objects[0].symmetries == {}                                # the bracket's entry has none
    assert x.objects[2].symmetries == "auto"
    assert expand_bop_objects(x).objects == x.objects                   # idempotent
    x.validate()
    # all ids when none are listed; the name prefixes them
    y = expand_bop_objects(bop_config(models, name="itodd"))
    assert [y.object_name(i) for i in range(3)] == ["itodd_000007", "itodd_000012", "itodd_000030"]


def test_exported_symmetries_copied_given_or_detected(tmp_path):
    models = make_bop_models(tmp_path / "models")
    cfg = bop_config(models)
    cfg.objects.append(C.ObjectEntry(filepath=str(C.assets_dir() / "nut.obj"), name="nut2", obj_id=40))
    cfg.objects.append(C.ObjectEntry(filepath=str(C.assets_dir() / "peg.obj"), name="peg2", obj_id=41,
                                     symmetries="none"))
    x = expand_bop_objects(cfg)
    meshes = {x.obj_id(i): load_obj_mm(n) for i, n in enumerate(["nut", "peg", "bracket", "nut", "peg"])}
    meshes = {k: (v / 1000.0, f) for k, (v, f) in meshes.items()}
    s = models_symmetries(x, meshes)
    assert s[7] == {"symmetries_discrete": [FLIP_Z]}                     # the source's, not detected
    assert s[12] == {"symmetries_continuous": [{"axis": [0.0, 0.0, 1.0], "offset": [0.0, 0.0, 0.0]}]}
    assert s[30] == {}
    assert len(s[40]["symmetries_discrete"]) == 11 and "symmetries_continuous" not in s[40]    # detected
    assert s[41] == {}


@pytest.mark.parametrize("entry, field, words", [
    ({"bop_models": "nowhere"}, "objects[0].bop_models", "no such folder"),
    ({"bop_models": "EMPTY"}, "objects[0].bop_models", "has no models_info.json"),
    ({"bop_obj_ids": [7, 99]}, "objects[0].bop_obj_ids", "[99] not in"),
    ({"bop_obj_ids": [12], "rm": 12}, "objects[0].bop_obj_ids", "has no obj_000012.ply"),
    ({"bop_obj_ids": [7], "filepath": "x.obj"}, "objects[0].filepath", "together with bop_models"),
    ({"symmetries": {"symmetries_discrete": [[1, 2]]}}, "objects[0].symmetries.symmetries_discrete[0]",
     "16 numbers"),
    ({"symmetries": "maybe"}, "objects[0].symmetries", "unknown value"),
    ({"symmetries": {"tolerance": 2}}, "objects[0].symmetries.tolerance", "got 2"),
])
def test_bad_entries_name_the_field_and_the_fix(tmp_path, entry, field, words):
    models = make_bop_models(tmp_path / "models")
    (tmp_path / "EMPTY").mkdir()
    entry = dict(entry)
    if "rm" in entry:
        (models / f"obj_{entry.pop('rm'):06d}.ply").unlink()
    entry.setdefault("bop_models", str(models))
    entry["bop_models"] = str(tmp_path / entry["bop_models"]) if entry["bop_models"] in ("nowhere", "EMPTY") \
        else entry["bop_models"]
    cfg = C.default_config()
    cfg.objects = [C.ObjectEntry(**entry)]
    with pytest.raises(ConfigError) as e:
        cfg.validate()
    hits = [p for p in e.value.problems if p.path == field]
    assert hits and words in hits[0].message and hits[0].fix, [str(p) for p in e.value.problems]


def test_duplicate_ids_across_entries(tmp_path):
    models = make_bop_models(tmp_path / "models")
    cfg = bop_config(models, bop_obj_ids=[7])
    cfg.objects.append(C.ObjectEntry(filepath=str(C.assets_dir() / "nut.obj"), obj_id=7))
    with pytest.raises(ConfigError, match=r"objects\[1\].obj_id: obj_id 7 is also the id of objects\[0\]"):
        cfg.validate()


def test_preset_json_round_trip(tmp_path):
    models = make_bop_models(tmp_path / "ds" / "models")
    preset = tmp_path / "ds" / "p.json"
    d = C.default_config().to_dict()
    d["objects"] = [{"bop_models": "models", "bop_obj_ids": [7, 12, 30], "max_instances": 2}]
    preset.write_text(json.dumps(d))
    cfg = C.load(preset)
    assert cfg.objects[0].bop_models == str(models.resolve())
    assert [k for _, k in planned_obj_ids(cfg)] == [7, 12, 30]
