"""A maximum-likelihood temporal decoder that knows the true noise (the "oracle" of issue #31), with its
posterior: the yardstick the decoder's coverage is measured against (benchmarks/bench_sl_coverage.py)
and whose calibration tests/sl/test_ml_oracle.py checks. Independent of datapipe.sl: the wrapped
phases are plain N-step least squares and the orders an exhaustive search.

Model (per pixel): the projector coordinate u = x / Wp in [0, 1); frequency i (K_i periods across the
projector) gives a wrapped phase c_i in cycles, c_i = K_i u - n_i + e_i with e_i ~ N(0, v_i) (the
Gaussian limit of the least-squares phase error, v_i = (sqrt(2/N) sigma_I / B_i / 2pi)^2 cycles^2).
An order vector n = (n_1 .. n_F) fixes the weighted least-squares coordinate u_n and its cost
chi2_n = sum_i (K_i u_n - c_i - n_i)^2 / v_i; under a flat prior on u the vector's likelihood
integrated over u is exp(-chi2_n / 2) sqrt(2pi / W) (W = sum_i K_i^2 / v_i, the same for every
vector), so the posterior of vector n is exp(-chi2_n / 2) normalised over the vectors, and given n, u
is Gaussian about u_n with standard deviation 1 / sqrt(W). The decision is the most likely vector;
its confidence is the posterior probability that the true coordinate lies within half a finest
period of the decided one (the benchmark's "right"): the sum over vectors of their posterior times
the Gaussian's mass inside that window.

Candidate vectors: for each order of the finest frequency, the other orders rounded at the
weighted least-squares coordinate (twice), and every other order +-1 around them (3^(F-1) per
finest order): the vectors the period set can tell apart over the projector, with the runners-up
near each. A vector two or more cycles off in a coarse frequency costs >= (1.5 cycles)^2 / v_i
more than its rounded neighbour: negligible at the noise levels where that frequency still decides
anything.
"""
from __future__ import annotations

import itertools

import numpy as np
from scipy.special import ndtr


def ls_phase(images, F, N):
    """Per frequency: wrapped phase in cycles [0, 1) and modulation (N-step least squares, uniform
    shifts, the pattern I = A + B cos(2pi K x / Wp + 2pi n / N) of docs/CONVENTIONS.md)."""
    d = 2 * np.pi * np.arange(N) / N
    cyc, mod = [], []
    for i in range(F):
        fr = np.asarray(images[i * N:(i + 1) * N], dtype=np.float64)
        C = np.tensordot(np.cos(d), fr, 1)
        S = np.tensordot(np.sin(d), fr, 1)
        cyc.append(np.mod(np.arctan2(-S, C) / (2 * np.pi), 1.0))
        mod.append(2.0 / N * np.hypot(C, S))
    return cyc, mod


def phase_var(sigma_i, modulation, steps):
    """Variance (cycles^2) of the N-step least-squares phase for intensity noise ``sigma_i`` and
    modulation B: sigma_phi = sqrt(2 / N) sigma_I / B radians (the Gaussian, high-SNR limit)."""
    sphi = np.sqrt(2.0 / steps) * sigma_i / np.maximum(modulation, 1e-9)
    return (sphi / (2 * np.pi)) ** 2


def decide(cyc, var, periods):
    """Maximum-likelihood coordinate u (projector widths; about [0, 1), not folded) and its confidence.

    ``cyc``, ``var``: per frequency, 1-D arrays of wrapped phase (cycles) and its variance (cycles^2).
    Returns ``(u, posterior)``: ``posterior`` is the probability that the true u is within half a
    finest period of ``u`` (circularly), under the model of the module docstring."""
    per = np.asarray(periods, float)
    F = len(per)
    f = int(np.argmax(per))
    others = [i for i in range(F) if i != f]
    cyc = [np.asarray(c, float) for c in cyc]
    var = [np.asarray(v, float) for v in var]
    W = sum(per[i] ** 2 / var[i] for i in range(F))
    sd_u = 1.0 / np.sqrt(W)

    def fit(n):
        u = sum(per[i] * (cyc[i] + n[i]) / var[i] for i in range(F)) / W
        return u, sum((per[i] * u - cyc[i] - n[i]) ** 2 / var[i] for i in range(F))

    def rounded(nf):
        u = (nf + cyc[f]) / per[f]
        for _ in range(2):
            n = [np.rint(per[i] * u - cyc[i]) if i != f else nf for i in range(F)]
            u = fit(n)[0]
        return n

    finest = range(int(round(per[f])))
    best_cost = np.full(cyc[0].shape, np.inf)        # pass 1: the decision (the rounded vectors)
    best_u = np.zeros(cyc[0].shape)
    for nf in finest:
        u, cost = fit(rounded(nf))
        better = cost < best_cost
        best_cost = np.where(better, cost, best_cost)
        best_u = np.where(better, u, best_u)
    h = 0.5 / per[f]                                 # pass 2: the posterior (streamed: no (candidates, pixels) array)
    total = np.zeros(cyc[0].shape)
    mass = np.zeros(cyc[0].shape)
    for nf in finest:
        n = rounded(nf)
        for delta in itertools.product((0, -1, 1), repeat=len(others)):
            m = list(n)
            for i, d in zip(others, delta):
                m[i] = n[i] + d
            u, cost = fit(m)
            weight = np.exp(-(cost - best_cost) / 2)     # posterior up to the normalisation
            d = u - best_u
            d -= np.rint(d)                              # circular: u and u +- 1 are the same column
            total += weight
            mass += weight * (ndtr((h - d) / sd_u) - ndtr((-h - d) / sd_u))
    post = mass / total
    return best_u, post


def true_phase_var(clean_images, F, N, read, e_per_dn, full_scale):
    """Per frequency, the true phase variance (cycles^2) of a ``synth.sensor_stack`` made from
    ``clean_images`` (radiance, (F*N, H, W)): read + shot noise at the noise-free offset, over the
    noise-free modulation."""
    _, mod0 = ls_phase(clean_images * full_scale, F, N)
    a0 = np.asarray(clean_images).reshape(F, N, *np.shape(clean_images)[1:]).mean(1) * full_scale
    return [phase_var(np.sqrt(read ** 2 + a0[i] / e_per_dn), mod0[i], N) for i in range(F)]
