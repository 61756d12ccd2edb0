"""The structured-light decoder: fringe images -> projector coordinate -> depth, with a reason per pixel.

Pipeline (row slabs of ~64k pixels so every intermediate stays in cache; the stack is never
copied and never converted to float64 as a whole):

1. N-step least-squares phase, offset A and modulation B per frequency (:mod:`.phase`), with
   saturated samples excluded and non-finite samples flagged;
2. validity: modulation above a floor derived from the noise (Rayleigh law, below), contrast
   ``B/A`` above ``min_contrast``;
3. temporal unwrapping (:mod:`.unwrap`) with a K^2-weighted combination of all frequencies and a
   per-pixel order reliability;
4. closed-form triangulation (:mod:`.triangulate`, coefficients cached per geometry).

Every output pixel is finite and valid, or NaN with a :class:`Reason` code.

Modulation floor. For a pixel that sees no fringe (B = 0) the estimated modulation of N-step
least squares follows a Rayleigh law with scale ``s = sigma_I * sqrt(2/N)`` (sl-notes), so
``P(B_hat > t) = exp(-t^2 / (2 s^2))``. With ``t = s * sqrt(-2 ln p)`` a pure-noise pixel passes
one frequency's test with probability ``p = false_valid_rate`` and all F frequencies with
``p^F``. ``sigma_I`` is ``noise_sigma`` (a number in image units, an (H, W) array, or a callable
``sigma(signal)`` such as :meth:`datapipe.sl.sensor.SensorModel.noise_sigma`, evaluated at each
pixel's offset A); by default it is estimated from the least-squares residuals (N >= 4).

Order floor. Each rounding stage of the unwrapping amplifies the phase noise by a gain g
(:meth:`UnwrapPlan.noise_gain`, e.g. sqrt(r^2+1) for a hierarchical ratio r) and picks a wrong
order with probability ``erfc(pi / (sqrt(2) g sigma_phi))``, ``sigma_phi = s / B``. Pixels whose
modulation is below ``order_sigmas * g * s / pi`` in some frequency (default 5 sigmas: a wrong
order with probability < 1e-6 per stage) are BAD_ORDER, as are pixels whose order estimate lies
farther than ``max_order_error`` from an integer.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import Callable, Sequence

import numpy as np
import scipy.stats

from ._errors import bad_type, bad_value
from .patterns import _check_steps, phase_shifts
from .phase import PhaseKernel, check_image_dtype, work_dtype_for
from .triangulate import Triangulator
from .unwrap import plan_unwrap, unwrap_cycles

__all__ = ["Reason", "DecodeResult", "decode", "estimate_noise_sigma", "modulation_floor_factor"]


class Reason(IntEnum):
    """Why a pixel has no depth (uint8 in :attr:`DecodeResult.reason`). When several apply, the
    first of INVALID_INPUT, SATURATED, NO_LIGHT, BAD_ORDER, ILL_CONDITIONED, OUTSIDE_PROJECTOR
    is reported (the more basic cause first)."""
    VALID = 0
    NO_LIGHT = 1            # modulation below the noise floor, or contrast B/A too low
    SATURATED = 2           # fewer than 3 unsaturated samples in some frequency
    BAD_ORDER = 3           # order estimate too far from an integer, or too little SNR to round it
    OUTSIDE_PROJECTOR = 4   # behind the projector or outside its other image axis
    ILL_CONDITIONED = 5     # camera ray (nearly) in a projector column plane: |dZ/dx| over the cap
    INVALID_INPUT = 6       # NaN or inf in a sample
    FILTERED = 7            # removed by a post-filter outside the decoder (the pipeline's edge/speckle filter)


_PRIORITY = (Reason.OUTSIDE_PROJECTOR, Reason.ILL_CONDITIONED, Reason.BAD_ORDER,
             Reason.NO_LIGHT, Reason.SATURATED, Reason.INVALID_INPUT)   # later overrides earlier


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
        counts = np.bincount(self.reason.ravel(), minlength=len(Reason))
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


def estimate_noise_sigma(frames: Sequence[np.ndarray], steps: int, *, shifts=None, saturation=None,
                         max_pixels: int = 1 << 16) -> float:
    """Robust global estimate of the image noise sigma (image units) from the fit residuals.

    With N >= 4 the least-squares residual sum of squares of a pixel is ``sigma^2 * chi2(N-3)``
    (pooled over the F frequencies: ``chi2(F*(N-3))``); the median over a pixel subsample divided
    by the chi-square median gives sigma^2. Shadow pixels (read noise only) and bright pixels
    (shot noise) mix, so in shot-noise-limited images this is between the two: the floor is then
    conservative. With N = 3 there is no residual: integer images use quantisation (1/sqrt(12)
    DN), float images 0.1% of the bright (99th percentile) offset, i.e. a 10-bit-camera floor.
    Pass ``noise_sigma`` explicitly (e.g. ``SensorModel.noise_sigma``) when it is known.
    """
    steps = int(steps)
    f = len(frames) // steps
    h, w = frames[0].shape
    s = max(1, int(np.ceil(np.sqrt(h * w / max_pixels))))
    sub = [np.asarray(fr[::s, ::s], dtype=np.float64).ravel() for fr in frames]
    if shifts is None:
        shifts = phase_shifts(steps)
    kern = PhaseKernel(shifts)
    is_int = np.dtype(frames[0].dtype).kind in "iu"
    sat = saturation
    if sat is None and is_int:
        sat = float(np.iinfo(frames[0].dtype).max)
    good = np.ones(sub[0].size, bool)
    for x in sub:
        good &= np.isfinite(x)
        if sat is not None and np.isfinite(sat):
            good &= x < sat
    off = np.zeros(sub[0].size)
    rss = np.zeros(sub[0].size)
    for i in range(f):
        y = np.stack(sub[i * steps:(i + 1) * steps])
        y = np.where(np.isfinite(y), y, 0.0)
        acs = kern.coef @ y
        rss += np.sum((y - kern.design @ acs) ** 2, axis=0)
        off += acs[0] / f
    eps = np.finfo(work_dtype_for([fr.dtype for fr in frames])).eps
    bright = float(np.percentile(np.abs(off[good]), 99)) if good.any() else 0.0
    floor = 16 * eps * bright                       # arithmetic rounding of the fit itself
    if is_int:
        floor = max(floor, 1.0 / np.sqrt(12.0))
    dof = f * (steps - 3)
    if dof == 0 or not good.any():
        if not is_int:
            floor = max(floor, 1e-3 * bright)
        return float(floor) if floor > 0 else 1e-12
    med = float(np.median(rss[good] / dof))
    corr = scipy.stats.chi2.median(dof) / dof
    return float(max(np.sqrt(med / corr), floor, 1e-12))


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


def decode(images, *, periods, steps, P_cam, P_proj, proj_size, unwrap: str = "auto",
           noise_sigma: float | np.ndarray | Callable | None = None, saturation: float | None = None,
           min_modulation: float | None = None, min_contrast: float = 0.05,
           false_valid_rate: float = 1e-3, max_order_error: float = 0.25, order_sigmas: float = 5.0,
           max_depth_slope: float | None = None, shifts=None, axis: str = "x",
           check_other_axis: bool = True, triangulator: Triangulator | None = None,
           slab_pixels: int = 1 << 16) -> DecodeResult:
    """Decode phase-shifted fringe images into depth (see the module doc).

    images: ``(F*N, H, W)`` frequency-major, ``(F, N, H, W)``, or a list of F*N ``(H, W)``
        arrays; uint8/uint16/int/float16/32/64 (linear intensities, e.g. from ``sl.sensor``).
    periods: fringe frequencies K (periods across the projector), in stack order.
    steps: phase steps N per frequency (>= 3). shifts: optional N shifts (radians) instead of
        the uniform ``2*pi*n/N``.
    P_cam, P_proj: 3x4 world -> pixel matrices (``K @ inv(T_world_cam)[:3]``); depth and points
        are in the camera frame of P_cam. proj_size: projector (width, height) in pixels.
    unwrap: 'auto' | 'heterodyne' | 'multi-frequency' (see :mod:`datapipe.sl.unwrap`).
    noise_sigma: image noise (number, (H, W) array, or callable of the signal); None = estimate.
    saturation: samples >= this are excluded (default: integer type max; none for floats).
    min_modulation: explicit modulation floor (image units), replaces the noise-derived floor.
    min_contrast: pixels with ``B < min_contrast * A`` are NO_LIGHT (washed-out fringes).
    false_valid_rate: per-frequency probability that a pure-noise pixel passes the floor.
    max_order_error: orders whose estimate is farther than this from an integer are BAD_ORDER.
    order_sigmas: noise margin required for rounding orders (see the module doc; 0 disables).
    max_depth_slope: cap on ``|dZ/dx|`` in metres per projector pixel (default: ``Z`` per pixel,
        i.e. relative 1.0); pixels above it are ILL_CONDITIONED.
    axis: 'x' when the fringes code projector columns, 'y' for rows.
    check_other_axis: flag points that fall outside the projector's other image axis.
    triangulator: reuse a :class:`Triangulator` (default: a cached one per geometry).
    """
    steps = _check_steps(steps)
    plan = plan_unwrap(periods, unwrap)
    per = plan.periods
    F = len(per)
    frames = _frames(images, F * steps, per, steps)
    H, W = frames[0].shape
    if shifts is not None:
        shifts = np.asarray(shifts, dtype=np.float64).ravel()
        if shifts.size != steps:
            raise bad_value("shifts", f"has {shifts.size} entries for steps={steps}", "give one shift per step")
    else:
        shifts = phase_shifts(steps)
    kernel = PhaseKernel(shifts)
    if axis not in ("x", "y"):
        raise bad_value("axis", f"must be 'x' or 'y', got {axis!r}", "'x' when fringes code projector columns")
    if triangulator is None:
        tri = Triangulator.cached(P_cam, P_proj, (W, H), proj_size, axis=axis)
    else:
        tri = triangulator
        if tri.cam_size != (W, H):
            raise bad_value("triangulator", f"was built for cam_size {tri.cam_size}, images are {(W, H)}",
                            "build the Triangulator with the images' (width, height)")
        if tri.axis != axis:
            raise bad_value("triangulator", f"codes axis {tri.axis!r}, decode was asked for {axis!r}",
                            "build it with the same axis")
    wcoded = tri.proj_size[0] if axis == "x" else tri.proj_size[1]

    in_dtype = frames[0].dtype
    is_float = any(f.dtype.kind == "f" for f in frames)
    work = work_dtype_for([f.dtype for f in frames])
    if saturation is None:
        sat = float(np.iinfo(in_dtype).max) if in_dtype.kind in "iu" else None
    else:
        sat = float(saturation)
        if np.isnan(sat):
            raise bad_value("saturation", "is NaN", "pass the saturation level in image units or None")
        if np.isinf(sat):
            sat = None
    min_contrast = _check_positive("min_contrast", min_contrast, strict=False)
    false_valid_rate = _check_positive("false_valid_rate", false_valid_rate, upper=0.5)
    max_order_error = _check_positive("max_order_error", max_order_error, upper=0.5)
    max_depth_slope = _check_positive("max_depth_slope", max_depth_slope)
    min_modulation = _check_positive("min_modulation", min_modulation, strict=False)
    order_sigmas = _check_positive("order_sigmas", order_sigmas, strict=False)

    # -- modulation floor -----------------------------------------------------------------
    factor = modulation_floor_factor(false_valid_rate=false_valid_rate, shifts=shifts)
    sigma_scalar = None
    sigma_map = None
    sigma_fn = None
    if min_modulation is not None and noise_sigma is None:
        floor_scalar = min_modulation
    else:
        if noise_sigma is None:
            sigma_scalar = estimate_noise_sigma(frames, steps, shifts=shifts, saturation=sat)
        elif callable(noise_sigma):
            sigma_fn = noise_sigma
        elif np.ndim(noise_sigma) == 0:
            sigma_scalar = _check_positive("noise_sigma", noise_sigma, strict=False)
        else:
            sigma_map = np.asarray(noise_sigma, dtype=np.float32)
            if sigma_map.shape != (H, W):
                raise bad_value("noise_sigma", f"has shape {sigma_map.shape}, images are {(H, W)}",
                                "pass a scalar, an (H, W) array or a callable sigma(signal)")
            if not np.all(np.isfinite(sigma_map)) or np.any(sigma_map < 0):
                raise bad_value("noise_sigma", "has negative or non-finite entries", "pass sigmas >= 0")
        floor_scalar = None if sigma_scalar is None else sigma_scalar * factor
        if min_modulation is not None:
            floor_scalar = min_modulation
    # modulation needed to round the fringe orders reliably (per unit of noise sigma)
    order_factor = 0.0
    if order_sigmas:
        order_factor = plan.noise_gain() * _row_sigma(shifts=shifts) * order_sigmas / np.pi
    order_floor = None
    if order_factor and sigma_scalar is not None:
        order_floor = sigma_scalar * order_factor

    # -- outputs ----------------------------------------------------------------------------
    f32 = np.float32
    depth = np.empty((H, W), f32)
    proj_x = np.empty((H, W), f32)
    phase = np.empty((H, W), f32)
    reason = np.empty((H, W), np.uint8)
    order_error = np.empty((H, W), f32)
    modulation = np.empty((F, H, W), f32)
    offset = np.empty((H, W), f32)
    wrapped = [np.empty((H, W), f32) for _ in range(F)]
    nan = f32(np.nan)

    rows = max(1, int(slab_pixels) // W)
    valid = np.empty((H, W), bool)
    tri.coefficients  # compute (or reuse) the per-pixel coefficients before the loop
    a_scale = kernel.a_scale
    contrast_k = (1.0 / (min_contrast * a_scale)) if min_contrast else None
    direct = work == np.float32
    inv2pi = work.type(1.0 / (2 * np.pi))
    with np.errstate(all="ignore"):
        for r0 in range(0, H, rows):
            r1 = min(H, r0 + rows)
            cycs = []
            nolight = satflag = invalid = lowsnr = None
            off = offset[r0:r1]
            for i in range(F):
                fr = [frames[i * steps + n][r0:r1] for n in range(steps)]
                wout, mout = wrapped[i][r0:r1], modulation[i, r0:r1]
                phi, a, b, sflag, inv = kernel.compute(
                    fr, work, sat, check_finite=is_float,
                    out_phase=wout if direct else None, out_mod=mout if direct else None)
                if not direct:
                    wout[...] = phi
                    mout[...] = b
                cycs.append(np.multiply(phi, inv2pi))
                if i == 0:
                    np.copyto(off, a, casting="same_kind")
                else:
                    np.add(off, a, out=off, casting="same_kind")
                if sflag is not None:
                    satflag = sflag if satflag is None else (satflag | sflag)
                if inv is not None:
                    invalid = inv if invalid is None else (invalid | inv)
                # noise floor (Rayleigh) and order floor, see the module doc
                ob = None
                sig = None
                if sigma_fn is not None:
                    sig = np.asarray(sigma_fn(np.maximum(a * work.type(a_scale), 0)), dtype=work)
                elif sigma_map is not None:
                    sig = sigma_map[r0:r1]
                if floor_scalar is not None:
                    nl = np.less_equal(b, work.type(floor_scalar))
                else:
                    nl = np.less_equal(b, sig * work.type(factor))
                if order_floor is not None:
                    ob = np.less(b, work.type(order_floor))
                elif sig is not None and order_factor:
                    ob = np.less(b, sig * work.type(order_factor))
                if ob is not None:
                    lowsnr = ob if lowsnr is None else np.logical_or(lowsnr, ob, out=lowsnr)
                if contrast_k is not None:       # B < min_contrast * A
                    nl |= np.less(b * work.type(contrast_k), a)
                nolight = nl if nolight is None else np.logical_or(nolight, nl, out=nolight)
            off *= f32(a_scale / F)
            un = unwrap_cycles(cycs, plan, wcoded)
            x = un.x if un.x.dtype == f32 else un.x.astype(f32)
            proj_x[r0:r1] = x
            order_error[r0:r1] = un.order_error
            phase[r0:r1] = un.phase
            z, ill, outside = tri.slab(x, r0, r1, max_depth_slope=max_depth_slope,
                                       check_other_axis=check_other_axis, out_depth=depth[r0:r1])
            rs = reason[r0:r1]
            rs.fill(0)
            badorder = np.greater(un.order_error, max_order_error)
            if lowsnr is not None:
                badorder |= lowsnr
            masks = (outside, ill, badorder, nolight, satflag, invalid)
            for r, m in zip(_PRIORITY, masks):
                if m is not None and m.any():
                    rs[m] = r.value
            bad = np.not_equal(rs, 0)
            np.logical_not(bad, out=valid[r0:r1])
            if bad.any():
                np.copyto(depth[r0:r1], nan, where=bad)
                np.copyto(proj_x[r0:r1], nan, where=bad)
                np.copyto(phase[r0:r1], nan, where=bad)
    return DecodeResult(depth=depth, valid=valid, proj_x=proj_x, modulation=modulation,
                        offset=offset, wrapped=wrapped, phase=phase, reason=reason,
                        order_error=order_error, periods=per, steps=steps, method=plan.method,
                        noise_sigma=sigma_scalar, modulation_floor=floor_scalar,
                        extras={"order_floor": order_floor, "noise_gain": plan.noise_gain()},
                        triangulator=tri)
