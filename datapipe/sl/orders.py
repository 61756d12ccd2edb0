"""Fringe orders of uncertain pixels from the pooled evidence of their surface (issue #31).

A pixel whose own frequencies leave its order uncertain (a dark surface: phase SNR of a few) still
knows its *finest* phase well enough to say how its coordinate differs from its neighbours' by a
fraction of a period. On one smooth surface those differences chain the pixels' finest orders
together (spatial unwrapping of the finest phase), leaving a single unknown integer per surface:
its offset ``m``. Every pixel's coarse phases then vote on that one integer, and the votes add up:
the log-likelihood of ``m`` is the sum over the pixels of their temporal log-likelihoods, so a patch
of n pixels has sqrt(n) times the coarse SNR of one pixel. This is the maximum-likelihood decision
for the patch under the same Gaussian phase-noise model that :mod:`.confidence` uses per pixel.

Steps (all vectorised; only the uncertain pixels take part, so a scene without them costs nothing):

1. Links: 4-neighbours that are both uncertain (their orders undecided but their finest phase
   precise: ``sigma_c <= MAX_FINE_NOISE`` cycles) and whose finest phases differ by at most
   ``LINK_MAX`` cycles. The relative finest order across a link is ``-round(c_q - c_p)``: exact
   while the true difference is below half a period (a smooth surface sampled finer than the
   fringe), wrong only across a depth step.
2. Components of the link graph (:func:`scipy.sparse.csgraph.connected_components`); relative
   orders along a breadth-first tree (pointer jumping, log(depth) vectorised passes). A link that
   disagrees with the tree (a loop whose steps do not sum to zero) means a step inside the
   component: the whole component is refused.
3. Blocks = component x ``TILE`` x ``TILE`` tile. Per block and candidate offset ``m`` (the
   finest frequency's ``K_f`` hypotheses; integer periods repeat after the width) the summed cost
   ``sum_q min(chi2_q(m), ROBUST_CAP)`` with ``chi2_q(m) = sum_{i != f} wrap(K_i x_q(m) / W -
   c_i)^2 / (v_i + (K_i / K_f)^2 v_f)``. The block's probability of a wrong offset is the posterior
   mass of the other offsets, ``sum_{m != m*} exp(-(S_m - S_m*) / 2)`` (flat prior).
4. Safety: blocks of one component that are each sure of their offset must name the same one
   (a depth step of a whole number of periods inside a component splits it into two surfaces
   whose blocks disagree: the component is refused); a pixel's own frequencies must not contradict
   the chosen offset (``chi2_q(m*)`` below the 1e-4 tail); the block must hold at least
   ``MIN_BLOCK`` pixels.

Accepted pixels get the order, the block's probability as their ``p_wrong`` and come out as
NEIGHBOUR_ORDER (their order rests on the same-surface assumption: the decoder lowers their
confidence by ``NEIGHBOUR_RISK``). Why only uncertain pixels form the components: a confident
neighbour across a depth step of about one period (issue #19: a dark box top beside a bright floor
on a 5 cm baseline) would otherwise outvote the patch's own coarse phases; here the patch decides
from its own evidence, which pooled over hundreds of pixels is decisive.
"""
from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph
from scipy.special import gammainccinv
from scipy.stats import chi2

from .confidence import phase_var_from_snr

__all__ = ["pooled_orders", "MAX_FINE_NOISE", "LINK_MAX", "TILE"]

MAX_FINE_NOISE = 0.12    # cycles: finest-phase noise (estimated) of a pixel that may take part
LINK_MAX = 0.25         # cycles: largest misfit of a link's finest-phase difference to the local gradient
TILE = 32               # pixels: block size (a step inside a component shows as blocks that disagree)
MIN_BLOCK = 32           # pixels in a block before it decides
SPLIT_REFUSES = False
GRAD = 5                # pixels: window of the finest-phase gradient estimate
HALF_MIN = 8            # pooled pixels a half window needs to speak
LOOP_ROUNDS = 3         # rounds of cutting loops that do not close
DIM_FALSE_RATE = 1e-3   # a NO_LIGHT pixel joins when its 3 x 3 candidates pass the joint modulation test at this rate
ROBUST_CAP = 25.0       # cap on one pixel's cost (a mixed pixel at an edge cannot outvote a patch)
LOCAL = 11              # pixels: window whose pooled pixels must prefer the offset by themselves
HALF = 7                # pixels: the window whose halves must not prefer another offset
OWN_P = 1e-4            # a pixel's own frequencies may contradict the offset at most at this tail


def _pairs(ok, W):
    """Flat indices (a, b) of the horizontal and the vertical neighbour pairs of ``ok`` pixels (flat
    bool of an image W wide), per direction."""
    idx = np.flatnonzero(ok)
    right = idx[(idx % W != W - 1)]
    right = right[ok[right + 1]]
    down = idx[idx + W < ok.size]
    down = down[ok[down + W]]
    return (right, right + 1), (down, down + W)


def _links(ok, cf, shape):
    """4-neighbour links among ``ok`` pixels whose finest-phase difference fits the local gradient
    within ``LINK_MAX`` cycles: (a, b, step), flat indices and ``step = N_b - N_a`` (finest orders).

    The gradient (cycles per pixel, per axis) at a pixel is the angle of the summed phasors of the
    wrapped differences of the pairs in its ``GRAD`` x ``GRAD`` window (a surface's fringe gradient
    varies slowly; one pair is too noisy). Work is done at the pairs only, not over the image."""
    import cv2

    H, W = shape
    k = dict(ksize=(GRAD, GRAD), normalize=False, borderType=cv2.BORDER_CONSTANT)
    pa, pb, ps = [], [], []
    zr = np.zeros(H * W, np.float32)
    zi = np.zeros(H * W, np.float32)
    for a, b in _pairs(ok, W):
        d = cf[b] - cf[a]
        ang = np.float32(2 * np.pi) * d
        zr[:] = 0
        zi[:] = 0
        zr[a] = np.cos(ang)
        zi[a] = np.sin(ang)
        sr = cv2.boxFilter(zr.reshape(H, W), -1, **k).ravel()
        si = cv2.boxFilter(zi.reshape(H, W), -1, **k).ravel()
        # the pair's gradient: the mean of its two ends' (windows centred on a and on b)
        g = (np.arctan2(si[a] + si[b], sr[a] + sr[b]) * np.float32(1 / (2 * np.pi))).astype(np.float32)
        t = g - d                                    # = N_b - N_a + noise on one smooth surface
        n = np.rint(t)
        keep = np.abs(t - n) <= LINK_MAX
        pa.append(a[keep])
        pb.append(b[keep])
        ps.append(n[keep].astype(np.int64))
    return np.concatenate(pa), np.concatenate(pb), np.concatenate(ps)


def _smoothed(cand, snr, shape):
    """Per frequency the mean of ``B_hat^2 / s^2`` over each candidate's 3 x 3 candidate neighbours
    (the phase noise follows from it far more precisely than from one pixel's B_hat), and their
    count."""
    import cv2

    H, W = shape
    k = dict(ksize=(3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
    m = np.zeros(H * W, np.float32)
    m[cand] = 1
    count = cv2.boxFilter(m.reshape(H, W), -1, **k).ravel()[cand]
    out = []
    for q in snr:
        m[cand] = q
        out.append((cv2.boxFilter(m.reshape(H, W), -1, **k).ravel()[cand] / count).astype(np.float32))
    return out, count


def _relative_orders(n, a, b, step):
    """Components and relative finest orders of n nodes linked by (a, b) (local node numbers)."""
    ncomp, comp = csgraph.connected_components(
        sparse.coo_matrix((np.ones(a.size), (a, b)), shape=(n, n)), directed=False)
    # a virtual root joined to the first node of every component: one breadth-first tree for all
    first = np.full(ncomp, -1, np.int64)
    first[comp[::-1]] = np.arange(n)[::-1]
    root = n
    rows = np.concatenate([a, b, np.full(ncomp, root)])
    cols = np.concatenate([b, a, first])
    g = sparse.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n + 1, n + 1))
    _, pred = csgraph.breadth_first_order(g, root, directed=True, return_predecessors=True)
    pred = pred.astype(np.int64)
    pred[root] = root
    # delta of every tree edge pred -> node from the link list (both directions)
    lut = sparse.csr_matrix((np.concatenate([step, -step]).astype(float) + 0.5,
                             (np.concatenate([a, b]), np.concatenate([b, a]))), shape=(n, n))
    acc = np.zeros(n + 1, np.int64)
    child = np.flatnonzero(pred[:n] != root)
    if child.size:
        acc[child] = np.rint(np.asarray(lut[pred[child], child]).ravel() - 0.5).astype(np.int64)
    ptr = pred.copy()
    while np.any(ptr[:n] != root):
        acc = acc + acc[ptr]
        ptr = ptr[ptr]
    rel = acc[:n]
    return comp, ncomp, rel, (rel[b] - rel[a]) != step


def _local_support(flat, capped, mq, shape, shifts):
    """Per pixel: the least, over the other offsets d, of the summed cost difference
    ``capped(m* + d) - capped(m*)`` over the pooled pixels in its ``LOCAL`` x ``LOCAL`` window
    (twice the log-likelihood ratio by which its neighbourhood prefers its block's offset), and the
    least of the same over the four halves of its ``HALF`` x ``HALF`` window that contain the pixel (top, bottom, left,
    right: at a depth step the half on the pixel's own side of it speaks for its own surface).
    Only the offsets ``shifts`` (relative to m*) are tried: those some block cannot rule out by far."""
    import cv2

    Kf, n = capped.shape
    H, W = shape
    r, c = np.divmod(flat, W)
    r0, c0 = r.min(), c.min()
    h, w = r.max() - r0 + 1, c.max() - c0 + 1
    rr, cc = r - r0, c - c0
    cols = np.arange(n)
    base = capped[mq, cols]
    worst = np.full(n, np.inf, np.float32)
    worst_half = np.full(n, np.inf, np.float32)
    img = np.zeros((h, w), np.float32)
    cnt = np.zeros((h, w), np.float32)
    cnt[rr, cc] = 1
    L, k = HALF, HALF // 2
    halves = [((L, k + 1), (k, k)), ((L, k + 1), (k, 0)), ((k + 1, L), (k, k)), ((k + 1, L), (0, k))]
    border = cv2.BORDER_CONSTANT
    enough = [cv2.boxFilter(cnt, -1, size, anchor=a, normalize=False, borderType=border)[rr, cc] >= HALF_MIN
              for size, a in halves]
    for d in shifts:
        img[rr, cc] = capped[(mq + d) % Kf, cols] - base
        s = cv2.boxFilter(img, -1, (LOCAL, LOCAL), normalize=False, borderType=border)
        np.minimum(worst, s[rr, cc], out=worst)
        for ((sw, sh), a), ok in zip(halves, enough):
            s = cv2.boxFilter(img, -1, (sw, sh), anchor=a, normalize=False, borderType=border)[rr, cc]
            np.minimum(worst_half, np.where(ok, s, np.inf), out=worst_half)
    return worst, worst_half


def pooled_orders(cand, cyc, snr, periods, length, shape, *, max_wrong, dim=None, x_sure=None):
    """Decide the orders of uncertain pixels from their surface's pooled evidence (module doc).

    cand: sorted flat indices of the candidate pixels (order undecided and consistent, or NO_LIGHT
    by the joint modulation floor alone: ``dim``); cyc: per frequency 1D arrays over ``cand``, the
    wrapped phases in cycles; snr: per frequency ``B_hat^2 / s^2`` (modulation over the noise of
    the least-squares coefficients); periods: integer frequencies; length: coded projector width
    (pixels); shape: (H, W); x_sure: optional (H, W) coordinates of the pixels decided on their own
    (NaN elsewhere): a pooled pixel more than half a finest period away from one of its 4-neighbours
    there is refused (a depth step between them, or a wrong order on one side). Returns ``(idx, x, p_wrong)`` of the accepted pixels (flat indices,
    finest-frequency coordinate in pixels, probability that the order is wrong)."""
    empty = (np.zeros(0, np.int64), np.zeros(0, np.float32), np.zeros(0, np.float32))
    per = np.asarray(periods, np.float64)
    F = per.size
    f = int(np.argmax(per))
    Kf = int(round(per[f]))
    if F < 2 or cand.size < MIN_BLOCK:
        return empty
    H, W = shape
    dim = np.zeros(cand.size, bool) if dim is None else dim
    qbar, count = _smoothed(cand, snr, (H, W))
    var_c = [phase_var_from_snr(q) for q in qbar]
    keep = var_c[f] <= MAX_FINE_NOISE ** 2
    if dim.any():                        # lit after all? the 3 x 3 candidates' joint modulation test
        lit = 0.5 * count * sum(qbar) > gammainccinv(F * count, DIM_FALSE_RATE)
        keep &= ~dim | lit
    cand, dim = cand[keep], dim[keep]
    cyc = [c[keep] for c in cyc]
    var_c = [v[keep] for v in var_c]
    n = cand.size
    if n < MIN_BLOCK:
        return empty
    cf_full = np.zeros(H * W, np.float32)
    cf_full[cand] = cyc[f]
    alive = np.ones(n, bool)
    for _ in range(LOOP_ROUNDS):
        ok = np.zeros(H * W, bool)
        ok[cand[alive]] = True
        ga, gb, step = _links(ok, cf_full, (H, W))
        if ga.size == 0:
            return empty
        a = np.searchsorted(cand, ga)
        b = np.searchsorted(cand, gb)
        comp, ncomp, rel, bad = _relative_orders(n, a, b, step)
        if not bad.any():
            break
        # a link that contradicts the tree closes a loop whose order steps do not sum to zero (a slip
        # of the finest phase, or a step): its ends leave, which cuts the loop; then again
        alive[a[bad]] = False
        alive[b[bad]] = False
    else:
        comp = comp.copy()
        comp[np.isin(comp, np.unique(comp[a[bad]]))] = -1
    comp[~alive] = -1
    # blocks: component x tile; singletons (no link) never decide
    r, c = np.divmod(cand, W)
    ntx = (W + TILE - 1) // TILE
    tile = (r // TILE) * ntx + c // TILE
    sizes = np.bincount(comp[comp >= 0], minlength=ncomp)
    use = (comp >= 0) & (sizes[np.maximum(comp, 0)] >= MIN_BLOCK)
    if not use.any():
        return empty
    sel = np.flatnonzero(use)
    bkey = comp[sel].astype(np.int64) * (tile.max() + 1) + tile[sel]
    ublk, binv = np.unique(bkey, return_inverse=True)
    nb = ublk.size
    # cost of every candidate offset m for every pixel: x_q(m) = (rel_q + m + c_f) T
    fine = rel[sel] + cyc[f][sel].astype(np.float64)          # finest cycles, up to the offset
    m = np.arange(Kf, dtype=np.float32)[:, None]
    cost = np.zeros((Kf, sel.size), np.float32)
    vf = var_c[f][sel]
    for i in range(F):
        if i == f:
            continue
        ratio = per[i] / per[f]
        # the phase each offset predicts, reduced to one cycle first (float32 keeps 1e-7 of a cycle)
        t0 = ratio * fine - cyc[i][sel]
        t = np.float32(ratio) * m + (t0 - np.rint(t0)).astype(np.float32)[None, :]
        t -= np.rint(t)
        t *= t
        t *= (np.float32(1) / (var_c[i][sel] + np.float32(ratio * ratio) * vf))[None, :]
        cost += t
    capped = np.minimum(cost, ROBUST_CAP)
    order = np.argsort(binv, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(binv[order]) != 0])
    S = np.add.reduceat(capped[:, order], starts, axis=1)      # (Kf, nb)
    best = np.argmin(S, 0)
    sb = S[best, np.arange(nb)]
    p_blk = np.sum(np.exp(-0.5 * (S - sb[None, :])), 0) - 1.0
    p_blk = p_blk / (1.0 + p_blk)
    nblk = np.bincount(binv, minlength=nb)
    sure = (p_blk <= max_wrong) & (nblk >= MIN_BLOCK)
    # blocks of one component that are sure must agree on the offset
    bcomp = ublk // (tile.max() + 1)
    sure_c, sure_m = bcomp[sure], best[sure]
    lo = np.full(ncomp, Kf, np.int64)
    hi = np.full(ncomp, -1, np.int64)
    np.minimum.at(lo, sure_c, sure_m)
    np.maximum.at(hi, sure_c, sure_m)
    split = (hi >= 0) & (lo != hi)
    if SPLIT_REFUSES:
        sure &= ~split[bcomp]
    mq = best[binv]
    cols = np.arange(sel.size)
    own = cost[mq, cols]
    acc = sure[binv] & (own <= chi2.isf(OWN_P, max(1, F - 1)))
    if dim[sel].any():                   # below the modulation floor: only inside the surface (4 linked neighbours)
        deg = np.bincount(a, minlength=n) + np.bincount(b, minlength=n)
        acc &= ~dim[sel] | (deg[sel] >= 4)
    if acc.any():
        # offsets worth a look: those some sure block prefers m* to by less than 8 x the local threshold,
        # scaled to a window's share of the block (the local test is far from binding for the others)
        gain = (S - sb[None, :]) * np.minimum(1.0, LOCAL * LOCAL / np.maximum(nblk, 1))[None, :]
        near = np.zeros(Kf, bool)
        for d in range(1, Kf):
            near[d] = np.any(gain[(best + d) % Kf, np.arange(nb)][sure] < 8 * 2.0 * np.log(1.0 / max_wrong))
        near[[1, Kf - 1]] = True
        full, half = _local_support(cand[sel], capped, mq, (H, W), np.flatnonzero(near))
        acc &= (full >= 2.0 * np.log(1.0 / max_wrong)) & (half >= 0)
    if not acc.any():
        return empty
    # integer periods repeat after the projector width: bring each block whole into the projector's
    # range by its median, and refuse its pixels that noise puts past an edge (a fold there would
    # move them a whole width)
    T = length / per[f]
    xr = (fine + mq) * T
    med = np.array([np.median(v) for v in np.split(xr[order], starts[1:])])
    xr -= np.floor((med[binv] + 0.5) / length) * length
    acc &= (xr >= -0.5) & (xr < length - 0.5)
    if not acc.any():
        return empty
    pick = sel[acc]
    xf = xr[acc]
    flat = cand[pick]
    if x_sure is not None:
        agree = _agrees_with_sure(flat, xf, x_sure, 0.5 * T)
        flat, xf, pick, acc_idx = flat[agree], xf[agree], pick[agree], np.flatnonzero(acc)[agree]
    else:
        acc_idx = np.flatnonzero(acc)
    return flat, xf.astype(np.float32), p_blk[binv[acc_idx]].astype(np.float32)


def _agrees_with_sure(flat, x, x_sure, tol):
    """False where a 4-neighbour decided on its own lies more than ``tol`` away from ``x``."""
    H, W = x_sure.shape
    r, c = np.divmod(flat, W)
    ok = np.ones(flat.size, bool)
    xs = x_sure.ravel()
    for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        rr, cc = r + dr, c + dc
        inside = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
        nb = np.full(flat.size, np.nan, np.float32)
        nb[inside] = xs[rr[inside] * W + cc[inside]]
        with np.errstate(invalid="ignore"):
            ok &= ~(np.abs(nb - x) > tol)
    return ok
