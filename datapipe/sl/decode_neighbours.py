"""Step 2 of the decoder (:mod:`datapipe.sl.decode`): uncertain pixels take (or confirm) their fringe
order from confident neighbours on the same surface (:mod:`datapipe.sl.spatial`) and are
triangulated again."""
from __future__ import annotations

import numpy as np

from .confidence import phase_var_cycles
from .decode_result import Reason
from .decode_setup import DecodeSetup
from .decode_slab import DecodeMaps
from .orders import pooled_orders
from .spatial import _combine_from_fine, correct_orders

__all__ = ["neighbour_pass"]


def _any_supported(st: DecodeSetup, out: DecodeMaps, idx, chunk: int = 4096) -> bool:
    """Has some candidate two confident 8-neighbours (the least any prediction pair needs)? Read at
    the candidates' neighbours only, so scattered noise pixels in a shadow cost no full-image pass;
    in chunks, so that a large uncertain region answers after its first few thousand pixels."""
    return any(_chunk_supported(st, out, idx[i:i + chunk]) for i in range(0, idx.size, chunk))


def _chunk_supported(st: DecodeSetup, out: DecodeMaps, idx) -> bool:
    H, W = st.shape
    r, c = np.divmod(idx, W)
    n = np.zeros(idx.size, np.int8)
    thr = np.float32(st.max_wrong)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            if dy or dx:
                q = np.clip(r + dy, 0, H - 1) * W + np.clip(c + dx, 0, W - 1)
                with np.errstate(invalid="ignore"):
                    ok = (out.p_wrong.ravel()[q] <= thr) & ~out.inconsistent.ravel()[q]
                if st.order_factor or st.max_order_error is not None:
                    ok &= ~out.legacy_bad.ravel()[q]
                n += ok & (q != idx)
    return bool(np.any(n >= 2))


def neighbour_pass(st: DecodeSetup, out: DecodeMaps):
    """Uncertain pixels take their order from the pooled evidence of their surface
    (:mod:`.orders`), then the rest take / confirm it from confident neighbours (:mod:`.spatial`);
    both are triangulated again."""
    if not out.candidates and not out.dim:
        return
    idx = np.concatenate(out.candidates + out.dim)
    n_cand = sum(c.size for c in out.candidates)
    dim = np.zeros(idx.size, bool)
    dim[n_cand:] = True
    srt = np.argsort(idx, kind="stable")
    idx, dim = idx[srt], dim[srt]
    F = len(st.plan.periods)
    if st.sigma_fn is not None:
        sig = np.asarray(st.sigma_fn(np.maximum(out.offset.ravel()[idx].astype(np.float64), 0)), np.float64)
    elif st.sigma_map is not None:
        sig = st.sigma_map.ravel()[idx].astype(np.float64)
    else:
        sig = np.full(idx.size, st.sigma_scalar)
    s = (sig * st.row_sigma).astype(np.float32)
    cyc = [out.wrapped[i].ravel()[idx] * np.float32(1 / (2 * np.pi)) for i in range(F)]
    if st.plan.integer:
        snr = [np.square(out.modulation[i].ravel()[idx] / np.maximum(s, np.float32(1e-30))) for i in range(F)]
        def x_sure(q):
            """Coordinates of the pixels q decided on their own, NaN for the others (read at the
            pooled pixels' neighbours only, not as a map)."""
            with np.errstate(invalid="ignore"):
                sure = (out.p_wrong.ravel()[q] <= np.float32(st.max_wrong)) & ~out.inconsistent.ravel()[q] \
                    & (out.reason.ravel()[q] == 0)
            return np.where(sure, out.proj_x.ravel()[q], np.float32(np.nan))

        ia, xf, pa, pos = pooled_orders(idx, cyc, snr, st.plan.periods, st.wcoded, st.shape, max_wrong=st.max_wrong,
                                        dim=dim, x_sure=x_sure)
        if ia.size:
            xa = _combine_from_fine(xf.astype(np.float64), [c[pos].astype(np.float64) for c in cyc],
                                    np.asarray(st.plan.periods, float), float(st.wcoded),
                                    _kept_weights(st.plan.periods)).astype(np.float32)
            _apply(st, out, ia, xa, pa)
            dim[pos] = True                  # decided: not for the neighbour pass
    rest = ~dim
    idx, cyc, s = idx[rest], [c[rest] for c in cyc], s[rest]
    if idx.size == 0 or not _any_supported(st, out, idx):
        return
    var_c = [phase_var_cycles(out.modulation[i].ravel()[idx], s) for i in range(F)]   # per pixel: at those left
    # p_wrong is NaN where no order was decoded (NO_LIGHT, SATURATED, INVALID_INPUT): not good
    with np.errstate(invalid="ignore"):
        good = out.p_wrong <= np.float32(st.max_wrong)
    good &= ~out.inconsistent
    if st.order_factor or st.max_order_error is not None:
        good &= ~out.legacy_bad
    if not good.any():
        return
    ia, xa, pa = correct_orders(out.proj_x, good, idx, cyc, var_c, st.plan.periods, st.wcoded,
                                max_wrong=st.max_wrong)
    if ia.size:
        _apply(st, out, ia, xa, pa)


def _kept_weights(periods):
    w = np.asarray(periods, float) ** 2
    return w >= 0.01 * w.sum()


def _apply(st: DecodeSetup, out: DecodeMaps, ia, xa, pa):
    """Write the new coordinates of pixels ia, mark them filled, triangulate them again (at those
    pixels only: :meth:`.Triangulator.at`, the same values as their rows' evaluation)."""
    out.proj_x.ravel()[ia] = xa
    out.p_wrong.ravel()[ia] = pa
    out.filled.ravel()[ia] = True
    out.phase.ravel()[ia] = xa * (2 * np.pi * max(st.plan.periods) / st.wcoded)
    z, ill, outside = st.tri.at(out.proj_x.ravel()[ia], ia, max_depth_slope=st.max_depth_slope,
                                check_other_axis=st.check_other_axis)
    out.depth.ravel()[ia] = z
    out.reason.ravel()[ia] = np.where(outside, np.uint8(Reason.OUTSIDE_PROJECTOR),
                                      np.where(ill, np.uint8(Reason.ILL_CONDITIONED), np.uint8(0)))
