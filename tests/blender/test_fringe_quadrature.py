"""The quadrature fringe mode against the render mode on a shiny scene, in real Cycles renders.

Scene: test_sl_glossy.py's mirror plate (metallic, roughness 0.05) tilted towards a diffuse wall
the projector lights, at 80x60: the plate's pixels see the wall's fringes mirrored, the light
path the fast mode cannot synthesise. Light is linear in the projected image and, in one Cycles
call with one seed, the white, cos and sin layers follow the same paths as the render mode's
pattern layers, so the mixed frames equal the path-traced ones path for path: the tolerances are
float rounding (1e-4 of the peak), not Monte-Carlo noise (two seeds differ by ~30% of the peak on
the plate at these 4 paths per pixel). The only designed difference: the coarse fringes' bounce
light that left the projector through its faded outer half texel (QuadratureFringes
.light_gains), measured at most 1% of the peak on 6 of the 4800 pixels."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from datapipe.core import materials as M  # noqa: E402
from datapipe.core import structured_light as SLM  # noqa: E402

from test_sl_glossy import C_PLATE, HALF, MIRRORS, WALL_TOP, WALL_X, _mirror_geometry  # noqa: E402
from test_structured_light import SEED, _add_box, build, plane_config  # noqa: E402

RES = (80, 60)


def mirror_scene(mode, coarse_supersample=None, kind="across", pack=True, plate_color=(0.9, 0.9, 0.9)):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    _, u_ax, v_ax, (y0, y1) = MIRRORS[kind]
    cfg = plane_config(res=RES)
    cfg.structured_light.periods = [1, 4, 16]
    cfg.structured_light.fringe_mode = mode
    for entry in cfg.objects:               # (not in this scene) grey: quadrature may pack
        entry.material = "matte_plastic"

    def add(scene):
        corners = [tuple(C_PLATE + su * HALF * u_ax + sv * HALF * v_ax)
                   for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
        me = bpy.data.meshes.new("plate")
        me.from_pydata(corners, [], [(0, 1, 2, 3)])
        plate = bpy.data.objects.new("plate", me)
        scene.collection.objects.link(plate)
        M.assign(plate, M.build({"name": "mirror", "base_color": list(plate_color), "metallic": 1.0,
                                 "roughness": 0.05}))
        _add_box(scene, (WALL_X, y0, 0.0), (WALL_X + 0.02, y1, WALL_TOP))

    blend, cam, _, slc, T = build(None, cfg, add=add, packed=pack, coarse_supersample=coarse_supersample)
    slc.set_sharp_glossy(SLM.has_shiny_surface(blend.scene))     # what process() does: True here
    hits = _mirror_geometry(cfg, cam.K, T, RES[::-1], kind)[1]   # plate pixels that mirror the lit wall
    return cfg, slc, hits


def frames(tmp_path, slc, name, seed=SEED):
    return slc.render_fringes(tmp_path / name, seed, rows=True)[0]


@pytest.mark.parametrize("pack", [False, True], ids=["one_per_layer", "packed"])
def test_quadrature_frames_equal_the_path_traced_ones_on_a_mirror(tmp_path, pack):
    cfg, slc, hits = mirror_scene("render")
    assert slc.sharp_glossy and hits.sum() > 30
    ref = frames(tmp_path, slc, "render")
    other_seed = frames(tmp_path, slc, "render2", SEED + 1)
    slc.teardown()
    cfg, slc, _ = mirror_scene("quadrature", coarse_supersample=2, pack=pack)
    # 1 + 2 x 3 + 2 images (vs 3 x 4 + 4 in render): one layer each, or white + 2 + 1 packed layers
    assert len(slc.plan.quad_calls()) == 1 and len(slc.strategy.layer_names) == (1 + 2 + 1 if pack else 1 + 2 * 3 + 2)
    quad = frames(tmp_path, slc, "quad")
    N = cfg.structured_light.steps
    assert quad.shape == ref.shape == (3 * N + N, *RES[::-1])
    scale = float(ref.max())
    d = np.abs(quad - ref)
    # everywhere but a few pixels: float rounding; there, the border fade, at most the bounce gain
    # of the fringe (16 periods: 0.002, the row code's 8 over the height: 0.02) or 3% for the coarse
    assert np.percentile(d, 99.5) < 1e-4 * scale
    Wp, Hp = cfg.projector.resolution
    gain = [SLM.indirect_gain(K, L) for K, L in ((1, Wp), (4, Wp), (16, Wp), (8, Hp))]
    for k, g in enumerate(gain):
        assert d[k * N:(k + 1) * N].max() < (1e-4 + min(g, 0.03)) * scale
    # the plate pixels carry the wall's fine fringe (mirrored light) in both: strongly modulated,
    # and Cycles noise alone would be far outside these tolerances
    fine = slice(2 * N, 3 * N)
    plate = float(ref[fine][:, hits].mean())
    assert np.ptp(ref[fine][:, hits], axis=0).mean() > 0.5 * plate
    assert np.abs(other_seed - ref)[fine][:, hits].mean() > 0.05 * plate

    # a dropped glossy term fails the comparison: glossy bounces blurred like diffuse ones (what
    # a scene without shiny surfaces gets) take the mirrored fine fringe off the plate
    slc.set_sharp_glossy(False)
    blurred = frames(tmp_path, slc, "blurred")
    assert np.abs(blurred - ref)[fine][:, hits].mean() > 0.2 * plate
    assert np.ptp(blurred[fine][:, hits], axis=0).mean() < 0.3 * np.ptp(ref[fine][:, hits], axis=0).mean()
    slc.teardown()


def test_split_quadrature_keeps_the_fine_fringe_exact(tmp_path):
    """The cheaper variant (coarse_supersample 1, not the default): the finest period and the row
    code on the render mode's 2x2 grid (their frames equal render mode's, same paths), the coarse
    periods in a second call at the camera grid; every light and layer of both calls removed by
    teardown."""
    cfg, slc, hits = mirror_scene("render")
    ref = frames(tmp_path, slc, "render")
    slc.teardown()
    cfg, slc, _ = mirror_scene("quadrature", coarse_supersample=1)
    assert [c.supersample for c in slc.plan.quad_calls()] == [2, 1]
    assert len(slc.strategy.layer_names) == (1 + 1 + 1) + (1 + 2)      # packed: white, 2 fringe + 2 row images; white, 4
    quad = frames(tmp_path, slc, "quad")
    N = cfg.structured_light.steps
    fine = slice(2 * N, 4 * N)                            # the 16-period fringe and the row code
    assert np.percentile(np.abs(quad[fine] - ref[fine]), 99.5) < 1e-4 * float(ref.max())
    # coarse frames: the centre sample of each pixel instead of the 2x2 mean -- the same light,
    # so on the flat floor (smooth coarse fringe) they agree closely
    floor = ~hits & (np.abs(ref[:N].mean(0) - quad[:N].mean(0)) < 1e-3)
    assert floor.mean() > 0.5
    slc.teardown()
    assert not [ld for ld in bpy.data.lights if ld.type == "SPOT"]
    assert not [vl for vl in slc.scene.view_layers if vl.name.startswith("sl_")]


def test_packed_layers_on_a_tinted_mirror_stay_within_float_noise_of_one_image_per_layer(tmp_path):
    """Three images per layer take an image back from one colour channel by its ratio to the white
    image there (sl.unpack_basis): exact for grey light (the test above), and for steel's tint
    (0.53, 0.51, 0.49) beside the grey wall the frames move by at most 0.2% of the peak (measured
    0.21%; a copper plate with a red wall: 9%, hence grey_materials)."""
    out = {}
    for pack in (False, True):
        cfg, slc, hits = mirror_scene("quadrature", coarse_supersample=2, pack=pack, plate_color=(0.53, 0.51, 0.49))
        assert slc.plan.packed is pack
        out[pack] = frames(tmp_path, slc, f"pack{pack}")
        slc.teardown()
    scale = float(out[False].max())
    d = np.abs(out[True] - out[False])
    assert np.percentile(d, 99.5) < 2e-3 * scale and d.max() < 5e-3 * scale
    assert np.abs(out[True] - out[False])[:, hits].mean() < 1e-3 * out[False][:, hits].mean()
