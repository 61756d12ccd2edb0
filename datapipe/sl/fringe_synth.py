"""Fringe images from one flat-lit render: every pattern's direct light, synthesised.

A projector is a point light. The light a surface point receives straight from it while it shows
pattern ``I`` is the light it receives while it shows a white image, times ``I`` at the point's
projector coordinate - whatever the shadowing and the BRDF (the geometry of the light path does not
depend on what the projector shows). So from one render with a white image, split into

    direct(s)    the white image's direct light at point sample s (radiance seen by the camera),
    indirect(s)  its bounced light (reached s after a bounce elsewhere),
    X(s)         the world point sample s sees,

each fringe frame is::

    frame_k(s) = direct(s) * I_k(x(s)) + indirect(s) * mean(I_k),    x(s) = column of P_proj X(s)

``I_k(x)`` is the pattern array interpolated linearly between projector pixel centres (what a
Blender image texture with 'Linear' interpolation returns; at the image border, where the texture
fades to black, the white image fades the same way and the fade is already in ``direct``).
Bounced light gets the pattern's mean (offset only, no modulation): a bounce averages a fine
fringe over many periods. For coarse fringes, whose modulation survives a bounce (gain g_K, the
render mode's blur), `bounce_modulation` adds it back from two extra renders per frequency:
bounced light is linear in the emitted pattern and every phase step is a mix of a cosine and a
sine fringe, ``I_n - a = b (cos(d_n) cos(phi) - sin(d_n) sin(phi))``, so

    bounce_n = g_K b (cos(d_n) C_K - sin(d_n) S_K),   C_K, S_K = bounce light of cos(phi), sin(phi)

(see core/fringe_fast.py for what is left out: glossy bounces of the fine fringe). Samples on a ``block x block`` grid per camera pixel are then averaged, exactly as
the render mode averages its point samples.
"""
from __future__ import annotations

import numpy as np

from ._errors import bad_value
from .patterns import fringe_patterns

__all__ = ["projector_columns", "pattern_profiles", "synthesize_fringes", "quadrature_profiles",
           "bounce_modulation", "indirect_gain", "INDIRECT_BLUR_PX"]

INDIRECT_BLUR_PX = 32.0          # projector px: Gaussian blur of the pattern as seen by inter-reflected light


def indirect_gain(K: float, proj_width: int, blur_px: float = INDIRECT_BLUR_PX) -> float:
    """Modulation left in a K-period fringe after a Gaussian blur of `blur_px` projector pixels:
    exp(-2 pi^2 (blur_px K / W)^2) (a blurred sinusoid is the same sinusoid, scaled). Both fringe
    modes render bounced light with it (core/fringe_call.py); the scanner's global-light filter
    reads the direct light from the frequencies it blurs away (sl.filters.global_light_filter)."""
    return float(np.exp(-2.0 * np.pi ** 2 * (blur_px * K / proj_width) ** 2))


def projector_columns(points: np.ndarray, P_proj: np.ndarray) -> np.ndarray:
    """Projector column (OpenCV, pixel centres at integers) of world points ``(..., 3)``; NaN for
    points that are not in front of the projector or not finite."""
    X = np.asarray(points, dtype=np.float64)
    P = np.asarray(P_proj, dtype=np.float64)
    if X.shape[-1] != 3 or P.shape != (3, 4):
        raise bad_value("points/P_proj", f"need (..., 3) points and a 3x4 matrix, got {X.shape} and {P.shape}",
                        "pass the Position pass (world metres) and projector_matrix(cfg, T_world_cam)")
    u = X @ P[0, :3] + P[0, 3]
    w = X @ P[2, :3] + P[2, 3]
    with np.errstate(invalid="ignore", divide="ignore"):
        x = np.where(w > 0, u / w, np.nan)
    return x


def pattern_profiles(width: int, periods, steps: int, *, a: float = 0.5, b: float = 0.5) -> np.ndarray:
    """(F*N, width) float32 pattern values along the projector columns, frequency-major: the
    row the projector's images hold (fringe_patterns, float32 as stored in the Blender image)."""
    return fringe_patterns(int(width), 1, periods, steps, a=a, b=b)[:, 0, :]


def synthesize_fringes(direct: np.ndarray, indirect: np.ndarray, points: np.ndarray, P_proj: np.ndarray,
                       profiles: np.ndarray, *, block: int = 1, indirect_level=0.5) -> np.ndarray:
    """(F*N, H, W) float32 fringe radiance from a flat-lit render on the point-sample grid.

    direct, indirect: (h, w) white-image radiance at each point sample (h = H*block, w = W*block);
    points: (h, w, 3) world point of each sample; P_proj: 3x4; profiles: (P, Wp) pattern values
    per projector column (`pattern_profiles`); indirect_level: the bounced light's share per
    pattern, a number or (P,) values (default 0.5 = the patterns' mean); block: samples per
    camera pixel along each axis, averaged."""
    d = np.asarray(direct, dtype=np.float32)
    ind = np.asarray(indirect, dtype=np.float32)
    prof = np.asarray(profiles, dtype=np.float32)
    if d.ndim != 2 or ind.shape != d.shape or np.shape(points)[:2] != d.shape:
        raise bad_value("direct/indirect/points", f"shapes {d.shape}, {ind.shape}, {np.shape(points)} differ",
                        "pass the flat-lit passes of one render: (h, w), (h, w), (h, w, 3)")
    if prof.ndim != 2 or prof.shape[0] < 1:
        raise bad_value("profiles", f"need (patterns, projector width), got {prof.shape}",
                        "use pattern_profiles(width, periods, steps)")
    block = int(block)
    h, w = d.shape
    if block < 1 or h % block or w % block:
        raise bad_value("block", f"{block} does not divide the sample grid {h}x{w}",
                        "render at an integer multiple (block) of the camera resolution")
    level = np.broadcast_to(np.asarray(indirect_level, dtype=np.float32), (prof.shape[0],))
    x = projector_columns(points, P_proj)
    lit = np.isfinite(x) & (d > 0)
    # linear interpolation between column centres, clamped at the ends (the fade is in `direct`)
    xc = np.clip(np.where(lit, x, 0.0), 0.0, prof.shape[1] - 1.0)
    i0 = np.minimum(np.floor(xc).astype(np.intp), prof.shape[1] - 2) if prof.shape[1] > 1 else np.zeros_like(xc, np.intp)
    t = (xc - i0).astype(np.float32) if prof.shape[1] > 1 else np.zeros_like(xc, np.float32)
    i1 = np.minimum(i0 + 1, prof.shape[1] - 1)
    dl = np.where(lit, d, 0.0).astype(np.float32)
    H, W = h // block, w // block
    out = np.empty((prof.shape[0], H, W), np.float32)
    for k, p in enumerate(prof):
        frame = dl * (p[i0] * (1.0 - t) + p[i1] * t) + ind * level[k]
        out[k] = frame.reshape(H, block, W, block).mean(axis=(1, 3), dtype=np.float32) if block > 1 else frame
    return out


def quadrature_profiles(width: int, K: float, *, a: float = 0.5, b: float = 0.5) -> np.ndarray:
    """(2, width) float32: a + b cos(phi) and a + b sin(phi), phi = 2 pi K x / width - the two
    non-negative images whose bounce light gives C_K and S_K (`bounce_modulation`)."""
    phi = 2.0 * np.pi * float(K) * np.arange(int(width), dtype=np.float64) / int(width)
    return np.stack([a + b * np.cos(phi), a + b * np.sin(phi)]).astype(np.float32)


def bounce_modulation(quadrature: dict, periods, steps: int, gains: dict, *, white=None, indirect=None,
                      smooth_px: float = 0.0, b: float = 0.5) -> np.ndarray | None:
    """(F*N, H, W) float32 bounce-light fringe per pattern, frequency-major, zero for the periods
    not in `quadrature`; None when it is empty.

    quadrature: {K: (C, S)} the bounce light (H, W) of the signed fringes cos(phi) and sin(phi)
    (= 2 x bounce(a + b cos phi) - bounce(1) with a = b = 0.5, and the same for sin); gains: {K:
    modulation a bounce keeps}.

    smooth_px > 0: C and S come from few paths per pixel (each path sees the fringe at one random
    bounce point); what varies slowly is their ratio to the white image's bounce light from the
    same paths, `white` (the mean cos / sin of the fringe phase where the light bounced). The
    ratios are taken of Gaussian-smoothed maps (sigma smooth_px) and multiplied by `indirect`,
    the white image's bounce light at this resolution from the better-sampled flat render."""
    if not quadrature:
        return None
    from .patterns import phase_shifts

    periods = list(periods)
    shape = np.shape(next(iter(quadrature.values()))[0])
    out = np.zeros((len(periods) * int(steps),) + tuple(shape), np.float32)
    delta = phase_shifts(int(steps))
    if smooth_px > 0:
        if white is None or indirect is None:
            raise bad_value("smooth_px", "needs `white` and `indirect`", "pass both maps, or smooth_px=0")
        from scipy.ndimage import gaussian_filter
        blur = lambda m: gaussian_filter(np.asarray(m, np.float64), float(smooth_px), mode="nearest")  # noqa: E731
        w = blur(white)
        scale = np.where(w > 1e-12 * max(float(w.max()), 1e-30), np.asarray(indirect, np.float64) / np.maximum(w, 1e-30), 0.0)
    for K, (C, S) in quadrature.items():
        if K not in periods:
            raise bad_value("quadrature", f"period {K} is not one of {periods}", "pass maps for the pattern periods")
        if smooth_px > 0:
            C, S = blur(C) * scale, blur(S) * scale
        C, S = np.asarray(C, np.float32), np.asarray(S, np.float32)
        i = periods.index(K)
        g = float(gains[K]) * b
        for n, d in enumerate(delta):
            out[i * int(steps) + n] = g * (np.cos(d) * C - np.sin(d) * S)
    return out
