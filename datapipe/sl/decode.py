"""The structured-light decoder: fringe images -> projector coordinate -> depth, with a reason per pixel.

Pipeline (row slabs of ~64k pixels so every intermediate stays in cache; the stack is never
copied and never converted to float64 as a whole), after the input checks and setup
(:mod:`.decode_setup`), one named step each:

1. :func:`.decode_slab.decode_slab`: N-step least-squares phase, offset A and modulation B per
   frequency (:mod:`.phase`), saturated samples excluded, non-finite samples flagged; optional projector
   gamma correction (:mod:`.gamma`); NO_LIGHT: modulation below a floor derived from the noise
   (Rayleigh law, below), contrast ``B/A`` below ``min_contrast``; temporal unwrapping
   (:mod:`.unwrap`, K^2-weighted combination of all frequencies); the probability that the orders
   are wrong from the agreement of all frequencies and the noise the sensor predicts
   (:mod:`.confidence`); closed-form triangulation (:mod:`.triangulate`);
2. :func:`.decode_neighbours.neighbour_pass`: uncertain pixels take (or confirm) their order from the
   coordinate their confident neighbours on the same surface predict (:mod:`.spatial`), and are triangulated
   again; they come out VALID with reason NEIGHBOUR_ORDER and their confidence lowered by
   ``NEIGHBOUR_RISK``;
3. :func:`_assemble` (here): reasons by priority, NaN fill, the :class:`DecodeResult`
   (:mod:`.decode_result`).

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

from typing import Callable

import numpy as np

from .decode_neighbours import neighbour_pass
from .decode_result import NEIGHBOUR_RISK, VALID_REASONS, DecodeResult, Reason
from .decode_setup import DecodeOptions, DecodeSetup, check_geometry_fits, modulation_floor_factor, prepare_decode
from .decode_slab import DecodeMaps, decode_slab
from .noise import estimate_noise_sigma
from .triangulate import Triangulator
from .unwrap import UnwrapPlan

# the public names stay importable from here (`from datapipe.sl.decode import Reason`), as before the split
__all__ = ["Reason", "VALID_REASONS", "NEIGHBOUR_RISK", "DecodeResult", "decode", "estimate_noise_sigma",
           "modulation_floor_factor"]


def _assemble(st: DecodeSetup, out: DecodeMaps) -> DecodeResult:
    """BAD_ORDER where the orders stayed uncertain (it outranks OUTSIDE / ILL, computed from a
    possibly wrong coordinate), NaN fill, confidence."""
    reason = out.reason
    with np.errstate(invalid="ignore"):
        bad = np.greater(out.p_wrong, np.float32(st.max_wrong))      # NaN (no order) -> False
    if st.order_factor or st.max_order_error is not None:        # the legacy rules set it, nothing else
        bad |= out.legacy_bad
    reason[bad] = Reason.BAD_ORDER
    reason[out.inconsistent] = Reason.INCONSISTENT
    valid = reason == 0
    filled = np.logical_and(out.filled, valid, out=out.filled)
    reason[filled] = Reason.NEIGHBOUR_ORDER
    # NaN fill by adding 0 (valid) or NaN (not): three plain passes instead of three masked copies
    with np.errstate(invalid="ignore"):
        nan_or_0 = np.divide(np.float32(0), valid, dtype=np.float32)
    for a in (out.depth, out.proj_x, out.phase):
        a += nan_or_0
    conf = np.subtract(np.float32(1), out.p_wrong, out=out.p_wrong)   # in place: p_wrong is not returned
    np.fmax(conf, np.float32(0), out=conf)                             # NaN (no order) -> 0; conf >= 0
    if filled.any():
        conf[filled] = np.maximum(conf[filled] - np.float32(NEIGHBOUR_RISK), 0)
    plan = st.plan
    return DecodeResult(depth=out.depth, valid=valid, proj_x=out.proj_x, modulation=out.modulation,
                        offset=out.offset, wrapped=out.wrapped, phase=out.phase, reason=reason,
                        order_error=out.order_error, confidence=conf, periods=plan.periods, steps=st.steps,
                        method=plan.method, noise_sigma=st.sigma_scalar, modulation_floor=st.floor_scalar,
                        extras={"order_floor": st.order_floor, "noise_gain": plan.noise_gain(),
                                "max_wrong": st.max_wrong, "noise_model": st.noise_model,
                                **({"response": st.response} if st.response else {})},
                        triangulator=st.tri)


def decode(images, *, periods, steps, P_cam, P_proj, proj_size, unwrap: str | UnwrapPlan = "auto",
           noise_sigma: float | np.ndarray | Callable | None = None, saturation: float | None = None,
           min_modulation: float | None = None, min_contrast: float = 0.05,
           false_valid_rate: float = 1e-3, max_order_error: float | None = None,
           order_sigmas: float | None = None, max_depth_slope: float | None = None, shifts=None,
           axis: str = "x", check_other_axis: bool = True, triangulator: Triangulator | None = None,
           slab_pixels: int = 1 << 16, max_wrong: float = 1e-3, spatial: bool = True,
           projector_gamma: float = 1.0, response=None, cam_size: tuple | None = None,
           stack_checks: bool = True) -> DecodeResult:
    """Decode phase-shifted fringe images into depth (see the module doc).

    images: ``(F*N, H, W)`` frequency-major, ``(F, N, H, W)``, or a list of F*N ``(H, W)``
        arrays; uint8/uint16/int/float16/32/64 (linear intensities, e.g. from ``sl.sensor``).
        ValueError, before any work: another count than F*N, frequencies in another order than
        ``periods`` (a finer fringe's phase must change faster), an image without a finite value
        (single NaN / inf samples are per-pixel INVALID_INPUT), images of another size than P_cam
        was made for (``cam_size`` if given; else its principal point outside the central 90% of
        the images, which misses an upscaled image: pass ``cam_size``). After the decode, a geometry
        that puts over a quarter of the decided pixels (and 5% of the image) outside the projector's
        image is a ValueError too (:func:`.decode_setup.check_geometry_fits`: images of another
        size, a proj_size of another projector mode).
    periods: fringe frequencies K (periods across the projector), in stack order.
    steps: phase steps N per frequency (>= 3). shifts: optional N shifts (radians) instead of
        the uniform ``2*pi*n/N``.
    P_cam, P_proj: 3x4 world -> pixel matrices (``K @ inv(T_world_cam)[:3]``); depth and points
        are in the camera frame of P_cam. proj_size: projector (width, height) in pixels.
    cam_size: the camera's (width, height) P_cam was calibrated at; images of another size are a
        ValueError (None: only the principal-point test above).
    stack_checks: False skips the two checks that guard a user's captures against a stack that does
        not match its ``periods`` or geometry (the period order, the decided pixels outside the
        projector): for a caller that makes the stack and the geometry from one description, as the
        pipeline's scanner does, where they can only be false alarms.
    unwrap: 'auto' | 'heterodyne' | 'multi-frequency' | 'number-theoretic' (:mod:`datapipe.sl.unwrap`),
        or the UnwrapPlan of these periods made beforehand (``plan_unwrap``: once per run, not per image).
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
    response: the camera's tone curve undone before decoding (:mod:`datapipe.sl.response`): None
        (the images are linear), ``'fit'`` (a power law fitted to the stack, N >= 4), a 1-D table
        indexed by the raw integer value, or a callable ``linear = response(values)``.
    """
    st = prepare_decode(images, DecodeOptions(
        periods=periods, steps=steps, P_cam=P_cam, P_proj=P_proj, proj_size=proj_size, unwrap=unwrap,
        noise_sigma=noise_sigma, saturation=saturation, min_modulation=min_modulation, min_contrast=min_contrast,
        false_valid_rate=false_valid_rate, max_order_error=max_order_error, order_sigmas=order_sigmas,
        max_wrong=max_wrong, max_depth_slope=max_depth_slope, shifts=shifts, axis=axis,
        check_other_axis=check_other_axis, triangulator=triangulator, spatial=spatial,
        projector_gamma=projector_gamma, response=response, cam_size=cam_size,
        stack_checks=stack_checks))
    H, W = st.shape
    out = DecodeMaps.allocate(H, W, len(st.plan.periods))
    st.tri.coefficients  # compute (or reuse) the per-pixel coefficients before the loop
    coefs = st.plan.stage_coefs()
    rows = max(1, int(slab_pixels) // W)
    with np.errstate(all="ignore"):
        for r0 in range(0, H, rows):
            decode_slab(st, out, r0, min(H, r0 + rows), coefs)
        if st.spatial:
            neighbour_pass(st, out)
    res = _assemble(st, out)
    check_geometry_fits(st, res.reason, res.valid)
    return res
