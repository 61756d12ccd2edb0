"""The decoder's input checks and setup: everything decided before the first pixel is touched
(frames, phase kernel, triangulator, saturation, noise sigma and the modulation floor of
:mod:`datapipe.sl.decode`'s module doc), gathered in a :class:`DecodeSetup`, from the images and
the named, typed :class:`DecodeOptions`."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
from scipy.special import gammainccinv

from ._errors import bad_type, bad_value
from .confidence import consistency_limits
from .decode_result import Reason
from .gamma import gamma_phase_lut
from .noise import fit_noise_model, variance_function
from .patterns import _check_steps, phase_shifts
from .phase import PhaseKernel, check_image_dtype, work_dtype_for
from .response import linearise
from .triangulate import Triangulator, _size
from .unwrap import as_plan

__all__ = ["DecodeOptions", "DecodeSetup", "prepare_decode", "modulation_floor_factor", "check_geometry_fits"]

# Share of the pixels with a decided order that may land outside the projector's image (or, with the
# default slope cap, along its column planes) before the geometry is called wrong for the images, if
# they are also GEOMETRY_MISFIT_PIXELS of the image. Pixels that see the fringes are inside the
# projector's frustum: a right geometry puts 0.3-0.6% of them outside (noise, multipath: the demo's
# and the original rig's renders of bench_sl_truth; sl_materials' glossy parts: at most 1.5% of the
# part pixels); images upscaled 2x for their P_cam or a proj_size half or twice the calibration's
# put 49-88% of them outside, 49-88% of the image (synthetic plane, box and dark-step scenes).
GEOMETRY_MISFIT = 0.25
GEOMETRY_MISFIT_PIXELS = 0.05


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
    _check_some_finite(frames, periods, steps)
    return frames


FINITE_STRIDE = 16    # the non-finite check reads every 16th row and column (1/256 of the samples)


def _check_some_finite(frames, periods, steps):
    """A float image without one finite sample on a sparse grid is a broken capture (a failed
    conversion, an unlit EXR layer read as NaN), not a scene: name it instead of returning a map of
    INVALID_INPUT. Single NaN / inf samples stay a per-pixel INVALID_INPUT (a dead pixel)."""
    for i, f in enumerate(frames):
        if f.dtype.kind == "f" and not np.isfinite(f[::FINITE_STRIDE, ::FINITE_STRIDE]).any():
            raise bad_value("images", f"image {i} (period {periods[i // steps]:g}, step {i % steps}) has only "
                            "NaN or inf values", "pass finite intensities (check the conversion or the file "
                            "this image was read from)")


def _check_image_size(tri: Triangulator, W: int, H: int):
    """The camera matrix must be the images' own: its principal point (K's cx, cy) lies in the
    central 90% of the image for any real lens (a Blender lens shift of 0.45 of the sensor is the
    most it moves). Images resized or cropped after calibration (half size: cx at the right edge)
    or a P_cam of another camera would otherwise triangulate every pixel along a wrong ray."""
    cx, cy = float(tri.K_cam[0, 2]), float(tri.K_cam[1, 2])
    fx, fy = cx / W, cy / H
    if not (0.05 <= fx <= 0.95 and 0.05 <= fy <= 0.95):
        raise bad_value("P_cam", f"has its principal point at ({cx:.1f}, {cy:.1f}) px, {100 * fx:.0f}% / "
                        f"{100 * fy:.0f}% across the {W}x{H} images: it was made for images of another size",
                        "pass the camera matrix of the images' resolution (scale K's first two rows by the "
                        "resize factor, shift cx, cy by a crop) or the images P_cam was calibrated for")


ORDER_SAMPLES = 4096   # pixels sampled by the period-order check (a grid over the image)


def _check_period_order(frames, periods, steps: int, kernel: PhaseKernel):
    """The stack must hold the frequencies in the order of ``periods``: a finer fringe's phase changes
    faster from pixel to pixel (K times |du/dpixel|). On a grid of about ORDER_SAMPLES pixels with the
    upper half of every frequency's modulation, the median phase step to the next pixel (right and
    down, wrapped) of a period K_i >= 1.5 K_j must be at least sqrt(K_j / K_i) times K_j's: it is
    K_i / K_j times as large where the fringes dominate the noise, about as large where the noise
    does (noise only raises a step), and K_j / K_i times as large when the two are swapped. Periods
    listed in another order than the stack (e.g. (64, 8, 1) for a (1, 8, 64) stack: 27.5% valid, 64%
    of those > 5 mm off before this check) fail; a fringe finer than 2 camera pixels aliases and can
    fail it too. Sets of near periods (ratio < 1.5: (16, 15), (9, 10, 11)) are not checked."""
    per = [float(k) for k in periods]
    F = len(per)
    H, W = frames[0].shape
    if F < 2 or H < 2 or W < 2:
        return
    st = max(1, int(np.sqrt((H - 1) * (W - 1) / ORDER_SAMPLES)))
    h, w = (H - 2) // st + 1, (W - 2) // st + 1

    def phase_mod(i, dr, dc):
        fr = [np.asarray(frames[i * steps + n][dr::st, dc::st][:h, :w], dtype=np.float64) for n in range(steps)]
        c = sum(kernel.coef[1][n] * fr[n] for n in range(steps))
        s = sum(kernel.coef[2][n] * fr[n] for n in range(steps))
        return np.arctan2(s, c), np.hypot(c, s)

    step, good = [], np.ones((h, w), bool)
    with np.errstate(invalid="ignore"):
        for i in range(F):
            p0, b = phase_mod(i, 0, 0)
            d = [np.mod(phase_mod(i, dr, dc)[0] - p0 + np.pi, 2 * np.pi) - np.pi for dr, dc in ((0, 1), (1, 0))]
            step.append(np.hypot(*d))
            good &= np.isfinite(b) & (b >= np.nanmedian(b)) & np.isfinite(step[-1])
    if good.sum() < 50:
        return
    med = [float(np.median(g[good])) for g in step]
    for i in range(F):
        for j in range(F):
            if per[i] >= 1.5 * per[j] and med[i] < np.sqrt(per[j] / per[i]) * med[j]:
                listed = ", ".join(f"{k:g}" for k in per)
                raise bad_value("periods", f"({listed}) does not match the stack: the images given for period "
                                f"{per[i]:g} change phase by {med[i]:.3g} rad per pixel (median), those for period "
                                f"{per[j]:g} by {med[j]:.3g}, though a finer fringe changes faster",
                                "list periods in the order of the images (frequency-major stack), or project "
                                "fringes the camera resolves (>= 2 camera pixels per period)")


def _check_cam_size(cam_size, W: int, H: int):
    """The images must be the size the camera was calibrated at, when the caller says which: the
    principal-point test of :func:`_check_image_size` cannot see an upscaled image (2x: cx at 25%,
    every pixel on a wrong ray, measured on a plane: half the pixels valid, all > 5 mm off, median 0.7 m)."""
    if cam_size is None:
        return
    w, h = _size(cam_size, "cam_size")
    if (w, h) != (W, H):
        raise bad_value("images", f"are {W}x{H} pixels but cam_size (the size P_cam was calibrated at) is {w}x{h}",
                        "pass the images at the calibration's resolution, or P_cam and cam_size of the images' "
                        "resolution (scale K's first two rows by the resize factor, shift cx, cy by a crop)")


def check_geometry_fits(st: "DecodeSetup", reason: np.ndarray, valid: np.ndarray):
    """The one input check the pixels answer, after the decode: the geometry must put the decoded
    points inside the projector's image. Images of another size than P_cam's (when cam_size is not
    given and the principal point still looks central) or a proj_size of another projector mode
    triangulate about half the pixels outside it and the rest to wrong depths: an error, not that
    depth map."""
    if not (st.check_other_axis and st.stack_checks):
        return
    off = int(np.count_nonzero(reason == Reason.OUTSIDE_PROJECTOR))
    if st.max_depth_slope is None:           # the default cap flags only near-grazing rays
        off += int(np.count_nonzero(reason == Reason.ILL_CONDITIONED))
    decided = off + int(np.count_nonzero(valid))
    if off > GEOMETRY_MISFIT * decided and off >= GEOMETRY_MISFIT_PIXELS * reason.size:
        raise bad_value("P_cam / P_proj / proj_size",
                        f"{off} of the {decided} pixels that see the fringes with a decided order "
                        f"({100 * off / decided:.0f}%) triangulate outside the projector's image or along its "
                        "column planes: this geometry does not fit these images",
                        "pass P_cam of the images' resolution (and cam_size), proj_size as (width, height) at the "
                        "resolution K_proj was calibrated at, and the axis the fringes code")


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
class DecodeSetup:
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
    response: dict | None = None          # the tone curve undone before decoding (.response), None: none
    stack_checks: bool = True             # DecodeOptions.stack_checks

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


def _noise_setup(st: DecodeSetup, noise_sigma, min_modulation, order_sigmas, shifts):
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


@dataclass(frozen=True)
class DecodeOptions:
    """:func:`datapipe.sl.decode.decode`'s arguments besides the images (their meaning: its doc),
    by name and type; :func:`prepare_decode` checks them."""
    periods: tuple
    steps: int
    P_cam: np.ndarray
    P_proj: np.ndarray
    proj_size: tuple
    unwrap: str = "auto"
    noise_sigma: float | np.ndarray | Callable | None = None
    saturation: float | None = None
    min_modulation: float | None = None
    min_contrast: float = 0.05
    false_valid_rate: float = 1e-3
    max_order_error: float | None = None
    order_sigmas: float | None = None
    max_wrong: float = 1e-3
    max_depth_slope: float | None = None
    shifts: np.ndarray | None = None
    axis: str = "x"
    check_other_axis: bool = True
    triangulator: Triangulator | None = None
    spatial: bool = True
    projector_gamma: float = 1.0
    response: object = None             # None, 'fit', a 1-D table or a callable (.response)
    cam_size: tuple | None = None       # (width, height) P_cam was calibrated at; None: not checked
    stack_checks: bool = True           # period order and geometry fit (guards for a user's captures)


def _saturation_level(saturation, in_dtype):
    """Samples >= this are excluded: the integer type's maximum by default, none for floats."""
    if saturation is None:
        return float(np.iinfo(in_dtype).max) if in_dtype.kind in "iu" else None
    sat = float(saturation)
    if np.isnan(sat):
        raise bad_value("saturation", "is NaN", "pass the saturation level in image units or None")
    return None if np.isinf(sat) else sat


def prepare_decode(images, o: DecodeOptions) -> DecodeSetup:
    """Check :func:`datapipe.sl.decode.decode`'s arguments (an error names the field, before any work)
    and decide everything its steps need."""
    steps = _check_steps(o.steps)
    plan = as_plan(o.periods, o.unwrap)   # a method name, or the plan made once per run
    frames = _frames(images, len(plan.periods) * steps, plan.periods, steps)
    H, W = frames[0].shape
    _check_cam_size(o.cam_size, W, H)
    if o.shifts is not None:
        shifts = np.asarray(o.shifts, dtype=np.float64).ravel()
        if shifts.size != steps:
            raise bad_value("shifts", f"has {shifts.size} entries for steps={steps}", "give one shift per step")
    else:
        shifts = phase_shifts(steps)
    kernel = PhaseKernel(shifts)
    if o.stack_checks:
        _check_period_order(frames, plan.periods, steps, kernel)
    tri = _check_triangulator(o.triangulator, o.P_cam, o.P_proj, W, H, o.proj_size, o.axis)
    sat = _saturation_level(o.saturation, frames[0].dtype)
    frames, sat, response_info = linearise(frames, o.response, steps, shifts, sat)
    gamma = _check_positive("projector_gamma", o.projector_gamma, allow_none=False, upper=10.0)
    false_valid_rate = _check_positive("false_valid_rate", o.false_valid_rate, upper=0.5)
    F = len(plan.periods)
    q2 = 2.0 * float(gammainccinv(F, false_valid_rate))
    st = DecodeSetup(plan=plan, frames=frames, steps=steps, kernel=kernel, tri=tri,
                     wcoded=tri.proj_size[0] if o.axis == "x" else tri.proj_size[1],
                     work=work_dtype_for([f.dtype for f in frames]),
                     is_float=any(f.dtype.kind == "f" for f in frames),
                     sat=sat, min_contrast=_check_positive("min_contrast", o.min_contrast, strict=False),
                     max_depth_slope=_check_positive("max_depth_slope", o.max_depth_slope),
                     check_other_axis=bool(o.check_other_axis),
                     max_wrong=_check_positive("max_wrong", o.max_wrong, allow_none=False, upper=1.0),
                     max_order_error=_check_positive("max_order_error", o.max_order_error, upper=0.5),
                     spatial=bool(o.spatial), gamma_lut=None if gamma == 1.0 else gamma_phase_lut(gamma, shifts),
                     factor=_row_sigma(shifts=shifts) * float(np.sqrt(q2 / F)),
                     row_sigma=_row_sigma(shifts=shifts), joint_q2=q2)
    st.response = response_info
    st.stack_checks = bool(o.stack_checks)
    st.consistency_limits = consistency_limits(F, plan.lattice.d_min if plan.lattice is not None else 1.0)
    min_modulation = _check_positive("min_modulation", o.min_modulation, strict=False)
    order_sigmas = _check_positive("order_sigmas", o.order_sigmas, strict=False)
    if o.noise_sigma is not None:                    # the given noise's checks before the geometry's
        _noise_setup(st, o.noise_sigma, min_modulation, order_sigmas, shifts)
    _check_image_size(tri, W, H)
    if o.noise_sigma is None:                        # the fit: the first work on the pixels
        _noise_setup(st, o.noise_sigma, min_modulation, order_sigmas, shifts)
    return st
