"""Accuracy metrics and the theoretical noise limits of phase-shifting structured light (docs/STRUCTURED_LIGHT.md).

- phase noise of N-step least squares: ``sigma_phi = sqrt(2/N) * sigma_I / B``
  (8-bit rounding adds 1/12 DN^2 to ``sigma_I^2``);
- projector coordinate: ``sigma_x = T/(2*pi) * sigma_phi`` with T the fringe period in pixels;
- depth: ``sigma_Z ~= Z^2 / (f_p * b) * sigma_x`` (f_p projector focal length in pixels, b baseline).

With several frequencies combined by K^2 weights (``datapipe.sl.unwrap``), the coordinate noise
is that of a single pattern with the effective period ``T_eff = W / sqrt(sum K^2)`` (equal
modulation in every frequency): use :func:`effective_period` for ``period_px``.
"""
from __future__ import annotations

import numpy as np

__all__ = ["depth_error_stats", "theoretical_phase_sigma", "theoretical_depth_sigma", "effective_period"]


def theoretical_phase_sigma(noise_sigma, modulation, steps):
    """``sqrt(2/N) * sigma_I / B`` (radians)."""
    return np.sqrt(2.0 / np.asarray(steps, dtype=np.float64)) * np.asarray(noise_sigma, np.float64) \
        / np.asarray(modulation, np.float64)


def theoretical_depth_sigma(Z, f_p, baseline, period_px, phase_sigma):
    """``Z^2 / (f_p * b) * (T / 2 pi) * sigma_phi`` (metres)."""
    Z = np.asarray(Z, dtype=np.float64)
    return Z ** 2 / (f_p * baseline) * (np.asarray(period_px, np.float64) / (2 * np.pi)) * phase_sigma


def effective_period(proj_width, periods) -> float:
    """Fringe period (pixels) equivalent to the K^2-weighted combination: ``W / sqrt(sum K^2)``."""
    k = np.asarray(periods, dtype=np.float64)
    return float(proj_width / np.sqrt(np.sum(k * k)))


def depth_error_stats(depth, gt_depth, valid=None, lit=None, shadow=None, outlier_m: float = 0.005) -> dict:
    """Error statistics of a decoded depth map against ground truth (metres).

    valid: decoded pixels (default: finite depth). lit: pixels that should decode (e.g. lit by
    the projector and not in its shadow); shadow: pixels that must not decode.
    Returns ``count`` (valid pixels with finite ground truth), ``median_abs``, ``rmse``, ``p99``
    (of |error|), ``mean`` (bias), ``outlier_fraction`` (|error| > outlier_m), ``decoded_fraction``
    (valid among lit; NaN without ``lit``), ``false_valid_shadow`` (valid among shadow; NaN
    without ``shadow``).
    """
    d = np.asarray(depth, dtype=np.float64)
    g = np.asarray(gt_depth, dtype=np.float64)
    if d.shape != g.shape:
        raise ValueError(f"depth: shape {d.shape} differs from gt_depth {g.shape} (fix: pass maps of one size)")
    v = np.isfinite(d) if valid is None else (np.asarray(valid, bool) & np.isfinite(d))
    sel = v & np.isfinite(g)
    err = (d - g)[sel]
    n = int(err.size)
    a = np.abs(err)
    out = {
        "count": n,
        "median_abs": float(np.median(a)) if n else float("nan"),
        "rmse": float(np.sqrt(np.mean(err ** 2))) if n else float("nan"),
        "p99": float(np.percentile(a, 99)) if n else float("nan"),
        "mean": float(np.mean(err)) if n else float("nan"),
        "outlier_fraction": float(np.mean(a > outlier_m)) if n else float("nan"),
    }
    if lit is not None:
        lit = np.asarray(lit, bool)
        out["decoded_fraction"] = float(np.mean(v[lit])) if lit.any() else float("nan")
    else:
        out["decoded_fraction"] = float("nan")
    if shadow is not None:
        sh = np.asarray(shadow, bool)
        out["false_valid_shadow"] = float(np.mean(v[sh])) if sh.any() else float("nan")
    else:
        out["false_valid_shadow"] = float("nan")
    return out


def pixel_depth_sigma(res, noise_sigma, proj_width: int, steps: int) -> np.ndarray:
    """Per-pixel theoretical depth sigma (m) from docs/STRUCTURED_LIGHT.md: for each frequency K the phase noise
    sigma_phi = sqrt(2/N) * sigma_I / B (B its modulation, sigma_I the sensor noise at the pixel's
    offset; `noise_sigma` a number or a function of the signal such as SensorModel.noise_sigma), combined with the decoder's K^2 weights: sigma_x = W / (2 pi sum K^2) *
    sqrt(sum K^2 sigma_phi^2), times |dZ/dx| of the triangulation. NaN where not decoded."""
    per = np.asarray(res.periods, dtype=np.float64)
    sig_i = np.asarray(noise_sigma(np.maximum(res.offset, 0).astype(np.float64)) if callable(noise_sigma)
                       else noise_sigma, np.float64)
    var = np.zeros(res.offset.shape, np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        for k, K in enumerate(per):
            sphi = np.sqrt(2.0 / steps) * sig_i / res.modulation[k].astype(np.float64)
            var += K * K * sphi * sphi
        sigma_x = proj_width / (2 * np.pi * np.sum(per * per)) * np.sqrt(var)
        slope = res.triangulator.depth_slope(np.where(res.valid, res.depth, np.nan))
        out = (np.abs(slope) * sigma_x).astype(np.float32)
    out[~res.valid] = np.nan
    return out
