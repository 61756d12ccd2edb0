"""Fringe synthesis from a flat-lit render (sl.fringe_synth), against the analytic ray caster of
synth.py: its fringe images evaluate the pattern formula at the exact projector coordinate of each
point sample, independently of the pattern arrays the synthesis interpolates."""
import numpy as np
import pytest

import synth
from sl_helpers import PERIODS, STEPS, decode_kw

from datapipe import sl
from datapipe.sl import pattern_profiles, projector_columns, synthesize_fringes

SS = 2                     # point samples per camera pixel along each axis (the render mode's 2x2)


def flat_lit(scene, cam, proj, ss=SS):
    """What the flat-lit Blender render gives, cast analytically: the white image's direct light
    (albedo where lit), and the world point of every sample on the ss x ss grid per pixel."""
    w, h = cam.size
    direct = np.zeros((h * ss, w * ss))
    hit = np.zeros((h * ss, w * ss), bool)
    albedo = np.zeros((h * ss, w * ss))
    points = np.zeros((h * ss, w * ss, 3))
    offs = (np.arange(ss) + 0.5) / ss - 0.5
    for j, oy in enumerate(offs):
        for i, ox in enumerate(offs):
            t, hs, X, _, lit, _, alb = synth._surface(scene, cam, proj, offset=(ox, oy))
            direct[j::ss, i::ss] = np.where(lit, alb, 0.0)
            hit[j::ss, i::ss] = hs
            albedo[j::ss, i::ss] = alb
            points[j::ss, i::ss] = X
    return direct, hit, albedo, points


def interpolation_bound(K, width, b=0.5):
    """Largest gap between a sinusoid of K periods over `width` samples and its piecewise-linear
    interpolant: b * (2 pi K / width)^2 / 8 (|f''| max times h^2 / 8, h = 1 px)."""
    return b * (2 * np.pi * K / width) ** 2 / 8


def test_direct_light_matches_the_pattern_formula(rig):
    cam, proj = rig
    scene = synth.box_scene(albedo=0.7)
    direct, hit, albedo, points = flat_lit(scene, cam, proj)
    ambient = 0.05                                   # synth's ambient: albedo * ambient on every hit
    indirect = 2 * ambient * albedo * hit            # the bounce light of the white image (x mean 0.5)
    prof = pattern_profiles(proj.size[0], PERIODS, STEPS)
    got = synthesize_fringes(direct, indirect, points, proj.P, prof, block=SS)
    want = synth.render(scene, cam, proj, PERIODS, STEPS, supersample=SS, ambient=ambient).images
    assert got.shape == want.shape and got.dtype == np.float32
    for i, K in enumerate(PERIODS):
        err = np.abs(got[i * STEPS:(i + 1) * STEPS] - want[i * STEPS:(i + 1) * STEPS])
        bound = 0.7 * interpolation_bound(K, proj.size[0]) + 1e-5
        assert err.max() <= bound, (K, err.max(), bound)
    # the coarse pattern is practically exact; the fine one really shows its interpolation error
    assert np.abs(got[:STEPS] - want[:STEPS]).max() < 1e-4
    assert np.abs(got[-STEPS:] - want[-STEPS:]).max() > 0.1 * interpolation_bound(PERIODS[-1], proj.size[0])


def test_exact_at_projector_pixel_centres(rig):
    """Points whose projector column is an integer get the stored pattern value itself."""
    cam, proj = rig
    Wp = proj.size[0]
    cols = np.array([0.0, 1.0, 17.0, Wp / 2, Wp - 1.0])
    # world points on the projector rays through those columns (row = centre), 1 m out
    pix = np.stack([cols, np.full_like(cols, proj.size[1] / 2 - 0.5), np.ones_like(cols)], -1)
    d = pix @ np.linalg.inv(proj.K).T
    X = (d / d[:, 2:3]) @ proj.T[:3, :3].T + proj.T[:3, 3]
    assert np.allclose(projector_columns(X, proj.P), cols, atol=1e-9)
    prof = pattern_profiles(Wp, PERIODS, STEPS)
    got = synthesize_fringes(np.ones((1, 5)), np.zeros((1, 5)), X[None], proj.P, prof)
    assert np.allclose(got[:, 0, :], prof[:, cols.astype(int)], atol=1e-6)


def test_decoded_like_the_analytic_fringes(rig):
    """Decoding the synthesised fringes gives the projector columns (and depth) that decoding the
    analytic 2x2 point-sampled fringes gives: the synthesis puts each pattern at the right column
    (a wrong P_proj convention or sample grid would show as a bias of a pixel or more). What is
    left is the linear interpolation between projector pixels (8 px per finest period here):
    measured 0.033 px at most, halving with each doubling of the projector width."""
    cam, proj = rig
    scene = synth.plane_scene(albedo=0.8)
    direct, hit, albedo, points = flat_lit(scene, cam, proj)
    prof = pattern_profiles(proj.size[0], PERIODS, STEPS)
    stack = synthesize_fringes(direct, np.zeros_like(direct), points, proj.P, prof, block=SS)
    analytic = synth.render(scene, cam, proj, PERIODS, STEPS, supersample=SS)
    a = sl.decode(stack, **decode_kw(cam, proj), noise_sigma=1e-3)
    b = sl.decode(analytic.images, **decode_kw(cam, proj), noise_sigma=1e-3)
    assert a.valid.mean() > 0.9 and np.array_equal(a.valid, b.valid)
    dx = a.proj_x[a.valid] - b.proj_x[a.valid]
    assert np.abs(dx).max() < 0.05 and abs(np.median(dx)) < 0.005
    err = a.depth[a.valid] - analytic.depth[a.valid]
    assert abs(np.median(err)) < 2e-5 and np.percentile(np.abs(err), 99) < 0.5e-3   # 0.033 px x 11 mm/px


def test_bounced_light_is_offset_only():
    """Without direct light every frame is the bounced light times the patterns' mean: no fringe."""
    prof = pattern_profiles(64, PERIODS, STEPS)
    ind = np.random.default_rng(0).uniform(0, 1, (8, 8)).astype(np.float32)
    pts = np.zeros((8, 8, 3))
    P = np.hstack([np.eye(3), [[0.0], [0.0], [1.0]]])
    got = synthesize_fringes(np.zeros((8, 8)), ind, pts, P, prof, block=2)
    want = ind.reshape(4, 2, 4, 2).mean(axis=(1, 3)) * 0.5
    assert np.allclose(got, want[None], atol=1e-7)


def test_points_behind_the_projector_get_no_pattern():
    P = np.hstack([np.eye(3), np.zeros((3, 1))])
    x = projector_columns(np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [np.nan, 0, 1]]), P)
    assert x[0] == 0.0 and np.isnan(x[1]) and np.isnan(x[2])


@pytest.mark.parametrize("kw, field", [
    (dict(direct=np.zeros((4, 4)), indirect=np.zeros((4, 5))), "direct/indirect/points"),
    (dict(block=3), "block"),
    (dict(profiles=np.zeros(8)), "profiles"),
])
def test_bad_input_names_the_argument(kw, field):
    args = dict(direct=np.zeros((4, 4)), indirect=np.zeros((4, 4)), points=np.zeros((4, 4, 3)),
                P_proj=np.hstack([np.eye(3), np.zeros((3, 1))]), profiles=np.ones((2, 8)), block=2)
    args.update(kw)
    with pytest.raises(ValueError, match=field.replace("/", "/")):
        synthesize_fringes(**args)


def test_bounce_modulation_from_two_quadrature_images():
    """Bounced light is linear in the emitted image: model it as any linear map A from projector
    columns to camera pixels (random here). The render mode's bounce of step n sees the pattern
    blurred to a + g (I_n - a); the fast mode gets it from the bounce of the white image and of the
    two quadrature images only."""
    from datapipe.sl import bounce_modulation, quadrature_profiles

    Wp, periods, steps = 96, (1, 8, 32), 5
    A = np.random.default_rng(3).uniform(0, 1, (6 * 7, Wp)) / Wp        # pixels x projector columns
    prof = pattern_profiles(Wp, periods, steps).astype(np.float64)
    gains = {1: 0.98, 8: 0.21}
    ones = np.ones(Wp)
    quad = {}
    for K in gains:
        Ec, Es = quadrature_profiles(Wp, K).astype(np.float64)
        quad[K] = ((2 * A @ Ec - A @ ones).reshape(6, 7), (2 * A @ Es - A @ ones).reshape(6, 7))
    got = bounce_modulation(quad, periods, steps, gains)
    for i, K in enumerate(periods):
        g = gains.get(K, 0.0)
        for n in range(steps):
            p = prof[i * steps + n]
            want = (A @ (0.5 + g * (p - 0.5))) - 0.5 * (A @ ones)    # minus the offset part (synthesised)
            assert np.allclose(got[i * steps + n].ravel(), want, atol=1e-6), (K, n)
    assert bounce_modulation({}, periods, steps, gains) is None
    with pytest.raises(ValueError, match="quadrature"):
        bounce_modulation({4: quad[1]}, periods, steps, {4: 0.5})


def test_smoothed_bounce_keeps_the_ratio_and_takes_the_better_magnitude():
    """Few-path bounce maps: noisy white-bounce W and C = rho * W from the same paths (rho the mean
    cos of the bounce points' phase, smooth). Smoothing keeps rho exactly and scales it by the
    well-sampled bounce light `indirect`; without smoothing the noise stays."""
    from datapipe.sl import bounce_modulation

    rng = np.random.default_rng(5)
    H, W = 40, 50
    yy, xx = np.mgrid[0:H, 0:W]
    rho_c, rho_s = 0.6 * np.cos(xx / 15.0), 0.5 * np.sin(yy / 12.0)
    white = rng.exponential(1.0, (H, W))                  # one path per pixel: heavy noise
    indirect = np.full((H, W), 0.8)
    quad = {1: (rho_c * white, rho_s * white)}
    got = bounce_modulation(quad, (1, 8), 4, {1: 1.0}, white=white, indirect=indirect, smooth_px=2.0)
    want = 0.5 * 0.8 * rho_c                             # step 0: g b (cos 0 C - sin 0 S) = b rho_c indirect
    inner = (slice(4, -4), slice(4, -4))                  # away from the borders (nearest padding)
    assert np.abs(got[0][inner] - want[inner]).max() < 0.02
    assert np.abs(got[4:]).max() == 0                      # no bounce layers for period 8
    raw = bounce_modulation(quad, (1, 8), 4, {1: 1.0})
    assert np.abs(raw[0] - 0.5 * rho_c * white).max() < 1e-6 and np.std(raw[0] - want) > 0.1
    with pytest.raises(ValueError, match="smooth_px"):
        bounce_modulation(quad, (1, 8), 4, {1: 1.0}, smooth_px=2.0)
