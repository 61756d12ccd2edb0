"""The fast fringe mode against the render mode, in real Cycles renders at tiny resolution.

Same scenes as test_structured_light.py (the preset's camera 0.8 m above the floor, a box on it).
Direct light of a point light has no Monte-Carlo noise, so with no bounces the synthesised fringes
must equal the path-traced ones to float precision; with bounces only the bounce light's
modulation of the coarse fringes may differ (the fine fringe's bounce light is offset only in
both modes)."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from datapipe.core import structured_light as SLM  # noqa: E402
from datapipe.core.fringe_fast import FLAT_NODE  # noqa: E402

from test_structured_light import SEED, build, plane_config  # noqa: E402


def fringes(tmp_path, cfg, mode, box=True, bounce_min_gain=None):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    cfg = cfg.copy()
    cfg.structured_light.fringe_mode = mode
    blend, _, _, slc, T = build(tmp_path, cfg, box=box, bounce_min_gain=bounce_min_gain)
    stack, _ = slc.render_fringes(tmp_path / mode, SEED, T)
    return stack, slc, blend


@pytest.mark.parametrize("bounces", [0, 4])
def test_fast_fringes_equal_rendered_fringes(tmp_path, bounces):
    cfg = plane_config(res=(48, 36))
    cfg.render.max_bounces = bounces
    ref, _, _ = fringes(tmp_path, cfg, "render")
    fast, slc, _ = fringes(tmp_path, cfg, "fast")
    assert fast.shape == ref.shape == (12, 36, 48)
    scale = float(ref.max())
    assert scale > 0.3 and (ref > 0.01).mean() > 0.5           # the projector lights most of the view
    N = cfg.structured_light.steps
    fine = slice(len(ref) - N, len(ref))
    # direct light (everything without bounces; the fine fringe with them) agrees to float precision
    assert np.abs(fast[fine] - ref[fine]).max() < 1e-4 * scale
    if bounces == 0:
        assert np.abs(fast - ref).max() < 1e-4 * scale
    else:          # coarse fringes: only the bounce light's modulation (box walls <-> floor) differs
        d = np.abs(fast[:N] - ref[:N])
        assert 1e-4 * scale < d.max() < 0.2 * scale and d.mean() < 0.02 * ref[:N].mean()
        # ... and the bounce layers model it: the 1-period fringe's bounce part (frame minus the
        # offset-only synthesis) follows the path-traced one (correlation ~0.7 measured; the render
        # mode's own is 4-path noisy) and fast is closer to render than offset-only is
        offset_only, _, _ = fringes(tmp_path, cfg, "fast", bounce_min_gain=2.0)
        a, b = (ref[:N] - offset_only[:N]).ravel(), (fast[:N] - offset_only[:N]).ravel()
        assert np.corrcoef(a, b)[0, 1] > 0.4
        assert np.sqrt(np.mean((a - b) ** 2)) < 0.85 * np.sqrt(np.mean(a ** 2))


def test_fast_mode_builds_its_lights_and_cleans_up(tmp_path):
    """One flat-lit light + layer; bounce layers (white, cos, sin) for the periods whose bounce keeps
    modulation (1 and 8 of the default 1, 8, 64); none of it used by the native call; all removed
    by teardown or by a later run's setup."""
    cfg = plane_config(res=(32, 24))
    stack, slc, blend = fringes(tmp_path, cfg, "fast", box=False)
    assert sorted(slc.strategy.flat.gains) == [1, 8]
    n = 1 + 1 + 2 * 2
    assert len([ld for ld in bpy.data.lights if ld.type == "SPOT"]) == n
    fringe_layers = [vl for vl in blend.scene.view_layers if vl.name.startswith("sl_")]
    assert [vl.name for vl in fringe_layers] == [f"sl_{i:02d}" for i in range(n)]
    assert not any(vl.use for vl in fringe_layers)                   # the native call skips them
    assert not list((tmp_path / "fast").glob("*.exr"))              # the scratch EXRs are gone
    # a second run in the same session replaces the leftovers (the pipeline does not tear down)
    again = SLM.StructuredLightCamera(slc.cfg, blend.scene, slc.camera, slc.renderer)
    again.setup()
    assert len([ld for ld in bpy.data.lights if ld.type == "SPOT"]) == n
    assert len([nd for nd in slc.renderer.tree.nodes if nd.name.startswith(FLAT_NODE)]) == 2
    again.teardown()
    assert not [ld for ld in bpy.data.lights if ld.type == "SPOT"]
    assert not [nd for nd in slc.renderer.tree.nodes if nd.name.startswith(SLM.OUTPUT_NODE)]
    assert not [vl for vl in blend.scene.view_layers if vl.name.startswith("sl_")]


def test_auto_mode_renders_the_fringes_only_where_a_material_is_shiny():
    """'auto' = fast for diffuse scenes (where the modes agree) and quadrature (every light path
    path-traced, as render: test_fringe_quadrature.py) as soon as any configured material is shiny
    enough to mirror the fringes, render with a projector gamma; explicit modes are kept as given."""
    from datapipe.config import default_config

    cfg = default_config()
    cfg.structured_light.fringe_mode = "auto"
    assert SLM.resolve_fringe_mode(cfg) == "fast"                    # 'file' materials: diffuse
    cfg.objects[0].material = ["matte_plastic", "rubber"]
    assert SLM.resolve_fringe_mode(cfg) == "fast"                    # roughness 0.6, 0.85
    cfg.objects[-1].material = ["rubber", "steel"]                   # one shiny choice is enough
    assert SLM.resolve_fringe_mode(cfg) == "quadrature"
    cfg.structured_light.projector_gamma = 2.2                      # no mix of cos and sin any more
    assert SLM.resolve_fringe_mode(cfg) == "render"
    cfg.structured_light.projector_gamma = 1.0
    cfg.objects[-1].material = "file"
    cfg.scene.bin_material = {"base_color": [0.5, 0.5, 0.5], "roughness": 0.1}
    assert SLM.resolve_fringe_mode(cfg) == "quadrature"
    cfg.scene.bin_material = {"base_color": [0.5, 0.5, 0.5], "roughness": SLM.SHINY_ROUGHNESS}
    assert SLM.resolve_fringe_mode(cfg) == "fast"                    # the threshold itself is diffuse
    cfg.structured_light.reflection_filter = "global"               # its row code is path-traced
    assert SLM.resolve_fringe_mode(cfg) == "quadrature"
    cfg.structured_light.reflection_filter = "auto"
    cfg.structured_light.fringe_mode = "fast"
    cfg.scene.bin_material = "steel"
    assert SLM.resolve_fringe_mode(cfg) == "fast"                    # an explicit choice wins
