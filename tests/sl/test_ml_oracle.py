"""The maximum-likelihood oracle's posterior (tests/sl/ml_oracle.py) is calibrated: among pixels it gives
posterior p of being right, a share p is right. The oracle is the yardstick of issue #31's coverage
benchmark, and its "sure" form (posterior >= 1 - 1e-4) is what the decoder's coverage is compared with
at the issue's wrong share; a posterior computed with the wrong noise would make that yardstick wrong.

Ground truth: projector coordinates drawn uniformly, the pattern formula of docs/CONVENTIONS.md plus
Gaussian intensity noise of known sigma; right = the decided coordinate within half a finest period
of the drawn one (circularly), as in the benchmark."""
import numpy as np
import pytest

import ml_oracle

PIXELS = 40_000


def draw(periods, steps, snr, seed):
    """(true u, wrapped phases per frequency, intensity sigma, modulation) for PIXELS pixels;
    ``snr`` = B / sigma, one value or a (low, high) range drawn uniformly per pixel."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(0.0, 1.0, PIXELS)
    A, B = 100.0, 100.0
    sigma = B / (rng.uniform(*snr, PIXELS) if isinstance(snr, tuple) else snr)
    shifts = 2 * np.pi * np.arange(steps) / steps
    imgs = np.array([A + B * np.cos(2 * np.pi * K * u + d) + sigma * rng.standard_normal(PIXELS)
                     for K in periods for d in shifts])
    cyc, _ = ml_oracle.ls_phase(imgs, len(periods), steps)
    return u, cyc, sigma, B


def calibration(periods, steps, snr, sigma_scale, seed=3):
    """Per posterior bin with >= 300 pixels: (pixels, mean posterior, right share), the decision's
    posterior computed with ``sigma_scale`` x the true noise."""
    u, cyc, sigma, B = draw(periods, steps, snr, seed)
    var = [np.broadcast_to(ml_oracle.phase_var(sigma * sigma_scale, B, steps), u.shape) for _ in periods]
    ud, post = ml_oracle.decide(cyc, var, periods)
    e = ud - u
    e -= np.rint(e)
    right = np.abs(e) < 0.5 / max(periods)
    out = []
    for lo, hi in [(0.0, 0.5), (0.5, 0.8), (0.8, 0.9), (0.9, 0.99), (0.99, 0.999), (0.999, 2.0)]:
        m = (post >= lo) & (post < hi)
        if m.sum() >= 300:
            out.append((int(m.sum()), float(post[m].mean()), float(right[m].mean())))
    return out


def off(bins):
    """Largest miss between right share and mean posterior, in binomial standard deviations plus a
    0.01 allowance: the least-squares phase error is Gaussian only in the high-SNR limit (at B / sigma
    = 6, 3 steps, its tails differ from the Gaussian's by about a percent of the pixels they hold)."""
    return max(abs(r - p) / (np.sqrt(max(p * (1 - p), 1e-6) / n) + 0.01 / 4) for n, p, r in bins)


@pytest.mark.parametrize("periods,steps,snr", [((16, 15), 4, 6.0), ((8, 7), 3, 6.0)])
def test_posterior_is_calibrated(periods, steps, snr):
    """With the true noise the right share matches the mean posterior in every bin (within 4 of the
    units of ``off``); with twice or half the true sigma it does not (the check can fail)."""
    bins = calibration(periods, steps, snr, 1.0)
    assert len(bins) >= 3, bins                     # the noise spreads the posteriors over several bins
    assert off(bins) <= 4.0, bins
    assert off(calibration(periods, steps, snr, 2.0)) > 8.0
    assert off(calibration(periods, steps, snr, 0.5)) > 8.0


def test_sure_pixels_meet_the_wrong_limit():
    """The sure oracle (posterior >= 1 - 1e-4) is wrong on about <= 0.01% of what it keeps, on pixels
    of mixed noise (B / sigma 5-12 with the (8, 7) x 3 set) where the whole oracle is wrong on a few
    percent: it keeps the quiet pixels and drops the noisy ones."""
    periods, steps = (8, 7), 3
    u, cyc, sigma, B = draw(periods, steps, (5.0, 12.0), seed=4)
    var = [ml_oracle.phase_var(sigma, B, steps) for _ in periods]
    ud, post = ml_oracle.decide(cyc, var, periods)
    e = ud - u
    e -= np.rint(e)
    right = np.abs(e) < 0.5 / max(periods)
    sure = post >= 1 - 1e-4
    assert 0.01 < 1 - right.mean() < 0.1
    assert 0.2 < sure.mean() < 0.95
    assert sigma[sure].mean() < sigma[~sure].mean()
    # 1e-4 of the ~27k kept pixels is 2.7 (the posterior itself expects 0.2): more than 6 wrong would
    # happen by chance with probability < 2% even at the limit
    assert np.sum(sure & ~right) <= 6, (np.sum(sure & ~right), sure.sum())
