"""The structured-light decoder: fringe images -> projector coordinate -> depth, with a reason per pixel.

Pipeline (row slabs of ~64k pixels so every intermediate stays in cache; the stack is never
copied and never converted to float64 as a whole), one named step each:

1. :func:`_decode_slab`: N-step least-squares phase, offset A and modulation B per frequency
   (:mod:`.phase`), saturated samples excluded, non-finite samples flagged; optional projector
   gamma correction (:mod:`.gamma`); NO_LIGHT: modulation below a floor derived from the noise
   (Rayleigh law, below), contrast ``B/A`` below ``min_contrast``; temporal unwrapping
   (:mod:`.unwrap`, K^2-weighted combination of all frequencies); the probability that the orders
   are wrong from the agreement of all frequencies and the noise the sensor predicts
   (:mod:`.confidence`); closed-form triangulation (:mod:`.triangulate`);
2. :func:`_neighbour_pass`: uncertain pixels take (or confirm) their order from the coordinate
   their confident neighbours on the same surface predict (:mod:`.spatial`), and are triangulated
   again; they come out VALID with reason NEIGHBOUR_ORDER and their confidence lowered by
   ``NEIGHBOUR_RISK``;
3. :func:`_assemble`: reasons by priority, NaN fill.

Every output pixel is finite and valid, or NaN with a :class:`Reason` code.

Modulation floor. For a pixel that sees no fringe (B = 0) the estimated modulation of N-step
least squares follows a Rayleigh law with scale ``s = sigma_I * sqrt(2/N)`` (docs/STRUCTURED_LIGHT.md), so
``B_hat^2 / (2 s^2)`` is exponential with mean 1 and the sum over the F frequencies,
``Q = sum_i B_hat_i^2 / (2 s_i^2)``, is Gamma(F, 1). A pixel is NO_LIGHT when ``Q`` is below the
Gamma quantile that a pure-noise pixel exceeds with probability ``p = false_valid_rate``: all
frequencies' evidence counts together (one frequency alone: ``B_hat <= s sqrt(-2 ln p)``), and a
pure-noise pixel that passes still has to pass the order decision, where its frequencies disagree.
``sigma_I`` is ``noise_sigma`` (a number in image units, an (H, W) array, or a callable
``sigma(signal)`` such as :meth:`datapipe.sl.sensor.SensorModel.noise_sigma`, evaluated at each
pixel's offset A); by default :mod:`.noise` fits ``sigma^2(A)`` (read + shot noise) to the stack's own
fit residuals and offsets and evaluates it per pixel (``extras["noise_model"]`` says which noise was
used). An explicit ``min_modulation`` replaces the test by ``B_hat <= min_modulation`` in any frequency.

Order decision. A pixel is BAD_ORDER when the probability that some order is wrong
(:attr:`DecodeResult.confidence` is one minus it) exceeds ``max_wrong`` (default 1e-3) after the
neighbour pass. The former worst-case rules stay available: ``order_sigmas`` (refuse pixels whose
modulation is below ``order_sigmas * g * s / pi`` in some frequency, g the largest stage gain)
and ``max_order_error`` (refuse order estimates farther than that from an integer); both are off
by default because they threw away a fifth of the correctly decoded pixels (issue #10).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import Callable, Sequence

import numpy as np
from scipy.special import gammainccinv

from ._errors import bad_type, bad_value
from .patterns import _check_steps, phase_shifts
from .phase import PhaseKernel, check_image_dtype, work_dtype_for
from .confidence import consistency_limits, phase_var_cycles, phase_var_from_snr, wrong_probability
from .gamma import correct_cycles, gamma_phase_lut
from .noise import estimate_noise_sigma, fit_noise_model, variance_function
from .spatial import MAX_FINE_NOISE, correct_orders
from .triangulate import Triangulator
from .unwrap import plan_unwrap, unwrap_cycles

__all__ = ["Reason", "VALID_REASONS", "NEIGHBOUR_RISK", "DecodeResult", "decode", "estimate_noise_sigma", "modulation_floor_factor"]


class Reason(IntEnum):
    """Why a pixel has no depth (uint8 in :attr:`DecodeResult.reason`), or how a valid one got it
    (VALID: its own frequencies; NEIGHBOUR_ORDER: its order from its neighbours). When several
    apply, the first of INVALID_INPUT, SATURATED, NO_LIGHT, INCONSISTENT, BAD_ORDER, ILL_CONDITIONED,
    OUTSIDE_PROJECTOR is reported (the more basic cause first)."""
    VALID = 0
    NO_LIGHT = 1            # modulation below the noise floor, or contrast B/A too low
    SATURATED = 2           # fewer than 3 unsaturated samples in some frequency
    BAD_ORDER = 3           # probability of a wrong fringe order above max_wrong, even with the neighbours' help
    OUTSIDE_PROJECTOR = 4   # behind the projector or outside its other image axis
    ILL_CONDITIONED = 5     # camera ray (nearly) in a projector column plane: |dZ/dx| over the cap
    INVALID_INPUT = 6       # NaN or inf in a sample
    FILTERED = 7            # removed by a post-filter outside the decoder (the pipeline's edge/speckle filter)
    MULTIPATH = 8           # removed by the reflection/multipath filter (sl.filters.multipath_filter)
    INCONSISTENT = 9        # the frequencies disagree by more than the noise allows (aliasing, mixed pixel,
                            # inter-reflection, tone curve): see datapipe.sl.confidence
    REFLECTION = 10         # removed by the global reflection filter: the row-coded patterns say the light
                            # left the projector from another row than the decoded point's (a mirror ghost,
                            # sl.filters.reflection_filter)
    NEIGHBOUR_ORDER = 11    # VALID, but the fringe order came from confident neighbours on the same surface
                            # (sl.spatial), not from the pixel's own frequencies alone; its confidence is
                            # lowered by NEIGHBOUR_RISK


VALID_REASONS = (Reason.VALID, Reason.NEIGHBOUR_ORDER)   # reason codes of pixels with depth
NEIGHBOUR_RISK = 1e-3   # subtracted from a neighbour-filled pixel's confidence: the chance that the surface
                        # does not continue through it despite the same-surface tests (sl.spatial); on the
                        # adversarial scenes of tests/sl/test_sl_trust.py the measured share is below it


_NO_ORDER = (Reason.NO_LIGHT, Reason.SATURATED, Reason.INVALID_INPUT)   # no order decoded at all


@dataclass
class DecodeResult:
    """Decoded maps, all (H, W) unless noted. NaN marks invalid pixels in depth/points/proj_x/phase."""
    depth: np.ndarray                 # float32, metres along the camera z axis
    valid: np.ndarray                 # bool
    proj_x: np.ndarray                # float32 projector coordinate (column for axis='x'), pixels
    modulation: np.ndarray            # (F, H, W) float32, per frequency, image units
    offset: np.ndarray                # float32, mean offset A over the frequencies, image units
    wrapped: list                     # F arrays (H, W) float32 in [0, 2*pi)
    phase: np.ndarray                 # float32 absolute phase of the finest frequency
    reason: np.ndarray                # uint8, see Reason
    order_error: np.ndarray           # float32 in [0, 0.5]: distance of the order estimate from an integer
    confidence: np.ndarray | None = None  # float32: probability that the fringe orders are right (0 where
                                          # no order was decoded: NO_LIGHT, SATURATED, INVALID_INPUT;
                                          # NEIGHBOUR_ORDER pixels: lowered by NEIGHBOUR_RISK)
    periods: tuple = ()
    steps: int = 0
    method: str = ""
    noise_sigma: float | None = None  # scalar noise sigma used for the floor (None if per-pixel)
    modulation_floor: float | None = None   # scalar floor used (None if per-pixel)
    extras: dict = field(default_factory=dict)
    triangulator: Triangulator | None = field(default=None, repr=False)
    _points: np.ndarray | None = field(default=None, init=False, repr=False)

    @property
    def points(self) -> np.ndarray:
        """(H, W, 3) float32 camera-frame points (OpenCV), metres, NaN where invalid. Computed
        from ``depth`` and the camera rays on first access (saves 12 bytes per pixel otherwise)."""
        if self._points is None:
            self._points = self.triangulator.points(self.depth)
        return self._points

    def reason_counts(self) -> dict[str, int]:
        counts = np.bincount(self.reason.ravel(), minlength=max(Reason) + 1)
        return {r.name: int(counts[r.value]) for r in Reason}


def modulation_floor_factor(steps: int | np.ndarray = None, false_valid_rate: float = 1e-3, *,
                            shifts=None) -> float:
    """Floor / sigma_I: ``sqrt(2/N) * sqrt(-2 ln p)`` for uniform shifts (generic shifts: the mean
    variance of the least-squares C and S rows replaces 2/N)."""
    return _row_sigma(steps, shifts) * float(np.sqrt(-2.0 * np.log(false_valid_rate)))


def _row_sigma(steps=None, shifts=None) -> float:
    """Noise of the least-squares C and S estimates per unit image noise: sqrt(2/N) if uniform."""
    if shifts is None:
        shifts = phase_shifts(int(steps))
    coef = PhaseKernel(shifts).coef
    return float(np.sqrt(0.5 * (np.sum(coef[1] ** 2) + np.sum(coef[2] ** 2))))


def _frames(images, n_expected: int, periods, steps):
    """List of 2D frames (views, no copy) from (F*N,H,W), (F,N,H,W) or a sequence of 2D arrays."""
    if isinstance(images, np.ndarray):
        arr = images
        if arr.ndim == 4:
            if arr.shape[:2] != (len(periods), steps):
                raise bad_value("images", f"has shape {arr.shape}: (F, N) = {arr.shape[:2]} but "
                                f"periods/steps give ({len(periods)}, {steps})",
                                "pass (len(periods), steps, H, W) or (len(periods)*steps, H, W)")
            arr = arr.reshape((-1,) + arr.shape[2:])
        elif arr.ndim != 3:
            raise bad_value("images", f"has shape {arr.shape}; expected (F*N, H, W) or (F, N, H, W)",
                            "stack the fringe images frequency-major along the first axis")
        frames = list(arr)
    elif isinstance(images, (list, tuple)):
        frames = []
        for i, f in enumerate(images):
            if not isinstance(f, np.ndarray):
                raise bad_type("images", f"item {i} is a {type(f).__name__}, not a numpy array",
                               "pass a list of (H, W) numpy arrays or one stacked array")
            frames.append(f)
        if frames and frames[0].ndim != 2:
            raise bad_value("images", f"list items have shape {frames[0].shape}; expected (H, W)",
                            "pass single-channel images")
    else:
        raise bad_type("images", f"must be a numpy array or a list of arrays, got {type(images).__name__}",
                       "pass an (F*N, H, W) array")
    if len(frames) != n_expected:
        raise bad_value("images", f"has {len(frames)} images but periods={tuple(periods)} x steps={steps} "
                        f"needs {n_expected}",
                        "pass all N steps of every frequency, frequency-major, or fix periods/steps")
    shape = frames[0].shape
    for f in frames:
        check_image_dtype(f.dtype)
        if f.shape != shape:
            raise bad_value("images", f"mixes image shapes {shape} and {f.shape}", "pass equally sized images")
    if min(shape) < 1:
        raise bad_value("images", f"has empty images of shape {shape}", "pass non-empty images")
    return frames


def _check_positive(name, v, allow_none=True, upper=None, strict=True):
    if v is None and allow_none:
        return None
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise bad_type(name, f"must be a number, got {v!r}", "pass a float") from None
    if not np.isfinite(x) or (x <= 0 if strict else x < 0) or (upper is not None and x > upper):
        rng = f"in (0, {upper}]" if upper is not None else ("> 0" if strict else ">= 0")
        raise bad_value(name, f"must be a finite number {rng}, got {v!r}", f"pass a value {rng}")
    return x


@dataclass
class _Setup:
    """Everything decided before the first pixel is touched."""
    plan: object
    frames: list
    steps: int
    kernel: PhaseKernel
    tri: Triangulator
    wcoded: int
    work: np.dtype
    is_float: bool
    sat: float | None
    min_contrast: float
    max_depth_slope: float | None
    check_other_axis: bool
    max_wrong: float
    max_order_error: float | None
    spatial: bool
    gamma_lut: tuple | None
    factor: float
    row_sigma: float
    joint_q2: float             # 2 * Gamma(F) quantile of the joint modulation test (module doc)
    consistency_limits: tuple = ()
    min_modulation: float | None = None
    floor_scalar: float | None = None
    sigma_scalar: float | None = None
    sigma_map: np.ndarray | None = None
    sigma_fn: Callable | None = None
    var_fn: Callable | None = None        # raw slab offset -> (sigma_I * row_sigma)^2 (noise.variance_function)
    order_factor: float = 0.0
    order_floor: float | None = None
    noise_model: dict = field(default_factory=dict)

    @property
    def shape(self):
        return self.frames[0].shape


def _check_triangulator(triangulator, P_cam, P_proj, W, H, proj_size, axis):
    if axis not in ("x", "y"):
        raise bad_value("axis", f"must be 'x' or 'y', got {axis!r}", "'x' when fringes code projector columns")
    if triangulator is None:
        return Triangulator.cached(P_cam, P_proj, (W, H), proj_size, axis=axis)
    if triangulator.cam_size != (W, H):
        raise bad_value("triangulator", f"was built for cam_size {triangulator.cam_size}, images are {(W, H)}",
                        "build the Triangulator with the images' (width, height)")
    if triangulator.axis != axis:
        raise bad_value("triangulator", f"codes axis {triangulator.axis!r}, decode was asked for {axis!r}",
                        "build it with the same axis")
    return triangulator


def _noise_setup(st: _Setup, noise_sigma, min_modulation, order_sigmas, shifts):
    """Noise sigma (scalar / map / callable; None: fitted per pixel, :mod:`.noise`), modulation
    floor and the legacy order floor. ``st.noise_model`` says which."""
    H, W = st.shape
    st.min_modulation = min_modulation
    if noise_sigma is None:
        fit = fit_noise_model(st.frames, st.steps, shifts=shifts, saturation=st.sat)
        st.noise_model = dict(fit.describe(),
                              source="fitted per pixel from the stack: sigma^2 against the mean intensity A")
        if not fit.bin_a:
            st.sigma_scalar = float(np.sqrt(fit.read_var))
        else:
            st.sigma_fn = fit
    elif callable(noise_sigma):
        st.sigma_fn = noise_sigma
        st.noise_model = {"kind": "callable", "source": "given: noise_sigma(signal) per pixel"}
    elif np.ndim(noise_sigma) == 0:
        st.sigma_scalar = _check_positive("noise_sigma", noise_sigma, strict=False)
        st.noise_model = {"kind": "scalar", "source": "given: one sigma for every pixel"}
    else:
        sigma_map = np.asarray(noise_sigma, dtype=np.float32)
        if sigma_map.shape != (H, W):
            raise bad_value("noise_sigma", f"has shape {sigma_map.shape}, images are {(H, W)}",
                            "pass a scalar, an (H, W) array or a callable sigma(signal)")
        if not np.all(np.isfinite(sigma_map)) or np.any(sigma_map < 0):
            raise bad_value("noise_sigma", "has negative or non-finite entries", "pass sigmas >= 0")
        st.sigma_map = sigma_map
        st.noise_model = {"kind": "map", "source": "given: (H, W) sigma map"}
    st.floor_scalar = None if st.sigma_scalar is None else st.sigma_scalar * st.factor
    if min_modulation is not None:
        st.floor_scalar = min_modulation
    if st.sigma_fn is not None:
        st.var_fn = variance_function(st.sigma_fn, st.kernel.a_scale, st.row_sigma ** 2)
    if order_sigmas:
        st.order_factor = st.plan.noise_gain() * st.row_sigma * order_sigmas / np.pi
        if st.sigma_scalar is not None:
            st.order_floor = st.sigma_scalar * st.order_factor


def _setup(images, periods, steps, P_cam, P_proj, proj_size, unwrap, noise_sigma, saturation,
           min_modulation, min_contrast, false_valid_rate, max_order_error, order_sigmas, max_wrong,
           max_depth_slope, shifts, axis, check_other_axis, triangulator, spatial, projector_gamma) -> _Setup:
    steps = _check_steps(steps)
    plan = plan_unwrap(periods, unwrap)
    frames = _frames(images, len(plan.periods) * steps, plan.periods, steps)
    H, W = frames[0].shape
    if shifts is not None:
        shifts = np.asarray(shifts, dtype=np.float64).ravel()
        if shifts.size != steps:
            raise bad_value("shifts", f"has {shifts.size} entries for steps={steps}", "give one shift per step")
    else:
        shifts = phase_shifts(steps)
    kernel = PhaseKernel(shifts)
    tri = _check_triangulator(triangulator, P_cam, P_proj, W, H, proj_size, axis)
    in_dtype = frames[0].dtype
    if saturation is None:
        sat = float(np.iinfo(in_dtype).max) if in_dtype.kind in "iu" else None
    else:
        sat = float(saturation)
        if np.isnan(sat):
            raise bad_value("saturation", "is NaN", "pass the saturation level in image units or None")
        if np.isinf(sat):
            sat = None
    gamma = _check_positive("projector_gamma", projector_gamma, allow_none=False, upper=10.0)
    false_valid_rate = _check_positive("false_valid_rate", false_valid_rate, upper=0.5)
    F = len(plan.periods)
    q2 = 2.0 * float(gammainccinv(F, false_valid_rate))
    st = _Setup(plan=plan, frames=frames, steps=steps, kernel=kernel, tri=tri,
                wcoded=tri.proj_size[0] if axis == "x" else tri.proj_size[1],
                work=work_dtype_for([f.dtype for f in frames]), is_float=any(f.dtype.kind == "f" for f in frames),
                sat=sat, min_contrast=_check_positive("min_contrast", min_contrast, strict=False),
                max_depth_slope=_check_positive("max_depth_slope", max_depth_slope),
                check_other_axis=bool(check_other_axis),
                max_wrong=_check_positive("max_wrong", max_wrong, allow_none=False, upper=1.0),
                max_order_error=_check_positive("max_order_error", max_order_error, upper=0.5),
                spatial=bool(spatial), gamma_lut=None if gamma == 1.0 else gamma_phase_lut(gamma, shifts),
                factor=_row_sigma(shifts=shifts) * float(np.sqrt(q2 / F)),
                row_sigma=_row_sigma(shifts=shifts), joint_q2=q2)
    st.consistency_limits = consistency_limits(F, plan.lattice.d_min if plan.lattice is not None else 1.0)
    _noise_setup(st, noise_sigma, _check_positive("min_modulation", min_modulation, strict=False),
                 _check_positive("order_sigmas", order_sigmas, strict=False), shifts)
    return st


@dataclass
class _Out:
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

    @classmethod
    def allocate(cls, H, W, F):
        f32 = np.float32
        return cls(depth=np.empty((H, W), f32), proj_x=np.empty((H, W), f32), phase=np.empty((H, W), f32),
                   reason=np.zeros((H, W), np.uint8), order_error=np.empty((H, W), f32),
                   p_wrong=np.empty((H, W), f32), legacy_bad=np.zeros((H, W), bool),
                   inconsistent=np.zeros((H, W), bool), filled=np.zeros((H, W), bool),
                   modulation=np.empty((F, H, W), f32), offset=np.empty((H, W), f32),
                   wrapped=[np.empty((H, W), f32) for _ in range(F)])


def _slab_var(st: _Setup, a, r0, r1):
    """Per-pixel noise variance of the least-squares C and S rows, ``(sigma_I * row_sigma)^2``, of a
    slab from its raw offset ``a`` (None when the noise is one scalar)."""
    if st.var_fn is not None:
        return st.var_fn(a)
    if st.sigma_map is not None:
        s = st.sigma_map[r0:r1]
        return s * s * st.work.type(st.row_sigma ** 2)
    return None


def _decode_slab(st: _Setup, out: _Out, r0: int, r1: int, coefs):
    """Rows r0:r1: phases, NO_LIGHT / SATURATED / INVALID_INPUT, orders, p_wrong, depth."""
    wt = st.work.type
    F = len(st.plan.periods)
    direct = st.work == np.float32
    inv2pi = wt(1.0 / (2 * np.pi))
    cycs, var_c = [], []
    nolight = satflag = invalid = lowsnr = None
    off = out.offset[r0:r1]
    contrast_k = (1.0 / (st.min_contrast * st.kernel.a_scale)) if st.min_contrast else None
    for i in range(F):
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
        if sflag is not None:
            satflag = sflag if satflag is None else (satflag | sflag)
        if inv is not None:
            invalid = inv if invalid is None else (invalid | inv)
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
            nl = np.less_equal(b, wt(st.min_modulation))
        else:                            # joint Gamma test: accumulate B^2 / s^2
            nl = None
            qsum = q.copy() if i == 0 else np.add(qsum, q, out=qsum)
        if st.order_factor:          # legacy worst-case order floor
            ob = np.less(b, wt(st.order_floor)) if st.order_floor is not None else \
                np.less(b, sig * wt(st.order_factor))
            lowsnr = ob if lowsnr is None else np.logical_or(lowsnr, ob, out=lowsnr)
        if contrast_k is not None:       # B < min_contrast * A
            low = np.less(b * wt(contrast_k), a)
            nl = low if nl is None else (nl | low)
        if nl is not None:
            nolight = nl if nolight is None else np.logical_or(nolight, nl, out=nolight)
    if st.min_modulation is None:
        floor = np.less_equal(qsum, wt(st.joint_q2))
        nolight = floor if nolight is None else np.logical_or(nolight, floor, out=nolight)
    off *= np.float32(st.kernel.a_scale / F)
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
    if lowsnr is not None:
        legacy |= lowsnr
    if st.max_order_error is not None:
        legacy |= np.greater(un.order_error, st.max_order_error)
    z, ill, outside = st.tri.slab(x, r0, r1, max_depth_slope=st.max_depth_slope,
                                  check_other_axis=st.check_other_axis, out_depth=out.depth[r0:r1])
    rs = out.reason[r0:r1]
    for r, m in ((Reason.OUTSIDE_PROJECTOR, outside), (Reason.ILL_CONDITIONED, ill), (Reason.NO_LIGHT, nolight),
                 (Reason.SATURATED, satflag), (Reason.INVALID_INPUT, invalid)):
        if m is not None and m.any():
            rs[m] = r.value
    basic = (rs == Reason.NO_LIGHT) | (rs == Reason.SATURATED) | (rs == Reason.INVALID_INPUT)
    if basic.any():                      # no order decoded: no order verdict either
        out.p_wrong[r0:r1][basic] = np.nan
        out.inconsistent[r0:r1][basic] = False
        legacy[basic] = False
        fillable &= ~basic
    fillable &= ~inc                     # the neighbour pass's candidates (sl.spatial)
    if st.order_factor or st.max_order_error is not None:
        fillable &= ~legacy
    if fillable.any():
        out.candidates.append(np.flatnonzero(fillable) + r0 * fillable.shape[1])


def _any_supported(st: _Setup, out: _Out, idx) -> bool:
    """Has some candidate two confident 8-neighbours (the least any prediction pair needs)? Read at
    the candidates' neighbours only, so scattered noise pixels in a shadow cost no full-image pass."""
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


def _neighbour_pass(st: _Setup, out: _Out):
    """Uncertain pixels take / confirm their order from confident neighbours, then are
    triangulated again (see :mod:`.spatial`)."""
    if not out.candidates:
        return
    idx = np.concatenate(out.candidates)
    if not _any_supported(st, out, idx):
        return
    # p_wrong is NaN where no order was decoded (NO_LIGHT, SATURATED, INVALID_INPUT): not good
    with np.errstate(invalid="ignore"):
        good = out.p_wrong <= np.float32(st.max_wrong)
    good &= ~out.inconsistent
    if st.order_factor or st.max_order_error is not None:
        good &= ~out.legacy_bad
    if not good.any():
        return
    F = len(st.plan.periods)
    if st.sigma_fn is not None:
        sig = np.asarray(st.sigma_fn(np.maximum(out.offset.ravel()[idx].astype(np.float64), 0)), np.float64)
    elif st.sigma_map is not None:
        sig = st.sigma_map.ravel()[idx].astype(np.float64)
    else:
        sig = np.full(idx.size, st.sigma_scalar)
    s = sig * st.row_sigma
    cyc = [out.wrapped[i].ravel()[idx] * np.float32(1 / (2 * np.pi)) for i in range(F)]
    s = s.astype(np.float32)
    var_c = [phase_var_cycles(out.modulation[i].ravel()[idx], s) for i in range(F)]
    ia, xa, pa = correct_orders(out.proj_x, good, idx, cyc, var_c, st.plan.periods, st.wcoded,
                                max_wrong=st.max_wrong)
    if ia.size == 0:
        return
    out.proj_x.ravel()[ia] = xa
    out.p_wrong.ravel()[ia] = pa
    out.filled.ravel()[ia] = True
    out.phase.ravel()[ia] = xa * (2 * np.pi * max(st.plan.periods) / st.wcoded)
    H, W = st.shape
    rows = np.unique(ia // W)
    # re-triangulate the touched rows (contiguous runs), keep the result only for corrected pixels
    hit = np.zeros((H, W), bool)
    hit.ravel()[ia] = True
    starts = rows[np.r_[True, np.diff(rows) > 1]]
    ends = rows[np.r_[np.diff(rows) > 1, True]] + 1
    for r0, r1 in zip(starts, ends):
        z, ill, outside = st.tri.slab(out.proj_x[r0:r1], r0, r1, max_depth_slope=st.max_depth_slope,
                                      check_other_axis=st.check_other_axis)
        h = hit[r0:r1]
        out.depth[r0:r1][h] = z[h]
        rs = out.reason[r0:r1]
        rs[h] = 0
        rs[h & ill] = Reason.ILL_CONDITIONED
        rs[h & outside] = Reason.OUTSIDE_PROJECTOR


def _assemble(st: _Setup, out: _Out) -> DecodeResult:
    """BAD_ORDER where the orders stayed uncertain (it outranks OUTSIDE / ILL, computed from a
    possibly wrong coordinate), NaN fill, confidence."""
    reason = out.reason
    with np.errstate(invalid="ignore"):
        bad = np.greater(out.p_wrong, np.float32(st.max_wrong))      # NaN (no order) -> False
    bad |= out.legacy_bad
    reason[bad] = Reason.BAD_ORDER
    reason[out.inconsistent] = Reason.INCONSISTENT
    valid = reason == 0
    filled = np.logical_and(out.filled, valid, out=out.filled)
    reason[filled] = Reason.NEIGHBOUR_ORDER
    inv = ~valid
    nan = np.float32(np.nan)
    for a in (out.depth, out.proj_x, out.phase):
        np.copyto(a, nan, where=inv)
    conf = np.subtract(np.float32(1), out.p_wrong, out=out.p_wrong)   # in place: p_wrong is not returned
    np.nan_to_num(conf, copy=False, nan=0.0)
    if filled.any():
        conf[filled] = np.maximum(conf[filled] - np.float32(NEIGHBOUR_RISK), 0)
    plan = st.plan
    return DecodeResult(depth=out.depth, valid=valid, proj_x=out.proj_x, modulation=out.modulation,
                        offset=out.offset, wrapped=out.wrapped, phase=out.phase, reason=reason,
                        order_error=out.order_error, confidence=conf, periods=plan.periods, steps=st.steps,
                        method=plan.method, noise_sigma=st.sigma_scalar, modulation_floor=st.floor_scalar,
                        extras={"order_floor": st.order_floor, "noise_gain": plan.noise_gain(),
                                "max_wrong": st.max_wrong, "noise_model": st.noise_model},
                        triangulator=st.tri)


def decode(images, *, periods, steps, P_cam, P_proj, proj_size, unwrap: str = "auto",
           noise_sigma: float | np.ndarray | Callable | None = None, saturation: float | None = None,
           min_modulation: float | None = None, min_contrast: float = 0.05,
           false_valid_rate: float = 1e-3, max_order_error: float | None = None,
           order_sigmas: float | None = None, max_depth_slope: float | None = None, shifts=None,
           axis: str = "x", check_other_axis: bool = True, triangulator: Triangulator | None = None,
           slab_pixels: int = 1 << 16, max_wrong: float = 1e-3, spatial: bool = True,
           projector_gamma: float = 1.0) -> DecodeResult:
    """Decode phase-shifted fringe images into depth (see the module doc).

    images: ``(F*N, H, W)`` frequency-major, ``(F, N, H, W)``, or a list of F*N ``(H, W)``
        arrays; uint8/uint16/int/float16/32/64 (linear intensities, e.g. from ``sl.sensor``).
    periods: fringe frequencies K (periods across the projector), in stack order.
    steps: phase steps N per frequency (>= 3). shifts: optional N shifts (radians) instead of
        the uniform ``2*pi*n/N``.
    P_cam, P_proj: 3x4 world -> pixel matrices (``K @ inv(T_world_cam)[:3]``); depth and points
        are in the camera frame of P_cam. proj_size: projector (width, height) in pixels.
    unwrap: 'auto' | 'heterodyne' | 'multi-frequency' | 'number-theoretic' (:mod:`datapipe.sl.unwrap`).
    noise_sigma: image noise (number, (H, W) array, or callable of the signal); None = fitted per
        pixel from the stack (:func:`datapipe.sl.noise.fit_noise_model`).
    saturation: samples >= this are excluded (default: integer type max; none for floats).
    min_modulation: explicit modulation floor (image units), replaces the noise-derived floor.
    min_contrast: pixels with ``B < min_contrast * A`` are NO_LIGHT (washed-out fringes).
    false_valid_rate: probability that a pure-noise pixel passes the (joint) modulation floor.
    max_wrong: pixels whose orders are wrong with a probability above this are BAD_ORDER
        (:mod:`datapipe.sl.confidence`); ``spatial``: let confident neighbours decide / confirm the
        order of uncertain pixels first (:mod:`datapipe.sl.spatial`).
    max_order_error, order_sigmas: the former worst-case order rules (module doc), off by default.
    max_depth_slope: cap on ``|dZ/dx|`` in metres per projector pixel (default: ``Z`` per pixel,
        i.e. relative 1.0); pixels above it are ILL_CONDITIONED.
    axis: 'x' when the fringes code projector columns, 'y' for rows.
    check_other_axis: flag points that fall outside the projector's other image axis.
    triangulator: reuse a :class:`Triangulator` (default: a cached one per geometry).
    projector_gamma: the projector's response exponent (patterns ``a = b = 0.5`` emitted as
        ``p ** gamma``); != 1 corrects the phase ripple it causes (:mod:`datapipe.sl.gamma`).
    """
    st = _setup(images, periods, steps, P_cam, P_proj, proj_size, unwrap, noise_sigma, saturation,
                min_modulation, min_contrast, false_valid_rate, max_order_error, order_sigmas, max_wrong,
                max_depth_slope, shifts, axis, check_other_axis, triangulator, spatial, projector_gamma)
    H, W = st.shape
    out = _Out.allocate(H, W, len(st.plan.periods))
    st.tri.coefficients  # compute (or reuse) the per-pixel coefficients before the loop
    coefs = st.plan.stage_coefs()
    rows = max(1, int(slab_pixels) // W)
    with np.errstate(all="ignore"):
        for r0 in range(0, H, rows):
            _decode_slab(st, out, r0, min(H, r0 + rows), coefs)
        if st.spatial:
            _neighbour_pass(st, out)
    return _assemble(st, out)
