"""Probability that a pixel's fringe orders are right, from all the evidence of its own samples.

Phase noise per frequency. N-step least squares gives the cosine and sine coefficients with noise
``s = sigma_I * row_sigma`` each (``sqrt(2/N) sigma_I`` for uniform shifts), so the phase has noise
``s / B`` radians, ``sigma_c = s / (2 pi B)`` cycles. The measured modulation is Rician:
``E[B_hat^2] = B^2 + 2 s^2``; ``B_eff^2 = max(B_hat^2 - 2 s^2, s^2 / 4)`` removes that bias (a dark
pixel would otherwise look more certain than it is) and keeps pure noise at ``sigma_c ~ 0.3``.

Posterior of a rounding stage. A stage rounds a value ``r = integer + e`` with Gaussian noise
``e`` of variance ``v = sum(coef_j^2 sigma_c,j^2)`` (:meth:`UnwrapPlan.stage_coefs`). Given the
observed deviation ``d = r - round(r)``, the chosen order is right with likelihood
``exp(-d^2 / 2v)`` and the next order with ``exp(-(1 - |d|)^2 / 2v)``: with a flat prior over the
orders the log-odds that it is right are ``(1 - 2|d|) / (2 v)`` = ``margin / (2 v)``. A lattice
stage (:mod:`.lattice`) gives ``margin = d2^2 - d1^2`` (cycles^2) with ``v`` the largest
``sigma_c,j^2``. This uses the actual agreement of the frequencies, not the worst case: a dark
pixel whose frequencies agree well is kept, a bright one whose frequencies disagree is not.
Farther orders (``|d| + 1`` ...) are negligible wherever the probability matters (< 1e-2).

``p_wrong = sum over stages of 1 / (1 + exp(log-odds))`` (union bound: stages fail independently).
The decoder keeps pixels with ``p_wrong <= max_wrong``, so the expected share of wrong orders among
the kept pixels is at most ``max_wrong`` and in practice far below (most pixels have ~0).

Consistency. The same numbers also test the model: under it the squared distance to the chosen
order, divided by ``v``, is chi-square (1 dof per rounding stage, F-1 for a lattice stage). A pixel
far beyond that (``p < 1e-8``: 5.7 sigma for one dof) has frequencies that disagree with each other more than the sensor's
noise allows -- a phase biased by aliasing of fringes finer than the pixel, a mixed pixel at a depth
step, inter-reflections, an uncorrected tone curve -- and is INCONSISTENT, whatever its margin,
provided the disagreement also threatens the order: at least 0.25 of an order (0.3 ``d_min`` for a
lattice stage). Smaller biases leave the order right (a real scanner keeps those pixels); they
only bias the depth, which the per-pixel sigma does not cover. Why 0.25 and not less: a coarse
fringe keeps most of its modulation in light bounced between parts and walls, so on auto-exposed
(low-noise) parts its phase carries a multipath bias of 0.15-0.25 of an order while the order is
right; at 0.15 the bin scenes of benchmarks/results/sl_materials.md lost 7-10 points of their
part pixels within 1 mm (gui rig at 0.55 m: 79% instead of 86%) with no change in the share
off by more than 5 mm.
"""
from __future__ import annotations

import numpy as np
from .distributions import chi2_isf

__all__ = ["phase_var_cycles", "phase_var_from_snr", "wrong_probability", "consistency_limits"]

INV_2PI_SQ = 1.0 / (2.0 * np.pi) ** 2
CONSISTENCY_P = 1e-8
MIN_INCONSISTENCY = 0.25      # of an order, rounding stage (see the module doc for why 0.25)
MIN_INCONSISTENCY_LATTICE = 0.3   # of d_min, lattice stage


def phase_var_cycles(b, s, out=None):
    """Phase noise variance in cycles^2 of modulation ``b`` with coefficient noise ``s`` (scalar or
    array, same units), Rician bias removed (module doc). float32 in -> float32 out."""
    T = b.dtype.type
    s2 = np.multiply(s, s, dtype=b.dtype) if np.ndim(s) else T(float(s) ** 2)
    b2 = np.multiply(b, b, out=out)
    b2 -= T(2) * s2
    np.maximum(b2, T(0.25) * s2, out=b2)
    np.maximum(b2, T(np.finfo(b.dtype).tiny), out=b2)       # s = 0 (noise-free): infinite certainty
    np.divide(s2 * T(INV_2PI_SQ), b2, out=b2)
    return b2


def phase_var_from_snr(q):
    """:func:`phase_var_cycles` from ``q = B_hat^2 / s^2`` (in place): ``1 / (4 pi^2 max(q - 2, 1/4))``."""
    T = q.dtype.type
    v = np.subtract(q, T(2))
    np.maximum(v, T(0.25), out=v)
    np.reciprocal(v, out=v)
    v *= T(INV_2PI_SQ)
    return v


def consistency_limits(n_freq: int, d_min: float = 1.0):
    """Consistency test limits: chi-square for one dof and for a lattice stage's n_freq - 1 dofs,
    and the smallest squared residual that counts (rounding stage, lattice stage of ``d_min``)."""
    return (float(chi2_isf(CONSISTENCY_P, 1)), float(chi2_isf(CONSISTENCY_P, max(1, n_freq - 1))),
            MIN_INCONSISTENCY ** 2, (MIN_INCONSISTENCY_LATTICE * d_min) ** 2)


def _stage_variance(coef, var_c, v, tmp):
    """``v = sum_j coef_j^2 var_c_j`` (the terms in order, the first written instead of added to 0)."""
    T = v.dtype.type
    first = True
    for c, vc in zip(coef, var_c):
        if not c:
            continue
        if first:
            np.multiply(vc, T(c * c), out=v)
            first = False
        else:
            np.multiply(vc, T(c * c), out=tmp)
            v += tmp
    if first:
        v.fill(0)


def wrong_probability(margins, coefs, var_c, residuals=None, out=None, limits=None):
    """Union-bound probability that some stage rounded to a wrong order, and the INCONSISTENT mask
    (module doc). margins / residuals: per stage arrays (residual None: ``((1 - margin)/2)^2``);
    coefs: per stage coefficient vectors (None for a lattice stage); var_c: per frequency phase
    variances in cycles^2 (:func:`phase_var_cycles`). Returns ``(p, inconsistent)``."""
    dt = var_c[0].dtype
    T = dt.type
    p = out if out is not None else np.empty(var_c[0].shape, dt)
    p.fill(0)
    inconsistent = np.zeros(p.shape, bool)
    if not margins:
        return p, inconsistent
    residuals = residuals or [None] * len(margins)
    lim1, lim_lattice, floor1, floor_lattice = limits if limits else consistency_limits(len(var_c))
    v = np.empty(p.shape, dt)
    q = np.empty(p.shape, dt)
    vmax = None
    for m, coef, res in zip(margins, coefs, residuals):
        if coef is None:
            if vmax is None:
                vmax = var_c[0].copy()
                for vc in var_c[1:]:
                    np.maximum(vmax, vc, out=vmax)
            np.copyto(v, vmax)
            lim, floor = lim_lattice, floor_lattice
        else:
            _stage_variance(coef, var_c, v, q)
            lim, floor = lim1, floor1
        if res is None:                  # |d| = (1 - margin) / 2
            np.subtract(T(1), m, out=q)
            q *= T(0.5)
            np.multiply(q, q, out=q)
        else:
            np.copyto(q, res)
        # inconsistent: q > v lim and q > floor; the second is rare (a quarter order off), so the
        # first is evaluated only there (the same comparisons, at a few pixels)
        far = np.flatnonzero(np.greater(q, T(floor)))
        if far.size:
            qf, vf = q.reshape(-1)[far], v.reshape(-1)[far]
            inconsistent.reshape(-1)[far[qf > vf * T(lim)]] = True
        # p += 1 / (1 + exp(m / 2v)); float32 exp overflows to inf for certain pixels -> 0
        np.multiply(v, T(2), out=v)
        np.divide(m, v, out=v)           # log-odds that the stage is right
        unsure = np.less(v, T(40))       # p > 4e-18: worth the exp (usually a small share)
        n = np.count_nonzero(unsure)
        if n * 4 < v.size:
            if n:
                i = np.flatnonzero(unsure)
                lo = v.reshape(-1)[i]
                p.reshape(-1)[i] += T(1) / (T(1) + np.exp(lo))
        else:
            np.exp(v, out=v)             # overflow to inf for certain pixels: p += 0
            v += T(1)
            np.reciprocal(v, out=v)
            p += v
    np.minimum(p, T(1), out=p)
    return p, inconsistent
