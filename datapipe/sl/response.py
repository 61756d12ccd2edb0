"""A camera's response (tone curve) undone before decoding: given, or fitted from the stack.

N-step phase shifting assumes the image values are linear in the light. A camera whose image
processor applies a tone curve (sRGB-like: 2nd harmonics of 11-17% of the fringe, 3rd 2-5%) breaks
that: for N = 4 the 3rd and 5th harmonics alias onto the fundamental and bend the phase into a
ripple of four periods per fringe, the 2nd lands in the residual. The noise estimate copes with the
residual (:mod:`.noise`); the phase ripple needs the values made linear again:

* given: ``decode(..., response=lut)`` with a 1-D array indexed by the raw integer value (the
  camera's inverse tone curve, e.g. from a photometric calibration or the camera's data sheet), or
  any callable ``linear = response(values)``;
* fitted: ``response="fit"`` (:func:`fit_response`): the power law ``linear = (v / v_max) ** gamma``
  whose linearised stack leaves the least 2nd-harmonic energy in the N-step residuals of the
  brightly modulated pixels (N >= 4: with N = 3 nothing is left of the residual to measure it by).
  An sRGB curve is close to gamma 2.2 (IEC 61966-2-1 approximates it so); other curves (a knee, an
  S-curve) are only approximated by it -- give their inverse when it is known.

The linearised stack is float32 (4 bytes per sample, one pass per image); a decode without
``response`` does none of this.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from ._errors import bad_type, bad_value
from .patterns import phase_shifts
from .phase import PhaseKernel

__all__ = ["Response", "fit_response", "linearise"]

GAMMA_RANGE = (0.25, 4.0)      # power laws the fit searches (cameras encode with 1/2.2 .. 1/2.6)
FIT_PIXELS = 1 << 14            # subsample of the fit
BRIGHT_SHARE = 0.25             # the brightest-modulated quarter of the samples: harmonics over noise


@dataclass(frozen=True)
class Response:
    """``linear = scale * (v / v_max) ** gamma`` (the fitted power law); ``scale = v_max`` keeps the
    values in the images' units."""
    gamma: float
    v_max: float

    def __call__(self, values):
        v = np.asarray(values, np.float32)
        out = np.maximum(v, np.float32(0)) * np.float32(1.0 / self.v_max)
        np.power(out, np.float32(self.gamma), out=out)
        out *= np.float32(self.v_max)
        return out


def _residual_share(samples, kern, steps, gamma, v_max):
    """2nd-harmonic energy left in the N-step residuals per unit modulation energy, after the
    power law ``gamma`` (samples: (F*N, n) raw values)."""
    lin = (np.maximum(samples, 0.0) / v_max) ** gamma
    res_e = mod_e = 0.0
    for i in range(samples.shape[0] // steps):
        y = lin[i * steps:(i + 1) * steps]
        acs = kern.coef @ y
        r = y - kern.design @ acs
        b2 = acs[1] ** 2 + acs[2] ** 2
        res_e += float(np.sum(r * r))
        mod_e += float(np.sum(b2))
    return res_e / max(mod_e, 1e-300)


def fit_response(frames, steps: int, *, shifts=None, saturation=None) -> Response:
    """The power law that linearises the stack best (module doc): a golden-section search of the
    exponent over GAMMA_RANGE for the least residual energy per modulation energy on the
    BRIGHT_SHARE of a subsample with the strongest modulation (where a tone curve's harmonics
    stand out of the noise). frames: (F*N, H, W) or a list, frequency-major."""
    frames = [np.asarray(f) for f in frames]
    steps = int(steps)
    if steps < 4:
        raise bad_value("response", f"'fit' needs at least 4 phase steps (got {steps}): with 3 the least-squares "
                        "fit leaves no residual to measure a tone curve by", "give the camera's inverse tone "
                        "curve as a look-up table or a callable, or capture 4 or more steps")
    h, w = frames[0].shape
    s = max(1, int(np.ceil(np.sqrt(h * w / FIT_PIXELS))))
    sub = np.stack([np.asarray(f[::s, ::s], np.float64).ravel() for f in frames])
    dt = frames[0].dtype
    if saturation is None and dt.kind in "iu":
        saturation = float(np.iinfo(dt).max)
    ok = np.isfinite(sub).all(0)
    if saturation is not None:
        ok &= (sub < saturation).all(0)
    sub = sub[:, ok]
    kern = PhaseKernel(phase_shifts(steps) if shifts is None else shifts)
    v_max = float(saturation) if saturation is not None else float(np.max(sub)) if sub.size else 1.0
    # the brightly modulated samples (modulation of the raw values, averaged over the frequencies)
    b = np.zeros(sub.shape[1])
    for i in range(sub.shape[0] // steps):
        acs = kern.coef @ sub[i * steps:(i + 1) * steps]
        b += np.hypot(acs[1], acs[2])
    if sub.shape[1] < 64:
        raise bad_value("images", "has too few unsaturated finite pixels to fit a response",
                        "give the camera's inverse tone curve as response=")
    bright = sub[:, b >= np.quantile(b, 1.0 - BRIGHT_SHARE)]
    lo, hi = np.log(GAMMA_RANGE[0]), np.log(GAMMA_RANGE[1])
    g = (np.sqrt(5.0) - 1.0) / 2.0
    x1, x2 = hi - g * (hi - lo), lo + g * (hi - lo)
    f1 = _residual_share(bright, kern, steps, np.exp(x1), v_max)
    f2 = _residual_share(bright, kern, steps, np.exp(x2), v_max)
    for _ in range(40):                         # log-gamma bracket shrinks to 1e-8 of its width
        if f1 < f2:
            hi, x2, f2 = x2, x1, f1
            x1 = hi - g * (hi - lo)
            f1 = _residual_share(bright, kern, steps, np.exp(x1), v_max)
        else:
            lo, x1, f1 = x1, x2, f2
            x2 = lo + g * (hi - lo)
            f2 = _residual_share(bright, kern, steps, np.exp(x2), v_max)
    return Response(float(np.exp(0.5 * (lo + hi))), v_max)


def linearise(frames, response, steps: int, shifts=None, saturation=None):
    """(float32 frames, saturation level in linear units, what was applied) for ``decode``'s
    ``response``: None (frames unchanged), "fit", a 1-D look-up table indexed by the raw integer
    value, or a callable."""
    if response is None:
        return frames, saturation, None
    dt = frames[0].dtype
    if isinstance(response, str):
        if response != "fit":
            raise bad_value("response", f"unknown value {response!r}", "pass 'fit', a look-up table or a callable")
        response = fit_response(frames, steps, shifts=shifts, saturation=saturation)
    if isinstance(response, np.ndarray) or isinstance(response, (list, tuple)):
        lut = np.asarray(response, np.float32)
        if lut.ndim != 1 or dt.kind not in "iu":
            raise bad_value("response", f"a look-up table of shape {lut.shape} for {dt} images",
                            "pass a 1-D table indexed by the raw value of integer images, or a callable")
        top = max(int(f.max(initial=0)) for f in frames)
        if lut.size <= top or int(min(f.min(initial=0) for f in frames)) < 0:
            raise bad_value("response", f"has {lut.size} entries but the images hold values up to {top}",
                            f"give one linear value per raw value 0..{top} (e.g. {int(np.iinfo(dt).max) + 1} "
                            f"entries for {dt})")
        if not np.all(np.isfinite(lut)) or np.any(np.diff(lut) < 0):
            raise bad_value("response", "is not finite and non-decreasing", "pass the camera's inverse tone curve")
        out = [np.take(lut, f) for f in frames]
        sat = None if saturation is None else float(lut[min(int(saturation), lut.size - 1)])
        return out, sat, {"kind": "table", "entries": int(lut.size)}
    if not callable(response):
        raise bad_type("response", f"must be None, 'fit', a look-up table or a callable, got {type(response).__name__}",
                       "pass e.g. response='fit'")
    out = [np.asarray(response(np.asarray(f, np.float32)), np.float32) for f in frames]
    if any(o.shape != frames[0].shape for o in out):
        raise bad_value("response", "returned arrays of another shape", "return one value per pixel")
    if saturation is None and dt.kind in "iu":
        saturation = float(np.iinfo(dt).max)
    sat = None if saturation is None else float(np.asarray(response(np.float32([saturation])), np.float32)[0])
    info = {"kind": "fit", "gamma": response.gamma} if isinstance(response, Response) else {"kind": "callable"}
    return out, sat, info
