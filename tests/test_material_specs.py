"""Material specs without Blender: validation, per-instance draws, the add-on's text form."""
import pytest

from datapipe import materials_spec as M


def test_every_preset_is_valid_and_physical():
    for name, v in M.PRESETS.items():
        assert M.material_problem(name) is None and M.material_problem(v) is None
        if v["metallic"] == 1.0:          # metals: base colour = F0, bright (Filament: metals sRGB >= 170)
            assert min(v["base_color"]) >= (170 / 255) ** 2.2
        else:                             # dielectrics: albedo within sRGB 10..240, IOR of plastics/rubber
            assert (10 / 255) ** 2.2 <= max(v["base_color"]) <= (240 / 255) ** 2.2
            assert 1.45 <= v["ior"] <= 1.6


def test_list_draw_is_seeded_and_per_entry():
    names = ["steel", "aluminium", "dark_plastic"]
    a = M.draw(names, 50, scene_seed=7, entry_index=0)
    assert a == M.draw(names, 50, scene_seed=7, entry_index=0)
    assert a != M.draw(names, 50, scene_seed=8, entry_index=0)
    assert a != M.draw(names, 50, scene_seed=7, entry_index=1)
    assert set(a) == set(names)
    assert M.draw("steel", 3, 7) == ["steel"] * 3


@pytest.mark.parametrize("value", ["steel", ["steel", "rubber"], {"base_color": [0.1, 0.2, 0.3], "roughness": 0.2},
                                   ["steel", {"metallic": 1.0}]])
def test_text_form_round_trip(value):
    assert M.parse_text(M.format_text(value)) == value


def test_text_form_errors():
    assert M.parse_text("  ") == "file"
    with pytest.raises(ValueError, match="JSON"):
        M.parse_text("{roughness: 1}")
