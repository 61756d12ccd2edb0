"""Quality gates (datapipe.checks.quality): each useless render is named, a good one says nothing."""
import numpy as np

from datapipe.checks import quality as Q


def good_rgb():
    rng = np.random.default_rng(0)
    return rng.integers(20, 230, size=(24, 32, 3), dtype=np.uint8)


def test_good_render_has_no_warning():
    assert Q.render_warnings(rgb=good_rgb(), visible_px=[120, 0, 33], sl_valid_fraction=0.4,
                             parts_dropped=3, parts_lost=0) == []


def test_black_and_saturated_rgb():
    black = np.zeros((24, 32, 3), np.uint8)
    black[0, :5] = 200                       # a few hot pixels (< 1%) do not make an image
    assert "black" in Q.rgb_warnings(black)[0]
    white = good_rgb()
    white[:18] = 255                         # 75% clipped
    assert "saturated" in Q.rgb_warnings(white)[0]
    white[:10] = 100                         # 33% clipped: a bright part, not a useless image
    assert Q.rgb_warnings(white) == []


def test_no_visible_part_sl_and_lost_parts():
    w = Q.render_warnings(rgb=good_rgb(), visible_px=[0, 0], sl_valid_fraction=0.005, parts_dropped=4,
                          parts_lost=2)
    assert any("no part is visible" in x for x in w)
    assert any("0.5% of the pixels" in x for x in w)
    assert any("2 of 4 parts lost" in x for x in w)
    w = Q.render_warnings(rgb=None, visible_px=[None], sl_valid_fraction=None, parts_dropped=2, parts_lost=2)
    assert w == ["all 2 parts were lost in the simulation (left the bin)"]
