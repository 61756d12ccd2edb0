"""Neighbourhood order correction: pixels whose own frequencies leave the order uncertain take it
from the projector coordinate their confident neighbours predict (as scanners' spatial filters
do), and may so get a *different* order than their temporal decoding gave.

Per uncertain pixel and pass: predictions of its coordinate from confident 8-neighbours, two-sided
``(x[p-d] + x[p+d]) / 2`` (4 axes) and one-sided ``2 x[p+d] - x[p+2d]`` (8 directions), all exact on
planes. Their median ``x_hat`` is trusted only when at least ``min_support`` predictions and 3/4 of
those available agree with it within a quarter of the finest period ``T`` (at a depth step the two
sides disagree and the pixel is left alone). Candidates are the finest phase's three coordinates
``x_n = (n + c_f) T`` nearest ``x_hat``; each is scored with the spatial term
``(x_n - x_hat)^2 / (sigma_p^2 + sigma_f^2)`` (``sigma_p``: spread of the agreeing predictions plus
``0.05 T``; ``sigma_f``: the pixel's own fine-phase noise) plus the temporal term
``sum_i wrap(K_i x_n / W - c_i)^2 / v_i`` of every other frequency. The posterior of the best
candidate against the other two must leave ``p_wrong <= max_wrong``, and its temporal term must pass
a chi-square test at 1e-4 (its frequencies must not contradict the neighbours). Accepted pixels
count as confident in the next pass, so corrections grow into dark regions one pixel per pass;
a pass looks only at the uncertain pixels next to those accepted in the pass before (a frontier),
so its cost follows the frontier, not the whole uncertain area.
"""
from __future__ import annotations

import numpy as np
from scipy.stats import chi2

__all__ = ["correct_orders"]

_AXES = ((0, 1), (1, 0), (1, 1), (1, -1))
_DIRS = _AXES + tuple((-dy, -dx) for dy, dx in _AXES)


def _gather(a, r, c, dy, dx, shape):
    """a[r+dy, c+dx] (flat a) with a validity mask for out-of-image neighbours."""
    H, W = shape
    rr, cc = r + dy, c + dx
    inside = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
    idx = np.where(inside, rr * W + cc, 0)
    return a[idx], inside


def _predictions(x, good, r, c, shape):
    preds = []
    for dy, dx in _AXES:
        xa, ia = _gather(x, r, c, dy, dx, shape)
        ga = _gather(good, r, c, dy, dx, shape)[0] & ia
        xb, ib = _gather(x, r, c, -dy, -dx, shape)
        gb = _gather(good, r, c, -dy, -dx, shape)[0] & ib
        preds.append(np.where(ga & gb, 0.5 * (xa + xb), np.nan))
    for dy, dx in _DIRS:
        x1, i1 = _gather(x, r, c, dy, dx, shape)
        g1 = _gather(good, r, c, dy, dx, shape)[0] & i1
        x2, i2 = _gather(x, r, c, 2 * dy, 2 * dx, shape)
        g2 = _gather(good, r, c, 2 * dy, 2 * dx, shape)[0] & i2
        preds.append(np.where(g1 & g2, 2.0 * x1 - x2, np.nan))
    return np.stack(preds)


def _wrapd(t):
    return t - np.rint(t)


def _neighbours(idx, shape):
    """Flat indices of the 8-neighbours of flat indices idx (out-of-image ones dropped)."""
    H, W = shape
    r, c = np.divmod(idx, W)
    out = []
    for dy, dx in _DIRS:
        rr, cc = r + dy, c + dx
        ok = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
        out.append((rr * W + cc)[ok])
    return np.concatenate(out)


def correct_orders(x, good, cand, cyc, var_c, periods, length, *, max_wrong, passes=1000,
                   min_support=3, weights_min=0.01):
    """Correct / confirm the orders of ``cand`` pixels from confident neighbours (module doc).

    x: (H, W) float32 coordinates (temporal decode; NaN allowed outside good/cand); good, cand:
    (H, W) bool; cyc, var_c: per frequency 1D arrays over ``flatnonzero(cand)`` (cycles,
    cycles^2). Returns (idx, x_new, p_wrong) of the accepted pixels (flat indices)."""
    shape = x.shape
    per = np.asarray(periods, np.float64)
    f = int(np.argmax(per))
    T = length / per[f]
    L = float(length)
    xf = x.astype(np.float64).ravel().copy()
    gf = good.ravel().copy()
    idx_all = np.flatnonzero(cand)
    todo = np.ones(idx_all.size, bool)
    pos = np.full(x.size, -1, np.int64)
    pos[idx_all] = np.arange(idx_all.size)
    near = pos[_neighbours(np.flatnonzero(gf), shape)]
    active = np.zeros(idx_all.size, bool)
    active[near[near >= 0]] = True
    chi_max = chi2.isf(1e-4, max(1, len(per) - 1))
    w = per * per
    keep = w >= weights_min * w.sum()
    out_idx, out_x, out_p = [], [], []
    for _ in range(passes):
        sel = np.flatnonzero(active & todo)
        active[:] = False
        if sel.size == 0:
            break
        idx = idx_all[sel]
        r, c = np.divmod(idx, shape[1])
        P = _predictions(xf, gf, r, c, shape)
        avail = np.isfinite(P).sum(0)
        has = avail >= min_support
        if not has.any():
            continue
        sel, idx, P, avail = sel[has], idx[has], P[:, has], avail[has]
        with np.errstate(invalid="ignore", all="ignore"):
            xh = np.nanmedian(P, axis=0)
            dev = np.abs(P - xh)
            agree = dev < 0.25 * T
            n_agree = agree.sum(0)
            spread = np.sqrt(np.nansum(np.where(agree, dev * dev, 0.0), 0) / np.maximum(n_agree, 1))
        ok = (n_agree >= min_support) & (4 * n_agree >= 3 * avail)
        if not ok.any():
            continue
        sel, idx, xh, spread = sel[ok], idx[ok], xh[ok], spread[ok]
        cf = cyc[f][sel].astype(np.float64)
        vf = var_c[f][sel].astype(np.float64)
        var_sp = spread ** 2 + (0.05 * T) ** 2 + vf * T * T
        n0 = np.rint(xh / T - cf)
        scores, temps, xs = [], [], []
        for dn in (-1.0, 0.0, 1.0):
            xn = (n0 + dn + cf) * T
            temp = np.zeros(xn.shape)
            for i, k in enumerate(per):
                if i == f:
                    continue
                v = var_c[i][sel].astype(np.float64) + (k / per[f]) ** 2 * vf
                temp += _wrapd(k * xn / L - cyc[i][sel]) ** 2 / v
            scores.append((xn - xh) ** 2 / var_sp + temp)
            temps.append(temp)
            xs.append(xn)
        S = np.stack(scores)
        b = np.argmin(S, 0)
        cols = np.arange(b.size)
        sb = S[b, cols]
        with np.errstate(over="ignore"):
            p = np.sum(np.exp(-0.5 * (S - sb)), 0) - 1.0
        p = p / (1.0 + p)
        tb = np.stack(temps)[b, cols]
        acc = (p <= max_wrong) & (tb <= chi_max)
        if not acc.any():
            continue
        xbest = np.stack(xs)[b, cols][acc]
        sel_a = sel[acc]
        xnew = _combine_from_fine(xbest, [cyc[i][sel_a].astype(np.float64) for i in range(len(per))],
                                  per, L, keep)
        ia = idx[acc]
        xf[ia] = xnew
        gf[ia] = True
        todo[sel_a] = False
        near = pos[_neighbours(ia, shape)]
        active[near[near >= 0]] = True
        out_idx.append(ia)
        out_x.append(xnew)
        out_p.append(p[acc])
    if not out_idx:
        e = np.zeros(0)
        return np.zeros(0, np.int64), e, e
    return np.concatenate(out_idx), np.concatenate(out_x), np.concatenate(out_p)


def _combine_from_fine(xbest, cyc, per, L, keep):
    """Every frequency's coordinate from its order next to ``xbest``, K^2-weighted (as unwrap)."""
    num = np.zeros(xbest.shape)
    den = 0.0
    for i, k in enumerate(per):
        if not keep[i]:
            continue
        n = np.rint(k * xbest / L - cyc[i])
        xi = (n + cyc[i]) * (L / k)
        num += k * k * (xi - xbest)
        den += k * k
    return xbest + num / den
