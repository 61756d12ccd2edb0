"""Every phase step of a sinusoidal fringe from three projector images: the quadrature basis.

Light is linear in what the projector emits: whatever the path (direct, mirrored by a shiny part,
bounced off a diffuse wall), the radiance a camera pixel receives while the projector shows
``alpha * A + beta * B`` is ``alpha * R(A) + beta * R(B)``, with ``R(X)`` the pixel's radiance for
image ``X`` over the same light paths. The phase steps (sl.patterns, docs/CONVENTIONS.md)::

    I_n(x) = a + b cos(phi(x) + d_n) = a + b cos(d_n) cos(phi) - b sin(d_n) sin(phi)

are therefore, for any N, a mix of three images: white (1), ``a + b cos(phi)`` and
``a + b sin(phi)`` (all three non-negative, so a real light can emit them)::

    R(I_n) = a R(1) + cos(d_n) (R(c) - a R(1)) - sin(d_n) (R(s) - a R(1))

so a frequency costs 2 rendered images instead of N, and the white image is shared by all of
them (and by the row code): 1 + 2F images for F frequencies instead of F * N. It is exact for every
light path (glossy mirror images of the fringes included), not an approximation of the bounce
light: rendered with the same Cycles seed the three images follow the same paths, so the mixed
frames equal the path-traced steps path for path (float rounding aside; tests/blender).

It needs the emitted image to be an affine function of cos(phi) and sin(phi): a projector gamma
(``I ** gamma``, sl.patterns) makes harmonics of every order, and a binary or Gray code is no
sinusoid at all: those are path-traced pattern by pattern (fringe_mode "render").
"""
from __future__ import annotations

import numpy as np

from ._errors import bad_value
from .patterns import _check_periods, phase_shifts

__all__ = ["quadrature_basis", "frames_from_basis", "basis_size"]


def basis_size(n_periods: int, rows: bool = False) -> int:
    """Images of the basis: white + (cos, sin) per frequency (+ the row code's cos, sin)."""
    return 1 + 2 * int(n_periods) + (2 if rows else 0)


def quadrature_basis(width: int, height: int, periods, *, row_periods=(), a: float = 0.5,
                     b: float = 0.5) -> np.ndarray:
    """(1 + 2F (+ 2R), height, width) float32 projector images: white, then ``a + b cos(phi_K)``
    and ``a + b sin(phi_K)`` per period K across the width (the `fringe_patterns` phase), then the
    same along the height for each of `row_periods` (the row code)."""
    per = _check_periods(periods)
    rper = _check_periods(row_periods) if len(row_periods) else ()
    out = [np.ones((int(height), int(width)), np.float32)]
    for axis, ks, length in (("x", per, int(width)), ("y", rper, int(height))):
        for K in ks:
            phi = 2.0 * np.pi * K * np.arange(length, dtype=np.float64) / length
            for prof in (a + b * np.cos(phi), a + b * np.sin(phi)):
                prof = prof.astype(np.float32)
                out.append(np.broadcast_to(prof[None, :] if axis == "x" else prof[:, None],
                                           (int(height), int(width))).copy())
    return np.stack(out)


def frames_from_basis(rendered, steps: int, *, a: float = 0.5) -> np.ndarray:
    """(G*N, H, W) float32 fringe frames, frequency-major, from the radiance of the basis images
    ``(1 + 2G, H, W)`` (white, then (cos, sin) per frequency: G = the fringe periods, plus the row
    code's when it was rendered): step n of frequency g is
    ``a W + cos(d_n) (C_g - a W) - sin(d_n) (S_g - a W)`` (module doc)."""
    r = np.asarray(rendered, dtype=np.float32)
    if r.ndim != 3 or r.shape[0] < 3 or r.shape[0] % 2 != 1:
        raise bad_value("rendered", f"has shape {r.shape}",
                        "pass the white image's radiance, then a (cos, sin) pair per frequency")
    d = phase_shifts(steps)
    white = a * r[0]
    out = np.empty(((r.shape[0] - 1) // 2 * len(d),) + r.shape[1:], np.float32)
    for g in range((r.shape[0] - 1) // 2):
        C, S = r[1 + 2 * g] - white, r[2 + 2 * g] - white
        for n, dn in enumerate(d):
            out[g * len(d) + n] = white + np.float32(np.cos(dn)) * C - np.float32(np.sin(dn)) * S
    return out
