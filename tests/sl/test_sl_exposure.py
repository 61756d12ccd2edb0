"""Auto exposure and HDR fusion (datapipe.sl.exposure) on synthetic fringe stacks, without Blender.

Ground truth: the analytic plane render of `synth` (depth per pixel) scaled by a known per-pixel
reflectance map, so the dynamic range of the scene is set by construction."""
import numpy as np
import pytest

import synth
from sl_helpers import PERIODS, STEPS, decode_kw

from datapipe import sl
from datapipe.errors import DataPipeError
from datapipe.sl import exposure as X

IND = sl.SensorModel.preset("industrial")
FW_RAD = IND.full_well / IND.electrons_per_unit      # radiance that fills the well at exposure 1


@pytest.fixture(scope="module")
def plane(rig):
    cam, proj = rig
    return cam, proj, synth.render(synth.plane_scene(), cam, proj, PERIODS, STEPS)


def reflectance_ramp(shape, lo, hi):
    """Per-pixel gain growing geometrically from `lo` (left) to `hi` (right): a scene with a
    dynamic range of hi/lo."""
    H, W = shape
    return np.broadcast_to(np.geomspace(lo, hi, W)[None, :], (H, W))


# -- auto exposure --------------------------------------------------------------------------------

def test_auto_exposure_puts_the_metered_peak_at_the_target(plane):
    """Peaks (A + B = 1 x gain) span a 4x ramp; the 99th percentile of the lit peaks must land at
    80% of the full well; with that exposure at most 1% of the lit pixels clip, with 1.5x it
    more do."""
    cam, proj, r = plane
    gain = reflectance_ramp(r.lit.shape, 0.5, 2.0)
    stack = (r.images * gain).astype(np.float32)
    e = X.auto_exposure(stack, IND)
    peak = stack.max(axis=0)[r.lit]
    assert e * np.percentile(peak, 99) == pytest.approx(0.8 * FW_RAD, rel=0.01)
    def clipped(exposure):
        dn, sat = IND.apply(stack * exposure, 3)
        return (dn >= sat).any(axis=0)[r.lit].mean()
    assert clipped(e) <= 0.01
    assert clipped(1.5 * e) > 0.05          # the target leaves a margin, not a wide one


def test_auto_exposure_ignores_unmodulated_light(plane):
    """A bright area outside the projector's reach (ambient only: no swing) must not pull the
    exposure down; ambient on the lit pixels raises their peaks and so lowers it."""
    cam, proj, r = plane
    stack = r.images.astype(np.float32)
    e0 = X.auto_exposure(stack, IND)
    lamp = stack.copy()
    lamp[:, ~r.lit] = 50.0                    # a lamp in view, unmodulated
    assert X.auto_exposure(lamp, IND) == pytest.approx(e0, rel=1e-6)
    lifted = stack + 1.0 * r.lit              # ambient of the projector's peak level on every lit pixel
    assert X.auto_exposure(lifted, IND) == pytest.approx(e0 / 2, rel=0.02)


def test_auto_exposure_fallbacks():
    dark = np.zeros((12, 8, 8), np.float32)
    assert X.auto_exposure(dark, IND) == X.FALLBACK_EXPOSURE
    ideal = sl.SensorModel.preset("ideal")
    assert X.auto_exposure(np.random.default_rng(0).uniform(0, 1, (12, 8, 8)), ideal) == 1.0
    tiny = np.zeros((12, 8, 8), np.float32)
    tiny[0] = 1e-9                            # modulated but absurdly dark: clamped
    assert X.auto_exposure(tiny, IND) == X.EXPOSURE_LIMITS[1]


# -- single exposure ------------------------------------------------------------------------------

def test_single_exposure_is_the_sensor_model_itself(plane):
    cam, proj, r = plane
    cap = X.capture(r.images, IND, [0.7], 5)
    dn, sat = IND.apply(np.clip(r.images.astype(np.float32), 0, None) * np.float32(0.7), 5)
    assert cap.images.tobytes() == dn.tobytes() and cap.saturation == sat
    assert cap.chosen is None and cap.noise_sigma == IND.noise_sigma
    assert X.exposure_set(0.7, None) == [0.7]
    assert X.exposure_set(0.5, [1, 4, 16]) == [0.5, 2.0, 8.0]


# -- HDR fusion -----------------------------------------------------------------------------------

def test_hdr_recovers_a_scene_no_single_exposure_covers(plane):
    """Reflectance spans 2000x. At the exposure that keeps the brightest pixels unsaturated, the
    darkest part has no fringe above the noise floor; at 16x that exposure the bright half clips.
    Fused [1, 4, 16] the decoder gets depth nearly everywhere, with errors at the noise level:
    the fused noise sigma it is given must be the real one (checked through the phase error)."""
    cam, proj, r = plane
    gain = reflectance_ramp(r.lit.shape, 0.001, 2.0)
    stack = (r.images * gain).astype(np.float32)
    base = X.auto_exposure(stack, IND)
    kw = decode_kw(cam, proj, min_contrast=0.05)
    lit = r.lit

    def valid_frac(cap):
        res = sl.decode(cap.images, noise_sigma=cap.noise_sigma, saturation=cap.saturation, **kw)
        return res, res.valid[lit].mean()

    low, v_low = valid_frac(X.capture(stack, IND, [base], 1))
    high, v_high = valid_frac(X.capture(stack, IND, [16 * base], 1))
    cap = X.capture(stack, IND, X.exposure_set(base, [1, 4, 16]), 1)
    fused, v_fused = valid_frac(cap)
    assert v_fused > max(v_low, v_high) + 0.1
    assert v_fused > 0.99                             # single exposures: 0.76 and 0.70
    counts = np.bincount(cap.chosen.ravel(), minlength=len(cap.exposures))   # pixels per exposure
    assert len(counts) == 3 and min(counts) > 0           # every exposure serves part of the ramp
    # the highest exposure serves the dark side, the base exposure the bright side
    W = lit.shape[1]
    assert np.all(cap.chosen[:, : W // 8][lit[:, : W // 8]] == 2)
    assert np.all(cap.chosen[:, -W // 8:][lit[:, -W // 8:]] == 0)
    err = (fused.depth - r.depth)[fused.valid & lit]
    assert np.median(np.abs(err)) < 1e-3
    # noise consistency: phase error / predicted phase sigma ~ N(0, 1) on the finest frequency
    ok = fused.valid & lit
    sig = cap.noise_sigma[ok]
    sphi = sl.theoretical_phase_sigma(sig, fused.modulation[-1][ok], STEPS)
    true_phi = 2 * np.pi * PERIODS[-1] * r.proj_x[ok] / proj.size[0]
    dphi = np.angle(np.exp(1j * (fused.wrapped[-1][ok] - np.mod(true_phi, 2 * np.pi))))
    z = dphi / sphi
    assert 1.4826 * np.median(np.abs(z - np.median(z))) == pytest.approx(1.0, abs=0.15)


def test_hdr_fused_units_and_saturation(plane):
    """Fused values are DN at the reference exposure: a pixel served by a 4x exposure reads 1/4 of
    its DN there. Pixels clipped in every exposure (and only those) reach the fused saturation."""
    cam, proj, r = plane
    gain = reflectance_ramp(r.lit.shape, 0.05, 20.0)
    stack = (r.images * gain).astype(np.float32)
    e = [0.5, 2.0]
    cap = X.capture(stack, IND, e, 9)
    noiseless = stack * np.float32(0.5) * IND.electrons_per_unit / IND.gain
    m = cap.chosen == 1
    assert m.any() and (cap.chosen == 0).any()
    rel = np.abs(cap.images[:, m] - noiseless[:, m]).mean() / noiseless[:, m].mean()
    assert rel < 0.03
    clipped_everywhere = (stack.max(axis=0) * 0.5 * IND.electrons_per_unit) > IND.full_well * 1.05
    assert clipped_everywhere.any()
    reaches = (cap.images >= cap.saturation).any(axis=0)
    assert np.all(reaches[clipped_everywhere])
    assert not reaches[cap.chosen == 1].any()


def test_hdr_exposures_have_independent_noise():
    """Two equal exposures fused: each pixel takes one of them; the DN noise of the two streams is
    uncorrelated (independent captures), and the fused map is deterministic in the seed."""
    flat = np.full((4, 200, 200), 0.3, np.float32)
    a = X.capture(flat, IND, [1.0, 1.0000001], 4)
    b = X.capture(flat, IND, [1.0, 1.0000001], 4)
    assert a.images.tobytes() == b.images.tobytes()
    d0, _ = IND.apply(flat, 4)
    d1, _ = IND.apply(flat, X._stream(4, 1))
    c = np.corrcoef(d0.ravel().astype(float), d1.ravel().astype(float))[0, 1]
    assert abs(c) < 0.01


@pytest.mark.parametrize("value, ok", [("auto", True), (0.5, True), (2, True), (0, False), (-1, False),
                                       ("bright", False), (float("nan"), False), (True, False), (None, False)])
def test_check_exposure(value, ok):
    if ok:
        assert X.check_exposure(value) == value
    else:
        with pytest.raises(DataPipeError, match="exposure"):
            X.check_exposure(value)


def test_check_hdr():
    assert X.check_hdr(None) is None and X.check_hdr([]) is None
    assert X.check_hdr([1, 4, 16]) == [1.0, 4.0, 16.0]
    assert X.check_hdr("auto") == "auto"
    for bad in ([1, 1], [1, 0], ["auto"], "1,4", "AUTO"):
        with pytest.raises(DataPipeError, match="hdr"):
            X.check_hdr(bad)


# -- auto HDR ------------------------------------------------------------------------------------

def _highlight(r, factor, share):
    """The plane's stack with a patch of `share` of the lit pixels `factor` x brighter (a specular
    highlight on a shiny part): below 1%, so auto exposure meters the matte rest."""
    gain = np.ones(r.lit.shape)
    rows, cols = np.nonzero(r.lit)
    n = int(share * rows.size)
    sel = np.argsort(rows * r.lit.shape[1] + cols)[r.lit.sum() // 2:][:n]      # a block of lit pixels
    gain[rows[sel], cols[sel]] = factor
    hl = np.zeros(r.lit.shape, bool)
    hl[rows[sel], cols[sel]] = True
    return (r.images * gain).astype(np.float32), hl


def test_auto_hdr_adds_short_exposures_only_for_clipping_highlights(plane):
    """A matte scene keeps its one exposure (no fusion work, the same bytes as hdr=[]). A highlight
    on 0.5% of the lit pixels, 3x the metered level, clips at the auto exposure (every highlight
    pixel SATURATED): auto HDR adds 1/4 (3 x 0.8 x 1/4 = 0.6 of the well) and the decoder gets
    their depth back; 10x needs 1/4 and 1/16 (10 x 0.8 / 16 = 0.5); 200x would need a fourth
    exposure: at most AUTO_HDR_MAX."""
    cam, proj, r = plane
    matte = r.images.astype(np.float32)
    assert X.auto_hdr(matte, IND, X.auto_exposure(matte, IND)) == [1.0]
    kw = dict(K_cam=cam.K, T_world_cam=cam.T)
    T_cp = np.linalg.inv(cam.T) @ proj.T

    def scan(stack, hdr):
        s = sl.Scanner(PERIODS, STEPS, proj.size, proj.K, T_cp, hdr=hdr, min_contrast=0.05)
        return s.scan(stack, 5, kw["K_cam"], kw["T_world_cam"])

    one, auto = scan(matte, []), scan(matte, "auto")
    assert np.array_equal(one.result.depth, auto.result.depth, equal_nan=True) and auto.capture.chosen is None
    stack, hl = _highlight(r, 3.0, 0.005)
    base = X.auto_exposure(stack, IND)
    assert X.auto_hdr(stack, IND, base) == [1.0, 0.25]
    single, fused = scan(stack, []), scan(stack, "auto")
    assert (single.result.reason[hl] == sl.Reason.SATURATED).all()
    assert fused.result.valid[hl].mean() > 0.99 and fused.summary()["hdr"] == [1.0, 0.25]
    assert np.nanmedian(np.abs(fused.result.depth - r.depth)[hl]) < 1e-3
    assert fused.result.valid[r.lit & ~hl].mean() >= single.result.valid[r.lit & ~hl].mean() - 0.001
    assert X.auto_hdr(*_highlight(r, 10.0, 0.005)[:1], IND, base) == [1.0, 0.25, 0.0625]
    assert len(X.auto_hdr(_highlight(r, 200.0, 0.005)[0], IND, base)) == X.AUTO_HDR_MAX


def test_hdr_fusion_keeps_partly_clipped_pixels_at_the_longer_exposure(plane):
    """With `steps`, a pixel whose frequencies each keep >= 3 unclipped samples stays at the longer
    exposure (its clipped samples set to the fused saturation level, which the decoder leaves out)
    instead of moving to a 4x shorter one: more pixels at full signal, the same depth, less noise."""
    cam, proj, r = plane
    gain = reflectance_ramp(r.lit.shape, 0.3, 3.0)
    stack = (r.images * gain).astype(np.float32)
    base = X.auto_exposure(r.images.astype(np.float32) * 0.3, IND)      # metered on the dim end
    e = X.exposure_set(base, [1.0, 0.25])
    old, new = X.capture(stack, IND, e, 2), X.capture(stack, IND, e, 2, steps=STEPS)
    lit = r.lit
    assert (new.chosen == 0)[lit].mean() > (old.chosen == 0)[lit].mean() + 0.05
    partly = lit & (new.chosen == 0) & (new.images >= new.saturation).any(axis=0)
    assert partly.sum() > 100                                   # kept long, with clipped samples
    assert (old.chosen[partly] == 1).all()                      # the old rule moved them down
    kw = decode_kw(cam, proj, min_contrast=0.05)
    ro = sl.decode(old.images, noise_sigma=old.noise_sigma, saturation=old.saturation, **kw)
    rn = sl.decode(new.images, noise_sigma=new.noise_sigma, saturation=new.saturation, **kw)
    assert rn.valid[partly].mean() > 0.99 and ro.valid[partly].mean() > 0.99
    err_o = np.abs(ro.depth - r.depth)[partly]
    err_n = np.abs(rn.depth - r.depth)[partly]
    assert np.median(err_n) < 0.75 * np.median(err_o)           # longer exposure: less noise
    assert rn.valid[lit].mean() >= ro.valid[lit].mean() - 0.001
