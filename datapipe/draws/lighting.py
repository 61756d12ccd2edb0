"""Per-scene lighting draws and blackbody colours. No bpy (core/scene.py applies a draw).

`draw_lighting(cfg.lighting, rng)` draws, uniformly within each [min, max] of
`config.LightingConfig`: the key light's power (W), colour temperature (K), size (m) and a
horizontal offset (uniform in a disc of radius `key_position_jitter`), and the ambient world
strength. The key light's colour is the blackbody colour of the drawn temperature at unit
luminance, so the power alone sets how bright the bin is and the temperature only its tint.

Blackbody colour (`blackbody_rgb`): Planck's law integrated against the CIE 1931 2-degree colour
matching functions, 360..830 nm in 1 nm steps, gives XYZ; the matching functions are the
piecewise-Gaussian fit of Wyman, Sloan & Shirley, "Simple Analytic Approximations to the CIE XYZ
Color Matching Functions", JCGT 2(2), 2013 (within ~1% of the tabulated functions). XYZ -> linear
sRGB / Rec.709 primaries with the D65 matrix of IEC 61966-2-1 (Blender's scene-linear space), then
scaled to luminance Y = 1; the few negative components of very red (< ~1900 K) colours, outside the
sRGB gamut, are clipped to 0.
"""
from __future__ import annotations

import math

import numpy as np

_C2 = 1.438776877e-2          # m K, second radiation constant h c / k
_XYZ_TO_SRGB = np.array([[3.2404542, -1.5371385, -0.4985314],
                         [-0.9692660, 1.8760108, 0.0415560],
                         [0.0556434, -0.2040259, 1.0572252]])
_LAMBDA_NM = np.arange(360.0, 831.0, 1.0)


def _g(lam, mu, s1, s2):
    s = np.where(lam < mu, s1, s2)
    return np.exp(-0.5 * ((lam - mu) / s) ** 2)


def cie1931_cmf(lam_nm) -> np.ndarray:
    """(N, 3) x-bar, y-bar, z-bar at wavelengths `lam_nm` (Wyman et al. 2013, multi-lobe fit)."""
    lam = np.asarray(lam_nm, dtype=np.float64)
    x = 1.056 * _g(lam, 599.8, 37.9, 31.0) + 0.362 * _g(lam, 442.0, 16.0, 26.7) - 0.065 * _g(lam, 501.1, 20.4, 26.2)
    y = 0.821 * _g(lam, 568.8, 46.9, 40.5) + 0.286 * _g(lam, 530.9, 16.3, 31.1)
    z = 1.217 * _g(lam, 437.0, 11.8, 36.0) + 0.681 * _g(lam, 459.0, 26.0, 13.8)
    return np.stack([x, y, z], axis=-1)


_CMF = cie1931_cmf(_LAMBDA_NM)


def blackbody_xyz(kelvin: float) -> np.ndarray:
    """CIE XYZ of a blackbody at `kelvin`, scaled to Y = 1."""
    lam = _LAMBDA_NM * 1e-9
    spectrum = 1.0 / (lam ** 5 * np.expm1(_C2 / (lam * float(kelvin))))   # Planck, constant factor dropped
    xyz = spectrum @ _CMF
    return xyz / xyz[1]


def blackbody_rgb(kelvin: float) -> tuple[float, float, float]:
    """Linear sRGB (Rec.709, D65) colour of a blackbody at `kelvin`, luminance 1 (see module doc)."""
    rgb = np.clip(_XYZ_TO_SRGB @ blackbody_xyz(kelvin), 0.0, None)
    rgb /= float(np.array([0.2126, 0.7152, 0.0722]) @ rgb)                # Rec.709 luminance
    return tuple(float(v) for v in rgb)


def _uniform(rng: np.random.Generator, lo_hi) -> float:
    lo, hi = (float(v) for v in lo_hi)
    return lo if hi <= lo else float(rng.uniform(lo, hi))


def draw_lighting(lighting, rng: np.random.Generator) -> dict:
    """One scene's lighting from `lighting` (a `config.LightingConfig`): what scene.json records and
    `core.scene.BlendScene.apply_lighting` applies. Fixed draw order: power, temperature, size,
    offset, ambient."""
    power = _uniform(rng, lighting.key_power)
    kelvin = _uniform(rng, lighting.key_color_temperature)
    size = _uniform(rng, lighting.key_size)
    j = float(lighting.key_position_jitter)
    rho = j * math.sqrt(float(rng.uniform())) if j > 0 else 0.0
    phi = float(rng.uniform(0.0, 2 * math.pi)) if j > 0 else 0.0
    ambient = _uniform(rng, lighting.ambient)
    return {"key_power": power, "key_color_temperature": kelvin, "key_color": list(blackbody_rgb(kelvin)),
            "key_size": size, "key_offset": [rho * math.cos(phi), rho * math.sin(phi), 0.0],
            "ambient": ambient}
