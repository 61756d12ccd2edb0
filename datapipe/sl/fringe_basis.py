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

Three images per rendered layer (``packed_layout``, ``pack_basis``, ``unpack_basis``)
--------------------------------------------------------------------------------------
A path tracer carries red, green and blue along every path at once, so a projector that emits
three different basis images in its R, G and B channels gets all three through the same paths for
the price of one image: the basis costs 1 + ceil(2F / 3) (+ 1 for the row code) rendered layers
instead of 1 + 2F (+ 2). The camera of the scanner is monochrome: a pattern's frame is the grey
value ``V = lum(R(pattern) in R, G, B)`` the render mode's layer gives (the compositor's
luminance). A channel c of a packed layer holds ``R_c(X)`` only, the scene's response in that
channel, which differs from the grey one by the colour of the surfaces on the path. The first
layer is therefore the white image in all three channels (and its grey value), and image X in
channel c is taken back as::

    R(X) = V(white) * R_c(X) / R_c(white)

exact wherever every path into the pixel has the same colour balance (grey materials, any single
material, and each single path: over one path R_c(X) / R_c(white) is the pattern's value where the
path left the projector, whatever its colour), approximate where light of different colours mixes
in one point sample (a bounce off a red part beside a direct grey one: the ratio is a
colour-weighted average of the two pattern values instead of a grey-weighted one;
benchmarks/results/sl_glossy_modes.md measures it).
"""
from __future__ import annotations

import numpy as np

from ._errors import bad_value
from .patterns import _check_periods, phase_shifts

__all__ = ["quadrature_basis", "frames_from_basis", "basis_size", "packed_layout", "pack_basis", "unpack_basis"]


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


def packed_layout(n_periods: int, n_row_periods: int = 0) -> list[tuple]:
    """Which basis image (its index in `quadrature_basis`'s order) each channel (R, G, B) of each
    packed layer carries, None for an unused channel: the white image in all three channels of the
    first layer, then the fringes' (cos, sin) images three to a layer, then the row code's in
    layers of their own (so a render without the row code leaves those layers out)."""
    layers = [(0, 0, 0)]
    for first, count in ((1, 2 * int(n_periods)), (1 + 2 * int(n_periods), 2 * int(n_row_periods))):
        idx = list(range(first, first + count))
        for i in range(0, len(idx), 3):
            chunk = idx[i:i + 3]
            layers.append(tuple(chunk + [None] * (3 - len(chunk))))
    return layers


def pack_basis(basis, layout) -> np.ndarray:
    """(L, H, W, 3) float32 projector images (RGB last) of the basis ``(n, H, W)`` packed by
    `layout` (`packed_layout`); an unused channel emits nothing."""
    b = np.asarray(basis, dtype=np.float32)
    out = np.zeros((len(layout),) + b.shape[1:] + (3,), np.float32)
    for li, chans in enumerate(layout):
        for c, j in enumerate(chans):
            if j is not None:
                out[li, ..., c] = b[j]
    return out


def unpack_basis(rgb, grey, layout, *, a: float = 0.5, min_share: float = 0.01) -> np.ndarray:
    """The basis radiance ``(n, H, W)`` float32 (grey, as if each image were rendered alone) from
    the packed layers' radiance `rgb` ``(L, 3, H, W)`` (channels R, G, B first: planar, as an EXR
    holds them) and the white layer's grey value `grey`
    ``(H, W)``: image j in channel c of a layer is ``grey * rgb[layer, c] / rgb[0, c]`` (module
    doc). Where a channel in use gets less than `min_share` of the grey white light (a saturated
    red part has no blue to carry a pattern), that pixel's images are ``a * grey``: no modulation,
    so the decoder drops the pixel instead of reading a phase from the other channels alone.
    Layers past ``len(rgb)`` (the row code's, not rendered) are left out: n counts the images of
    the layers given."""
    rgb = np.asarray(rgb, dtype=np.float32)
    grey = np.asarray(grey, dtype=np.float32)
    if rgb.ndim != 4 or rgb.shape[1] != 3 or rgb.shape[2:] != grey.shape or not 1 <= len(rgb) <= len(layout):
        raise bad_value("rgb", f"has shape {rgb.shape} for a white image of shape {grey.shape}",
                        "pass (layers, 3, H, W) packed radiance, the white layer first")
    if tuple(layout[0]) != (0, 0, 0):
        raise bad_value("layout", f"starts with {layout[0]}", "put the white image in all channels of layer 0")
    used = sorted({c for chans in layout[1:len(rgb)] for c, j in enumerate(chans) if j is not None})
    n = 1 + max((j for chans in layout[:len(rgb)] for j in chans if j is not None), default=0)
    out = np.empty((n,) + grey.shape, np.float32)
    out[0] = grey
    scale = np.zeros((3,) + grey.shape, np.float32)      # grey / white per channel, 0 where unlit
    blind = np.zeros(grey.shape, bool)                   # a channel in use too dark to carry a pattern
    for c in range(3):
        white_c = rgb[0, c]
        np.divide(grey, white_c, out=scale[c], where=white_c > 0)
        if c in used:
            blind |= (grey > 0) & (white_c < np.float32(min_share) * grey)
    for li in range(1, len(rgb)):
        for c, j in enumerate(layout[li]):
            if j is not None:
                np.multiply(rgb[li, c], scale[c], out=out[j])
    if blind.any():
        out[1:, blind] = np.float32(a) * grey[blind]
    return out
