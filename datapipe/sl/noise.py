"""The image noise the decoder weighs its evidence with, when no sensor model is given.

Everything the decoder decides -- the modulation floor (NO_LIGHT), the probability of a wrong
fringe order (``confidence``), the neighbour pass's consistency tests -- scales with the image
noise sigma of each pixel. A camera's temporal noise is read noise plus shot noise, so its variance
grows linearly with the signal (the photon transfer curve of EMVA 1288):

    sigma^2(A) = read_var + A / gain           (DN^2, A = the pixel's mean intensity)

:func:`fit_noise_model` measures that curve on the fringe stack itself. Per pixel of a subsample
it pools two statistics whose expectation is sigma^2 times a chi-square variable:

* the least-squares residual of every frequency's N-step fit: ``chi2(F (N - 3))`` (none for N = 3);
* the spread of the F offsets ``A_i`` (every frequency measures the same mean, the pattern's
  offset times the albedo): ``sum (A_i - mean A)^2 / g`` is ``chi2(F - 1)``, ``g`` the variance
  of one offset per unit noise (``1/N`` for uniform shifts). This is what N = 3 sets have.

The pixels are sorted into bins equally spaced in sqrt(A); each bin's mean statistic without its
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
import scipy.stats

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


def _statistics(frames, steps, shifts, saturation, max_pixels):
    """Per pixel of a subsample: offset A, pooled chi-square statistic / sigma^2 sum, and its dof;
    plus the bright offset and the images' floor."""
    steps = int(steps)
    f = len(frames) // steps
    h, w = frames[0].shape
    s = max(1, int(np.ceil(np.sqrt(h * w / max_pixels))))
    sub = [np.asarray(fr[::s, ::s], dtype=np.float64).ravel() for fr in frames]
    if shifts is None:
        shifts = phase_shifts(steps)
    kern = PhaseKernel(shifts)
    is_int = np.dtype(frames[0].dtype).kind in "iu"
    sat = saturation
    if sat is None and is_int:
        sat = float(np.iinfo(frames[0].dtype).max)
    good = np.ones(sub[0].size, bool)
    for x in sub:
        good &= np.isfinite(x)
        if sat is not None and np.isfinite(sat):
            good &= x < sat
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
    eps = np.finfo(work_dtype_for([fr.dtype for fr in frames])).eps
    bright = float(np.percentile(np.abs(a[good]), 99)) if good.any() else 0.0
    floor = 16 * eps * bright                       # arithmetic rounding of the fit itself
    if is_int:
        floor = max(floor, 1.0 / np.sqrt(12.0))
    elif f * (steps - 3) + f - 1 == 0:
        floor = max(floor, 1e-3 * bright)
    return a[good], rss[good], f * (steps - 3) + f - 1, max(floor, 1e-12)


def fit_noise_model(frames: Sequence[np.ndarray], steps: int, *, shifts=None, saturation=None,
                    max_pixels: int = 1 << 15) -> NoiseModel:
    """sigma^2(A) from the stack itself (module doc); frames frequency-major."""
    a, stat, dof, floor = _statistics(frames, steps, shifts, saturation, max_pixels)
    if dof == 0 or a.size == 0:
        return NoiseModel(floor * floor, 0.0, kind="floor", pixels=int(a.size), dof=dof)
    # per bin: the mean of the statistic without its top TRIM (pixels at depth edges, whose residual
    # is model error), over what that trimmed mean is for chi2(dof): unbiased for Gaussian noise and,
    # unlike a median, also for the skewed noise of pixels clipped at the ADC's zero (a sensor
    # without black level: there the median understated sigma^2 by 2x and shadows passed the floor)
    q = scipy.stats.chi2.ppf(1.0 - TRIM, dof)
    corr = dof * scipy.stats.chi2.cdf(q, dof + 2) / (1.0 - TRIM)
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
        s2 = max(float(np.median(stat)) / scipy.stats.chi2.median(dof), floor * floor)
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
    """One global noise sigma (image units): the median over the subsample of the pooled statistic
    of :func:`fit_noise_model`. Between the shadows' and the bright pixels' noise in shot-noise
    limited images; the decoder uses the per-pixel :func:`fit_noise_model` instead."""
    a, stat, dof, floor = _statistics(frames, steps, shifts, saturation, max_pixels)
    if dof == 0 or a.size == 0:
        return float(floor)
    med = float(np.median(stat / dof))
    return float(max(np.sqrt(med / (scipy.stats.chi2.median(dof) / dof)), floor))
