"""Fringe orders of uncertain pixels from the pooled evidence of their surface (issue #31).

A pixel whose own frequencies leave its order uncertain (a dark surface: phase SNR of a few) still
knows its *finest* phase well enough to say how its coordinate differs from its neighbours' by a
fraction of a period. On one smooth surface those differences chain the pixels' finest orders
together (spatial unwrapping of the finest phase), leaving a single unknown integer per surface:
its offset ``m``. Every pixel's coarse phases then vote on that one integer, and the votes add up:
the log-likelihood of ``m`` is the sum over the pixels of their temporal log-likelihoods, so a patch
of n pixels has sqrt(n) times the coarse SNR of one pixel. This is the maximum-likelihood decision
for the patch under the same Gaussian phase-noise model that :mod:`.confidence` uses per pixel.

Steps (all vectorised; only the candidates take part: a scene without uncertain or dim pixels
costs next to nothing):

0. Candidates: pixels whose orders stayed uncertain (and consistent), and pixels NO_LIGHT by the
   joint modulation floor alone (``dim``). The phase noise of each comes from the mean of
   ``B_hat^2 / s^2`` over its 3 x 3 candidate neighbours (one pixel's B_hat is too noisy); the
   finest phase must be precise (``sigma_c <= MAX_FINE_NOISE`` cycles); a dim pixel's 3 x 3
   candidates must pass the joint modulation test at ``DIM_FALSE_RATE`` (pure noise: 1e-3).
1. Links: 4-neighbour candidates whose finest-phase difference fits the local fringe gradient
   (phasor mean of the pair differences in a ``GRAD`` x ``GRAD`` window) within ``LINK_MAX``
   cycles. The relative finest order across a link is ``round(c_p + g - c_q)``: exact on a smooth
   surface sampled finer than the fringe, unknowable across a depth step.
2. Components of the link graph (:func:`scipy.sparse.csgraph.connected_components`); relative
   orders along a breadth-first tree (pointer jumping, log(depth) vectorised passes). A link that
   disagrees with the tree closes a loop whose steps do not sum to zero: its two ends leave and the
   components are built again (``LOOP_ROUNDS`` times; what the cut touches only). Steps 1 and 2
   live in :mod:`.surfaces`.
3. Blocks = component x ``TILE`` x ``TILE`` tile, of at least ``MIN_BLOCK`` pixels. Per block and
   offset ``m`` (the finest frequency's ``K_f`` hypotheses; integer periods repeat after the width)
   the summed cost ``S_m = sum_q min(chi2_q(m), ROBUST_CAP)`` with ``chi2_q(m) = sum_{i != f}
   wrap(K_i x_q(m) / W - c_i)^2 / (v_i + (K_i / K_f)^2 v_f)``. The block's probability of a wrong
   offset is the posterior mass of the others, ``sum_{m != m*} exp(-(S_m - S_m*) / 2)`` (flat prior);
   it decides when that is <= ``max_wrong``.
4. Per pixel (a depth step of about a whole period inside a block is what these catch): its own
   frequencies must not contradict the offset (``chi2_q(m*)`` below the ``OWN_P`` tail); its own
   ``LOCAL`` x ``LOCAL`` neighbourhood must prefer the offset by a likelihood ratio of
   ``1 / max_wrong`` and no half of its ``HALF`` x ``HALF`` window may prefer another (at a step,
   the half on the pixel's side speaks for its surface); a dim pixel needs all 4 links; a pixel
   more than half a period from a 4-neighbour decided on its own is refused (the caller's
   ``x_sure``); the block is placed in the projector's range by its median and pixels past an edge
   are refused.

Accepted pixels get the order, the block's probability as their ``p_wrong`` and come out as
NEIGHBOUR_ORDER (their order rests on the same-surface assumption: the decoder lowers their
confidence by ``NEIGHBOUR_RISK``). Why only uncertain pixels form the components: a confident
neighbour across a depth step of about one period (issue #19: a dark box top beside a bright floor
on a 5 cm baseline) would otherwise outvote the patch's own coarse phases; here the patch decides
from its own evidence, which pooled over hundreds of pixels is decisive.
"""
from __future__ import annotations

import numpy as np
from scipy.special import gammainccinv
from .distributions import chi2_isf

from .confidence import phase_var_from_snr
from .surfaces import LINK_MAX, surfaces

__all__ = ["pooled_orders", "MAX_FINE_NOISE", "LINK_MAX", "TILE"]

MAX_FINE_NOISE = 0.12    # cycles: finest-phase noise (estimated) of a pixel that may take part
TILE = 32               # pixels: block size (a step inside a component shows as blocks that disagree)
MIN_BLOCK = 32           # pixels in a block before it decides
HALF_MIN = 8            # pooled pixels a half window needs to speak
DIM_FALSE_RATE = 1e-3   # a NO_LIGHT pixel joins when its 3 x 3 candidates pass the joint modulation test at this rate
ROBUST_CAP = 25.0       # cap on one pixel's cost (a mixed pixel at an edge cannot outvote a patch)
LOCAL = 15              # pixels: window whose pooled pixels must prefer the offset by themselves
HALF = 7                # pixels: the window whose halves must not prefer another offset
OWN_P = 1e-4            # a pixel's own frequencies may contradict the offset at most at this tail


def _smoothed(cand, snr, shape):
    """Per frequency the mean of ``B_hat^2 / s^2`` over each candidate's 3 x 3 candidate neighbours
    (the phase noise follows from it far more precisely than from one pixel's B_hat), and their
    count."""
    import cv2

    k = dict(ksize=(3, 3), normalize=False, borderType=cv2.BORDER_CONSTANT)
    box, h, w = _box(cand, shape, 1)
    m = np.zeros(h * w, np.float32)
    m[box] = 1
    count = cv2.boxFilter(m.reshape(h, w), -1, **k).ravel()[box]
    out = []
    for q in snr:
        m[box] = q
        out.append((cv2.boxFilter(m.reshape(h, w), -1, **k).ravel()[box] / count).astype(np.float32))
    return out, count


def _box(flat, shape, reach):
    """The pixels ``flat`` as flat indices in their bounding box grown by ``reach`` (clipped to the
    image), and the box's (h, w). A box filter of reach <= ``reach`` over the box gives the sums
    it gives over the image (zero outside the box, as the constant border is; OpenCV sums float32
    in float64, so the sums do not depend on where a row starts), on less image."""
    H, W = shape
    r, c = np.divmod(flat, W)
    r0, c0 = max(int(r.min()) - reach, 0), max(int(c.min()) - reach, 0)
    h, w = min(int(r.max()) + reach + 1, H) - r0, min(int(c.max()) + reach + 1, W) - c0
    return (r - r0) * w + (c - c0), h, w


def _local_support(flat, capped_at, mq, Kf, shape, shifts):
    """Per pixel: the least, over the other offsets d, of the summed cost difference
    ``capped(m* + d) - capped(m*)`` (``capped_at(m)``: each pixel's capped cost at its offset m[q];
    K_f offsets) over the pooled pixels in its ``LOCAL`` x ``LOCAL`` window
    (twice the log-likelihood ratio by which its neighbourhood prefers its block's offset), and the
    least of the same over the four halves of its ``HALF`` x ``HALF`` window that contain the pixel (top, bottom, left,
    right: at a depth step the half on the pixel's own side of it speaks for its own surface).
    Only the offsets ``shifts`` (relative to m*) are tried: those some block cannot rule out by far.

    The top half of a pixel's window is the bottom half of the pixel ``HALF // 2`` rows up (and the
    left half the right half of the pixel as many columns left), so one filter gives both halves of
    an axis, read at two places of an image with ``HALF // 2`` zero rows (columns) before it."""
    import cv2

    H, W = shape
    r, c = np.divmod(flat, W)
    r0, c0 = r.min(), c.min()
    h, w = r.max() - r0 + 1, c.max() - c0 + 1
    k = HALF // 2
    pv = (r - r0 + k) * w + (c - c0)                 # the pixels in the (h + k, w) image: k zero rows above
    ph = (r - r0) * (w + k) + (c - c0 + k)           # in the (h, w + k) image: k zero columns left
    border = cv2.BORDER_CONSTANT

    def halves(img_v, img_h):
        """Sums over the top, bottom, left and right halves of each pixel's HALF x HALF window."""
        sv = cv2.boxFilter(img_v.reshape(h + k, w), -1, (HALF, k + 1), anchor=(k, 0), normalize=False,
                           borderType=border).ravel()
        sh = cv2.boxFilter(img_h.reshape(h, w + k), -1, (k + 1, HALF), anchor=(0, k), normalize=False,
                           borderType=border).ravel()
        return sv[pv - k * w], sv[pv], sh[ph - k], sh[ph]

    img_v, img_h = np.zeros((h + k) * w, np.float32), np.zeros(h * (w + k), np.float32)
    img_v[pv], img_h[ph] = 1, 1
    enough = [s >= HALF_MIN for s in halves(img_v, img_h)]
    n = flat.size
    base = capped_at(mq)
    worst = np.full(n, np.inf, np.float32)
    worst_half = np.full(n, np.inf, np.float32)
    for d in shifts:
        diff = capped_at((mq + d) % Kf) - base
        img_v[pv], img_h[ph] = diff, diff
        s = cv2.boxFilter(img_v.reshape(h + k, w), -1, (LOCAL, LOCAL), normalize=False, borderType=border)
        np.minimum(worst, s.ravel()[pv], out=worst)
        for s, ok in zip(halves(img_v, img_h), enough):
            np.minimum(worst_half, np.where(ok, s, np.inf), out=worst_half)
    return worst, worst_half


def pooled_orders(cand, cyc, snr, periods, length, shape, *, max_wrong, dim=None, x_sure=None):
    """Decide the orders of uncertain pixels from their surface's pooled evidence (module doc).

    cand: sorted flat indices of the candidate pixels (order undecided and consistent, or NO_LIGHT
    by the joint modulation floor alone: ``dim``); cyc: per frequency 1D arrays over ``cand``, the
    wrapped phases in cycles; snr: per frequency ``B_hat^2 / s^2`` (modulation over the noise of
    the least-squares coefficients); periods: integer frequencies; length: coded projector width
    (pixels); shape: (H, W); x_sure: optional (H, W) coordinates of the pixels decided on their own
    (NaN elsewhere), or a function of flat indices giving them at those pixels: a pooled pixel more
    than half a finest period away from one of its 4-neighbours there is refused (a depth step
    between them, or a wrong order on one side).
    Returns ``(idx, x, p_wrong, pos)`` of the accepted pixels (flat indices, finest-frequency
    coordinate in pixels, probability that the order is wrong, and their positions in ``cand``:
    the caller reads its per-candidate arrays there without searching)."""
    empty = (np.zeros(0, np.int64), np.zeros(0, np.float32), np.zeros(0, np.float32), np.zeros(0, np.int64))
    per = np.asarray(periods, np.float64)
    F, f = per.size, int(np.argmax(per))
    if F < 2 or cand.size < MIN_BLOCK:
        return empty
    H, W = shape
    dim = np.zeros(cand.size, bool) if dim is None else dim
    keep, var_c = _precise_and_lit(cand, snr, dim, (H, W), f)
    num = np.flatnonzero(keep)                   # their positions in the caller's candidates
    cand, dim = cand[keep], dim[keep]
    cyc = [c[keep] for c in cyc]
    var_c = [v[keep] for v in var_c]
    if cand.size < MIN_BLOCK:
        return empty
    surf = surfaces(cand, cyc[f], (H, W))
    if surf is None:
        return empty
    comp, ncomp, rel, a, b = surf
    # blocks: component x tile; small components never decide
    r, c = np.divmod(cand, W)
    ntiles = ((H + TILE - 1) // TILE) * ((W + TILE - 1) // TILE)
    tile = (r // TILE) * ((W + TILE - 1) // TILE) + c // TILE
    sizes = np.bincount(comp[comp >= 0], minlength=ncomp)
    sel = np.flatnonzero((comp >= 0) & (sizes[np.maximum(comp, 0)] >= MIN_BLOCK))
    if sel.size == 0:
        return empty
    # the pooled pixels in block order (ascending pixel order inside a block, one stable sort): the
    # block sums then read contiguous columns, with no gathered copy of the (K_f, n) costs
    key = comp[sel].astype(np.int64) * ntiles + tile[sel]
    by_block = np.argsort(key, kind="stable")
    sel, key = sel[by_block], key[by_block]
    binv = np.cumsum(np.r_[False, key[1:] != key[:-1]])      # block numbers 0, 1, ... in key order
    fine = rel[sel] + cyc[f][sel].astype(np.float64)          # finest cycles, up to the offset
    own_max = chi2_isf(OWN_P, max(1, F - 1))
    sub_cyc, sub_var = [c_[sel] for c_ in cyc], [v[sel] for v in var_c]
    costs = _OffsetCosts(fine, sub_cyc, sub_var, per)
    blk = _block_posterior(costs, binv, max_wrong)
    mq = blk["best"][binv]
    acc = blk["sure"][binv] & (costs.at(mq) <= own_max)       # the pixel's own test: uncapped
    if dim[sel].any():                   # below the modulation floor: only inside the surface (4 linked neighbours)
        deg = np.bincount(a, minlength=cand.size) + np.bincount(b, minlength=cand.size)
        acc &= ~dim[sel] | (deg[sel] >= 4)
    if acc.any():
        full, half = _local_support(cand[sel], lambda m: costs.at(m, ROBUST_CAP), mq, costs.Kf, (H, W),
                                    _shifts_to_check(blk, max_wrong))
        acc &= (full >= 2.0 * np.log(1.0 / max_wrong)) & (half >= 0)
    if not acc.any():
        return empty
    # integer periods repeat after the projector width: bring each block whole into the projector's
    # range by its median, and refuse its pixels that noise puts past an edge (a fold there would
    # move them a whole width)
    T = length / per[f]
    xr = (fine + mq) * T
    xr -= _block_folds(xr, binv, blk["starts"], blk["size"], length)[binv] * length
    acc &= (xr >= -0.5) & (xr < length - 0.5)
    if x_sure is not None:
        acc[acc] = _agrees_with_sure(cand[sel[acc]], xr[acc], x_sure, (H, W), 0.5 * T)
    if not acc.any():
        return empty
    # back to ascending pixel order, as the candidates came (sel holds distinct candidate numbers)
    xs, ps_ = np.zeros(cand.size), np.zeros(cand.size)
    xs[sel[acc]], ps_[sel[acc]] = xr[acc], blk["p"][binv[acc]]
    mine = np.zeros(cand.size, bool)
    mine[sel[acc]] = True
    return cand[mine], xs[mine].astype(np.float32), ps_[mine].astype(np.float32), num[mine]


def _block_folds(x, binv, starts, size, length):
    """Per block (its pixels contiguous: ``starts``, ``size``), ``floor((median + 0.5) / length)``:
    how many projector widths to fold it back by. Where the block's least and largest x give the
    same, so does the median between them; the medians themselves (:func:`_block_medians`) only for
    the blocks that straddle a fold (few: a block lies inside the projector's range)."""
    lo = np.floor((np.minimum.reduceat(x, starts) + 0.5) / length)
    hi = np.floor((np.maximum.reduceat(x, starts) + 0.5) / length)
    split = np.flatnonzero(lo != hi)
    if split.size:
        n = size[split]
        first = np.repeat(starts[split] - np.r_[0, np.cumsum(n)[:-1]], n)
        pix = first + np.arange(n.sum())                 # the split blocks' pixels, block by block
        sub = np.repeat(np.arange(split.size), n)
        med = _block_medians(x[pix], sub, np.r_[0, np.cumsum(n)[:-1]], n)
        lo[split] = np.floor((med + 0.5) / length)
    return lo


def _block_medians(x, binv, starts, size):
    """``np.median`` of x over each block (blocks numbered 0.. by binv; ``starts`` of the blocks in
    block order, ``size`` their sizes), by one sort instead of a median per block: the middle value,
    or the mean of the two middle values."""
    v = x[np.lexsort((x, binv))]
    hi = starts + size // 2
    lo = np.where(size % 2 == 1, hi, hi - 1)
    return np.where(lo == hi, v[hi], (v[lo] + v[hi]) / 2)


def _precise_and_lit(cand, snr, dim, shape, f):
    """(keep mask, per-frequency phase variances in cycles^2 from the 3x3 mean SNR): the finest
    phase precise enough to link, and a ``dim`` pixel's 3x3 candidates passing the joint
    modulation test at ``DIM_FALSE_RATE``."""
    qbar, count = _smoothed(cand, snr, shape)
    var_c = [phase_var_from_snr(q) for q in qbar]
    keep = var_c[f] <= MAX_FINE_NOISE ** 2
    if dim.any():                        # lit after all? the 3 x 3 candidates' joint modulation test
        # count is a whole number 1..9: the Gamma quantile from a 10-entry table, not per pixel
        quantile = gammainccinv(len(snr) * np.arange(10, dtype=np.float32), DIM_FALSE_RATE)
        lit = 0.5 * count * sum(qbar) > quantile[count.astype(np.intp)]
        keep &= ~dim | lit
    return keep, var_c


class _OffsetCosts:
    """``chi2_q(m) = sum_{i != f} wrap(K_i x_q(m) / W - c_i)^2 / (v_i + (K_i / K_f)^2 v_f)`` with
    ``x_q(m) = (fine_q + m) T``, for the offsets m of the finest frequency, optionally capped:
    summed per block for every offset (:meth:`block_sums`), or per pixel at one offset each
    (:meth:`at`). The (K_f, n) array of all of them is never kept: 34 MB on the benchmark's stack,
    whose first touch alone (page faults of fresh memory) cost ~9 ms of the decision's ~150.

    Both give the float32 values of the same element-wise operations (an add, a rint, a subtract,
    a square, a multiply, an add per term, then the cap), so a pixel's cost at m is the same number
    whichever way it is read."""

    def __init__(self, fine, cyc, var_c, per):
        self.f = f = int(np.argmax(per))
        self.Kf = int(round(per[f]))
        self.n = fine.size
        self.terms = []
        for i in range(per.size):
            if i == f:
                continue
            ratio = per[i] / per[f]
            # the phase each offset predicts, reduced to one cycle first (float32 keeps 1e-7 of a cycle)
            t0 = ratio * fine - cyc[i]
            self.terms.append((np.float32(ratio), (t0 - np.rint(t0)).astype(np.float32),
                               np.float32(1) / (var_c[i] + np.float32(ratio * ratio) * var_c[f])))

    def _costs(self, mks, j0, j1, out, t, r, cap):
        """Costs of pixels j0:j1 into ``out`` (t, r: scratch of its shape); ``mks`` per term its
        offsets times its frequency ratio, broadcast against the pixels' columns."""
        cols = (None, slice(j0, j1)) if out.ndim == 2 else slice(j0, j1)
        for first, mk, (_, frac, w) in zip((True,) + (False,) * len(mks), mks, self.terms):
            np.add(mk, frac[cols], out=t)
            t -= np.rint(t, out=r)
            t *= t
            if first:
                np.multiply(t, w[cols], out=out)
            else:
                t *= w[cols]
                out += t
        if cap < np.inf:
            np.minimum(out, np.float32(cap), out=out)
        return out

    def at(self, m, cap=np.inf):
        """(n,) float32: pixel q's cost at offset ``m[q]``, capped at ``cap``."""
        if not self.terms:
            return np.zeros(self.n, np.float32)
        mf = np.asarray(m).astype(np.float32)
        out, t, r = (np.empty(self.n, np.float32) for _ in range(3))
        return self._costs([ratio * mf for ratio, _, _ in self.terms], 0, self.n, out, t, r, cap)

    def block_sums(self, starts, cap=np.inf, chunk: int = 2048):
        """(K_f, nb) float32: per block (pixels contiguous from ``starts``) and offset the sum of its
        pixels' capped costs, ``np.add.reduceat`` over the blocks of the whole (K_f, n) array,
        computed a few whole blocks (~``chunk`` pixels) at a time in reused buffers that stay in
        the cache: a block's sum reads only its own columns, in the same order, so the sums are
        the whole array's."""
        Kf, n = self.Kf, self.n
        nb = starts.size
        if not self.terms:
            return np.zeros((Kf, nb), np.float32)
        ends = np.r_[starts[1:], n]
        width = max(chunk, int((ends - starts).max()))
        bufs = [np.empty(Kf * width, np.float32) for _ in range(3)]
        m = np.arange(Kf, dtype=np.float32)[:, None]
        mks = [ratio * m for ratio, _, _ in self.terms]
        S = np.empty((Kf, nb), np.float32)
        b0 = 0
        while b0 < nb:
            b1 = max(b0 + 1, int(np.searchsorted(ends, starts[b0] + width, "right")))
            j0, j1 = int(starts[b0]), int(ends[b1 - 1])
            out, t, r = (buf[:Kf * (j1 - j0)].reshape(Kf, j1 - j0) for buf in bufs)
            self._costs(mks, j0, j1, out, t, r, cap)
            S[:, b0:b1] = np.add.reduceat(out, starts[b0:b1] - j0, axis=1)
            b0 = b1
        return S


def _block_posterior(costs, binv, max_wrong):
    """Per block (binv sorted: each block's pixels contiguous): summed capped costs S (K_f, nb; costs:
    an :class:`_OffsetCosts`), best offset, probability that it is wrong (posterior mass of the
    others, flat prior), size, and whether it decides (sure)."""
    starts = np.flatnonzero(np.r_[True, np.diff(binv) != 0])
    S = costs.block_sums(starts, ROBUST_CAP)
    nb = S.shape[1]
    best = np.argmin(S, 0)
    sb = S[best, np.arange(nb)]
    p = np.sum(np.exp(-0.5 * (S - sb[None, :])), 0) - 1.0
    p = p / (1.0 + p)
    size = np.bincount(binv, minlength=nb)
    return dict(S=S, sb=sb, best=best, p=p, size=size, sure=(p <= max_wrong) & (size >= MIN_BLOCK),
                starts=starts)


def _shifts_to_check(blk, max_wrong):
    """Offsets (relative to m*) worth a local look: those some sure block prefers m* to by less than
    8 x the local threshold, scaled to a window's share of the block; always +-1."""
    S, sb, best, size, sure = blk["S"], blk["sb"], blk["best"], blk["size"], blk["sure"]
    Kf, nb = S.shape
    gain = (S - sb[None, :]) * np.minimum(1.0, LOCAL * LOCAL / np.maximum(size, 1))[None, :]
    d = np.arange(Kf)[:, None]
    cols = np.flatnonzero(sure)
    # (K_f, sure blocks): the gain of each block's offset m* + d, all d at once
    near = np.any(gain[(best[None, cols] + d) % Kf, cols[None, :]] < 8 * 2.0 * np.log(1.0 / max_wrong), axis=1)
    near[0] = False
    near[[1, Kf - 1]] = True
    return np.flatnonzero(near)


def _agrees_with_sure(flat, x, x_sure, shape, tol):
    """False where a 4-neighbour decided on its own lies more than ``tol`` away from ``x`` (x_sure:
    an (H, W) map or a function of flat indices, pooled_orders' doc)."""
    H, W = shape
    read = x_sure if callable(x_sure) else x_sure.ravel().__getitem__
    r, c = np.divmod(flat, W)
    ok = np.ones(flat.size, bool)
    for dr, dc in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        rr, cc = r + dr, c + dc
        inside = (rr >= 0) & (rr < H) & (cc >= 0) & (cc < W)
        nb = np.full(flat.size, np.nan, np.float32)
        nb[inside] = read(rr[inside] * W + cc[inside])
        with np.errstate(invalid="ignore"):
            ok &= ~(np.abs(nb - x) > tol)
    return ok
