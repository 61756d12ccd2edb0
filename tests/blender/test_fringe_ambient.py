"""structured_light.ambient in Blender (real Cycles, 80x60): the projector-off layer is made only
with "scene", rendered in the fringe call of every fringe mode, and a plane lit by the projector and
the scene's key light at three strengths decodes at the photon-noise limit.

The plane is the floor of the preset's scene (no bin) 0.8 m under the camera, periods [1, 4, 16]
(the snapshot test's: 5 camera px per finest fringe at 80 px), 4 fringe samples per camera pixel."""
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from datapipe import config as C  # noqa: E402
from datapipe import sl  # noqa: E402
from datapipe.config.plan import FringePlan  # noqa: E402
from datapipe.core import structured_light as SLM  # noqa: E402
from datapipe.core.camera import BlendCamera  # noqa: E402
from datapipe.core.projector import AMBIENT_LAYER  # noqa: E402
from datapipe.core.renderer import Renderer  # noqa: E402
from datapipe.core.scene import BlendScene  # noqa: E402

SEED = 11
STEPS = 4


def _config(ambient: str, mode: str) -> C.Config:
    cfg = C.default_config()
    cfg.camera.resolution = [80, 60]
    cfg.scene.make_bin = False            # the floor alone: a plane 0.8 m under the camera
    cfg.render.samples = 4
    cfg.render.threads = 2
    s = cfg.structured_light
    s.enabled, s.periods, s.ambient, s.fringe_mode = True, [1, 4, 16], ambient, mode
    return cfg


def _build(cfg, pack=None):
    blend = BlendScene(cfg).setup()
    cam = BlendCamera(cfg, blend.scene).setup()
    ren = Renderer(cfg, blend.scene, cam).setup()
    slc = SLM.StructuredLightCamera(cfg, blend.scene, cam, ren, FringePlan.from_config(cfg, packed=pack))
    slc.setup()
    return blend, cam, slc, cam.set_pose(0)


def _items(slc):
    from blender_probes import file_output_input_names
    return file_output_input_names(slc.strategy.file_output)


MODES = [("fast", None), ("render", None), ("quadrature", True), ("quadrature", False)]   # (mode, packed)


def test_off_makes_nothing_and_scene_one_layer_in_every_fringe_mode(tmp_path):
    """"off": no projector-off layer, no output item, no ambient image. "scene": one layer (off for
    the native call), rendered in the fringe call at the fringes' grid; its image is the same in
    every mode (the same layer, seed and grid), the fringe frames are the "off" frames to the last
    bit (a view layer more in the call changes no other layer), and teardown removes the layer."""
    images = []
    for mode, pack in MODES:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        blend, cam, slc, T = _build(_config("off", mode), pack)
        assert AMBIENT_LAYER not in blend.scene.view_layers and AMBIENT_LAYER not in _items(slc)
        off, _ = slc.render_fringes(tmp_path / f"{mode}{pack}off", SEED, T)
        assert slc.ambient_image is None
        if mode == "fast":                 # the scene.json record: today's keys only
            _, info = slc.process(tmp_path / "record_off", SEED, T)
            assert not any(k.startswith("ambient") for k in info)
        slc.teardown()
        bpy.ops.wm.read_factory_settings(use_empty=True)
        blend, cam, slc, T = _build(_config("scene", mode), pack)
        names = [vl.name for vl in blend.scene.view_layers]
        assert names.count(AMBIENT_LAYER) == 1 and not blend.scene.view_layers[AMBIENT_LAYER].use
        assert AMBIENT_LAYER in _items(slc)
        stack, _ = slc.render_fringes(tmp_path / f"{mode}{pack}scene", SEED, T)
        assert np.array_equal(stack, off), mode
        amb = slc.ambient_image
        assert amb.shape == (60, 80) and amb.dtype == np.float32
        # the preset's 50 W key light 2.5 m above the floor: E ~ P / (pi d^2) = 2.5 W/m^2, against the
        # projector's 10 W x 5 / (4 pi) / 0.8^2 = 6.2 W/m^2 at its white peak: ~0.4 x the white pattern's
        white = 2 * np.median(stack[:STEPS].mean(axis=0))            # the 1-period fringe's A + B
        assert 0.3 < np.median(amb) / white < 0.5, mode
        images.append(amb)
        slc.teardown()
        assert AMBIENT_LAYER not in blend.scene.view_layers
    for mode, amb in zip(MODES[1:], images[1:]):
        np.testing.assert_allclose(amb, images[0], rtol=1e-5, atol=1e-6, err_msg=str(mode))


def test_plane_precision_follows_photon_noise_as_the_hall_light_grows(tmp_path):
    """The key light at 50, 200 and 800 W (hall light 0.86, 3.5 and 13.5 x the projector's mean light
    on the plane: the scan's `ambient_to_projector`), auto exposure: the RMS phase noise of the
    finest fringe is sqrt(2/N) sigma_I / B within 10% (measured 1.001, 1.013, 1.009 x; 0.021, 0.046,
    0.130 rad), B and A the noise-free frames' least-squares modulation and offset (ambient
    included) in DN, sigma_I the sensor's noise at A (~4000 pixels: 1% statistical uncertainty);
    it grows with the hall light; no plane pixel is MULTIPATH. At 800 W the plane's dim edge drops
    out (B/A < MIN_CONTRAST: 2942 valid pixels of 3957)."""
    cfg = _config("scene", "fast")
    blend, cam, slc, T = _build(cfg)
    model = slc.scanner.sensor
    out, ratios = [], []
    for watts in (50.0, 200.0, 800.0):
        blend.key_light.data.energy = watts
        stack, _ = slc.render_fringes(tmp_path / f"w{int(watts)}", SEED, T)
        amb = slc.ambient_image
        scan = slc.scanner.scan(stack, SEED, cam.K, T, ambient=amb)
        res = scan.result
        assert not (res.reason == sl.Reason.MULTIPATH).any()
        dn = np.float64(scan.exposure * model.electrons_per_unit / model.gain)
        clean = sl.phase_shift((stack[-STEPS:].astype(np.float64) + amb[None]) * dn)   # noise-free fine fringe
        peak = (stack[-STEPS:].astype(np.float64) + amb[None]).max(axis=0) * dn
        use = res.valid & (peak < 0.9 * model.saturation_level)     # no sample near the well (no clipped fit)
        err = np.angle(np.exp(1j * (res.wrapped[-1].astype(np.float64) - clean.phase)))[use]
        with np.errstate(divide="ignore"):        # no modulation outside the projector's image
            sigma_phi = np.sqrt(2.0 / STEPS) * model.noise_sigma(clean.offset) / clean.modulation
        measured, predicted = float(np.sqrt(np.mean(err ** 2))), float(np.sqrt(np.mean(sigma_phi[use] ** 2)))
        assert use.sum() > 2500
        print(f"{watts:.0f} W: ambient/projector {scan.summary()['ambient_to_projector']:.2f}, pixels {use.sum()}, "
              f"phase noise {measured:.4f} rad, predicted {predicted:.4f}, ratio {measured / predicted:.3f}")
        assert measured == pytest.approx(predicted, rel=0.10), (watts, measured, predicted)
        out.append(measured)
        ratios.append(scan.summary()["ambient_to_projector"])
    assert out[0] < out[1] < out[2]
    _, info = slc.process(tmp_path / "record", SEED, T)       # the scene.json record says so
    assert info["ambient"] == "scene" and info["ambient_to_projector"] == pytest.approx(ratios[-1], rel=0.02)
    assert 0.5 < ratios[0] < 1.2 and ratios[1] == pytest.approx(4 * ratios[0], rel=0.1)
