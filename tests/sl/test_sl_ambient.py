"""Ambient light in the fringe captures (structured_light.ambient "scene"; no bpy): the scanner adds
the projector-off radiance to every frame before exposure and sensor, takes a projector-off capture,
and its global-light filter takes that capture off the offset.

Ground truth is synth.py's analytic plane (point-sampled, no pixel MTF), so the fine fringe's
modulation is exactly 0.5 x albedo and the expected phase noise of an N-step least-squares fit is
the textbook sigma_phi = sqrt(2/N) sigma_I / B (sl/phase.py), sigma_I the sensor's shot + read +
quantisation noise at the pixel's mean signal A + ambient (SensorModel.noise_sigma)."""
import numpy as np
import pytest
import synth
from sl_helpers import PERIODS, STEPS

from datapipe import sl
from datapipe.sl import exposure as X
from datapipe.sl.filters import global_light_filter

AMBIENT = (0.0, 0.25, 1.0, 2.5)     # hall light, in units of the projector's peak (white pattern) radiance


def _scanner(cam, proj, **kw):
    return sl.Scanner(PERIODS, STEPS, proj.size, proj.K, np.linalg.inv(cam.T) @ proj.T, **kw)


def _wrap(a):
    return np.mod(a + np.pi, 2 * np.pi) - np.pi


@pytest.fixture(scope="module")
def plane(rig):
    cam, proj = rig
    return synth.render(synth.plane_scene(albedo=0.6), cam, proj, PERIODS, STEPS)


def _precision(cam, proj, r, amb_level, seed=7):
    """(measured, predicted) RMS phase error of the finest fringe over the plane's lit pixels away
    from the image border, auto exposure, the projector-off image `amb_level` x albedo."""
    ambient = (amb_level * r.albedo).astype(np.float32)
    model = sl.SensorModel.preset("industrial")
    scan = _scanner(cam, proj, edge_filter=False).scan(r.images.astype(np.float32), seed, cam.K, cam.T,
                                                       ambient=ambient)
    res = scan.result
    K, W = PERIODS[-1], proj.size[0]
    truth = 2 * np.pi * K * r.proj_x / W
    use = r.lit & res.valid
    use[:3], use[-3:], use[:, :3], use[:, -3:] = False, False, False, False
    err = _wrap(res.wrapped[-1] - truth)[use]
    # the prediction from first principles: DN per unit radiance at the scan's exposure
    dn = scan.exposure * model.electrons_per_unit / model.gain
    fine = r.images[-STEPS:]
    A = (fine.mean(axis=0) + ambient) * dn
    B = 0.5 * r.albedo * dn
    sigma_phi = np.sqrt(2.0 / STEPS) * model.noise_sigma(A + model.black_level) / B
    return float(np.sqrt(np.mean(err ** 2))), float(np.sqrt(np.mean(sigma_phi[use] ** 2))), scan


def test_precision_follows_the_photon_noise_prediction_as_the_hall_light_grows(rig, plane):
    """With auto exposure the total peak (projector + hall) is metered to 80% of the full well, so a
    brighter hall lowers the exposure, hence B in electrons, and adds its own shot noise: the phase
    noise grows, and stays within 10% of sqrt(2/N) sigma_I / B at every level (measured on ~15 000
    pixels, a 1% statistical uncertainty of an RMS). Every plane pixel stays valid: the hall light
    alone costs no pixel here (B/A >= 0.12 > MIN_CONTRAST). Measured / predicted: 0.999, 1.000,
    0.997, 1.005. The depth error against the analytic plane follows the scanner's own per-pixel
    `sigma_z` (the annotated precision sees the hall light too): 0.16, 0.22, 0.39, 0.73 mm RMS,
    within 0.3% of it."""
    cam, proj = rig
    out = []
    for level in AMBIENT:
        measured, predicted, scan = _precision(cam, proj, plane, level)
        assert measured == pytest.approx(predicted, rel=0.10), (level, measured, predicted)
        assert scan.result.valid[plane.lit].mean() > 0.99
        v = scan.result.valid & plane.lit
        depth_rms = np.sqrt(np.mean((scan.result.depth - plane.depth)[v] ** 2))
        assert depth_rms == pytest.approx(np.sqrt(np.mean(scan.sigma_z[v] ** 2)), rel=0.10), level
        out.append(measured)
    assert all(b > 1.15 * a for a, b in zip(out, out[1:])), out      # precision falls with the hall light
    assert out[-1] > 2.0 * out[0]


def test_no_flat_matte_pixel_is_taken_for_multipath_because_of_ambient_light(rig, plane):
    """A flat matte plane under a hall light 2.5x as bright as the projector's peak: no pixel is
    MULTIPATH (the projector-off capture leaves the offset to the projector's light). Taken as one
    with the fringes and no projector-off capture (the radiance summed by hand), the offset is 6x
    the modulation and the global-light filter drops the whole plane."""
    cam, proj = rig
    ambient = (2.5 * plane.albedo).astype(np.float32)
    img = plane.images.astype(np.float32)
    scan = _scanner(cam, proj).scan(img, 5, cam.K, cam.T, ambient=ambient)
    assert not (scan.result.reason == sl.Reason.MULTIPATH).any()
    assert not scan.multipath.any()
    assert scan.result.valid[plane.lit].mean() > 0.98
    assert scan.summary()["ambient_to_projector"] == pytest.approx(2.5 / 0.5, rel=0.02)
    assert "ambient" in scan.maps(debug=True)["sl_debug"]
    blind = _scanner(cam, proj).scan(img + ambient[None], 5, cam.K, cam.T)
    assert (blind.result.reason[plane.lit] == sl.Reason.MULTIPATH).mean() > 0.95
    assert "ambient_to_projector" not in blind.summary()


def test_projector_off_capture_keeps_the_global_light_filter_for_bounced_light(rig, plane):
    """Real bounced projector light is still found under a hall light: the right half gets, besides
    the hall light, twice as much bounced projector light as direct (blurred to an offset in the
    fine fringe); g / d = 2 > 0.7, removed; the left half (hall light only) kept."""
    cam, proj = rig
    lit = plane.lit
    cols = np.arange(lit.shape[1])[None, :]
    right = lit & (cols >= lit.shape[1] // 2)
    img = plane.images.copy()
    img[:, right] += 1.0 * plane.albedo[right]          # bounced light g = 2 d: an offset (A = (d + g) / 2)
    ambient = (1.0 * plane.albedo).astype(np.float32)
    scan = _scanner(cam, proj).scan(img.astype(np.float32), 5, cam.K, cam.T, ambient=ambient)
    mp = scan.result.reason == sl.Reason.MULTIPATH
    assert mp[right].mean() > 0.98
    assert not mp[lit & ~right].any()


def test_global_light_filter_noise_margin_adds_the_projector_off_capture():
    """The test itself: offset A = ambient + B (direct light alone) stays below the limit by exactly
    the ambient; with g / d at the limit the margin includes the projector-off capture's noise (a
    pixel 2.9 sigma over the limit with it is kept, 3.1 sigma over removed)."""
    B = np.array([[[100.0]], [[100.0]]])     # (F, H, W): two direct frequencies
    freqs = np.array([True, True])
    sig, s_off = 4.0, 6.0
    tol = 3.0 * np.sqrt(sig ** 2 * (1.7 ** 2 * 2 / 4 + 1 / 8) + s_off ** 2)
    for amb in (0.0, 500.0, 5000.0):
        for over, removed in ((2.9, False), (3.1, True)):
            A = np.array([[amb + 170.0 + over / 3.0 * tol]])
            got = global_light_filter(B, A, freqs, 4, sig, np.ones((1, 1), bool), ambient=np.array([[amb]]),
                                      ambient_sigma=np.array([[s_off]]))
            assert bool(got[0, 0]) is removed, (amb, over)


def test_phase_shift_separates_a_constant_offset_exactly():
    """The DC term: adding the same light c to all N samples moves the least-squares offset A by c
    and leaves the modulation B and the phase unchanged (the cos and sin rows of the pseudo-inverse
    sum to zero over uniform shifts), so a hall light costs the phase nothing but its noise."""
    rng = np.random.default_rng(3)
    phi = rng.uniform(0, 2 * np.pi, (30, 40))
    A0, B0 = rng.uniform(0.2, 1.0, phi.shape), rng.uniform(0.05, 0.2, phi.shape)
    for N in (3, 4, 7):
        d = 2 * np.pi * np.arange(N) / N
        I = A0 + B0 * np.cos(phi[None] + d[:, None, None])
        base = sl.phase_shift(I)
        for c in (0.5, 3.0, 40.0):
            lit = sl.phase_shift(I + c)
            np.testing.assert_allclose(lit.offset, base.offset + c, rtol=1e-12, atol=1e-12)
            np.testing.assert_allclose(lit.modulation, base.modulation, rtol=1e-9, atol=1e-12)
            assert np.abs(_wrap(lit.phase - base.phase)).max() < 1e-9


def test_auto_exposure_meters_the_hall_light_and_finds_the_lit_pixels(rig, plane):
    """Auto exposure puts the total peak (projector + hall) at 80% of the full well; the
    projector-off image tells which pixels the projector lights, which a hall 5x as bright as the
    projector's peak hides from the swing test of the summed stack."""
    model = sl.SensorModel.preset("industrial")
    ambient = 5.0 * plane.albedo
    total = (plane.images + ambient[None]).astype(np.float32)
    peak, lit = X.lit_pixels(total, ambient)
    assert lit[plane.lit].mean() > 0.99 and not lit[~plane.lit].any()
    assert not X.lit_pixels(total)[1].any()             # the summed stack alone: nothing to meter
    e = X.auto_exposure(total, model, lit=(peak, lit))
    expect = X.AUTO_TARGET * model.full_well / model.electrons_per_unit / np.percentile(peak[lit], 99)
    assert e == pytest.approx(expect, rel=1e-9)
    assert e < 0.2 * X.auto_exposure(plane.images.astype(np.float32), model)   # 1 + 5 x the light
    # without the hint the stack meters as before, byte for byte
    p0, l0 = X.lit_pixels(plane.images)
    p1, l1 = X.lit_pixels(plane.images, None)
    assert np.array_equal(l0, l1) and np.array_equal(p0, p1)


def test_a_fixed_exposure_clips_under_a_bright_hall(rig, plane):
    """At a fixed exposure the hall light fills the well: pixels whose projector-off light alone
    is past the full well are SATURATED, the others keep decoding."""
    cam, proj = rig
    model = sl.SensorModel.preset("industrial")
    e = 0.5
    well = model.full_well / model.electrons_per_unit / e          # radiance that fills the well
    cols = np.arange(plane.lit.shape[1])[None, :].repeat(plane.lit.shape[0], 0)
    ambient = np.where(cols < 40, 1.2 * well, 0.2 * well).astype(np.float32)
    scan = _scanner(cam, proj, exposure=e, hdr=[]).scan(plane.images.astype(np.float32), 5, cam.K, cam.T,
                                                        ambient=ambient)
    reason = scan.result.reason
    assert (reason[plane.lit & (cols < 40)] == sl.Reason.SATURATED).all()
    assert scan.result.valid[plane.lit & (cols >= 45)].mean() > 0.98


def test_ambient_must_match_the_image_size(rig, plane):
    cam, proj = rig
    with pytest.raises(ValueError, match="ambient"):
        _scanner(cam, proj).scan(plane.images.astype(np.float32), 5, cam.K, cam.T, ambient=np.zeros((3, 3)))


def test_auto_hdr_adds_shorter_exposures_where_the_hall_light_clips(rig, plane):
    """At a fixed exposure where the hall light alone would fill 1.2x the well on the left 40
    columns, `hdr="auto"` sees the sum and adds shorter exposures (x 1/4): those pixels decode
    again, and the projector-off capture is read at each pixel's fused exposure, rescaled to the
    base exposure's DN (its mean there is the ambient radiance x base exposure in DN, within 4
    sigma of its noise over the region; its noise sigma is the chosen exposure's, rescaled)."""
    cam, proj = rig
    model = sl.SensorModel.preset("industrial")
    e = 0.5
    well = model.full_well / model.electrons_per_unit / e
    cols = np.arange(plane.lit.shape[1])[None, :].repeat(plane.lit.shape[0], 0)
    left = cols < 40
    ambient = np.where(left, 1.2 * well, 0.2 * well).astype(np.float32)
    scan = _scanner(cam, proj, exposure=e, hdr="auto").scan(plane.images.astype(np.float32), 5, cam.K, cam.T,
                                                            ambient=ambient)
    assert scan.summary()["hdr"][:2] == [1.0, 0.25]
    assert scan.result.valid[plane.lit & left].mean() > 0.98
    cap, off = scan.capture, scan.ambient
    assert (cap.chosen[left] != 0).all() and (cap.chosen[cols >= 45] == 0).all()
    dn = e * model.electrons_per_unit / model.gain                   # DN per unit radiance at the base exposure
    region = left & plane.lit
    n = region.sum()
    assert off.signal[region].mean() == pytest.approx(1.2 * well * dn, abs=4 * off.sigma[region].mean() / np.sqrt(n))
    k = int(np.bincount(cap.chosen[region]).argmax())
    scale = cap.reference / cap.exposures[k]
    expect = model.noise_sigma(1.2 * well * dn / scale) * scale
    assert np.median(off.sigma[region & (cap.chosen == k)]) == pytest.approx(expect, rel=0.02)
