"""Step 1 of the decoder (:mod:`datapipe.sl.decode`), one row slab at a time: phases, NO_LIGHT /
SATURATED / INVALID_INPUT, fringe orders and the probability that they are wrong, depth; into the
image-sized :class:`DecodeMaps`."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .confidence import phase_var_from_snr, wrong_probability
from .decode_result import Reason
from .decode_setup import DecodeSetup
from .gamma import correct_cycles
from .phase import aligned_empty
from .orders import MAX_FINE_NOISE as POOL_FINE_NOISE
from .spatial import MAX_FINE_NOISE as SPATIAL_FINE_NOISE
from .unwrap import unwrap_cycles

__all__ = ["DecodeMaps", "decode_slab"]

# the step-2 candidates: precise enough a finest phase for the pooled decision or the neighbour pass
MAX_FINE_NOISE = max(POOL_FINE_NOISE, SPATIAL_FINE_NOISE)


@dataclass
class DecodeMaps:
    """The image-sized maps the steps fill: slab by slab (:func:`decode_slab`), then the neighbour pass."""
    depth: np.ndarray
    proj_x: np.ndarray
    phase: np.ndarray
    reason: np.ndarray        # causes other than BAD_ORDER until _assemble
    order_error: np.ndarray
    p_wrong: np.ndarray       # NaN where no order was decoded
    legacy_bad: np.ndarray    # legacy order rules (order_sigmas / max_order_error)
    inconsistent: np.ndarray
    filled: np.ndarray        # order taken from the neighbours (sl.spatial)
    modulation: np.ndarray
    offset: np.ndarray
    wrapped: list
    candidates: list = field(default_factory=list)   # per slab: flat indices of the pixels the neighbour pass
                                                      # may fill (above max_wrong, order decoded, fine phase precise)
    dim: list = field(default_factory=list)          # per slab: NO_LIGHT by the joint floor alone: the pooled
                                                      # decision (sl.orders) may find them lit, with their surface

    @classmethod
    def allocate(cls, H, W, F):
        f32 = np.float32
        return cls(depth=np.empty((H, W), f32), proj_x=np.empty((H, W), f32), phase=np.empty((H, W), f32),
                   reason=np.zeros((H, W), np.uint8), order_error=np.empty((H, W), f32),
                   p_wrong=np.empty((H, W), f32), legacy_bad=np.zeros((H, W), bool),
                   inconsistent=np.zeros((H, W), bool), filled=np.zeros((H, W), bool),
                   modulation=aligned_empty((F, H, W), f32), offset=np.empty((H, W), f32),
                   wrapped=[aligned_empty((H, W), f32) for _ in range(F)])


def _slab_var(st: DecodeSetup, a, r0, r1):
    """Per-pixel noise variance of the least-squares C and S rows, ``(sigma_I * row_sigma)^2``, of a
    slab from its raw offset ``a`` (None when the noise is one scalar)."""
    if st.var_fn is not None:
        return st.var_fn(a)
    if st.sigma_map is not None:
        s = st.sigma_map[r0:r1]
        return s * s * st.work.type(st.row_sigma ** 2)
    return None


@dataclass
class _SlabFlags:
    """What the frequencies of a slab say besides their phases (None: nothing flagged)."""
    nolight: np.ndarray | None = None     # contrast or explicit modulation floor
    saturated: np.ndarray | None = None
    invalid: np.ndarray | None = None
    lowsnr: np.ndarray | None = None      # the legacy worst-case order floor (order_sigmas)
    qsum: np.ndarray | None = None        # sum over the frequencies of B^2 / s^2 (joint Gamma test)

    def add(self, name, mask):
        if mask is not None:
            old = getattr(self, name)
            setattr(self, name, mask if old is None else np.logical_or(old, mask, out=old))


def _frequencies(st: DecodeSetup, out: DecodeMaps, r0: int, r1: int):
    """Per frequency of rows r0:r1: wrapped phase and modulation (into ``out``), the offset (summed
    into ``out.offset``), the phase in cycles and its noise variance (cycles^2), and the flags."""
    wt = st.work.type
    direct = st.work == np.float32
    inv2pi = wt(1.0 / (2 * np.pi))
    cycs, var_c, fl = [], [], _SlabFlags()
    off = out.offset[r0:r1]
    contrast_k = (1.0 / (st.min_contrast * st.kernel.a_scale)) if st.min_contrast else None
    for i in range(len(st.plan.periods)):
        fr = [st.frames[i * st.steps + n][r0:r1] for n in range(st.steps)]
        wout, mout = out.wrapped[i][r0:r1], out.modulation[i, r0:r1]
        phi, a, b, sflag, inv = st.kernel.compute(
            fr, st.work, st.sat, check_finite=st.is_float,
            out_phase=wout if direct else None, out_mod=mout if direct else None)
        if not direct:
            wout[...] = phi
            mout[...] = b
        c = np.multiply(phi, inv2pi)
        if st.gamma_lut is not None:
            c = correct_cycles(c, st.gamma_lut)
            np.multiply(c, wt(2 * np.pi), out=wout, casting="same_kind")
        cycs.append(c)
        if i == 0:
            np.copyto(off, a, casting="same_kind")
        else:
            np.add(off, a, out=off, casting="same_kind")
        fl.add("saturated", sflag)
        fl.add("invalid", inv)
        if i == 0:                       # noise of the slab (from the offset, alike in all frequencies)
            s2 = _slab_var(st, a, r0, r1)
            if s2 is None:
                s2 = wt((st.sigma_scalar * st.row_sigma) ** 2)
            elif st.order_factor and st.order_floor is None:
                sig = np.sqrt(s2) / wt(st.row_sigma)
        q = np.multiply(b, b)
        np.divide(q, s2, out=q)          # B^2 / s^2: Gamma evidence (floor) and phase SNR
        var_c.append(phase_var_from_snr(q))
        if st.min_modulation is not None:
            fl.add("nolight", np.less_equal(b, wt(st.min_modulation)))
        else:                            # joint Gamma test: accumulate B^2 / s^2
            fl.qsum = q.copy() if i == 0 else np.add(fl.qsum, q, out=fl.qsum)
        if st.order_factor:          # legacy worst-case order floor
            fl.add("lowsnr", np.less(b, wt(st.order_floor)) if st.order_floor is not None else
                   np.less(b, sig * wt(st.order_factor)))
        if contrast_k is not None:       # B < min_contrast * A
            fl.add("nolight", np.less(b * wt(contrast_k), a))
    return cycs, var_c, fl


def decode_slab(st: DecodeSetup, out: DecodeMaps, r0: int, r1: int, coefs):
    """Rows r0:r1: phases, NO_LIGHT / SATURATED / INVALID_INPUT, orders, p_wrong, depth."""
    wt = st.work.type
    F = len(st.plan.periods)
    direct = st.work == np.float32
    cycs, var_c, fl = _frequencies(st, out, r0, r1)
    nolight, satflag, invalid = fl.nolight, fl.saturated, fl.invalid
    dim = None
    if st.min_modulation is None:
        floor = np.less_equal(fl.qsum, wt(st.joint_q2))
        if st.spatial and st.plan.integer:   # dim but lit? the pooled decision (sl.orders) may tell
            dim = floor.copy()
            if nolight is not None:
                dim &= ~nolight
        nolight = floor if nolight is None else np.logical_or(nolight, floor, out=nolight)
    out.offset[r0:r1] *= np.float32(st.kernel.a_scale / F)
    un = unwrap_cycles(cycs, st.plan, st.wcoded)
    x = un.x if un.x.dtype == np.float32 else un.x.astype(np.float32)
    out.proj_x[r0:r1] = x
    out.order_error[r0:r1] = un.order_error
    out.phase[r0:r1] = un.phase
    p, inc = wrong_probability(un.margins, coefs, var_c, un.residuals, limits=st.consistency_limits,
                               out=out.p_wrong[r0:r1] if direct else None)
    if not direct:
        out.p_wrong[r0:r1] = p
    out.inconsistent[r0:r1] = inc
    fillable = np.less_equal(var_c[st.plan.finest], wt(MAX_FINE_NOISE ** 2))
    np.logical_and(np.greater(p, wt(st.max_wrong)), fillable, out=fillable)    # NaN p: False
    legacy = out.legacy_bad[r0:r1]
    if fl.lowsnr is not None:
        legacy |= fl.lowsnr
    if st.max_order_error is not None:
        legacy |= np.greater(un.order_error, st.max_order_error)
    z, ill, outside = st.tri.slab(x, r0, r1, max_depth_slope=st.max_depth_slope,
                                  check_other_axis=st.check_other_axis, out_depth=out.depth[r0:r1])
    rs = out.reason[r0:r1]
    for r, m in ((Reason.OUTSIDE_PROJECTOR, outside), (Reason.ILL_CONDITIONED, ill), (Reason.NO_LIGHT, nolight),
                 (Reason.SATURATED, satflag), (Reason.INVALID_INPUT, invalid)):
        if m is not None and m.any():
            rs[m] = r.value
    _candidates(st, out, r0, rs, fillable, inc, legacy, dim, (satflag, invalid))


def _candidates(st: DecodeSetup, out: DecodeMaps, r0, rs, fillable, inc, legacy, dim, unusable):
    """Pixels without a decoded order get no order verdict; the slab's candidates of step 2 (the
    uncertain, consistent ones with a precise finest phase) and its dim pixels go to ``out``."""
    basic = (rs == Reason.NO_LIGHT) | (rs == Reason.SATURATED) | (rs == Reason.INVALID_INPUT)
    r1 = r0 + rs.shape[0]
    if basic.any():                      # no order decoded: no order verdict either
        out.p_wrong[r0:r1][basic] = np.nan
        out.inconsistent[r0:r1][basic] = False
        legacy[basic] = False
        fillable &= ~basic
    if dim is not None:
        for m in unusable:
            if m is not None:
                dim &= ~m
        if dim.any():
            out.dim.append(np.flatnonzero(dim) + r0 * dim.shape[1])
    fillable &= ~inc                     # the neighbour pass's candidates (sl.spatial)
    if st.order_factor or st.max_order_error is not None:
        fillable &= ~legacy
    if fillable.any():
        out.candidates.append(np.flatnonzero(fillable) + r0 * fillable.shape[1])
