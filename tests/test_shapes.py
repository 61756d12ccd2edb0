"""Procedural distractor shapes (datapipe/shapes.py) and the rules of objects[i].annotate / shape.

The meshes are judged against closed-form geometry: the volume of a closed, outward-facing mesh
(divergence theorem) equals the prism's (base polygon area x length, computed here from the
polygon's formula, not the code's vertices), every edge is shared by exactly two faces in opposite
directions, and the centroid is the origin (Blender's rigid body turns about the object origin)."""
from __future__ import annotations

import json
import math
from collections import Counter
from pathlib import Path

import numpy as np
import pytest

from datapipe import shapes
from datapipe.config import Config
from datapipe.errors import ConfigError

PRESETS = Path(__file__).resolve().parents[1] / "datapipe" / "presets"
N = shapes.ROUND_SEGMENTS


def _ngon_area(d):            # regular N-gon inscribed in a circle of diameter d
    return 0.5 * N * (d / 2) ** 2 * math.sin(2 * math.pi / N)


def _volume_centroid(v, f):
    a, b, c = v[f[:, 0]], v[f[:, 1]], v[f[:, 2]]
    vol6 = np.einsum("ij,ij->i", a, np.cross(b, c))
    return vol6.sum() / 6, (vol6[:, None] * (a + b + c)).sum(0) / (4 * vol6.sum())


@pytest.mark.parametrize("kind,size,volume", [
    ("box", [0.03, 0.02, 0.01], 0.03 * 0.02 * 0.01),
    ("plate", [0.06, 0.04, 0.005], 0.06 * 0.04 * 0.005),
    ("cylinder", [0.02, 0.05], _ngon_area(0.02) * 0.05),
    ("tube", [0.03, 0.004, 0.04], (_ngon_area(0.03) - _ngon_area(0.022)) * 0.04),
])
def test_meshes_are_closed_solids_of_their_size(kind, size, volume):
    v, f = shapes.mesh(kind, size)
    vol, centroid = _volume_centroid(v, f)
    assert vol == pytest.approx(volume, rel=1e-9)            # positive: outward-facing
    assert np.abs(centroid).max() < 1e-12
    edges = Counter((int(a), int(b)) for tri in f for a, b in zip(tri, np.roll(tri, -1)))
    assert all(edges[(b, a)] == 1 and n == 1 for (a, b), n in edges.items())     # closed, consistent
    extent = np.ptp(v, axis=0)
    if kind in ("box", "plate"):
        assert extent == pytest.approx(size, abs=1e-12)
    else:
        assert extent[2] == pytest.approx(size[-1], abs=1e-12) and extent[0] == pytest.approx(size[0], abs=1e-12)


def test_tube_pieces_are_convex_and_fill_the_wall():
    from datapipe.draws.fill import hull_volume
    size = [0.03, 0.004, 0.04]
    pieces = shapes.convex_pieces("tube", size)
    assert len(pieces) == N
    vols = [_volume_centroid(pv, pf)[0] for pv, pf in pieces]
    assert all(hull_volume(pv) == pytest.approx(vol, rel=1e-9) for (pv, _), vol in zip(pieces, vols))
    assert sum(vols) == pytest.approx(_volume_centroid(*shapes.mesh("tube", size))[0], rel=1e-9)
    assert len(shapes.convex_pieces("box", [0.01, 0.02, 0.03])) == 1


def test_sizes_are_drawn_in_their_range_and_a_fixed_size_draws_nothing():
    spec = {"kind": "box", "size": [[0.01, 0.02, 0.03], [0.02, 0.02, 0.05]]}
    a = shapes.draw_sizes(np.random.default_rng(3), spec, 2.0, 500)
    assert a.shape == (500, 3)
    assert (a >= [0.02, 0.04, 0.06]).all() and (a <= [0.04, 0.04, 0.1]).all()
    assert np.ptp(a[:, 0]) > 0.018 and np.ptp(a[:, 1]) == 0         # spread over the range; fixed stays fixed
    assert np.array_equal(a, shapes.draw_sizes(np.random.default_rng(3), spec, 2.0, 500))
    rng = np.random.default_rng(3)
    shapes.draw_sizes(rng, {"kind": "box", "size": [0.01, 0.02, 0.03]}, 1.0, 4)
    assert rng.random() == np.random.default_rng(3).random()


def _with(objects):
    d = json.loads((PRESETS / "default.json").read_text())
    d["objects"] = objects
    return d


def _problems(objects) -> dict[str, str]:
    with pytest.raises(ConfigError) as e:
        Config.from_dict(_with(objects), base_dir=PRESETS).validate()
    return {p.path: f"{p.message} (fix: {p.fix})" for p in e.value.problems}


PEG = {"filepath": "../assets/peg.obj", "name": "peg"}


def test_a_distractor_preset_is_accepted():
    cfg = Config.from_dict(_with([PEG, {"annotate": False, "shape": {"kind": "tube", "size": [[0.02, 0.002, 0.02],
                                                                                         [0.03, 0.004, 0.04]]}},
                                  {"annotate": False, "filepath": "../assets/nut.obj"}]), base_dir=PRESETS).validate()
    assert [cfg.object_name(i) for i in range(3)] == ["peg", "tube", "nut"]
    assert [o.annotate for o in cfg.objects] == [True, False, False]


def test_a_scene_of_only_distractors_is_refused():
    p = _problems([dict(PEG, annotate=False), {"annotate": False, "shape": {"kind": "box", "size": [0.01] * 3}}])
    assert "annotate: true" in p["objects"]
    p = _problems([dict(PEG, max_instances=0, min_instances=0),
                   {"annotate": False, "shape": {"kind": "box", "size": [0.01] * 3}}])
    assert "annotate: true" in p["objects"]


@pytest.mark.parametrize("shape,field,words", [
    ({"kind": "cone", "size": [0.01]}, "shape.kind", "box, plate, cylinder, tube"),
    ({"kind": "box", "size": [0.01, 0.02]}, "shape.size", "3 sizes in metres (x, y, z)"),
    ({"kind": "box", "size": [[0.03, 0.01, 0.01], [0.02, 0.02, 0.02]]}, "shape.size", "min <= its max"),
    ({"kind": "box", "size": [0.0005, 0.01, 0.01]}, "shape.size", ">= 0.001"),
    ({"kind": "box", "size": [0.01, float("nan"), 0.01]}, "shape.size", "finite"),
    ({"kind": "tube", "size": [0.02, 0.01, 0.03]}, "shape.size", "below half the smallest outer diameter"),
    ({"kind": "plate", "size": [0.04, 0.03, 0.02]}, "shape.size", "use kind \"box\""),
    ({"kind": "box", "size": [0.01] * 3, "colour": 1}, "shape.colour", "only \"kind\" and \"size\""),
    ("box", "shape", "\"kind\""),
])
def test_bad_shapes_are_refused_naming_the_field_and_fix(shape, field, words):
    p = _problems([PEG, {"annotate": False, "shape": shape}])
    assert words in p[f"objects[1].{field}"]


def test_a_shape_must_be_a_distractor_without_a_file():
    p = _problems([PEG, {"shape": {"kind": "box", "size": [0.01] * 3}, "filepath": "../assets/nut.obj",
                         "collision_shape": "BOX"}])
    assert "annotate: false" in p["objects[1].annotate"]
    assert "either a shape or a mesh file" in p["objects[1].shape"]
    assert "AUTO" in p["objects[1].collision_shape"]
