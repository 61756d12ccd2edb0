"""The image noise the decoder weighs its evidence with, when no sensor model is given.

Everything the decoder decides -- the modulation floor (NO_LIGHT), the probability of a wrong
fringe order (``confidence``), the neighbour pass's consistency tests -- scales with the image
noise sigma of each pixel. A camera's temporal noise is read noise plus shot noise, so its variance
grows linearly with the signal (the photon transfer curve of EMVA 1288):

    sigma^2(A) = read_var + A / gain           (DN^2, A = the pixel's mean intensity)

:func:`fit_noise_model` measures that curve on the fringe stack itself, on a subsample of pixels,
with statistics whose expectation is sigma^2 times a chi-square variable:

* a linear camera: per pixel, the least-squares residual of every frequency's N-step fit
  (``chi2(F (N - 3))``) plus the spread of the F offsets ``A_i`` (every frequency measures the same
  mean): ``sum (A_i - mean A)^2 / g`` is ``chi2(F - 1)``, ``g`` the variance of one offset per unit
  noise (``1/N`` for uniform shifts). This is all N = 3 sets have.
* a camera with a tone curve (N >= 4): an image processor's sRGB-like curve (2nd harmonics of
  11-17% of the fringe, 3rd 2-5%, 4th 0.5-2%) or a projector's gamma is a fixed function of the
  intensity, so its harmonics alias into each pixel's residual (and offsets) as a smooth function
  of its offset A, modulation B and phase -- not noise. The statistic above counted them and
  overstated the noise 7-13x on such images (issue #31). A probe on a coarse grid tests, per
  A-bin, a least-squares fit of the residuals on ``B^p cos(k (phi + d_n))``, ``B^p sin(...)``
  (k = 2..4, p = 1, 2, projected on the residual space) against none; where it explains them (an
  F-test, and 5% of their variance in all) the same regression runs on every pixel and frequency,
  and the residual it leaves, ``chi2(N - 3)``, is the statistic (no offsets). The phase and
  modulation in those features come from the pixel's 4-neighbours (the pair along the fringe),
  not from its own samples: with shot noise the residual correlates with the pixel's own noise,
  and a regression on its own phase removed a quarter of the true noise.

The samples are sorted into bins equally spaced in sqrt(A); each bin's mean statistic without its
top 2% (the pixels at depth edges, whose residuals also carry model error), over the same trimmed
mean of the chi-square law, estimates sigma^2 at the bin's A. Between the bins sigma^2 is
interpolated linearly, so the curve follows the data where the sensor is not linear (a sensor
without black level clips the dark pixels' noise at zero: there sigma^2 is smaller and skewed,
and a trimmed mean, unlike a median, keeps its tail); beyond the last bin it grows with the slope
of a weighted least-squares line ``read_var + shot * A`` through the bins (weights: pixel counts
over sigma^4), which is also what the result reports. The result is a per-pixel sigma, evaluated at
each pixel's own A: a dark patch gets the small noise it really has instead of a global figure
dominated by bright, shot-noise-limited pixels (which overstated it 1.3-1.5x on issue #19's dark
box top and let the neighbour pass accept orders its frequencies contradicted), and a shadow gets
its read noise instead of the quantisation floor (which let pure noise pass the modulation floor of
N = 3 sets).

With one frequency of three steps nothing in the stack measures the noise: integer images then use
their quantisation (1/sqrt(12) DN), float images 0.1% of the bright (99th percentile) offset, a
10-bit camera's floor (``kind = "floor"``). Pass ``noise_sigma`` (e.g. the sensor model's) when it
is known, as the scanner does.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Sequence

import numpy as np

from .distributions import chi2_cdf, chi2_median, chi2_ppf, f_isf
from .patterns import phase_shifts
from .phase import PhaseKernel, work_dtype_for

__all__ = ["NoiseModel", "fit_noise_model", "estimate_noise_sigma"]

MIN_BIN = 128        # pixels per A-bin at least (its sigma^2 then within ~10% for 3 dof)
BINS = 48            # bins equally spaced in sqrt(A) (shot noise's variance-stabilising scale)
TRIM = 0.02         # share of the largest statistics left out per bin
TABLE = 1024         # entries of the sigma look-up table, also equally spaced in sqrt(A)


@dataclass(frozen=True)
class NoiseModel:
    """Noise sigma as a function of the signal A (image units, see the module doc): the bins'
    ``(bin_a, bin_var)``, linearly interpolated (beyond the last bin: extrapolated with the
    fitted shot term); evaluated through a look-up table over ``sqrt(A)``."""
    read_var: float            # fitted line: image units^2 at A = 0 ...
    shot: float                # ... plus this per unit of A (1 / conversion gain)
    bin_a: tuple = ()          # median A of each populated bin
    bin_var: tuple = ()        # sigma^2 of those bins
    kind: str = "fit"          # "fit" (from the stack) or "floor" (nothing to fit: constant)
    pixels: int = 0            # pixels the fit used
    dof: int = 0               # chi-square degrees of freedom per pixel

    def variance(self, a):
        """sigma^2 at signal(s) a (float64), exact (no table)."""
        a = np.maximum(np.asarray(a, np.float64), 0.0)
        if not self.bin_a:
            return np.full(a.shape, self.read_var + self.shot * 0.0) + self.shot * a
        v = np.interp(a, self.bin_a, self.bin_var)
        return v + self.shot * np.maximum(a - self.bin_a[-1], 0.0)

    @cached_property
    def _table(self):
        """(sigma^2 at the midpoints of TABLE steps of sqrt(A) up to 4x the last bin, steps per sqrt(A))."""
        top = max(4.0 * (self.bin_a[-1] if self.bin_a else 1.0), 1e-12)
        k = TABLE / np.sqrt(top)
        grid = ((np.arange(TABLE) + 0.5) / k) ** 2
        return self.variance(grid).astype(np.float32), float(k)

    def scaled_variance(self, a_raw, scale: float = 1.0, factor: float = 1.0):
        """``factor * sigma^2(scale * a_raw)`` (float32) by table look-up: three passes over the slab
        (negative or NaN A reads the table's first entry, A beyond 4x the last bin its last)."""
        table, k = self._table
        t = table * np.float32(factor) if factor != 1.0 else table
        with np.errstate(invalid="ignore"):
            idx = np.sqrt(np.asarray(a_raw), dtype=np.float32)
        idx *= np.float32(k * np.sqrt(scale))
        return np.take(t, idx.astype(np.int32), mode="clip")

    def __call__(self, signal):
        a = np.asarray(signal)
        dt = a.dtype if a.dtype.kind == "f" else np.dtype(np.float64)
        if not self.bin_a:
            return np.sqrt(self.variance(a)).astype(dt)
        return np.sqrt(self.scaled_variance(a)).astype(dt, copy=False)

    def describe(self) -> dict:
        """What ``DecodeResult.extras["noise_model"]`` records."""
        return {"kind": self.kind, "read_sigma": float(np.sqrt(self.read_var)), "shot_var_per_signal": self.shot,
                "bins": len(self.bin_a), "pixels": self.pixels, "dof": self.dof}


def variance_function(noise_sigma, a_scale: float, factor: float):
    """``a_raw -> factor * sigma^2(a_scale * a_raw)`` (float32) for a callable ``noise_sigma``: the
    table of a :class:`NoiseModel`, the affine variance of a :class:`~.sensor.SensorModel`'s bound
    ``noise_sigma`` (shot + read + quantisation, a few float32 passes), else the callable itself."""
    if isinstance(noise_sigma, NoiseModel) and noise_sigma.bin_a:
        return lambda a: noise_sigma.scaled_variance(a, a_scale, factor)
    terms = getattr(getattr(noise_sigma, "__self__", None), "variance_terms", None)
    if terms is not None and getattr(noise_sigma, "__name__", "") == "noise_sigma":
        black, c0, c1 = terms()
        f32 = np.float32

        def affine(a):
            v = np.multiply(a, f32(a_scale * c1 * factor), dtype=f32)
            v -= f32(black * c1 * factor)
            np.maximum(v, f32(0), out=v)
            v += f32(c0 * factor)
            return v
        return affine

    def generic(a):
        sig = np.asarray(noise_sigma(np.maximum(a * a.dtype.type(a_scale), 0)), dtype=a.dtype)
        return sig * sig * a.dtype.type(factor)
    return generic


TONE_HARMONICS = range(2, 5)   # the 2nd-4th harmonics of a tone curve (those above are < 1% of the fringe)
TONE_POWERS = (1, 2)           # their amplitude within an A-bin: linear + quadratic in B (c_k ~ B^k for small B)
TONE_BINS = 48                 # A-bins of that regression (equally spaced in sqrt(A))
TONE_PROBE_BINS = 12           # A-bins of the probe for a tone curve
TONE_PROBE_STRIDE = 4          # ... on every 4th row and column of the subsample
TONE_MIN_OBS = 10              # residual coordinates per regression parameter a bin needs at least
TONE_FIT_SAMPLES = 4096        # samples per bin the regression is fitted on (evaluated on all)
TONE_MAX_SPREAD = 0.3          # neighbour pairs further apart than this (~0.3 rad): phase too uncertain for the features
TONE_P = 1e-3                  # F-test level of the probe for a tone curve (a linear camera: 1 in 1000 bins flags)
TONE_MIN_SHARE = 0.05          # ... and the share of the probe's residual variance the curve must explain


def _residual_basis(kern) -> np.ndarray:
    """(N, N-3) orthonormal basis of the N-step fit's residual space (orthogonal to 1, cos, sin)."""
    q, _ = np.linalg.qr(kern.design, mode="complete")
    return q[:, 3:]


def _tone_features(Qt, shifts, z) -> np.ndarray:
    """(m, n, N-3) features of a tone curve in the residual coordinates of n samples: for every
    harmonic k of TONE_HARMONICS whose aliases reach the residual space and every power p of
    TONE_POWERS, ``B^p cos(k (phi + d_n))`` and ``B^p sin(k (phi + d_n))`` projected on it
    (``cos(k (phi + d)) = cos(k phi) cos(k d) - sin(k phi) sin(k d)``: two fixed vectors per k;
    ``cos(k phi) + i sin(k phi) = (z / |z|)^k`` with ``z = C + i S``)."""
    C, S = z[0], z[1]                         # the phasor (C, S) of each sample (2, n)
    B = np.hypot(C, S)
    inv = 1.0 / np.where(B > 0, B, 1.0)
    c1, s1 = C * inv, S * inv                 # cos(phi), sin(phi)
    bmax = max(float(np.percentile(B, 99)), 1e-12)
    pw = [(B * (1.0 / bmax)) ** p for p in TONE_POWERS]
    feats = []
    ck_, sk_ = c1, s1
    for k in range(2, max(TONE_HARMONICS) + 1):
        ck_, sk_ = ck_ * c1 - sk_ * s1, sk_ * c1 + ck_ * s1     # cos(k phi), sin(k phi) by angle addition
        if k not in TONE_HARMONICS:
            continue
        ck, sk = Qt @ np.cos(k * shifts), Qt @ np.sin(k * shifts)
        if max(np.abs(ck).max(), np.abs(sk).max()) < 1e-9:
            continue                 # aliases onto the offset or the fundamental: not in the residual
        for w in pw:
            wc, ws = w * ck_, w * sk_
            feats.append(np.multiply.outer(wc, ck) - np.multiply.outer(ws, sk))
            feats.append(np.multiply.outer(ws, ck) + np.multiply.outer(wc, sk))
    return np.stack(feats)


def _bin_order(a, bins=None):
    """Samples sorted by ``bins`` (TONE_BINS) bins equally spaced in sqrt(A): (order, bounds)."""
    bins = bins or TONE_BINS
    r = np.sqrt(np.maximum(a, 0.0))
    top = float(np.percentile(r, 99.9)) if r.size else 0.0
    edges = np.linspace(0.0, top if top > 0 else 1.0, bins + 1)
    which = np.clip(np.searchsorted(edges, r, side="right") - 1, 0, bins - 1).astype(np.int16)
    order = np.argsort(which, kind="stable")          # int16: a radix sort
    return order, np.searchsorted(which[order], np.arange(bins + 1))


def _fit_bin(X, y, d, refit=True):
    """Least squares y ~ coef @ X (X: (m, n d)) by the normal equations, refitted once without the
    2% largest per-sample squared residuals; returns (coef, rss of the first fit, of no fit)."""
    m = X.shape[0]
    w = np.ones(y.size)
    rss = []
    for _ in range(2 if refit else 1):
        Xw = X * w
        G = np.einsum("ik,jk->ij", Xw, X)
        G[np.diag_indices(m)] += 1e-12 * max(float(np.trace(G)), 1e-300)
        coef = np.linalg.solve(G, np.einsum("ik,k->i", Xw, y))
        e = (y - np.einsum("i,ik->k", coef, X)).reshape(-1, d)
        st = np.sum(e * e, axis=1)
        rss.append(float(np.sum(st)))
        if not refit:
            break
        k = int(np.ceil((1.0 - TRIM) * st.size)) - 1
        w = np.repeat(st <= np.partition(st, k)[k], d).astype(np.float64)
    return coef, rss[0], float(np.sum(y * y))


def _tone_present(res, feats, a) -> bool:
    """Does a tone curve explain the residuals ``res`` (n, N-3) of this probe? Per A-bin the tone
    regression against none, an F-test at TONE_P in some bin, and over all tested bins at least
    TONE_MIN_SHARE of the residual variance explained: a curve that bends only a few clipped
    shadow pixels is not worth the full fit (their noise stays overestimated, as without it)."""
    n, d = res.shape
    m = feats.shape[0]
    order, bounds = _bin_order(a, TONE_PROBE_BINS)
    significant, explained, total = False, 0.0, 0.0
    for b0, b1 in zip(bounds[:-1], bounds[1:]):
        nobs = (b1 - b0) * d
        if nobs < TONE_MIN_OBS * m:
            continue
        sel = order[b0:b1]
        _, rss1, rss0 = _fit_bin(feats[:, sel].reshape(m, -1), res[sel].reshape(-1), d, refit=False)
        significant |= (rss0 - rss1) / m > f_isf(TONE_P, m, nobs - m) * rss1 / (nobs - m)
        explained += rss0 - rss1
        total += rss0
    return bool(significant and explained >= TONE_MIN_SHARE * total)


def _tone_free_rss(res, feats, a):
    """Residual coordinates ``res`` (n, N-3) less what a tone curve explains: per A-bin, least
    squares of the residuals on the tone features ``feats`` (m, n, N-3) (:func:`_tone_features`;
    fitted on at most TONE_FIT_SAMPLES evenly spread samples, refitted once without their 2%
    largest: depth edges). Returns the per-sample squared residual, scaled by
    ``n_obs / (n_obs - m)`` so that it stays unbiased for noise alone (the fit absorbs m of the
    n_obs degrees of freedom)."""
    n, d = res.shape
    m = feats.shape[0]
    out = np.sum(res * res, axis=1)
    order, bounds = _bin_order(a)
    feats, res = feats[:, order], res[order]          # each bin a contiguous slice from here on
    for b0, b1 in zip(bounds[:-1], bounds[1:]):
        nb = b1 - b0
        if nb * d < TONE_MIN_OBS * m:
            continue
        step = max(1, nb // TONE_FIT_SAMPLES)
        coef, _, _ = _fit_bin(feats[:, b0:b1:step].reshape(m, -1), res[b0:b1:step].reshape(-1), d)
        e = res[b0:b1] - np.einsum("i,ik->k", coef, feats[:, b0:b1].reshape(m, -1)).reshape(-1, d)
        out[order[b0:b1]] = np.sum(e * e, axis=1) * (nb * d / max(nb * d - m, 1))
    return out


def _neighbour_phasors(frames, kern, steps, rows, cols, ok):
    """Per frequency, the phasor ``(C, S)`` (2, n) of each pixel of the grid ``rows x cols`` from its
    4-neighbours, not from itself: the mean of the up/down or the left/right pair, whichever pair
    agrees better (along the fringe the phase hardly changes; across it the pair's mean still has
    the centre's phase to first order), and that pair's disagreement over its mean (~ the phase
    step between them; inf where a neighbour is outside the image or not usable, ``ok``). Taken
    from the pixel's own samples the tone features would share its noise, and with signal-dependent
    (shot) noise the residual correlates with that noise: the regression then removed 25% of a
    shot-noise-limited stack's noise variance."""
    h, w = frames[0].shape
    f = len(frames) // steps
    cs = kern.coef[1:]
    nb, inside = {}, np.ones(rows.size * cols.size, bool)
    sliced = rows[0] >= 1 and cols[0] >= 1 and rows[-1] + 1 < h and cols[-1] + 1 < w and \
        np.all(np.diff(rows) == rows[1] - rows[0]) and np.all(np.diff(cols) == cols[1] - cols[0])
    for k, (dy, dx) in {"u": (-1, 0), "d": (1, 0), "l": (0, -1), "r": (0, 1)}.items():
        if sliced:                       # every neighbour inside: strided views, no index arrays
            ix = (slice(rows[0] + dy, rows[-1] + dy + 1, rows[1] - rows[0]),
                  slice(cols[0] + dx, cols[-1] + dx + 1, cols[1] - cols[0]))
        else:
            r, c = rows + dy, cols + dx
            inside &= ((r >= 0) & (r < h))[:, None].repeat(cols.size, 1).ravel() & \
                np.tile((c >= 0) & (c < w), rows.size)
            ix = np.ix_(np.clip(r, 0, h - 1), np.clip(c, 0, w - 1))
        nb[k] = np.stack([np.asarray(fr[ix], np.float64).reshape(-1) for fr in frames])
    usable = inside & ok(np.concatenate(list(nb.values())))
    out = []
    for i in range(f):
        z = {k: cs @ v[i * steps:(i + 1) * steps] for k, v in nb.items()}
        dv = np.hypot(*(z["u"] - z["d"]))
        dh = np.hypot(*(z["l"] - z["r"]))
        zz = np.where(dv <= dh, z["u"] + z["d"], z["l"] + z["r"]) * 0.5
        spread = np.minimum(dv, dh) / np.maximum(np.hypot(*zz), 1e-300)
        out.append((zz, np.where(usable, spread, np.inf)))
    return out


def _statistics(frames, steps, shifts, saturation, max_pixels):
    """Per sample: offset A, chi-square statistic / sigma^2 and its dof; plus the images' floor.

    Without a tone curve (a linear camera) the statistic is what it was before issue #31, per pixel
    of the subsample: the N-step residuals of all frequencies plus the spread of their offsets
    (``chi2(F (N - 3) + F - 1)``, :func:`_linear_statistic`). With N >= 4 a probe on every 4th row
    and column of the subsample tests for a tone curve (:func:`_tone_present`): it is a fixed
    function of the intensity, so its harmonics alias into each frequency's residual as a smooth
    function of (A, B, phase) -- not noise -- and into the offsets too. Where the probe finds one,
    the statistic is per pixel and frequency instead (:func:`_tone_statistic`). With N = 3 nothing
    is left of the residual: a tone curve's 3rd harmonic aliases onto the offsets; pass
    ``noise_sigma``, or linearise the images with ``response``, for such a camera."""
    steps = int(steps)
    h, w = frames[0].shape
    s = max(1, int(np.ceil(np.sqrt(h * w / max_pixels))))
    sub = [np.asarray(fr[::s, ::s], dtype=np.float64).ravel() for fr in frames]
    grid = (np.arange(0, h, s), np.arange(0, w, s))
    shifts = np.asarray(phase_shifts(steps) if shifts is None else shifts, np.float64)
    kern = PhaseKernel(shifts)
    is_int = np.dtype(frames[0].dtype).kind in "iu"
    sat = saturation
    if sat is None and is_int:
        sat = float(np.iinfo(frames[0].dtype).max)

    def ok(samples):
        g = np.isfinite(samples).all(0)
        if sat is not None and np.isfinite(sat):
            g &= (samples < sat).all(0)
        return g

    good = ok(np.stack(sub))
    a, rss, dof = _linear_statistic(sub, kern, steps)
    a, rss = a[good], rss[good]
    if steps > 3 and a.size and min(grid[0].size, grid[1].size) >= 3:
        tone = _tone_statistic(frames, sub, kern, steps, grid, good, a, ok)
        if tone is not None:
            a, rss, dof = tone
    eps = np.finfo(work_dtype_for([fr.dtype for fr in frames])).eps
    bright = float(np.percentile(np.abs(a), 99)) if a.size else 0.0
    floor = 16 * eps * bright                       # arithmetic rounding of the fit itself
    if is_int:
        floor = max(floor, 1.0 / np.sqrt(12.0))
    elif dof == 0:
        floor = max(floor, 1e-3 * bright)
    return a, rss, dof, max(floor, 1e-12)


def _linear_statistic(sub, kern, steps):
    """The statistic of a linear camera (kept as it was before issue #31): per subsampled pixel the
    mean offset A, the N-step residuals of all frequencies plus the spread of their offsets over
    sigma^2, and its dof ``F (N - 3) + F - 1``."""
    f = len(sub) // steps
    offs = []
    rss = np.zeros(sub[0].size)
    for i in range(f):
        y = np.stack(sub[i * steps:(i + 1) * steps])
        y = np.where(np.isfinite(y), y, 0.0)
        acs = kern.coef @ y
        rss += np.sum((y - kern.design @ acs) ** 2, axis=0)
        offs.append(acs[0])
    offs = np.stack(offs)
    a = offs.mean(0)
    if f > 1:            # offsets of the F frequencies: one mean, noise g sigma^2 each
        g = float(np.sum(kern.coef[0] ** 2))
        rss += np.sum((offs - a) ** 2, axis=0) / g
    return a, rss, f * (steps - 3) + f - 1


def _tone_statistic(frames, sub, kern, steps, grid, good, a, ok):
    """With a tone curve found by the probe (every ``TONE_PROBE_STRIDE``-th row and column of the
    subsample ``grid``): per kept pixel and frequency the residual with the tone curve's part
    regressed out (:func:`_tone_free_rss`, features from the neighbours' phasors,
    :func:`_neighbour_phasors`), ``chi2(N - 3)``, leaving out the samples whose neighbours do not
    pin their phase, and the offsets. Returns (A, statistic, dof), or None (no tone curve, or too
    few pixels to fit it)."""
    rows, cols = grid
    h, w = frames[0].shape
    f = len(sub) // steps
    shifts = kern.shifts
    Qt = _residual_basis(kern).T                         # (N-3, N): orthogonal to the design
    res = np.concatenate([np.einsum("jn,nk->kj", Qt, np.stack(sub[i * steps:(i + 1) * steps])[:, good])
                          for i in range(f)])              # einsum: no BLAS threads for a (N-3) x N product
    a_all = np.tile(a, f)
    n = a.size
    pos = np.cumsum(good) - 1                            # grid pixel -> its column among the good ones
    pr = np.arange(1, rows.size, TONE_PROBE_STRIDE)    # from the 2nd row / column: all neighbours inside
    pc = np.arange(1, cols.size, TONE_PROBE_STRIDE)
    pr, pc = pr[rows[pr] + 1 < h], pc[cols[pc] + 1 < w]
    pgrid = np.zeros((rows.size, cols.size), bool)
    pgrid[np.ix_(pr, pc)] = True
    sel = (pgrid.ravel() & good)[pgrid.ravel()]          # probe pixels among the coarse grid's
    pnb = _neighbour_phasors(frames, kern, steps, rows[pr], cols[pc], ok)
    pidx = pos[np.flatnonzero(pgrid.ravel() & good)]
    probe = np.concatenate([i * n + pidx for i in range(f)])
    pz = np.concatenate([z[:, sel] for z, _ in pnb], axis=1)
    psp = np.concatenate([sp[sel] for _, sp in pnb])
    pk = psp <= TONE_MAX_SPREAD
    if not _tone_present(res[probe[pk]], _tone_features(Qt, shifts, pz[:, pk]), a_all[probe[pk]]):
        return None
    nbs = _neighbour_phasors(frames, kern, steps, rows, cols, ok)
    z = np.concatenate([zz[:, good] for zz, _ in nbs], axis=1)
    keep = np.concatenate([sp[good] for _, sp in nbs]) <= TONE_MAX_SPREAD
    if np.count_nonzero(keep) < MIN_BIN:                 # one statistic per kept pixel and frequency
        return None
    rss = _tone_free_rss(res[keep], _tone_features(Qt, shifts, z[:, keep]), a_all[keep])
    return a_all[keep], rss, steps - 3


def fit_noise_model(frames: Sequence[np.ndarray], steps: int, *, shifts=None, saturation=None,
                    max_pixels: int = 1 << 15) -> NoiseModel:
    """sigma^2(A) from the stack itself (module doc); frames frequency-major."""
    return _fit(*_statistics(frames, steps, shifts, saturation, max_pixels))


def _fit(a, stat, dof, floor) -> NoiseModel:
    """:func:`fit_noise_model` from the statistics of :func:`_statistics`."""
    if dof == 0 or a.size == 0:
        return NoiseModel(floor * floor, 0.0, kind="floor", pixels=int(a.size), dof=dof)
    # per bin: the mean of the statistic without its top TRIM (pixels at depth edges, whose residual
    # is model error), over what that trimmed mean is for chi2(dof): unbiased for Gaussian noise and,
    # unlike a median, also for the skewed noise of pixels clipped at the ADC's zero (a sensor
    # without black level: there the median understated sigma^2 by 2x and shadows passed the floor)
    q = chi2_ppf(1.0 - TRIM, dof)
    corr = dof * chi2_cdf(q, dof + 2) / (1.0 - TRIM)
    r = np.sqrt(np.maximum(a, 0.0))
    top = float(np.percentile(r, 99.9))
    edges = np.linspace(0.0, top if top > 0 else 1.0, BINS + 1)
    which = np.clip(np.searchsorted(edges, r, side="right") - 1, 0, BINS - 1).astype(np.int16)  # radix sort
    order = np.argsort(which, kind="stable")
    bounds = np.searchsorted(which[order], np.arange(BINS + 1))
    ab, vb, nn = [], [], []
    for b0, b1 in zip(bounds[:-1], bounds[1:]):
        if b1 - b0 >= MIN_BIN:
            sel = order[b0:b1]
            st = stat[sel]
            k = int(np.ceil((1.0 - TRIM) * st.size))
            kept = np.partition(st, k - 1)[:k]
            ab.append(float(np.median(np.maximum(a[sel], 0.0))))
            vb.append(max(float(np.mean(kept)) / corr, floor * floor))
            nn.append(b1 - b0)
    if not ab:
        s2 = max(float(np.median(stat)) / chi2_median(dof), floor * floor)
        return NoiseModel(s2, 0.0, kind="fit", pixels=int(a.size), dof=dof)
    ab, vb, nn = np.array(ab), np.array(vb), np.array(nn, float)
    # the line read + shot x A through the bins (weights: a median's variance ~ sigma^4 / n): it
    # extrapolates beyond the last bin and is what the result reports
    wts = nn / vb ** 2
    X = np.stack([np.ones_like(ab), ab], 1)
    c0, c1 = np.linalg.lstsq(X * np.sqrt(wts)[:, None], vb * np.sqrt(wts), rcond=None)[0]
    if c1 < 0:
        c1, c0 = 0.0, float(np.sum(wts * vb) / np.sum(wts))
    return NoiseModel(float(max(c0, floor * floor)), float(c1), tuple(ab.tolist()), tuple(vb.tolist()),
                      "fit", int(a.size), dof)


def estimate_noise_sigma(frames: Sequence[np.ndarray], steps: int, *, shifts=None, saturation=None,
                         max_pixels: int = 1 << 16) -> float:
    """One global noise sigma (image units): :func:`fit_noise_model`'s sigma at the median offset A
    of the subsample. Between the shadows' and the bright pixels' noise in shot-noise limited
    images; the decoder uses the per-pixel :func:`fit_noise_model` instead."""
    a, stat, dof, floor = _statistics(frames, steps, shifts, saturation, max_pixels)
    if dof == 0 or a.size == 0:
        return float(floor)
    return float(max(np.sqrt(_fit(a, stat, dof, floor).variance(np.median(a))), floor))
