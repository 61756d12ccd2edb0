"""Projector gamma: a non-linear projector response and its correction in decoding.

A projector fed the sinusoid ``p = a + b cos(phi + d_n)`` emits ``p ** gamma`` (``gamma = 1`` is
linear). The camera sees ``albedo * p ** gamma + ambient``: the harmonics of ``p ** gamma`` whose order
is ``1 +- N`` alias into the fundamental of N-step phase shifting and bend the phase into a ripple
with N periods per fringe (docs/STRUCTURED_LIGHT.md: 0.2 rad at N = 3, 0.0075 rad at N = 4 for gamma 2.2 on a
camera tone curve). Albedo scales every harmonic alike and ambient light only the offset, so the
phase error is a function of the true phase alone, ``e(phi)``, for given ``gamma``, ``a/b`` and
shifts: :func:`gamma_phase_lut` tabulates the measured phase against the true phase by running the
same least-squares estimator on the ideal samples, and the decoder maps every measured phase back
through it (exact up to the 4096-entry table's interpolation, < 1e-6 cycles).
"""
from __future__ import annotations

from functools import lru_cache

import numpy as np

from .phase import lsq_coefficients

__all__ = ["gamma_phase_lut", "correct_cycles"]


@lru_cache(maxsize=16)
def _lut(gamma: float, shifts: tuple, a: float, b: float, n: int):
    true = (np.arange(n) + 0.5) / n                       # cycles
    phi = 2 * np.pi * true
    d = np.asarray(shifts)
    samples = (a + b * np.cos(phi[None, :] + d[:, None])) ** gamma
    acs = lsq_coefficients(d) @ samples
    meas = np.mod(np.arctan2(acs[2], acs[1]) / (2 * np.pi), 1.0)
    err = meas - true
    err -= np.rint(err)
    meas = true + err                                     # continuous, may leave [0, 1) slightly
    order = np.argsort(meas)
    meas, true = meas[order], true[order]
    # periodic extension so np.interp covers [0, 1] whatever the error at the ends
    xp = np.concatenate([meas[-8:] - 1.0, meas, meas[:8] + 1.0])
    fp = np.concatenate([true[-8:] - 1.0, true, true[:8] + 1.0])
    return xp, fp


def gamma_phase_lut(gamma: float, shifts, a: float = 0.5, b: float = 0.5, n: int = 4096):
    """(measured cycles, true cycles) sample points of the phase response of N-step least squares
    to a projector of response ``p ** gamma`` (module doc); strictly increasing for gamma < ~4."""
    return _lut(float(gamma), tuple(float(s) for s in np.asarray(shifts).ravel()), float(a), float(b), int(n))


def correct_cycles(cyc, lut):
    """Map measured phases (cycles in [0, 1]) to true phases through ``lut``; same dtype, in [0, 1)."""
    xp, fp = lut
    out = np.interp(cyc, xp, fp).astype(cyc.dtype, copy=False)
    out -= np.floor(out)
    return out
