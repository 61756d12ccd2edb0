"""Lighting draws and blackbody colours without bpy. The colours are checked against an independent
reference: the Planckian locus chromaticity of Kim et al. (2002, US patent 7024034), a cubic fit
valid 1667..25000 K, not the Planck x CMF integration of datapipe.draws.lighting."""
import numpy as np
import pytest

from datapipe import config as C
from datapipe.draws.lighting import blackbody_rgb, blackbody_xyz, draw_lighting
from datapipe.draws.seeds import lighting_rng


def _kim_xy(T):
    if T <= 4000:
        x = -0.2661239e9 / T**3 - 0.2343589e6 / T**2 + 0.8776956e3 / T + 0.179910
    else:
        x = -3.0258469e9 / T**3 + 2.1070379e6 / T**2 + 0.2226347e3 / T + 0.240390
    if T <= 2222:
        y = -1.1063814 * x**3 - 1.34811020 * x**2 + 2.18555832 * x - 0.20219683
    elif T <= 4000:
        y = -0.9549476 * x**3 - 1.37418593 * x**2 + 2.09137015 * x - 0.16748867
    else:
        y = 3.0817580 * x**3 - 5.87338670 * x**2 + 3.75112997 * x - 0.37001483
    return x, y


@pytest.mark.parametrize("T", [2000.0, 3000.0, 4000.0, 5000.0, 6500.0, 10000.0])
def test_blackbody_chromaticity_on_the_planckian_locus(T):
    X, Y, Z = blackbody_xyz(T)
    # the CMF fit's ~1% errors move the chromaticity by up to 0.003 at 2000 K (less than a MacAdam
    # ellipse, an unseen tint change), 0.001 from 3000 K up
    tol = 4e-3 if T < 3000 else 1e-3
    assert (X / (X + Y + Z), Y / (X + Y + Z)) == pytest.approx(_kim_xy(T), abs=tol)


def test_blackbody_rgb_is_unit_luminance_and_warm_to_cool():
    cols = [np.array(blackbody_rgb(T)) for T in (2000, 3000, 4500, 6500, 10000)]
    for c in cols:
        assert np.all(c >= 0) and c @ [0.2126, 0.7152, 0.0722] == pytest.approx(1.0)
    ratios = [c[2] / c[0] for c in cols]          # blue over red grows with temperature
    assert all(a < b for a, b in zip(ratios, ratios[1:]))
    r, g, b = blackbody_rgb(6500)                 # a 6500 K blackbody is near D65 white
    assert max(r, g, b) / min(r, g, b) < 1.1


def test_draws_within_ranges_and_reproducible():
    li = C.LightingConfig(key_power=[20, 80], key_color_temperature=[3000, 6000], key_size=[0.4, 1.2],
                          key_position_jitter=0.3, ambient=[0.0, 0.5])
    draws = [draw_lighting(li, lighting_rng(5, i)) for i in range(50)]
    assert draws[:3] == [draw_lighting(li, lighting_rng(5, i)) for i in range(3)]
    for d in draws:
        assert 20 <= d["key_power"] <= 80 and 3000 <= d["key_color_temperature"] <= 6000
        assert 0.4 <= d["key_size"] <= 1.2 and 0 <= d["ambient"] <= 0.5
        assert np.hypot(*d["key_offset"][:2]) <= 0.3 and d["key_offset"][2] == 0
        assert d["key_color"] == list(blackbody_rgb(d["key_color_temperature"]))
    assert np.ptp([d["key_power"] for d in draws]) > 30


def test_config_lighting_absent_by_default_and_validated(tmp_path):
    cfg = C.default_config()
    assert cfg.lighting is None and cfg.to_dict()["lighting"] is None
    d = cfg.to_dict()
    d["lighting"] = {"key_power": [10, 40]}
    back = C.Config.from_dict(d)
    assert back.lighting.key_power == [10, 40] and back.lighting.ambient == C.LightingConfig().ambient
    C.save(back, tmp_path / "l.json")
    assert C.load(tmp_path / "l.json").to_dict() == back.to_dict()
    back.lighting = C.LightingConfig(key_power=[50, 10], key_color_temperature=[500, 6000], key_size=[0, 1],
                                     key_position_jitter=-1, ambient=[-1, 1, 2])
    assert {p.path for p in back.problems()} == {f"lighting.{k}" for k in (
        "key_power", "key_color_temperature", "key_size", "key_position_jitter", "ambient")}
