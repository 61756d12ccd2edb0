"""The golden snapshot's comparison (tests/snapshot_compare.py) on the stored snapshot itself, with
planted changes: what another CPU changes (last digits, the measured spread) passes, a real change
of behaviour (a pose 0.1 mm or 1e-4 rad off, one visible pixel, an SL class 25 px off, a renamed
part, a new field) fails and is named. No bpy."""
import copy
import json
from pathlib import Path

import numpy as np
import pytest

from snapshot_compare import compare_texts, differences

SNAPSHOTS = Path(__file__).resolve().parent / "snapshots" / "demo_small"


def _stored(name: str):
    return json.loads((SNAPSHOTS / name).read_text())


@pytest.fixture
def scene():
    return _stored("scene.0002.json")


def _first_object(d):
    return d["renders"][0]["objects"][0]


def _each_pose(d):
    for r in d["renders"]:
        yield r["T_world_cam"]
        for o in r["objects"]:
            yield o["T_cam_obj"]
            yield o["cam2obj_pose"]


def _rotate(T, angle):
    """T with its rotation turned by `angle` rad about the camera's z axis."""
    c, s = np.cos(angle), np.sin(angle)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    T = np.array(T)
    T[:3, :3] = R @ T[:3, :3]
    return T.tolist()


def test_every_stored_file_equals_itself():
    names = sorted(p.name for p in SNAPSHOTS.glob("*.json"))
    assert len(names) >= 3
    for name in names:
        text = (SNAPSHOTS / name).read_text()
        assert compare_texts(text, text, name) == []


def test_what_another_cpu_changes_passes(scene):
    got = copy.deepcopy(scene)
    for T in _each_pose(got):
        for row in T[:3]:
            row[3] += 1.4e-8                                   # the measured cross-CPU pose spread
            row[0] = float(np.nextafter(row[0], 2.0))          # last digit of a rotation entry
    sl = got["renders"][1]["structured_light"]
    sl["reasons"]["BAD_ORDER"] += 11                           # the measured cross-CPU SL spread
    sl["reasons"]["VALID"] -= 7
    sl["valid_fraction"] -= 7 / 4800
    sl["median_sigma_z"] *= 1.002
    sl["exposure"] *= 1 + 4e-8
    assert differences(got, scene) == []
    bop = _stored("bop_scene_gt.json")
    got_bop = copy.deepcopy(bop)
    for gts in got_bop.values():
        for gt in gts:
            gt["cam_t_m2c"] = [t + 1.4e-5 for t in gt["cam_t_m2c"]]   # mm
    assert differences(got_bop, bop) == []


@pytest.mark.parametrize("change, where", [
    (lambda d: _first_object(d)["T_cam_obj"][0].__setitem__(3, _first_object(d)["T_cam_obj"][0][3] + 1e-4),
     "renders[0].objects[0].T_cam_obj[0][3]"),
    (lambda d: _first_object(d).__setitem__("T_cam_obj", _rotate(_first_object(d)["T_cam_obj"], 1e-4)),
     "renders[0].objects[0].T_cam_obj[0][0]"),
    (lambda d: _first_object(d).__setitem__("px_count_visib", _first_object(d)["px_count_visib"] + 1),
     "renders[0].objects[0].px_count_visib"),
    (lambda d: d["renders"][0]["structured_light"]["reasons"].__setitem__(
        "VALID", d["renders"][0]["structured_light"]["reasons"]["VALID"] + 25),
     "renders[0].structured_light.reasons.VALID"),
    (lambda d: d["renders"][0]["structured_light"].__setitem__(
        "valid_fraction", d["renders"][0]["structured_light"]["valid_fraction"] + 0.011),   # 80cf20e's smallest
     "renders[0].structured_light.valid_fraction"),
    (lambda d: d["renders"][0]["structured_light"].__setitem__(
        "exposure", d["renders"][0]["structured_light"]["exposure"] * 0.99),
     "renders[0].structured_light.exposure"),
    (lambda d: _first_object(d).__setitem__("name", "peg_999"), "renders[0].objects[0].name"),
    (lambda d: _first_object(d).__setitem__("obj_id", 2), "renders[0].objects[0].obj_id"),
    (lambda d: d["renders"][0].__setitem__("new_field", 1), "renders[0].new_field"),
    (lambda d: d["renders"][0]["objects"].pop(), "renders[0].objects"),
    (lambda d: d["simulation"].__setitem__("frames", d["simulation"]["frames"] + 1), "simulation.frames"),
    (lambda d: d["simulation"].__setitem__("impact_speed", d["simulation"]["impact_speed"] + 3e-4),
     "simulation.impact_speed"),
    (lambda d: d["renders"][0]["K"][0].__setitem__(0, d["renders"][0]["K"][0][0] * 1.001), "renders[0].K[0][0]"),
    (lambda d: d["renders"][0]["K"][0].__setitem__(0, int(d["renders"][0]["K"][0][0])), "renders[0].K[0][0]"),
])
def test_a_real_change_fails_and_is_named(scene, change, where):
    got = copy.deepcopy(scene)
    change(got)
    diffs = differences(got, scene)
    assert len(diffs) >= 1 and diffs[0].startswith(where + ":"), diffs


def test_a_bop_translation_off_by_a_tenth_of_a_millimetre_fails():
    bop = _stored("bop_scene_gt.json")
    got = copy.deepcopy(bop)
    got["0"][0]["cam_t_m2c"][2] += 0.1                         # mm
    assert differences(got, bop) == [f"0[0].cam_t_m2c[2]: got {got['0'][0]['cam_t_m2c'][2]!r}, want "
                                     f"{bop['0'][0]['cam_t_m2c'][2]!r} (tolerance 1e-3 mm)"]
