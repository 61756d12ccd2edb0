"""config/plan.py FringePlan: the structured-light camera's decisions made once per run from a
Config (no Blender). Expected counts are worked out by hand from the pattern sets: F periods x N
steps fringe images; the row code is N images of ROW_PERIODS (one period set); quadrature renders
a white image + (cos, sin) per period (+ one pair for the row code), one per layer or three per
layer with the white image alone in the first."""
import ast
import dataclasses
import tempfile
from pathlib import Path

import pytest

from datapipe import config as C
from datapipe.config.plan import FringePlan, QuadCall, fringe_memory_bytes, layer_samples, quad_call_layers

ROOT = Path(__file__).resolve().parents[1]


def _cfg(mode="auto", material=None):
    cfg = C.default_config()
    cfg.structured_light.enabled = True
    cfg.structured_light.fringe_mode = mode
    if material is not None:
        for entry in cfg.objects:
            entry.material = material
    return cfg


def test_diffuse_parts_plan_the_fast_mode_without_a_row_code():
    cfg = _cfg()                                   # the demo: mesh-file materials count as diffuse
    plan = FringePlan.from_config(cfg)
    assert (plan.mode, plan.requested, plan.periods, plan.steps) == ("fast", "auto", (1, 8, 64), 4)
    assert plan.n_fringe == 12 and not plan.row_code and plan.row_images == 0
    assert not plan.packed and plan.supersample == 2 and plan.samples == 4 and plan.layer_samples == 1
    assert plan.unwrap.method == "multi-frequency" and plan.unwrap.periods == (1, 8, 64)
    assert plan.memory_bytes == fringe_memory_bytes(cfg)
    assert plan.describe() == ["fringe mode fast (auto: every configured material is diffuse)", "12 fringe images",
                               "exposure auto", "reflection filter auto"]


@pytest.mark.parametrize("samples, paths", [(1, 4), (3, 4), (5, 8), (4, None), (8, None)])
def test_the_plan_line_says_when_samples_are_rounded_up_to_the_point_grid(samples, paths):
    """Every point of the 2 x 2 grid gets at least one path: samples 1-3 render what 4 renders, 5
    what 8 does. validate's plan line says so instead of letting a user believe a cheaper setting."""
    cfg = _cfg()
    cfg.structured_light.samples = samples
    plan = FringePlan.from_config(cfg)
    line = plan.describe()[1]
    assert plan.layer_samples * plan.supersample ** 2 == (paths or samples)
    if paths is None:
        assert line == "12 fringe images"
    else:
        assert f"{paths} Cycles paths per camera pixel (samples {samples} rounded up" in line


def test_shiny_grey_parts_plan_packed_quadrature_with_the_row_code():
    plan = FringePlan.from_config(_cfg(material="steel"))
    assert plan.mode == "quadrature" and plan.packed and plan.grey
    assert plan.row_periods == (8,) and plan.row_images == 4
    assert plan.quad_calls() == [QuadCall((1, 8, 64), (8,), 2)]     # one call on the render mode's grid
    # white | 6 fringe images three to a layer | the row code's 2 | : 4 layers (9 unpacked)
    call = plan.quad_calls()[0]
    assert quad_call_layers(call, True) == 1 + 2 + 1 and quad_call_layers(call, False) == 1 + 6 + 2
    assert quad_call_layers(call, True, rows=False) == 3 and quad_call_layers(call, False, rows=False) == 7
    text = "; ".join(plan.describe())
    assert "12 fringe images (+4 row code on shiny renders), mixed from 7 rendered images" in text
    assert "three per Cycles layer: 4 layers (every material is grey)" in text


def test_variants_auto_never_picks_come_by_argument():
    cfg = _cfg(material="steel")
    unpacked = FringePlan.from_config(cfg, packed=False)
    assert unpacked.mode == "quadrature" and not unpacked.packed and unpacked.grey
    split = FringePlan.from_config(cfg, coarse_supersample=1)
    # the finest period and the row code on the 2x2 grid; the coarse ones at the camera grid
    assert split.quad_calls() == [QuadCall((64,), (8,), 2), QuadCall((1, 8), (), 1)]
    assert [quad_call_layers(c, True) for c in split.quad_calls()] == [1 + 1 + 1, 1 + 2]
    # packing is a quadrature variant: it changes nothing in the other modes
    assert not FringePlan.from_config(_cfg("render"), packed=True).packed
    assert FringePlan.from_config(_cfg("fast"), bounce_min_gain=2.0).bounce_min_gain == 2.0
    with pytest.raises(dataclasses.FrozenInstanceError):        # decided once: nobody flips it later
        split.packed = False


def test_coloured_or_file_materials_travel_one_image_per_layer():
    cfg = _cfg("quadrature")                       # mesh-file materials may carry any colour
    plan = FringePlan.from_config(cfg)
    assert not plan.packed and not plan.grey
    assert "one per Cycles layer (a material has a colour or comes from its mesh file" in plan.describe()[1]
    cfg.structured_light.reflection_filter = "off"      # no row code: 1 + 2F images, no +2
    plan = FringePlan.from_config(cfg)
    assert not plan.row_code and plan.describe()[1] == (
        "12 fringe images, mixed from 7 rendered images (white + cos, sin per period), one per Cycles layer "
        "(a material has a colour or comes from its mesh file: three per layer would mix its colours)")


def test_layer_samples_count_paths_per_camera_pixel():
    # a camera pixel holds 2 x 2 point samples: its paths are shared among them, at least one each
    assert [layer_samples(s, 2) for s in (1, 4, 5, 16)] == [1, 1, 2, 4]
    assert layer_samples(4, 1) == 4


def test_periods_the_decoder_cannot_unwrap_are_refused_by_the_plan():
    cfg = _cfg()
    cfg.structured_light.periods = [8, 64]          # no coarse pattern, beat of 56 periods: ambiguous
    with pytest.raises(ValueError, match="periods"):
        FringePlan.from_config(cfg)


def test_the_unwrap_plan_is_made_once_and_handed_on(monkeypatch):
    """The run's plan carries the decoder's UnwrapPlan; the scanner takes it as it is (and hands it
    to every decode) instead of planning the periods again; a plan of other periods is refused."""
    from datapipe import sl
    from datapipe.sl import unwrap as U

    cfg = _cfg()
    plan = FringePlan.from_config(cfg)
    calls = []
    monkeypatch.setattr(U, "plan_unwrap", lambda *a, **k: calls.append(a))
    scanner = sl.Scanner.from_config(cfg, unwrap=plan.unwrap)
    assert scanner.unwrap_plan is plan.unwrap and scanner.unwrap == "multi-frequency" and calls == []
    assert U.as_plan((1, 8, 64), plan.unwrap) is plan.unwrap and calls == []
    with pytest.raises(ValueError, match="unwrap"):
        U.as_plan((1, 8, 32), plan.unwrap)
    U.as_plan((1, 8, 64), "auto")                    # a method name is planned, as before
    assert len(calls) == 1


FRINGE_MODULES = {"datapipe.core.structured_light", "datapipe.core.fringe_render", "datapipe.core.fringe_quadrature",
                  "datapipe.core.fringe_fast", "datapipe.core.fringe_call", "datapipe.config.plan"}


def _fringe_module_assignments(path: Path) -> list[str]:
    """`alias.NAME = ...` in a file, where alias is one of FRINGE_MODULES as imported there (a module
    attribute set from outside; not `alias.Class.method = ...`, a wrapper a benchmark puts around a
    method to keep what it computes)."""
    tree = ast.parse(path.read_text())
    aliases = set()
    for n in ast.walk(tree):
        if isinstance(n, ast.Import):
            aliases |= {a.asname for a in n.names if a.name in FRINGE_MODULES and a.asname}
        elif isinstance(n, ast.ImportFrom) and n.module:
            aliases |= {a.asname or a.name for a in n.names if f"{n.module}.{a.name}" in FRINGE_MODULES}
    out = []
    for n in ast.walk(tree):
        targets = n.targets if isinstance(n, ast.Assign) else [n.target] if isinstance(n, ast.AugAssign) else []
        flat = [t for tg in targets for t in (tg.elts if isinstance(tg, ast.Tuple) else [tg])]
        out += [f"{path.name}:{n.lineno} {t.value.id}.{t.attr}" for t in flat
                if isinstance(t, ast.Attribute) and isinstance(t.value, ast.Name) and t.value.id in aliases]
    return out


def test_tests_and_benchmarks_choose_the_strategy_by_argument():
    """No module-level switch of the fringe modules is flipped from outside (the quadrature tests
    once set QUAD_PACK_CHANNELS and QUAD_COARSE_SUPERSAMPLE on the module): a variant is a
    FringePlan.from_config argument."""
    files = sorted((ROOT / "tests").rglob("*.py")) + sorted((ROOT / "benchmarks").rglob("*.py"))
    assert len(files) > 50
    assert [a for p in files for a in _fringe_module_assignments(p)] == []
    planted = ROOT / "tests" / "blender" / "test_fringe_quadrature.py"      # the check sees a planted switch
    probe = planted.read_text() + "\nSLM.QUAD_PACK_CHANNELS = False\n"
    tmp = Path(tempfile.mkdtemp()) / planted.name
    tmp.write_text(probe)
    assert _fringe_module_assignments(tmp) == [f"{planted.name}:{probe.count(chr(10))} SLM.QUAD_PACK_CHANNELS"]
