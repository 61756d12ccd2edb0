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
