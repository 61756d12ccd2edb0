"""Least-squares N-step phase shifting.

Model per pixel and step ``n`` (shift ``d_n``; uniform shifts are ``d_n = 2*pi*n/N``)::

    I_n = A + B*cos(phi + d_n) = A + C*cos(d_n) - S*sin(d_n),   C = B*cos(phi), S = B*sin(phi)

``(A, C, S)`` is the least-squares solution (pseudo-inverse of the ``N x 3`` design matrix, any
``N >= 3`` and any shifts with at least three distinct values mod ``2*pi``), so for the patterns
of :func:`datapipe.sl.patterns.fringe_patterns` the wrapped phase is ``2*pi*K*x/W mod 2*pi``,
returned in ``[0, 2*pi)``.

Precision: integer and float16 inputs are converted per frame (slab by slab) to float32, which
holds every uint16 value exactly; float64 inputs are computed in float64. The whole stack is never
copied.

Saturation: samples ``>= saturation`` are excluded and the pixel is solved by least squares over
the remaining samples when at least three remain (and the reduced system is well conditioned);
otherwise it is flagged ``saturated``. Pixels with a non-finite sample are flagged ``invalid``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ._errors import bad_type, bad_value
from .patterns import phase_shifts

try:  # cv2 computes sqrt(c^2 + s^2) in one SIMD pass, ~2.5x faster than three numpy passes
    import cv2 as _cv2
except ImportError:  # pragma: no cover - cv2 is a dependency, numpy is the fallback
    _cv2 = None

__all__ = ["PhaseResult", "phase_shift", "lsq_coefficients"]

TWO_PI = 2.0 * np.pi
_MAX_REDUCED_COND = 100.0   # condition number above which a reduced (saturation) fit is refused


def _design(shifts: np.ndarray) -> np.ndarray:
    return np.stack([np.ones_like(shifts), np.cos(shifts), -np.sin(shifts)], axis=1)


def lsq_coefficients(shifts) -> np.ndarray:
    """``(3, N)`` float64 matrix mapping the N samples of a pixel to ``(A, C, S)``."""
    d = np.asarray(shifts, dtype=np.float64).ravel()
    if d.size < 3:
        raise bad_value("shifts", f"{d.size} phase steps cannot separate offset, modulation and phase",
                        "use at least 3 phase steps")
    if not np.all(np.isfinite(d)):
        raise bad_value("shifts", "contains NaN or inf", "pass finite phase shifts in radians")
    m = _design(d)
    if np.linalg.cond(m) > 1e8:
        raise bad_value("shifts", f"{np.round(d, 4).tolist()} has fewer than 3 distinct shifts mod 2*pi",
                        "use e.g. the uniform shifts 2*pi*n/N")
    return np.linalg.pinv(m)


@dataclass
class PhaseResult:
    """Wrapped phase in ``[0, 2*pi)``, offset ``A`` and modulation ``B`` (input units), flags."""
    phase: np.ndarray
    offset: np.ndarray
    modulation: np.ndarray
    saturated: np.ndarray   # bool: fewer than 3 usable (unsaturated) samples
    invalid: np.ndarray     # bool: a sample was NaN or inf


class _Row:
    """One output row (A, C or S) as a weighted sum of frames, with fast paths for 0 / +-1.

    The row is computed up to the factor ``scale`` (weights normalised to max |w| = 1)."""

    def __init__(self, w: np.ndarray, scale: float | None = None):
        g = float(np.max(np.abs(w))) if scale is None else float(scale)
        self.scale = g
        plan = []
        for n, wn in enumerate(w / g):
            if abs(wn) < 1e-12:
                continue
            if abs(wn - 1.0) < 1e-12:
                plan.append((n, 1.0))
            elif abs(wn + 1.0) < 1e-12:
                plan.append((n, -1.0))
            else:
                plan.append((n, float(wn)))
        # put a +1 term first so the first two terms fuse into one add/subtract
        plan.sort(key=lambda t: t[1] != 1.0)
        self.plan = plan

    def __call__(self, frames, out, tmp):
        plan = self.plan
        i = 0
        if len(plan) >= 2 and plan[0][1] == 1.0 and plan[1][1] in (1.0, -1.0):
            op = np.add if plan[1][1] == 1.0 else np.subtract
            op(frames[plan[0][0]], frames[plan[1][0]], out=out)
            i = 2
        else:
            n, wn = plan[0]
            if wn == 1.0:
                np.copyto(out, frames[n])
            elif wn == -1.0:
                np.negative(frames[n], out=out)
            else:
                np.multiply(frames[n], wn, out=out)
            i = 1
        for n, wn in plan[i:]:
            f = frames[n]
            if wn == 1.0:
                np.add(out, f, out=out)
            elif wn == -1.0:
                np.subtract(out, f, out=out)
            else:
                np.multiply(f, wn, out=tmp)
                np.add(out, tmp, out=out)
        return out

    def direct(self, frames, out, tmp):
        """The same row from the raw integer / float32 frames into float32 ``out`` with OpenCV's
        converting add / subtract / addWeighted (``dtype=CV_32F``): each pass reads the uint8 or
        uint16 samples once, no float copy of the frames. Sums of +-1 weights are exact integer
        sums (as the numpy path's); other weights round once per pair in float32."""
        plan = self.plan
        f32 = _cv2.CV_32F
        i = 0
        dst = out
        while i < len(plan):
            if i + 1 < len(plan):
                (n0, w0), (n1, w1) = plan[i], plan[i + 1]
                a, b = frames[n0], frames[n1]
                if w0 == 1.0 and w1 == 1.0:
                    _cv2.add(a, b, dst=dst, dtype=f32)
                elif w0 == 1.0 and w1 == -1.0:
                    _cv2.subtract(a, b, dst=dst, dtype=f32)
                else:
                    _cv2.addWeighted(a, w0, b, w1, 0.0, dst=dst, dtype=f32)
                i += 2
            else:
                n0, w0 = plan[i]
                np.multiply(frames[n0], np.float32(w0), out=dst)
                i += 1
            if dst is tmp:
                _cv2.add(out, tmp, dst=out)
            dst = tmp
        return out


_DIRECT_DTYPES = (np.dtype(np.uint8), np.dtype(np.uint16), np.dtype(np.int16), np.dtype(np.float32))


def _direct_ok(frames, work) -> bool:
    """Rows straight from the raw frames (OpenCV, :meth:`_Row.direct`): float32 work, 2-D C-contiguous
    frames of one dtype OpenCV converts (uint8, uint16, int16, float32)."""
    if _cv2 is None or work != np.float32:
        return False
    dt = frames[0].dtype
    return dt in _DIRECT_DTYPES and all(f.dtype == dt and f.ndim == 2 and f.flags.c_contiguous for f in frames)


class PhaseKernel:
    """Precomputed least-squares weights for one set of shifts; computes slabs of frames.

    The C and S rows are negated so that ``atan2(-S, -C) + pi`` gives the phase in ``(0, 2*pi]``
    with one addition (the single value ``2*pi`` is folded to 0)."""

    def __init__(self, shifts):
        self.shifts = np.asarray(shifts, dtype=np.float64).ravel()
        self.n = self.shifts.size
        self.coef = lsq_coefficients(self.shifts)
        self.row_a = _Row(self.coef[0])
        g = float(max(np.max(np.abs(self.coef[1])), np.max(np.abs(self.coef[2]))))
        self.row_c = _Row(-self.coef[1], g)        # C' = -C/g, S' = -S/g: one common scale
        self.row_s = _Row(-self.coef[2], g)
        self.mod_scale = self.row_c.scale          # B = mod_scale * |(C', S')|
        self.a_scale = self.row_a.scale            # A = a_scale * A'
        self.design = _design(self.shifts)

    def compute(self, frames: Sequence[np.ndarray], work_dtype, saturation=None, check_finite=True,
                out_phase=None, out_mod=None):
        """frames: N equally shaped arrays (any dtype).

        Returns ``(phase, a_raw, b, saturated|None, invalid|None)``: phase in ``[0, 2*pi)``,
        ``a_raw * self.a_scale`` is the offset A, ``b`` the modulation B (work dtype). Phase and
        modulation are written into ``out_phase`` / ``out_mod`` when given (any float dtype).
        """
        work = np.dtype(work_dtype)
        wt = work.type
        shape = frames[0].shape
        a, c, s, tmp = (aligned_empty(shape, work) for _ in range(4))
        if _direct_ok(frames, work):          # read the integer samples once, no float copy of them
            for row, dst in ((self.row_a, a), (self.row_c, c), (self.row_s, s)):
                row.direct(frames, dst, tmp)
        else:
            fr = [f if f.dtype == work else f.astype(work) for f in frames]
            for row, dst in ((self.row_a, a), (self.row_c, c), (self.row_s, s)):
                row(fr, dst, tmp)
        if out_mod is None or out_mod.dtype != work:
            b = _magnitude(c, s, tmp)
        else:
            b = _magnitude(c, s, out_mod)
        if self.mod_scale != 1.0:
            np.multiply(b, wt(self.mod_scale), out=b)
        phi = np.arctan2(s, c, out=c)
        if out_phase is None:
            np.add(phi, wt(np.pi), out=phi)
        else:
            phi = np.add(phi, wt(np.pi), out=out_phase)
        phi[phi >= phi.dtype.type(TWO_PI)] = 0
        invalid = None
        if check_finite:
            chk = np.add(a, b, out=s)
            invalid = ~np.isfinite(chk)
        sat = None
        if saturation is not None and np.isfinite(saturation):
            sat = self._saturation(frames, saturation, phi, a, b)
        if out_mod is not None and b is not out_mod:
            out_mod[...] = b
        return phi, a, b, sat, invalid

    def _saturation(self, frames, level, phi, a_raw, b):
        mx = frames[0].copy()
        for f in frames[1:]:
            np.maximum(mx, f, out=mx)
        anysat = mx >= level
        flag = np.zeros(phi.shape, bool)
        if not anysat.any():
            return flag
        idx = np.flatnonzero(anysat)
        samples = np.stack([np.asarray(f).reshape(-1)[idx] for f in frames]).astype(np.float64)
        satm = samples >= level
        codes = np.zeros(idx.size, np.int64)
        for n in range(self.n):
            codes |= satm[n].astype(np.int64) << n
        phi_f, a_f, b_f, flag_f = phi.reshape(-1), a_raw.reshape(-1), b.reshape(-1), flag.reshape(-1)
        for code in np.unique(codes):
            sel = codes == code
            keep = np.array([not (code >> n) & 1 for n in range(self.n)])
            pix = idx[sel]
            if keep.sum() < 3 or np.linalg.cond(self.design[keep]) > _MAX_REDUCED_COND:
                flag_f[pix] = True
                continue
            coef = np.linalg.pinv(self.design[keep])
            acs = coef @ samples[keep][:, sel]
            a_f[pix] = acs[0] / self.a_scale
            b_f[pix] = np.sqrt(acs[1] ** 2 + acs[2] ** 2)
            p = np.arctan2(-acs[2], -acs[1]) + np.pi
            p[p >= TWO_PI] = 0.0
            phi_f[pix] = p
        return flag


ALIGN = 64    # bytes: OpenCV's magnitude (its IPP kernel) rounds some results differently by the output's
             # alignment: 2-3 of 65 536 values 1 ulp apart at offsets of 20 or 40 bytes from a 64-byte
             # boundary (OpenCV 4.11 with IPP 2021.12); the decoder's maps are allocated on a boundary,
             # so one stack gives one result, whatever memory the allocator hands out


def aligned_empty(shape, dtype) -> np.ndarray:
    """An uninitialised C-contiguous array whose data start on an ``ALIGN``-byte boundary."""
    dt = np.dtype(dtype)
    n = int(np.prod(shape))
    raw = np.empty(n * dt.itemsize + ALIGN, np.uint8)
    start = -raw.ctypes.data % ALIGN
    return raw[start:start + n * dt.itemsize].view(dt).reshape(shape)


def _magnitude(c, s, out):
    """sqrt(c^2 + s^2) into out; cv2.magnitude (one pass) for contiguous float32/64 arrays, computed
    on an ``ALIGN``-byte boundary (into a scratch array and copied when ``out`` is not on one)."""
    if _cv2 is not None and c.ndim == 2 and c.flags.c_contiguous and s.flags.c_contiguous \
            and out.flags.c_contiguous and out.dtype == c.dtype:
        if out.ctypes.data % ALIGN == 0:
            return _cv2.magnitude(c, s, out)
        np.copyto(out, _cv2.magnitude(c, s, aligned_empty(out.shape, out.dtype)))
        return out
    np.multiply(c, c, out=out)
    out += s * s
    return np.sqrt(out, out=out)


def work_dtype_for(dtypes) -> np.dtype:
    """float64 when any input is float64 (or wider), else float32 (exact for <= 24-bit integers)."""
    for dt in dtypes:
        dt = np.dtype(dt)
        if dt.kind == "f" and dt.itemsize >= 8:
            return np.dtype(np.float64)
        if dt.kind in "iu" and dt.itemsize >= 4:
            return np.dtype(np.float64)
    return np.dtype(np.float32)


def check_image_dtype(dt, arg="images"):
    dt = np.dtype(dt)
    if dt.kind not in "uif":
        raise bad_type(arg, f"has dtype {dt}, which is not a number type",
                       "pass uint8, uint16 or float images")
    return dt


def phase_shift(images, shifts=None, *, saturation=None) -> PhaseResult:
    """Least-squares N-step phase shifting of one frequency.

    images: ``(N, ...)`` array (or a sequence of N equally shaped arrays), any of uint8, uint16,
    int, float16/32/64. shifts: N shifts in radians (default uniform ``2*pi*n/N``; any shifts
    with 3 distinct values mod 2*pi). saturation: samples ``>=`` this are excluded (default: the
    type's maximum for integer images, none for floats; pass ``np.inf`` to disable).

    Returns :class:`PhaseResult` with ``phase`` in ``[0, 2*pi)`` consistent with
    ``I = A + B*cos(phi + shift)``, ``offset`` A, ``modulation`` B (float32, or float64 for
    float64 input), and boolean ``saturated`` / ``invalid`` masks.
    """
    if isinstance(images, np.ndarray):
        if images.ndim < 2:
            raise bad_value("images", f"has shape {images.shape}; expected (N, H, W)",
                            "stack the N phase-shifted images along the first axis")
        frames = list(images)
    elif isinstance(images, (list, tuple)):
        frames = [np.asarray(f) for f in images]
    else:
        raise bad_type("images", f"must be an array or a list of arrays, got {type(images).__name__}",
                       "pass an (N, H, W) numpy array")
    n = len(frames)
    if shifts is None:
        if n < 3:
            raise bad_value("images", f"has {n} phase steps", "use at least 3 phase-shifted images")
        shifts = phase_shifts(n)
    shifts = np.asarray(shifts, dtype=np.float64).ravel()
    if shifts.size != n:
        raise bad_value("shifts", f"has {shifts.size} entries for {n} images", "give one shift per image")
    shape = frames[0].shape
    for f in frames:
        check_image_dtype(f.dtype)
        if f.shape != shape:
            raise bad_value("images", f"mixes shapes {shape} and {f.shape}", "pass equally sized images")
    kern = PhaseKernel(shifts)
    dt = frames[0].dtype
    if saturation is None and dt.kind in "iu":
        saturation = float(np.iinfo(dt).max)
    work = work_dtype_for([f.dtype for f in frames])
    check = any(f.dtype.kind == "f" for f in frames)
    phi, a, b, sat, inv = kern.compute(frames, work, saturation, check_finite=check)
    if kern.a_scale != 1.0:
        a *= a.dtype.type(kern.a_scale)
    if sat is None:
        sat = np.zeros(shape, bool)
    if inv is None:
        inv = np.zeros(shape, bool)
    return PhaseResult(phase=phi, offset=a, modulation=b, saturated=sat, invalid=inv)
