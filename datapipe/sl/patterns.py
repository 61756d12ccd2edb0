"""Phase-shifted sinusoidal fringe patterns.

Convention (docs/CONVENTIONS.md): frequency ``K`` periods across the projector width ``Wp``, step
``n = 0..N-1``::

    I(x) = a + b * cos(2*pi*K*x/Wp + 2*pi*n/N)

``x`` is the projector column with pixel centres at integers (``x = 0..Wp-1``). Stacks are
frequency-major: all ``N`` steps of ``periods[0]``, then all of ``periods[1]``, ...
With ``axis='y'`` the same formula runs along the projector rows (``y``, using the height).
``gamma != 1`` models a projector whose emitted light is ``I(x) ** gamma`` (a non-linear
response: harmonics that ripple the decoded phase; ``decode(projector_gamma=)`` corrects it).
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ._errors import bad_type, bad_value

__all__ = ["fringe_patterns", "phase_shifts"]


def phase_shifts(steps: int) -> np.ndarray:
    """The uniform shifts ``2*pi*n/N`` (float64, radians) used by :func:`fringe_patterns`."""
    steps = _check_steps(steps)
    return 2.0 * np.pi * np.arange(steps, dtype=np.float64) / steps


def _check_steps(steps) -> int:
    if isinstance(steps, bool) or not isinstance(steps, (int, np.integer)):
        raise bad_type("steps", f"must be an int, got {type(steps).__name__}", "pass e.g. steps=4")
    if steps < 3:
        raise bad_value("steps", f"{steps} phase steps cannot separate offset, modulation and phase",
                        "use steps >= 3 (4 or more is robust to a residual tone curve)")
    return int(steps)


def _check_periods(periods) -> tuple[float, ...]:
    if np.isscalar(periods):
        periods = (periods,)
    try:
        per = tuple(float(p) for p in periods)
    except (TypeError, ValueError):
        raise bad_type("periods", f"must be a sequence of numbers, got {periods!r}",
                       "pass e.g. periods=(1, 8, 64)") from None
    if not per:
        raise bad_value("periods", "is empty", "pass at least one fringe frequency, e.g. (1, 8, 64)")
    for p in per:
        if not np.isfinite(p) or p <= 0:
            raise bad_value("periods", f"every entry must be a finite number > 0, got {periods!r}",
                            "give the number of fringe periods across the projector, e.g. (1, 8, 64)")
    if any(p != q for p, q in zip(per, periods)):       # compared exactly: 2**62+1 and 2**62-1 differ
        raise bad_value("periods", f"{periods!r} has entries a float cannot hold exactly (beyond 2^53)",
                        "give the number of fringe periods across the projector (at most its width / 3)")
    if len(set(per)) != len(per):
        raise bad_value("periods", f"contains duplicates: {periods!r}",
                        "list each fringe frequency once")
    return per


def fringe_patterns(width: int, height: int, periods: Sequence[float], steps: int, *,
                    a: float = 0.5, b: float = 0.5, axis: str = "x",
                    dtype=np.float32, gamma: float = 1.0) -> np.ndarray:
    """Fringe images ``(len(periods)*steps, height, width)``, frequency-major.

    Values are ``a + b*cos(2*pi*K*x/width + 2*pi*n/steps)`` (``axis='x'``) or the same along
    rows with ``height`` (``axis='y'``), evaluated in float64. Float dtypes get the values as
    they are; integer dtypes map ``[0, 1]`` to ``[0, max]`` of the type with rounding (so the
    defaults ``a = b = 0.5`` span the full 8-bit range for ``np.uint8``). ``gamma``: the
    projector's response exponent, applied to the values in [0, 1] before the type conversion.
    """
    for name, v in (("width", width), ("height", height)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise bad_value(name, f"must be a positive int, got {v!r}", "pass the projector resolution in pixels")
    per = _check_periods(periods)
    steps = _check_steps(steps)
    if axis not in ("x", "y"):
        raise bad_value("axis", f"must be 'x' or 'y', got {axis!r}",
                        "'x' codes projector columns (vertical fringes), 'y' codes rows")
    try:
        gamma = float(gamma)
    except (TypeError, ValueError):
        raise bad_type("gamma", f"must be a number, got {gamma!r}", "pass e.g. gamma=2.2") from None
    if not np.isfinite(gamma) or not 0 < gamma <= 10:
        raise bad_value("gamma", f"must be in (0, 10], got {gamma!r}", "1.0 is a linear projector")
    dtype = np.dtype(dtype)
    length = int(width) if axis == "x" else int(height)
    coord = np.arange(length, dtype=np.float64)
    out = np.empty((len(per) * steps, int(height), int(width)), dtype=dtype)
    shifts = phase_shifts(steps)
    scale = float(np.iinfo(dtype).max) if dtype.kind in "iu" else None
    for i, k in enumerate(per):
        for n in range(steps):
            prof = a + b * np.cos(2.0 * np.pi * k * coord / length + shifts[n])
            if gamma != 1.0:
                prof = np.clip(prof, 0.0, None) ** gamma
            if scale is not None:
                prof = np.clip(np.rint(prof * scale), 0, scale)
            prof = prof.astype(dtype)
            out[i * steps + n] = prof[None, :] if axis == "x" else prof[:, None]
    return out
