"""End-to-end decoding of ray-cast scenes (ground truth from tests/sl/synth.py, not the decoder)."""
import numpy as np
import pytest
from scipy import stats
from scipy.ndimage import binary_erosion

import synth
from sl_helpers import PERIODS, STEPS, add_noise, decode_kw
from datapipe.errors import DataPipeError
from datapipe.sl import VALID_REASONS, Reason, SensorModel, decode, depth_error_stats, fringe_patterns
from datapipe.sl.noise import fit_noise_model
from datapipe.sl.metrics import effective_period, theoretical_depth_sigma, theoretical_phase_sigma


def check_contract(res):
    """Every pixel is finite and valid, or NaN with a reason code; no inf anywhere."""
    for a in (res.depth, res.proj_x, res.phase):
        assert not np.isinf(a).any()
        np.testing.assert_array_equal(np.isfinite(a), res.valid)
    assert not np.isinf(res.points).any()
    np.testing.assert_array_equal(np.isfinite(res.points).all(-1), res.valid)
    np.testing.assert_array_equal(res.valid, np.isin(res.reason, VALID_REASONS))
    assert res.reason.dtype == np.uint8 and res.reason.max() <= max(Reason)
    assert np.all(res.depth[res.valid] > 0)


def order_errors(res, render, periods=PERIODS, proj_width=512):
    """Valid pixels whose projector coordinate is off by more than half the finest period."""
    half = proj_width / max(periods) / 2
    err = np.abs(res.proj_x - render.proj_x)
    return res.valid & ~(err < half)          # NaN ground truth (unlit yet valid) counts too


SCENES = {
    "plane": synth.plane_scene(),
    "tilted": synth.tilted_plane_scene(30),
    "sphere": synth.sphere_scene(),
    "box": synth.box_scene(),
}


@pytest.mark.parametrize("scene", list(SCENES))
@pytest.mark.parametrize("periods", [PERIODS, (64, 63), (70, 64, 59)])
def test_noise_free_is_exact(rig, scene, periods):
    """Noise-free float32 fringes: depth within 1 um. Error budget: float32 x carries half an ulp
    (1.5e-5 px at x < 512) times |dZ/dx| ~ 11 mm/px = 0.17 um, plus float32 phase/evaluation
    rounding of the same order; 1 um is the spec's bound. Every lit pixel decodes, nothing else."""
    cam, proj = rig
    r = synth.render(SCENES[scene], cam, proj, periods, STEPS)
    res = decode(r.images.astype(np.float32), **decode_kw(cam, proj, periods))
    check_contract(res)
    np.testing.assert_array_equal(res.valid, r.lit)
    assert np.abs(res.depth - r.depth)[res.valid].max() <= 1e-6
    assert np.abs(res.points - r.points)[res.valid].max() <= 1e-6
    assert np.abs(res.proj_x - r.proj_x)[res.valid].max() <= 1e-4
    assert np.all(res.reason[~r.lit] == Reason.NO_LIGHT)
    if scene == "box":
        assert r.shadow.sum() > 100 and not res.valid[r.shadow].any()


def test_noise_matches_theory():
    """Gaussian noise sigma_I = 0.01 on B = 0.5, N = 4: sigma_phi = sqrt(2/4)*0.01/0.5 = 0.0141
    rad per frequency; the K^2-weighted combination behaves like one pattern of period
    T_eff = W/sqrt(sum K^2) (K = 1 is left out: weight < 1%), so sigma_x = T_eff/(2 pi) sigma_phi.
    (a) Normalised by the exact per-pixel |dZ/dx| of the geometry the depth errors have unit std:
        77k pixels give the std to 0.3%; 5% tolerance.
    (b) Against the textbook sigma_Z = Z^2/(f_p b) (T/2 pi) sigma_phi at the mean depth (which
        ignores the converging projector and the depth spread; 1-6% in docs/STRUCTURED_LIGHT.md): the spec's 25%."""
    cam, proj = synth.make_rig(cam_size=(320, 240))
    r = synth.render(synth.plane_scene(), cam, proj, PERIODS, STEPS)
    sigma = 0.01
    res = decode(add_noise(r.images, sigma, 1).astype(np.float32), **decode_kw(cam, proj))
    check_contract(res)
    assert res.valid[r.lit].mean() == 1.0
    sphi = theoretical_phase_sigma(sigma, 0.5, STEPS)
    teff = effective_period(proj.size[0], (8, 64))
    sx = teff / (2 * np.pi) * sphi
    slope = synth.depth_slope(cam, proj, r.depth)
    err = (res.depth - r.depth)[res.valid]
    assert np.std(err / (slope * sx)[res.valid]) == pytest.approx(1.0, rel=0.05)
    z = np.mean(r.depth[res.valid])
    theory = theoretical_depth_sigma(z, proj.K[0, 0], 0.15, teff, sphi)
    assert np.std(err) == pytest.approx(theory, rel=0.25)
    assert abs(np.mean(err)) < 5 * np.std(err) / np.sqrt(err.size)       # unbiased


def test_depth_step_has_no_order_errors(rig, box_render):
    """Box of 0.15 m on the ground: at its edges the projector coordinate jumps by more than one
    finest period (asserted), which defeats spatial unwrapping. Temporal unwrapping must not
    lose a single order at default settings. Moderate noise: sigma_I = 0.02 (4% of B):
    sigma_phi = 0.028 rad, stage gain sqrt(65): sigma of the order estimate 0.036 cycles, so an
    order error (0.5 cycles, 14 sigma) has probability ~1e-44 per pixel."""
    cam, proj = rig
    r = box_render
    jump = np.nanmax(np.abs(np.diff(r.proj_x, axis=1)))
    assert jump > proj.size[0] / max(PERIODS)
    res = decode(add_noise(r.images, 0.02, 2).astype(np.float32), **decode_kw(cam, proj))
    check_contract(res)
    assert not order_errors(res, r).any()
    st = depth_error_stats(res.depth, r.depth, res.valid, lit=r.lit, shadow=r.shadow)
    assert st["decoded_fraction"] > 0.995 and st["false_valid_shadow"] == 0.0
    assert st["outlier_fraction"] == 0.0


def test_depth_step_through_industrial_sensor(rig, box_render):
    """The same scene through the 'industrial' camera model (shot + read noise, 12 bit,
    radiance 1.0 -> 8000 e-): decoding with the sensor's own noise law and saturation level,
    and with the default (residual-estimated) noise, loses no order and leaves the shadow empty."""
    cam, proj = rig
    sensor = SensorModel.preset("industrial")
    dn, sat = sensor.apply(box_render.images, 7)
    for kw in (dict(noise_sigma=sensor.noise_sigma, saturation=sat), dict(saturation=sat)):
        res = decode(dn, **decode_kw(cam, proj, **kw))
        check_contract(res)
        assert not order_errors(res, box_render).any()
        assert res.valid[box_render.lit].mean() > 0.995
        assert not res.valid[box_render.shadow].any()


def test_small_baseline_float32():
    """5 mm baseline at 1 m: |dZ/dx| = Z^2/(f_p b) ~ 0.33 m per projector pixel. Noise-free,
    float32 input: only float32 rounding of x (<= 1 ulp after combination) and of the
    evaluation remain: |error| <= 2 |dZ/dx| ulp(x) + 4 ulp(Z) (docs/STRUCTURED_LIGHT.md: <= 5 um)."""
    cam, proj = synth.make_rig(baseline=0.005)
    r = synth.render(synth.plane_scene(), cam, proj, PERIODS, STEPS)
    res = decode(r.images.astype(np.float32), **decode_kw(cam, proj))
    check_contract(res)
    assert res.valid[r.lit].all()
    slope = synth.depth_slope(cam, proj, r.depth)
    ulp_x = np.spacing(np.abs(r.proj_x).astype(np.float32)).astype(float)
    bound = 2 * slope * ulp_x + 4 * np.spacing(r.depth.astype(np.float32))
    err = np.abs(res.depth - r.depth)
    assert np.all(err[res.valid] <= bound[res.valid])
    assert err[res.valid].max() < 10e-6


def test_ray_in_column_plane_is_ill_conditioned():
    cam, proj = synth.make_rig(cam_size=(161, 121), proj_offset=(0, 0, -0.3), converge=False)
    r = synth.render(synth.plane_scene(), cam, proj, PERIODS, STEPS)
    res = decode(r.images, **decode_kw(cam, proj))
    check_contract(res)
    assert np.all(res.reason[:, 80] == Reason.ILL_CONDITIONED)
    slope = synth.depth_slope(cam, proj, r.depth)
    np.testing.assert_array_equal(res.reason == Reason.ILL_CONDITIONED, r.lit & (slope > r.depth))
    assert np.abs(res.depth - r.depth)[res.valid].max() < 1e-4


def test_grazing_surfaces_short_camera_periods():
    """A wide-angle camera (f = 100 px) sees the finest fringes (8 projector px) with camera
    periods P of 0.7-1.5 px; tilting the plane shortens them. Pixels integrate 4x4 samples, so the
    fringe modulation drops by the box-filter response sin(pi/P)/(pi/P) (negative, i.e. phase
    flipped by pi, for 0.5 < P < 1). Requirements: no valid pixel with a wrong order (error
    > T/4 = 2 px) anywhere; where P >= 1.2 px (response >= 0.53) every fully lit pixel decodes and
    its error stays within 6 sigma_x of the attenuated modulation plus 0.01 px of curvature bias."""
    cam, proj = synth.make_rig(f_cam=100)
    sigma = 0.004
    for ang in (0, 60, 75):
        r = synth.render(synth.tilted_plane_scene(ang), cam, proj, PERIODS, STEPS, supersample=4)
        grad = np.hypot(*np.gradient(r.proj_x))
        period = 8.0 / grad
        res = decode(add_noise(r.images, sigma, ang).astype(np.float32), **decode_kw(cam, proj, noise_sigma=sigma))
        check_contract(res)
        err = np.abs(res.proj_x - r.proj_x)
        inner = binary_erosion(r.lit, iterations=1)
        assert not (res.valid & inner & ~(err < 2.0)).any()
        good = inner & (period >= 1.2)
        if good.any():
            assert res.valid[good].all()
            att = np.sinc(1.0 / period[good])           # np.sinc(t) = sin(pi t)/(pi t)
            sx = effective_period(512, (8, 64)) / (2 * np.pi) * theoretical_phase_sigma(sigma, 0.5 * att, STEPS)
            assert np.all(err[good] <= 6 * sx + 0.01)
        flipped = inner & (period < 0.95)
        assert not (res.valid & flipped & ~(err < 2.0)).any()


def test_pure_noise_is_not_decoded():
    """B = 0 exactly (no fringe, only noise sigma = 0.01 on A = 0.3). Estimated modulation follows a
    Rayleigh law with scale sigma*sqrt(2/N); the floor passes a frequency with probability
    p = 1e-3, all three with 1e-9, so among 19200 pixels none may be valid (expected 2e-5).
    Checked with the true sigma and with the default per-pixel estimate of sigma (datapipe.sl.noise)."""
    rng = np.random.default_rng(9)
    cam, proj = synth.make_rig()
    imgs = 0.3 + rng.normal(0, 0.01, (12, 120, 160))
    for kw in (dict(noise_sigma=0.01), {}):
        res = decode(imgs, **decode_kw(cam, proj, **kw))
        check_contract(res)
        assert res.valid.sum() == 0
        if not kw:
            assert res.extras["noise_model"]["kind"] == "fit"
            assert float(fit_noise_model(list(imgs), STEPS)(0.3)) == pytest.approx(0.01, rel=0.05)


@pytest.mark.parametrize("known_sigma", [True, False])
def test_modulation_floor_follows_rician_law(rig, plane_render, known_sigma):
    """Bands of modulation B/s = 0, 1, ..., 7 (s = sigma sqrt(2/N)) on the projector coordinates of
    a plane; one frequency K = 1 (no order stage), p = 0.05 per frequency. The probability that a
    pixel passes the floor t = s sqrt(-2 ln p) is the Rician survival function sf(t/s; B/s): the
    NO_LIGHT fraction of each band (2400 px) must match within 5 binomial sigmas (+1% for the
    estimated sigma's own scatter, which is ~1% with 19k x 1 dof)."""
    cam, proj = rig
    sigma, n = 0.01, 4
    s = sigma * np.sqrt(2 / n)
    x = plane_render.proj_x
    levels = np.repeat(np.arange(8), 15)[:, None] * s          # 8 bands of 15 rows
    rng = np.random.default_rng(10)
    imgs = np.stack([0.5 + levels * np.cos(2 * np.pi * x / 512 + 2 * np.pi * k / n) for k in range(n)])
    imgs = imgs + rng.normal(0, sigma, imgs.shape)
    kw = dict(noise_sigma=sigma) if known_sigma else {}
    res = decode(imgs, **decode_kw(cam, proj, periods=(1,), steps=n, false_valid_rate=0.05,
                                   min_contrast=0.0, **kw))
    t = np.sqrt(-2 * np.log(0.05))
    for i in range(8):
        band = res.reason[i * 15:(i + 1) * 15] == Reason.NO_LIGHT
        p_pass = stats.rice.sf(t, i)
        p_nl = 1 - p_pass
        tol = 5 * np.sqrt(p_nl * (1 - p_nl) / band.size) + (0 if known_sigma else 0.01) + 1e-9
        assert band.mean() == pytest.approx(p_nl, abs=tol), i


@pytest.mark.parametrize("n, albedo", [(3, 1.06), (4, 1.25)])
def test_saturation(rig, n, albedo):
    """Fringes 6% / 25% over the saturation level 1.0. N = 4: pixels with one clipped sample are
    solved from the other three (exact: 1 um as noise-free), two or more -> SATURATED. N = 3: any
    clipped sample leaves 2 < 3 -> SATURATED. Without the exclusion the clipped samples bias the
    phase (~0.04 rad, docs/STRUCTURED_LIGHT.md), i.e. the depth by far more than 0.1 mm."""
    cam, proj = rig
    r = synth.render(synth.plane_scene(albedo=albedo), cam, proj, PERIODS, n)
    imgs = np.minimum(r.images, 1.0).astype(np.float32)
    res = decode(imgs, **decode_kw(cam, proj, steps=n, saturation=1.0))
    check_contract(res)
    nsat = (imgs >= 1.0).reshape(len(PERIODS), n, *imgs.shape[1:]).sum(1)
    flagged = np.any(nsat > n - 3, axis=0) & r.lit
    np.testing.assert_array_equal(res.reason == Reason.SATURATED, flagged)
    assert np.abs(res.depth - r.depth)[res.valid].max() <= 1e-6
    if n == 4:
        assert (res.valid & np.any(nsat == 1, axis=0)).sum() > 1000
    naive = decode(imgs, **decode_kw(cam, proj, steps=n, saturation=np.inf, noise_sigma=1e-3))
    assert np.nanmax(np.abs(naive.depth - r.depth)) > 1e-4


def test_gamma_at_three_steps(rig):
    """A residual gamma 2.2 tone curve at N = 3 gives ~0.2 rad RMS (0.29 max) phase error
    (docs/STRUCTURED_LIGHT.md, and test_sl_phase). Through a stage of ratio 4 that is up to 0.19 cycles of order
    deviation while the noise (sigma 1e-3 on B = 0.5) predicts 0.002: below the 0.25 of an order
    at which datapipe.sl.confidence calls a pixel INCONSISTENT, so the orders are right and the
    pixels are kept, as a real scanner keeps them -- every lit pixel valid or, where the bias does
    reach the limit, INCONSISTENT, none with a wrong order; the valid ones carry the biased phase: each frequency's
    coordinate is off by <= 0.29/(2 pi) T_i, the K^2-weighted mean (weights w_i) by
    <= 0.29/(2 pi) sum(w_i T_i), |dZ/dx| times that in depth (+5% for the slope's variation).
    The same intensities decoded with ``projector_gamma=2.2`` (the curve here is ``I ** 2.2``, i.e.
    what a projector of gamma 2.2 emits; albedo and exposure only scale it) come back exact: every
    lit pixel valid, depth within 1 um (the spec's noise-free bound)."""
    cam, proj = rig
    per = (1, 4, 16, 64)
    r = synth.render(synth.plane_scene(), cam, proj, per, 3, gamma=1 / 2.2)
    kw = decode_kw(cam, proj, periods=per, steps=3, noise_sigma=1e-3)
    res = decode(r.images.astype(np.float32), **kw)
    check_contract(res)
    assert np.mean(res.valid[r.lit]) > 0.95
    assert np.all((res.reason[r.lit] == Reason.INCONSISTENT) | res.valid[r.lit])
    assert not order_errors(res, r, per).any()
    slope = synth.depth_slope(cam, proj, r.depth)
    ks = [k for k in per if k * k >= 0.01 * sum(q * q for q in per)]
    w = np.array(ks, float) ** 2 / sum(k * k for k in ks)
    xbound = 0.29 / (2 * np.pi) * np.sum(w * 512 / np.array(ks, float))
    assert np.all(np.abs(res.depth - r.depth)[res.valid] <= (slope * xbound)[res.valid] * 1.05)
    fixed = decode(r.images.astype(np.float32), **kw, projector_gamma=2.2)
    check_contract(fixed)
    assert fixed.valid[r.lit].all()
    assert np.abs(fixed.depth - r.depth)[fixed.valid].max() <= 1e-6


def test_projector_edges():
    """A wide camera (f = 120 px) sees both projector edges. With noise sigma = 0.02 the coarse
    phase alone (sigma_x ~ 1.5 px) would wrap for pixels near the edges (13-18% within 5 px in
    docs/STRUCTURED_LIGHT.md); here no lit pixel within 5 px of an edge may get a wrong order, except within
    6 sigma_x of the wrap point itself (x = -0.5 == W - 0.5), see test_sl_unwrap."""
    cam, proj = synth.make_rig(f_cam=120)
    r = synth.render(synth.plane_scene(), cam, proj, PERIODS, STEPS)
    x = r.proj_x
    W = proj.size[0]
    edge = r.lit & ((x < 5) | (x > W - 6))
    assert edge.sum() > 150
    sigma = 0.02
    sx = effective_period(W, (8, 64)) / (2 * np.pi) * theoretical_phase_sigma(sigma, 0.5, STEPS)
    near = np.minimum(np.abs(x + 0.5), np.abs(x - (W - 0.5))) < 6 * sx
    for seed in range(3):
        res = decode(add_noise(r.images, sigma, 20 + seed), **decode_kw(cam, proj))
        check_contract(res)
        assert not (order_errors(res, r) & ~near).any()
        assert res.valid[edge & ~near].mean() > 0.99
        # off the projector: never valid; pure noise passes the joint modulation floor with
        # probability false_valid_rate = 1e-3 (then its frequencies disagree: BAD_ORDER)
        assert not res.valid[~r.lit].any()
        assert np.mean(res.reason[~r.lit] != Reason.NO_LIGHT) < 3e-3


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_integer_images(rig, plane_render, dtype):
    """Quantised inputs: 8 bit with 1 DN of noise before rounding -> sigma_I^2 = 1 + 1/12 DN^2
    (docs/STRUCTURED_LIGHT.md), B = 0.45 * 255 DN. The depth noise must match theory like float input (10%:
    19k pixels, 0.5% standard error; quantisation is not exactly Gaussian). 16 bit: quantisation
    alone (1/sqrt(12) DN on B = 29500 DN) is ~1e-5 rad: depth within 10 um."""
    cam, proj = rig
    r = plane_render
    scale = float(np.iinfo(dtype).max) * 0.9
    noise = 1.0 if dtype == np.uint8 else 0.0
    img = add_noise(r.images * scale, noise, 3) if noise else r.images * scale
    q = np.clip(np.rint(img), 0, np.iinfo(dtype).max).astype(dtype)
    res = decode(q, **decode_kw(cam, proj))
    check_contract(res)
    assert res.valid[r.lit].all()
    err = (res.depth - r.depth)[res.valid]
    if dtype == np.uint8:
        slope = synth.depth_slope(cam, proj, r.depth)[res.valid]
        sphi = theoretical_phase_sigma(np.sqrt(noise ** 2 + 1 / 12), 0.5 * scale, STEPS)
        sx = effective_period(512, (8, 64)) / (2 * np.pi) * sphi
        assert np.std(err / (slope * sx)) == pytest.approx(1.0, rel=0.1)
    else:
        assert np.abs(err).max() < 10e-6


def test_nonfinite_inputs(rig, plane_render):
    cam, proj = rig
    imgs = add_noise(plane_render.images, 0.01, 4).astype(np.float32)
    clean = decode(imgs, **decode_kw(cam, proj, noise_sigma=0.01))
    bad = imgs.copy()
    bad[0, 10, 10] = np.nan
    bad[5, 20, 30] = np.inf
    bad[11, 30, 50] = -np.inf
    bad[:, 40, 60] = np.nan
    res = decode(bad, **decode_kw(cam, proj, noise_sigma=0.01))
    check_contract(res)
    hit = np.zeros(res.valid.shape, bool)
    hit[[10, 20, 30, 40], [10, 30, 50, 60]] = True
    np.testing.assert_array_equal(res.reason == Reason.INVALID_INPUT, hit)
    np.testing.assert_array_equal(res.depth[~hit], clean.depth[~hit])
    # the default noise estimate ignores the non-finite samples
    dflt = decode(bad, **decode_kw(cam, proj))
    nm = dflt.extras["noise_model"]
    assert nm["kind"] in ("fit", "floor") and np.isfinite(nm["read_sigma"]) and (dflt.reason == Reason.INVALID_INPUT).sum() == 4


def test_input_layouts_and_axis_y():
    """(F*N, H, W), (F, N, H, W) and a list decode identically; vertical coding (axis='y') with a
    vertical baseline decodes as exactly as columns do."""
    cam, proj = synth.make_rig(proj_offset=(0.0, 0.15, 0.0))
    r = synth.render(synth.sphere_scene(), cam, proj, PERIODS, STEPS, axis="y")
    kw = decode_kw(cam, proj, axis="y")
    a = decode(r.images, **kw)
    b = decode(r.images.reshape(3, 4, 120, 160), **kw)
    c = decode(list(r.images), **kw)
    check_contract(a)
    for o in (b, c):
        np.testing.assert_array_equal(a.depth, o.depth)
    np.testing.assert_array_equal(a.valid, r.lit)
    assert np.abs(a.depth - r.depth)[a.valid].max() <= 1e-6


def test_repeat_decode_uses_cached_geometry(rig, plane_render):
    from datapipe.sl import Triangulator
    cam, proj = rig
    Triangulator.clear_cache()
    decode(plane_render.images, **decode_kw(cam, proj))
    tri = Triangulator.cached(cam.P, proj.P, cam.size, proj.size)
    coef = tri.coefficients
    decode(plane_render.images, **decode_kw(cam, proj))
    assert Triangulator.cached(cam.P, proj.P, cam.size, proj.size).coefficients is coef


@pytest.mark.parametrize("change, exc, msgs", [
    (dict(images=np.zeros((12, 8))), ValueError, ["images", "(F*N, H, W)"]),
    (dict(images=np.zeros((11, 8, 8))), ValueError, ["11 images", "needs 12"]),
    (dict(images=np.zeros((4, 3, 8, 8))), ValueError, ["(F, N) = (4, 3)"]),
    (dict(steps=2, images=np.zeros((6, 8, 8))), ValueError, ["steps", ">= 3"]),
    (dict(periods=(8, 64), images=np.zeros((8, 8, 8))), ValueError, ["periods", "(1, 8, 64)"]),
    (dict(P_cam=np.full((3, 4), np.inf)), ValueError, ["P_cam", "NaN or inf"]),
    (dict(P_proj=np.eye(3)), ValueError, ["P_proj", "shape"]),
    (dict(proj_size=(512,)), TypeError, ["proj_size"]),
    (dict(images=np.zeros((12, 8, 8), bool)), TypeError, ["dtype"]),
    (dict(images="frames"), TypeError, ["images"]),
    (dict(noise_sigma=np.ones((3, 3))), ValueError, ["noise_sigma", "shape"]),
    (dict(shifts=[0, 1, 2]), ValueError, ["shifts"]),
    (dict(unwrap="spatial"), ValueError, ["unknown method"]),
    (dict(max_order_error=0.7), ValueError, ["max_order_error"]),
])
def test_argument_errors(rig, change, exc, msgs):
    cam, proj = rig
    kw = decode_kw(cam, proj)
    kw["images"] = np.zeros((12, 8, 8), np.float32)
    kw.update(change)
    images = kw.pop("images")
    with pytest.raises(exc) as ei:
        decode(images, **kw)
    assert isinstance(ei.value, DataPipeError) and "fix:" in str(ei.value)
    for m in msgs:
        assert m in str(ei.value)


def test_patterns_module_drives_decoder_identically(rig):
    """fringe_patterns(...) sampled at integer projector columns == the continuous formula the
    synth uses: decoding a camera that sees the projector image 1:1 returns the column index."""
    cam, proj = rig
    W, H = 64, 8
    pats = fringe_patterns(W, H, (1, 4, 16), 4, dtype=np.float64)
    from datapipe.sl import phase_shift, unwrap_phase
    ph = [phase_shift(pats[i * 4:(i + 1) * 4]).phase for i in range(3)]
    x = unwrap_phase(ph, (1, 4, 16), proj_width=W).x
    np.testing.assert_allclose(x, np.broadcast_to(np.arange(W), (H, W)), atol=1e-4)


def _ramp(rig, per=(20, 19), seed=11):
    cam, proj = rig
    r = synth.render(synth.plane_scene(), cam, proj, per, STEPS)
    ramp = np.linspace(0.1, 1.0, r.images.shape[2])[None, None, :]
    return r, add_noise(r.images * ramp, 0.01, seed)


def test_low_snr_orders_are_refused(rig):
    """Two-frequency 20/19 (the original DataPipe's scheme, stage gain sqrt(20^2 + 19^2) = 27.6,
    docs/STRUCTURED_LIGHT.md) on an albedo ramp 0.1 .. 1 (B = 0.05 .. 0.5) with sigma = 0.01: at B = 0.1 the order
    estimate has sigma_k = 27.6 * sqrt(2/4) * 0.01 / 0.1 = 1.95 rad and is wrong with probability
    erfc(pi / (sqrt(2) sigma_k)) = 11%. Decoding every pixel (max_wrong=1, no neighbours) gets
    hundreds of orders wrong; the default decision keeps none of them, and with its surface's pooled
    evidence (sl.orders: one order offset for the whole ramp, hundreds of pixels' coarse phases
    voting) it keeps nearly every pixel, still with no order wrong. The former worst-case floor
    (order_sigmas=5: B >= 0.31) still works and refuses the dark half."""
    cam, proj = rig
    per = (20, 19)
    r, imgs = _ramp(rig, per)
    kw = decode_kw(cam, proj, periods=per, noise_sigma=0.01)
    loose = decode(imgs, **kw, max_wrong=1.0, spatial=False)
    assert order_errors(loose, r, per).sum() > 300
    own = decode(imgs, **kw, spatial=False)
    res = decode(imgs, **kw)
    for x in (own, res):
        check_contract(x)
        assert not order_errors(x, r, per).any()
    # one pixel's 20/19 phases cannot tell its order at the dark end; the ramp's pixels together can
    # (before issue #31 the dark end stayed a hole: 0.7-0.9 of the lit pixels)
    assert 0.7 < own.valid[r.lit].mean() < 0.9
    assert res.valid[r.lit].mean() >= 0.99
    legacy = decode(imgs, **kw, order_sigmas=5, spatial=False)
    floor = legacy.extras["order_floor"]
    assert floor == pytest.approx(5 * 27.586 * np.sqrt(0.5) * 0.01 / np.pi, rel=1e-3)
    modulation = 0.5 * np.linspace(0.1, 1.0, imgs.shape[2])[None, :]
    assert np.all(legacy.reason[r.lit & (modulation < 0.7 * floor)] == Reason.BAD_ORDER)


@pytest.mark.parametrize("per", [(20, 19), (1, 16)])
def test_confidence_is_calibrated(rig, per):
    """The per-pixel probability of a wrong order (1 - confidence, datapipe.sl.confidence) against
    the wrong orders actually decoded (every pixel kept, no neighbours), two noise seeds: in each
    band of predicted probability the observed count must match the predicted sum within 4 Poisson
    sigmas + 3 (and the band of p < 1e-3 must hold at most 3 wrong pixels)."""
    cam, proj = rig
    half = proj.size[0] / max(per) / 2
    pred = {}
    obs = {}
    bands = [(0, 1e-3), (1e-3, 1e-2), (1e-2, 0.1), (0.1, 0.3), (0.3, 1.01)]
    for seed in (11, 12):
        r, imgs = _ramp(rig, per, seed)
        res = decode(imgs, **decode_kw(cam, proj, periods=per, noise_sigma=0.01), max_wrong=1.0, spatial=False)
        pw = 1 - res.confidence
        wrong = ~(np.abs(res.proj_x - r.proj_x) < half)
        for band in bands:
            m = res.valid & r.lit & (pw >= band[0]) & (pw < band[1])
            pred[band] = pred.get(band, 0) + pw[m].sum()
            obs[band] = obs.get(band, 0) + wrong[m].sum()
    assert sum(obs.values()) > 50                 # the scene does get orders wrong
    for band in bands:
        assert abs(obs[band] - pred[band]) <= 4 * np.sqrt(pred[band]) + 3, (band, obs[band], pred[band])


@pytest.mark.parametrize("seed", range(4))
def test_random_rigs(seed):
    """Random baselines (direction and length 2-30 cm), converging or not, random periods scheme,
    sphere-on-plane scene, sigma = 0.005: the output contract holds, no valid pixel has a wrong order,
    and the depth error of valid pixels stays within 6 sigma_Z (per-pixel theory) + 1 um."""
    rng = np.random.default_rng(1000 + seed)
    d = rng.normal(size=3)
    d[2] *= 0.3
    off = d / np.linalg.norm(d) * rng.uniform(0.02, 0.3)
    cam, proj = synth.make_rig(proj_offset=off, converge=bool(seed % 2), distance=rng.uniform(0.7, 1.3))
    per = [PERIODS, (16, 15), (70, 64, 59), (1, 4, 16, 64)][seed]
    r = synth.render(synth.sphere_scene(), cam, proj, per, STEPS)
    sigma = 0.005
    res = decode(add_noise(r.images, sigma, seed).astype(np.float32), **decode_kw(cam, proj, per, noise_sigma=sigma))
    check_contract(res)
    assert not order_errors(res, r, per).any()
    slope = synth.depth_slope(cam, proj, r.depth)
    kept = [k for k in per if k * k >= 0.01 * sum(q * q for q in per)]
    sx = effective_period(512, kept) / (2 * np.pi) * theoretical_phase_sigma(sigma, 0.5, STEPS)
    err = np.abs(res.depth - r.depth)
    assert np.all(err[res.valid] <= 6 * (slope * sx)[res.valid] + 1e-6)
    assert res.valid[r.lit & (slope < 0.5 * r.depth)].mean() > 0.98


def test_pixel_depth_sigma_predicts_the_measured_noise():
    """`pixel_depth_sigma` (per pixel, from each frequency's measured modulation, the noise sigma and
    the triangulation slope) against the error actually measured over 77k pixels: the errors
    divided by it have unit std (5%, as the normalised test above), for a constant sigma and for a
    callable noise model. A wrong K^2 combination or slope would move it by > 30%."""
    from datapipe.sl import pixel_depth_sigma
    cam, proj = synth.make_rig(cam_size=(320, 240))
    r = synth.render(synth.plane_scene(), cam, proj, PERIODS, STEPS)
    sigma = 0.01
    res = decode(add_noise(r.images, sigma, 2).astype(np.float32), **decode_kw(cam, proj))
    for noise in (sigma, lambda signal: np.full_like(signal, sigma)):
        sz = pixel_depth_sigma(res, noise, proj.size[0], STEPS)
        assert np.isnan(sz[~res.valid]).all() and np.isfinite(sz[res.valid]).all()
        err = (res.depth - r.depth)[res.valid]
        assert np.std(err / sz[res.valid]) == pytest.approx(1.0, rel=0.05)


def _harmonics(gamma, a=0.5, b=0.5, n=4096):
    """Fourier cosine coefficients c_h of (a + b cos t) ** gamma (numerically, independent of the
    decoder's tables)."""
    t = 2 * np.pi * np.arange(n) / n
    return np.real(np.fft.rfft((a + b * np.cos(t)) ** gamma)) * 2 / n


def test_projector_gamma_ripple_and_its_correction(rig):
    """A projector of gamma 2.2 emits harmonics c_h of the sinusoid. With N = 4 steps the
    harmonics 3 (as e^{-3i phi}) and 5 alias into the fundamental, so to first order the phase
    error is a ripple (c_5 - c_3) / c_1 * sin(4 phi), 4 periods per fringe. Uncorrected, the
    measured error's sin(4 phi) component must match that amplitude (5%; the second-order terms
    are ~(c_3/c_1)^2 ~ 1%) and explain it (RMS residual < 10% of the ripple); with
    ``projector_gamma=2.2`` the error vanishes to noise-free precision (1 um of depth, as
    test_noise_free_is_exact), on a plane with a dark patch (albedo scales all harmonics alike)."""
    cam, proj = rig
    per = (1, 8, 64)
    r = synth.render(synth.plane_scene(), cam, proj, per, STEPS, projector_gamma=2.2)
    alb = np.ones(r.images.shape[1:])
    alb[40:80, 40:80] = 0.2
    imgs = (r.images * alb).astype(np.float32)
    kw = decode_kw(cam, proj, periods=per, noise_sigma=1e-4)
    raw = decode(imgs, **kw, max_wrong=1.0)
    phi = 2 * np.pi * 64 * r.proj_x / proj.size[0]
    err = np.angle(np.exp(1j * (raw.wrapped[2] - phi)))[r.lit]
    ph = phi[r.lit]
    s4 = np.sin(4 * ph)
    amp = np.sum(err * s4) / np.sum(s4 * s4)                   # least-squares sin(4 phi) amplitude
    c = _harmonics(2.2)
    want = (c[5] - c[3]) / c[1]
    assert abs(want) > 5e-3
    assert amp == pytest.approx(want, rel=0.05)
    assert np.sqrt(np.mean((err - amp * np.sin(4 * ph)) ** 2)) < 0.1 * abs(want)
    fixed = decode(imgs, **kw, projector_gamma=2.2)
    check_contract(fixed)
    assert fixed.valid[r.lit].all()
    err_fixed = np.angle(np.exp(1j * (fixed.wrapped[2] - phi)))[r.lit]
    assert np.abs(err_fixed).max() < 1e-4
    assert np.abs(fixed.depth - r.depth)[fixed.valid].max() <= 1e-6
