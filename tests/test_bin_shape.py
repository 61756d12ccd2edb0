"""Per-scene bin draws without bpy: in range, reproducible, off by default; validation."""
import numpy as np
import pytest

from datapipe import config as C
from datapipe.draws.bin_shape import draw_bin, varies
from datapipe.draws.seeds import bin_rng


def test_default_draws_nothing_and_ranges_are_respected():
    s = C.SceneConfig()
    assert not varies(s)
    s.bin_size_scale, s.bin_wall_scale = [0.8, 1.2], [0.5, 1.0]
    assert varies(s)
    draws = [draw_bin(s, [0.15, 0.1, 0.1], bin_rng(4, i)) for i in range(40)]
    assert draws[:2] == [draw_bin(s, [0.15, 0.1, 0.1], bin_rng(4, i)) for i in range(2)]
    for d in draws:
        assert 0.12 <= d["half_size"][0] <= 0.18 and 0.08 <= d["half_size"][1] <= 0.12
        assert d["half_size"][2] == 0.1 and 0.1 <= d["wall_height"] <= 0.2
        assert d["half_size"][0] == pytest.approx(0.15 * d["size_scale"][0])
    assert np.ptp([d["wall_height"] for d in draws]) > 0.05


def test_validation_of_bin_ranges():
    cfg = C.default_config()
    cfg.scene.bin_size_scale = [1.2, 0.8]
    cfg.scene.bin_wall_scale = [0.0, 1.0]
    assert {p.path for p in cfg.problems()} == {"scene.bin_size_scale", "scene.bin_wall_scale"}
    cfg.scene.bin_size_scale, cfg.scene.bin_wall_scale = [0.8, 1.2], [1.0, 3.0]
    cfg.camera.sampler = C.CameraSamplerConfig(kind="bin_view", distance=[0.5, 0.8], tilt_deg=[0, 60])
    # 0.5 m at 60 deg is 0.25 m up: below the highest walls (3 x 0.2 m) but above the zone's own
    assert [p.path for p in cfg.problems()] == ["camera.sampler.tilt_deg"]
    cfg.scene.bin_wall_scale = [1.0, 1.0]
    assert cfg.problems() == []
