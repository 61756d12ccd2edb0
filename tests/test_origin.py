"""objects[i].origin (issue #30 item 3), the parts without Blender: the choice is validated, and the
warning for a mesh whose origin lies far from its bounding box's centre while BOP output is on.
The re-centred runs themselves: tests/blender/test_origin_bbox_center.py."""
from __future__ import annotations

import numpy as np

from datapipe.checks.origins import origin_warning, origin_warnings
from datapipe.config import validate

import fixtures_native as fx

BOX = (np.array([0.0, 0.0, 0.0]), np.array([40.0, 30.0, 20.0]))     # mm file: origin at a corner


def _cfg(formats=("native", "bop")):
    cfg = fx.default_config(formats=formats)
    cfg.objects = cfg.objects[:2]
    return cfg


def test_origin_choice_is_validated():
    cfg = _cfg()
    cfg.objects[1].origin = "centre"
    problems = [p for p in validate(cfg, check_files=False) if p.path == "objects[1].origin"]
    assert problems and "bbox_center" in problems[0].fix
    cfg.objects[1].origin = "bbox_center"
    assert not [p for p in validate(cfg, check_files=False) if p.path.endswith(".origin")]


def test_corner_and_face_origins_warn_centred_ones_do_not():
    w = origin_warning("objects[0]", "objects[0]", *BOX, 0.001)
    assert w is not None and 'objects[0].origin to "bbox_center"' in w and "along xyz" in w
    assert f"{np.linalg.norm([20, 15, 10]):.3g} mm" in w                   # 26.9 mm from the centre
    # a CAD part standing on its base: origin at the bottom face's centre
    assert "along z" in origin_warning("o", "o", [-20, -15, 0], [20, 15, 20], 0.001)
    # centred, or off by less than a quarter of the extent: no warning
    assert origin_warning("o", "o", [-20, -15, -10], [20, 15, 10], 0.001) is None
    assert origin_warning("o", "o", [-15, -15, -10], [25, 15, 10], 0.001) is None   # 5 mm of 40 mm


def test_warning_only_with_bop_output_and_origin_file():
    boxes = {0: BOX, 1: BOX}
    assert len(origin_warnings(_cfg(), boxes)) == 2
    assert origin_warnings(_cfg(formats=("native",)), boxes) == []
    cfg = _cfg()
    cfg.objects[0].origin = "bbox_center"
    ws = origin_warnings(cfg, boxes)
    assert len(ws) == 1 and ws[0].startswith("objects[1]")
