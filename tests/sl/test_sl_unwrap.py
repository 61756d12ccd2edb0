"""Temporal unwrapping: scheme choice, errors, exactness, projector edges, noise behaviour."""
import numpy as np
import pytest

from datapipe.errors import DataPipeError
from datapipe.sl import plan_unwrap, unwrap_phase
from datapipe.sl.metrics import effective_period

W = 512
TWO_PI = 2 * np.pi


def phases_for(x, periods, sigma=0.0, seed=0, dtype=np.float32):
    rng = np.random.default_rng(seed)
    out = []
    for k in periods:
        p = TWO_PI * k * x / W + (rng.normal(0, sigma, x.shape) if sigma else 0.0)
        out.append(np.mod(p, TWO_PI).astype(dtype))
    return out


@pytest.mark.parametrize("periods, method", [
    ((1, 8, 64), "multi-frequency"), ((64, 8, 1), "multi-frequency"), ((1,), "multi-frequency"),
    ((0.9, 8, 64), "multi-frequency"), ((64, 63), "number-theoretic"), ((8, 7), "number-theoretic"),
    ((70, 64, 59), "number-theoretic"), ((100, 93, 88, 84), "number-theoretic"), ((13, 7), "number-theoretic"),
    ((9, 10, 11), "number-theoretic"), ((8.5, 7.5), "heterodyne"), ((20.5, 19.75, 18.5), "heterodyne"),
])
def test_auto_choice(periods, method):
    assert plan_unwrap(periods).method == method


@pytest.mark.parametrize("periods, method, msgs", [
    ((16, 64), "auto", ["cannot be unwrapped", "(1, 16, 64)"]),
    ((8, 6), "auto", ["beat of 8 and 6 has 2 periods", "share the factor 2", "(8, 7)"]),
    ((8.5, 6), "auto", ["beat of 8.5 and 6", "(13, 7)"]),
    ((8.5, 7.5), "number-theoretic", ["integer periods", "(13, 7)"]),
    ((64,), "auto", ["single frequency", "periods="]),
    ((8, 7), "multi-frequency", ["coarsest", "at most 1 period"]),
    ((1, 8, 64), "heterodyne", ["cannot be unwrapped"]),
    ((1, 8), "spatial", ["unknown method"]),
])
def test_ambiguous_sets_raise_with_suggestion(periods, method, msgs):
    with pytest.raises(ValueError) as ei:
        plan_unwrap(periods, method)
    assert isinstance(ei.value, DataPipeError)
    for m in msgs:
        assert m in str(ei.value)


@pytest.mark.parametrize("periods, method", [
    ((1, 8, 64), "auto"), ((1, 4, 16, 64), "auto"), ((64, 63), "heterodyne"), ((8, 7), "heterodyne"),
    ((70, 64, 59), "heterodyne"), ((100, 93, 88, 84), "heterodyne"), ((0.9, 8, 64), "auto"),
    ((64, 63), "auto"), ((70, 64, 59), "auto"), ((100, 93, 88, 84), "auto"), ((13, 7), "auto"),
    ((9, 10, 11), "auto"), ((1, 16), "number-theoretic"), ((8.5, 7.5), "auto")])
def test_noise_free_exact_across_projector(periods, method):
    """Every projector column from edge to edge (x in (-0.5, W-0.5)) comes back; float32
    phases carry ~4e-7 rad rounding, i.e. < 1e-4 px through the finest period (8 px)."""
    x = np.linspace(-0.5, W - 0.5, 20002)[1:-1]
    r = unwrap_phase(phases_for(x, periods), periods, method, proj_width=W)
    assert r.x.dtype == np.float32
    assert np.abs(r.x - x).max() < 2e-4
    assert r.order_error.max() < 1e-3
    np.testing.assert_allclose(r.phase, TWO_PI * max(periods) * r.x / W, rtol=1e-6, atol=1e-4)


def test_fraction_without_width():
    x = np.linspace(0, W - 1, 1000)
    r = unwrap_phase(phases_for(x, (1, 8, 64)), (1, 8, 64))
    assert np.abs(r.x * W - x).max() < 2e-4


def test_projector_edges():
    """Noise sigma_phi = 0.05 rad on every frequency. docs/STRUCTURED_LIGHT.md: a coarse phase wrapped at its own
    0/2pi lost the order for 13-18% of pixels within 5 px of an edge. Here the coarse estimate
    is centred on the projector and the fine phase decides the final wrap, so only pixels within
    the fine coordinate's noise of the wrap point x = -0.5 == W - 0.5 may flip: with
    sigma_x = T_eff/(2 pi) * 0.05 = 0.063 px, pixels farther than 6 sigma_x (0.38 px) must all be
    right. A coarsest frequency < 1 period (0.9) moves the wrap point off the projector: then
    every pixel must be right."""
    n = 200_000
    x = np.concatenate([np.linspace(-0.5, 5, n), np.linspace(W - 6, W - 0.5, n)])
    sigma = 0.05
    sx = effective_period(W, (8, 64)) / TWO_PI * sigma
    for periods in [(1, 8, 64), (0.9, 8, 64)]:
        r = unwrap_phase(phases_for(x, periods, sigma, seed=1), periods, proj_width=W)
        wrong = np.abs(r.x - x) > 4                 # half the finest period
        if periods[0] == 1:
            near = np.minimum(np.abs(x + 0.5), np.abs(x - (W - 0.5))) < 6 * sx
            assert not wrong[~near].any()
            # the flips that remain follow the Gaussian tail at the wrap point: per side
            # density * integral of Phi(-d/sigma_x) dd = (n / 5.5 px) * sigma_x / sqrt(2 pi)
            expected = 2 * (n / 5.5) * sx / np.sqrt(2 * np.pi)
            assert wrong.sum() == pytest.approx(expected, rel=0.15)
        else:
            assert not wrong.any()


@pytest.mark.parametrize("periods", [(1, 8, 64), (20, 19), (8, 7), (13, 7)])
def test_order_error_follows_noise_gain(periods):
    """The order estimate's deviation r - round(r) is Gaussian with sigma = gain * sigma_phi/2pi
    (docs/STRUCTURED_LIGHT.md: sqrt(r^2+1) for a hierarchical stage, sqrt(K1^2+K2^2) for a heterodyne pair);
    with sigma_phi = 0.01 rad no order is lost, so mean |r - k| of the worst stage is the
    half-normal mean sigma * sqrt(2/pi) (2e5 samples: 0.2% standard error; 5% tolerance)."""
    x = np.random.default_rng(3).uniform(1, W - 2, 200_000)       # away from the wrap point
    plan = plan_unwrap(periods)
    sigma = 0.01
    r = unwrap_phase(phases_for(x, periods, sigma, seed=4, dtype=np.float64), periods, proj_width=W)
    sig_r = plan.noise_gain() * sigma / TWO_PI
    if len(plan.stage_gains()) == 1:
        assert r.order_error.mean() == pytest.approx(sig_r * np.sqrt(2 / np.pi), rel=0.05)
    else:      # the max over stages: at least the worst stage's mean, at most sum of stage means
        assert sig_r * np.sqrt(2 / np.pi) * 0.95 <= r.order_error.mean() <= \
            sum(plan.stage_gains()) * sigma / TWO_PI * np.sqrt(2 / np.pi) * 1.05
    assert np.abs(r.x - x).max() < 2.0          # no order lost


@pytest.mark.parametrize("periods", [(8, 7), (64, 63), (1, 8, 64)])
def test_k2_weighting_lowers_noise(periods):
    """K^2 weights: sigma_x = T_eff/(2 pi) sigma_phi with T_eff = W / sqrt(sum K^2) (metrics).
    For 8/7 that is 1.33x better than the finest frequency alone; 3% tolerance (2e5 samples)."""
    x = np.random.default_rng(5).uniform(0, W - 1, 200_000)
    sigma = 0.002
    r = unwrap_phase(phases_for(x, periods, sigma, seed=6, dtype=np.float64), periods, proj_width=W)
    kept = [k for k in periods if k * k >= 0.01 * sum(q * q for q in periods)]
    want = effective_period(W, kept) / TWO_PI * sigma
    assert np.std(r.x - x) == pytest.approx(want, rel=0.03)


def test_mismatched_inputs():
    with pytest.raises(ValueError, match="2 phase maps for 3 periods"):
        unwrap_phase([np.zeros(3), np.zeros(3)], (1, 8, 64))


def test_number_theoretic_gains():
    """d_min of the lattice of consistent orders (lattice module doc): for two coprime frequencies
    the points lie on a line with spacing 1/|K| (gain sqrt(K1^2 + K2^2)); for (9, 10, 11) the
    shortest difference is the projection of (1, 1, 1) off K: |(1,1,1) - 30/302 K| = 0.1410."""
    assert plan_unwrap((13, 7)).noise_gain() == pytest.approx(np.hypot(13, 7), rel=1e-9)
    k = np.array([9.0, 10, 11])
    ones = np.ones(3)
    assert plan_unwrap((9, 10, 11)).noise_gain() == pytest.approx(
        1 / np.linalg.norm(ones - (ones @ k) / (k @ k) * k), rel=1e-9)


@pytest.mark.parametrize("periods", [(13, 7), (9, 10, 11), (70, 64, 59)])
def test_number_theoretic_noise_tolerance(periods):
    """Stated tolerance: an order is lost when the noise projected on the direction to another
    lattice point exceeds d_min/2, i.e. P(wrong) ~ n_min * Q(d_min / (2 sigma_c)). At
    sigma_c = d_min / 12 (6 sigma margin, Q = 1e-9) not one of 2e5 pixels may be wrong; at
    sigma_c = d_min / 4 (Q(2) = 2.3%) the wrong fraction must be between Q(2) and 6 Q(2)
    (n_min <= 6 neighbours in 2D), i.e. the tolerance is neither better nor worse than stated."""
    plan = plan_unwrap(periods)
    d = 1 / plan.noise_gain()
    x = np.random.default_rng(7).uniform(1, W - 2, 200_000)
    from scipy.stats import norm
    for frac, check in ((1 / 12, "none"), (1 / 4, "rate")):
        sig = d * frac * TWO_PI           # radians
        r = unwrap_phase(phases_for(x, periods, sig, seed=8, dtype=np.float64), periods, proj_width=W)
        wrong = np.mean(np.abs(r.x - x) > W / max(periods) / 2)
        q = norm.sf(1 / (2 * frac))
        if check == "none":
            assert wrong == 0
        else:
            assert q <= wrong <= 6 * q
