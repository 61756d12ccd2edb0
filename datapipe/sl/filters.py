"""Post-decode filters on depth maps (pure numpy), as real scanners apply them before output."""
from __future__ import annotations

import numpy as np

EDGE_SIGMAS = 5.0                # noise part of the neighbour tolerance (in combined sigmas)
EDGE_SLOPE = 3.7                 # tan(75 deg): steepest surface whose neighbours still agree
EDGE_MIN_SUPPORT = 3             # agreeing 8-neighbours a valid pixel needs


def edge_speckle_filter(depth, valid, sigma_z, pixel_angle: float, *, sigmas: float = EDGE_SIGMAS,
                        slope: float = EDGE_SLOPE, min_support: int = EDGE_MIN_SUPPORT) -> np.ndarray:
    """Valid pixels with fewer than `min_support` agreeing 8-neighbours (see the module doc);
    returns the bool mask of pixels to remove."""
    z = np.where(valid, depth, np.nan).astype(np.float64)
    s = np.where(valid, sigma_z, np.nan).astype(np.float64)
    s = np.where(np.isfinite(s), s, 0.0)
    H, W = z.shape
    zp = np.pad(z, 1, constant_values=np.nan)
    sp = np.pad(s, 1, constant_values=0.0)
    support = np.zeros((H, W), np.int32)
    with np.errstate(invalid="ignore"):
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dx == 0 and dy == 0:
                    continue
                zq = zp[1 + dy:1 + dy + H, 1 + dx:1 + dx + W]
                sq = sp[1 + dy:1 + dy + H, 1 + dx:1 + dx + W]
                tol = sigmas * np.sqrt(s * s + sq * sq) + slope * z * pixel_angle * np.hypot(dx, dy)
                support += (np.abs(zq - z) <= tol)
    return valid & (support < min_support)


# -- reflection / multipath filter -----------------------------------------------------------------
MULTIPATH_RATIO = 0.6            # min_K B_K / max_K B_K below this (beyond the noise) = light of 2 paths
MULTIPATH_SIGMAS = 3.0           # noise margin of that test, in sigmas of B_min - ratio * B_max
MULTIPATH_MIN_SPREAD = 4.0       # finest / coarsest period count below this: the test cannot see it


def multipath_filter(modulation, offset, periods, steps: int, noise_sigma, valid, *,
                     ratio: float = MULTIPATH_RATIO, sigmas: float = MULTIPATH_SIGMAS) -> np.ndarray:
    """Pixels whose fringe frequencies carry very different modulation: light that reached them
    over a second path (inter-reflection, a glossy bounce) and shifts the coarse phase, hence the
    fringe order; returns the bool mask of pixels to remove (the scanners' "reflection filter").

    Why this test: light arriving after a diffuse bounce has averaged the projector pattern over a
    footprint of many fine periods, so it keeps modulation in the coarse fringes and none in the
    finest (direct/global separation, Nayar et al. 2006: high-frequency patterns see only direct
    light). Its coarse phasor adds to the direct one, raising or cancelling the coarse modulation
    while the finest keeps the direct light's alone. Direct light modulates every frequency alike
    (finest / coarsest ~ the pixel's box-filter MTF: 0.93 at 5 camera px per finest period, 0.83
    at 3); ambient light modulates none -- unlike the contrast B/A, this test does not punish
    ambient light on a part. A pixel is removed when

        min_K B_K < ratio * max_K B_K - sigmas * sqrt(1 + ratio^2) * sigma_B,   sigma_B = sqrt(2/N) sigma_I

    (sigma_B the least-squares noise of a modulation estimate, sigma_I the sensor noise at the
    pixel's offset: dark pixels are not removed for noise alone). Period sets whose finest /
    coarsest count ratio is below MULTIPATH_MIN_SPREAD (e.g. heterodyne (70, 64, 59)) have no
    coarse pattern to compare with: nothing is removed. Not caught: a pixel that sees *only* a
    mirror image of a lit surface (every frequency sharp, one path): a ghost in real scanners too.

    modulation: (F, H, W) per frequency; offset: (H, W) mean A; noise_sigma: a number, an (H, W)
    array or a callable sigma(signal) such as SensorModel.noise_sigma."""
    per = np.asarray(periods, dtype=np.float64)
    valid = np.asarray(valid, bool)
    if per.max() / per.min() < MULTIPATH_MIN_SPREAD:
        return np.zeros(valid.shape, bool)
    B = np.asarray(modulation)
    sig = noise_sigma(np.maximum(np.asarray(offset, np.float64), 0)) if callable(noise_sigma) else noise_sigma
    sigma_b = np.sqrt(2.0 / int(steps)) * np.asarray(sig, np.float64)
    with np.errstate(invalid="ignore"):
        return valid & (B.min(axis=0) < ratio * B.max(axis=0) - sigmas * np.sqrt(1.0 + ratio * ratio) * sigma_b)
