"""Neighbourhood order correction: pixels whose own frequencies leave the order uncertain take it
from the projector coordinate their confident neighbours predict (as scanners' spatial filters
do), and may so get a *different* order than their temporal decoding gave -- but only where the
neighbours and the pixel are one surface: a neighbour never vouches across an edge.

Per uncertain pixel and pass: predictions of its coordinate from confident 8-neighbours, two-sided
``(x[p-d] + x[p+d]) / 2`` (4 axes) and one-sided ``2 x[p+d] - x[p+2d]`` (8 directions), all exact on
planes. Each prediction votes for the order of the pixel's own finest phase it implies; the median
``x_hat`` is trusted only when at least ``min_support`` (2) predictions and 3/4 of those available vote
for the order ``x_hat`` implies (at a depth step of more than half a period the two sides vote
differently and the pixel is left alone).

Same surface. A depth step whose projector-coordinate jump is close to a whole number of periods
fools that vote when all the confident neighbours lie on one side of it (issue #19: a dark box top
filled with the floor's orders). So the pixel must also lie *on* the neighbours' surface: along at
least one axis the four neighbours ``p-2d, p-d, p+d, p+2d`` are confident and the three predictions
through the pixel (the two-sided one and the one-sided one from each side) agree within
``SAME_SURFACE * T``: no step between the two sides and a continuous gradient across the pixel
(an interpolation, never an extrapolation from one side). And the pixel's own finest phase must
locate it within a period by itself (phase noise ``<= MAX_FINE_NOISE`` cycles), so a pixel of pure
noise (a projector shadow that slipped past the modulation floor) is not given its neighbours' depth.

Candidates are the finest phase's three coordinates ``x_n = (n + c_f) T`` nearest ``x_hat``; each is
scored with the spatial term ``(x_n - x_hat)^2 / (sigma_p^2 + sigma_f^2)`` (``sigma_p``: spread of the
agreeing predictions plus ``0.05 T``; ``sigma_f``: the pixel's own fine-phase noise) plus the temporal
term ``sum_i wrap(K_i x_n / W - c_i)^2 / v_i`` of every other frequency. The posterior of the best
candidate against the other two must leave ``p_wrong <= max_wrong``; its spatial term must pass a
chi-square test at 1e-3 (the pixel's fine phase agrees with the neighbours' prediction within its
noise) and its temporal term one at 1e-4 (its frequencies do not contradict the neighbours).
Accepted pixels count as confident in the next pass, so corrections grow into uncertain regions one
pixel per pass; a pass looks only at the uncertain pixels next to those accepted in the pass before
(a frontier), so its cost follows the frontier, not the whole uncertain area.

The decoder marks accepted pixels NEIGHBOUR_ORDER and lowers their confidence by ``NEIGHBOUR_RISK``
(:mod:`.decode`): the tests above make a fill across an edge unlikely, not impossible.
"""
from __future__ import annotations

import numpy as np
from .distributions import chi2_isf

__all__ = ["correct_orders"]

_AXES = ((0, 1), (1, 0), (1, 1), (1, -1))
_DIRS = _AXES + tuple((-dy, -dx) for dy, dx in _AXES)


SAME_SURFACE = 0.1     # of a finest period: the predictions through the pixel must agree within this
MAX_FINE_NOISE = 0.05  # cycles: the pixel's own finest phase must be at least this precise
SPATIAL_P = 1e-3       # chi-square tail of the spatial term (own fine phase vs the neighbours)
PAD = 2      # border of NaN around the image: neighbour look-ups need no bounds checks


def _predictions(xg, p, Wp):
    """(12, n) float32 predictions for padded flat indices p from xg (padded, NaN where not
    confident): the 16 neighbours are gathered once (8 at distance 1, 8 at distance 2) and every
    prediction is formed in place, in the same float32 operations as ``0.5 * (a + b)`` /
    ``2 * a - b``."""
    n = p.size
    # xg[p + o] read as xg[M + o:][p - M], M the largest reach back: one index array for all 24
    # gathers instead of one sum p + o each
    M = 2 * (Wp + 1)
    pm = p - M
    near = {}
    for dy, dx in _DIRS:
        near[(dy, dx)] = np.take(xg[M + dy * Wp + dx:], pm)
    P = np.empty((len(_AXES) + len(_DIRS), n), np.float32)
    half, two = np.float32(0.5), np.float32(2.0)
    for j, (dy, dx) in enumerate(_AXES):
        np.add(near[(dy, dx)], near[(-dy, -dx)], out=P[j])
        P[j] *= half
    for j, (dy, dx) in enumerate(_DIRS):
        row = P[len(_AXES) + j]
        np.multiply(near[(dy, dx)], two, out=row)
        row -= np.take(xg[M + 2 * (dy * Wp + dx):], pm)
    return P


def _batcher_pairs(n: int) -> list:
    """Comparators of Batcher's odd-even merge sort (Knuth, TAOCP vol. 3, 5.3.4) for n inputs: the
    network for the next power of two with every comparator that touches an index >= n dropped
    (those inputs are +inf and never move), 42 comparators for n = 12."""
    m = 1
    while m < n:
        m *= 2
    pairs = []
    p = 1
    while p < m:
        k = p
        while k >= 1:
            for j in range(k % p, m - k, 2 * k):
                for i in range(min(k, m - j - k)):
                    if (i + j) // (2 * p) == (i + j + k) // (2 * p) and i + j + k < n:
                        pairs.append((i + j, i + j + k))
            k //= 2
        p *= 2
    return pairs


_SORT12 = _batcher_pairs(len(_AXES) + len(_DIRS))


def _count_rows(mask):
    """Per column, the True entries of a (rows <= 255, n) bool array, as int64: a uint8 sum over
    the rows (``np.count_nonzero(axis=0)`` goes through a slow generic path, ~10x)."""
    return np.add.reduce(mask.view(np.uint8), axis=0, dtype=np.uint8).astype(np.int64)


_LOW = np.float32(-3e18)   # stands for "no prediction": below every coordinate, its square still finite


def _nan_median(P):
    """Median over axis 0 ignoring NaN, and the count of finite entries; NaN where all are NaN.
    A copy of P with NaN -> ``_LOW`` (sorts first) is sorted along axis 0 by a sorting network
    (element-wise min / max of rows: ~4x faster than ``np.sort(axis=0)`` on (12, n), same order).
    The rows live in one (rows + 1, n) buffer whose row order the network permutes (``at``), so
    the two middle values are read by one flat gather each (``np.choose`` over a list of 12 rows
    first copies them into one array)."""
    k = _count_rows(np.isfinite(P))
    n, m = P.shape
    buf = np.empty((n + 1, m), P.dtype)
    np.fmax(P, _LOW, out=buf[:n])            # fmax(NaN, low) = low: no masked copy
    at = list(range(n + 1))                  # at[i]: the buffer row holding sorted row i; at[n]: scratch
    for a, b in (_SORT12 if n == 12 else _batcher_pairs(n)):
        ra, rb, tmp = buf[at[a]], buf[at[b]], buf[at[n]]
        np.minimum(ra, rb, out=tmp)
        np.maximum(ra, rb, out=rb)
        at[a], at[n] = at[n], at[a]          # swap buffers instead of copying
    lo = np.minimum(n - k + np.maximum(k - 1, 0) // 2, n - 1)   # the k finite entries are the last k
    hi = np.minimum(n - k + k // 2, n - 1)
    row_of = np.asarray(at[:n], np.intp)
    flat, cols = buf.ravel(), np.arange(m)
    med = flat[row_of[lo] * m + cols]
    med += flat[row_of[hi] * m + cols]
    med *= np.float32(0.5)
    med[k == 0] = np.nan
    return med, k


def _through(P, tol):
    """(n,) bool: along some axis j the two-sided prediction (row j) and both one-sided ones (rows
    4 + j, 8 + j) exist and agree within tol (the pixel lies on the surface of both sides)."""
    ok = np.zeros(P.shape[1], bool)
    with np.errstate(invalid="ignore"):
        for j in range(len(_AXES)):
            m, a, b = P[j], P[len(_AXES) + j], P[2 * len(_AXES) + j]
            ok |= (np.abs(a - m) <= tol) & (np.abs(b - m) <= tol) & (np.abs(a - b) <= tol)
    return ok


def _wrapd(t):
    return t - np.rint(t)


def correct_orders(x, good, cand, cyc, var_c, periods, length, *, max_wrong, passes=1000,
                   min_support=2, weights_min=0.01):
    """Correct / confirm the orders of ``cand`` pixels from confident neighbours (module doc).

    x: (H, W) float32 coordinates (temporal decode; NaN allowed outside good/cand); good: (H, W)
    bool; cand: (H, W) bool or the sorted flat indices of the candidates; cyc, var_c: per frequency
    1D arrays over the candidates (cycles, cycles^2). Returns (idx, x_new, p_wrong) of the accepted pixels (flat indices)."""
    H, W = x.shape
    per = np.asarray(periods, np.float64)
    f = int(np.argmax(per))
    T = length / per[f]
    L = float(length)
    Wp = W + 2 * PAD
    xg = np.full((H + 2 * PAD, Wp), np.nan, np.float32)
    inner = xg[PAD:PAD + H, PAD:PAD + W]
    np.copyto(inner, x, where=good)
    xg = xg.ravel()
    idx_all = np.flatnonzero(cand) if cand.dtype == bool else np.asarray(cand)
    r_all, c_all = np.divmod(idx_all, W)
    p_all = (r_all + PAD) * Wp + (c_all + PAD)
    offs = np.array([dy * Wp + dx for dy, dx in _DIRS])
    todo = np.ones(idx_all.size, bool)
    slot = np.full(xg.size, -1, np.int32)        # padded pixel -> its candidate number (-1: none)
    slot[p_all] = np.arange(idx_all.size, dtype=np.int32)
    mark = np.zeros(idx_all.size + 1, bool)      # + 1: slot -1 (no candidate) marks the last, unused one
    active = np.zeros(idx_all.size, bool)
    for o in offs:
        active |= np.isfinite(xg[p_all + o])
    frontier = np.flatnonzero(active)
    score = _Scorer(per, L, cyc, var_c, max_wrong)
    w = per * per
    keep = w >= weights_min * w.sum()
    out_idx, out_x, out_p = [], [], []
    for _ in range(passes):
        sel = frontier[todo[frontier]]
        frontier = frontier[:0]
        if sel.size == 0:
            break
        voted = _vote(xg, p_all[sel], Wp, cyc[f][sel], T, min_support)
        if voted is None:
            continue
        has, xh, spread, ok, through = voted
        sel = sel[has]
        ok &= var_c[f][sel] <= MAX_FINE_NOISE ** 2
        if not ok.any():
            continue
        sel, xh, spread, through = sel[ok], xh[ok], spread[ok], through[ok]
        acc, xbest, p = score(sel, xh, spread, through)
        if not acc.any():
            continue
        sel_a = sel[acc]
        xnew = _combine_from_fine(xbest[acc], [cyc[i][sel_a] for i in range(len(per))], per, L, keep)
        pa = p_all[sel_a]
        xg[pa] = xnew
        todo[sel_a] = False
        j = slot[(pa[:, None] + offs[None, :]).ravel()]    # the candidates next to the accepted ones
        mark[j] = True
        mark[-1] = False
        frontier = np.flatnonzero(mark)
        mark[frontier] = False
        out_idx.append(idx_all[sel_a])
        out_x.append(xnew)
        out_p.append(p[acc])
    if not out_idx:
        e = np.zeros(0)
        return np.zeros(0, np.int64), e, e
    return np.concatenate(out_idx), np.concatenate(out_x), np.concatenate(out_p)


def _vote(xg, pp, Wp, cf_all, T, min_support):
    """The neighbours' vote at padded pixels pp (own finest phase ``cf_all``, cycles): which have at
    least ``min_support`` predictions (``has``), and for those the median prediction ``x_hat``, the
    spread of the predictions that vote for its order, whether enough of them do (``ok``), and
    whether the pixel lies on the surface of both sides along some axis (``through``). None when
    no pixel has the support."""
    P = _predictions(xg, pp, Wp)           # float32 throughout: x to 1e-4 px, enough for orders
    xh, avail = _nan_median(P)
    has = avail >= min_support
    if not has.any():
        return None
    P, avail, xh, cf_all = P[:, has], avail[has], xh[has], cf_all[has]
    # each prediction votes for the fine order it implies for this pixel's own fine phase
    with np.errstate(invalid="ignore"):
        votes = np.divide(P, T)              # in place below: (12, n) temporaries cost more than the math
        votes -= cf_all
        np.rint(votes, out=votes)
        agree = votes == np.rint(xh / T - cf_all)
        dev2 = np.fmax(P, _LOW, out=votes)    # NaN -> finite, so that x 0 below gives 0
        dev2 -= xh
        np.multiply(dev2, dev2, out=dev2)
        dev2 *= agree                         # only the agreeing predictions count
    n_agree = _count_rows(agree)
    spread = np.sqrt(np.sum(dev2, 0) / np.maximum(n_agree, 1))
    ok = (n_agree >= min_support) & (4 * n_agree >= 3 * avail)
    return has, xh, spread, ok, _through(P, SAME_SURFACE * T)


class _Scorer:
    """Scores the three finest orders nearest the neighbours' prediction ``x_hat`` of candidates
    (module doc): spatial term + temporal term, the posterior of the best, and the acceptance tests."""

    def __init__(self, per, L, cyc, var_c, max_wrong):
        self.per, self.L, self.cyc, self.var_c, self.max_wrong = per, L, cyc, var_c, max_wrong
        self.f = int(np.argmax(per))
        self.T = L / per[self.f]
        self.chi_max = chi2_isf(1e-4, max(1, len(per) - 1))
        self.chi_sp = chi2_isf(SPATIAL_P, 1)
        self.own_min = 2.0 * np.log(1.0 / max_wrong)          # likelihood ratio 1 / max_wrong

    def __call__(self, sel, xh, spread, through):
        """(accepted mask, best coordinate, p_wrong) of candidates ``sel``."""
        per, f, T, L = self.per, self.f, self.T, self.L
        cf = self.cyc[f][sel]
        vf = self.var_c[f][sel]
        var_sp = spread ** 2 + (0.05 * T) ** 2 + vf * T * T
        n0 = np.rint(xh / T - cf)
        # the other frequencies' phases and variances at these pixels, gathered once for the 3 orders
        others = [(k, self.cyc[i][sel], self.var_c[i][sel] + np.float32((k / per[f]) ** 2) * vf)
                  for i, k in enumerate(per) if i != f]
        scores, temps, spat, xs = [], [], [], []
        for dn in (-1.0, 0.0, 1.0):
            xn = (n0 + dn + cf) * T
            temp = np.zeros(xn.shape, xn.dtype)
            for k, c, v in others:
                temp += _wrapd(k * xn / L - c) ** 2 / v
            sp = (xn - xh) ** 2 / var_sp
            scores.append(sp + temp)
            temps.append(temp)
            spat.append(sp)
            xs.append(xn)
        S = np.stack(scores)
        b = np.argmin(S, 0)
        cols = np.arange(b.size)
        sb = S[b, cols]
        with np.errstate(over="ignore"):
            p = np.sum(np.exp(-0.5 * (S - sb)), 0) - 1.0
        p = p / (1.0 + p)
        Tm = np.stack(temps)
        tb = Tm[b, cols]
        # off the same-surface axis (extrapolation from one side): the pixel's own frequencies alone
        # must rule out the orders next to the chosen one (a step of ~ a whole period looks smooth)
        own = np.min(np.where(np.arange(3)[:, None] == b[None, :], np.inf, Tm), 0) - tb
        acc = (p <= self.max_wrong) & (tb <= self.chi_max) & (np.stack(spat)[b, cols] <= self.chi_sp) \
            & (through | (own >= self.own_min))
        return acc, np.stack(xs)[b, cols], p


def _combine_from_fine(xbest, cyc, per, L, keep):
    """Every frequency's coordinate from its order next to ``xbest``, K^2-weighted (as unwrap)."""
    num = np.zeros(xbest.shape, xbest.dtype)
    den = 0.0
    for i, k in enumerate(per):
        if not keep[i]:
            continue
        n = np.rint(k * xbest / L - cyc[i])
        xi = (n + cyc[i]) * (L / k)
        num += k * k * (xi - xbest)
        den += k * k
    return xbest + num / den
