"""Post-decode filters on depth maps (pure numpy), as real scanners apply them before output."""
from __future__ import annotations

import numpy as np

EDGE_SIGMAS = 5.0                # noise part of the neighbour tolerance (in combined sigmas)
EDGE_SLOPE = 3.7                 # tan(75 deg): steepest surface whose neighbours still agree
EDGE_MIN_SUPPORT = 3             # agreeing 8-neighbours a valid pixel needs


def neighbour_agreement(depth, valid, sigma_z, pixel_angle: float, *, sigmas: float = EDGE_SIGMAS,
                        slope: float = EDGE_SLOPE) -> dict:
    """{(dy, dx): (H, W) bool} for the 8 neighbour directions: valid pixel (y, x) and valid pixel
    (y + dy, x + dx) agree in depth within

        tol = sigmas * sqrt(sigma_p^2 + sigma_q^2) + slope * Z_p * pixel_angle * |q - p|

    (False where either is invalid or off the image): the edge filter's test, and what joins pixels
    into regions (sl.regions)."""
    z = np.where(valid, depth, np.nan).astype(np.float64)
    s = np.where(valid, sigma_z, np.nan).astype(np.float64)
    s = np.where(np.isfinite(s), s, 0.0)
    H, W = z.shape
    zp = np.pad(z, 1, constant_values=np.nan)
    sp = np.pad(s, 1, constant_values=0.0)
    agree = {}
    with np.errstate(invalid="ignore"):
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dx == 0 and dy == 0:
                    continue
                zq = zp[1 + dy:1 + dy + H, 1 + dx:1 + dx + W]
                sq = sp[1 + dy:1 + dy + H, 1 + dx:1 + dx + W]
                tol = sigmas * np.sqrt(s * s + sq * sq) + slope * z * pixel_angle * np.hypot(dx, dy)
                agree[(dy, dx)] = np.abs(zq - z) <= tol
    return agree


def edge_speckle_filter(depth, valid, sigma_z, pixel_angle: float, *, sigmas: float = EDGE_SIGMAS,
                        slope: float = EDGE_SLOPE, min_support: int = EDGE_MIN_SUPPORT, agree=None) -> np.ndarray:
    """Valid pixels with fewer than `min_support` agreeing 8-neighbours (see the module doc), and
    the remnants of islands that test leaves; returns the bool mask of pixels to remove. `agree`:
    `neighbour_agreement` of the same maps, where the caller has it.

    Remnants. The support test looks at all valid pixels at once, so in a small island of wrong
    points (a band of wrong fringe orders) the rim pixels lose their support and go while the
    middle one, supported by that rim, stays -- alone, with none of the pixels kept around it at
    its depth (demo render 1 in render mode: one bin-wall pixel 164 mm off among 3 removed
    neighbours at its depth and 3 kept floor pixels; benchmarks/results/sl_truth.md). A
    scanner's speckle filter removes such an island whole (OpenCV's filterSpeckles "Filters off
    small noise blobs (speckles)": https://docs.opencv.org/4.x/d9/d0c/group__calib3d.html). So a
    kept pixel is removed too when at least `min_support` of its kept 8-neighbours are valid and
    none of them agrees with it. Removing it takes no support from anyone, so one such step
    suffices. Not done instead: repeating the support test until what it keeps passes it (eroded
    0.5-2 points of correct pixels off the 16 renders of sl_truth.md, thin strips and steep walls)
    or removing every kept pixel without an agreeing kept neighbour (16-94 pixels a render,
    nearly all within 1 mm of the truth). Islands the support test keeps whole (every pixel with
    3 agreeing neighbours) are `bounce_island_filter`'s."""
    if agree is None:
        agree = neighbour_agreement(depth, valid, sigma_z, pixel_angle, sigmas=sigmas, slope=slope)
    H, W = np.shape(depth)
    support = np.zeros((H, W), np.int32)
    for a in agree.values():
        support += a
    valid = np.asarray(valid, bool)
    removed = valid & (support < min_support)
    kept = np.pad(valid & ~removed, 1)
    kept_agree = np.zeros((H, W), np.int32)
    kept_near = np.zeros((H, W), np.int32)
    for (dy, dx), a in agree.items():
        k = kept[1 + dy:1 + dy + H, 1 + dx:1 + dx + W]
        kept_agree += a & k
        kept_near += k
    removed |= valid & ~removed & (kept_agree == 0) & (kept_near >= min_support)
    return removed


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


# -- global-light filter: direct vs global light ---------------------------------------------------
GLOBAL_MAX_RATIO = 0.7           # global / direct light above this: the bounce may decide the coarse phases
GLOBAL_SIGMAS = 3.0              # noise margin of that test, in sigmas
DIRECT_MAX_GAIN = 0.5            # frequencies a bounce keeps less modulation of than this read the direct light


def direct_frequencies(periods, proj_width: int) -> np.ndarray:
    """(F,) bool: the frequencies whose modulation a diffuse bounce blurs to below DIRECT_MAX_GAIN
    (sl.fringe_synth.indirect_gain: 8 and 64 periods of (1, 8, 64) on a 912 px projector keep 21%
    and 0%); the finest always counts."""
    from .fringe_synth import indirect_gain

    per = np.asarray(periods, np.float64)
    out = np.array([indirect_gain(K, int(proj_width)) < DIRECT_MAX_GAIN for K in per])
    out[np.argmax(per)] = True
    return out


def direct_offset_ratio(projector_gamma: float = 1.0, steps: int = 4) -> float:
    """Offset / modulation (A / B) that direct light alone gives an N-step decode of patterns
    (1/2 + 1/2 cos)^gamma: 1 for a linear projector; otherwise the profile's mean over its first
    harmonic as `steps` samples see it (the harmonics alias into it and make it depend on the
    phase: the largest value over the phase, so direct light is never taken for global light;
    gamma 2.2, 4 steps: 0.74, gamma 0.25: 3.3). Global light gets the mean only."""
    from .patterns import phase_shifts

    if float(projector_gamma) == 1.0:
        return 1.0
    d = np.asarray(phase_shifts(int(steps)), np.float64)
    phi = np.linspace(0.0, 2.0 * np.pi, 720, endpoint=False)[:, None]
    p = (0.5 + 0.5 * np.cos(phi + d[None, :])) ** float(projector_gamma)
    B = 2.0 / d.size * np.abs((p * np.exp(1j * d[None, :])).sum(axis=1))
    return float(np.max(p.mean(axis=1) / B))


def global_light_filter(modulation, offset, direct_freqs, steps: int, noise_sigma, valid, *,
                        max_ratio: float = GLOBAL_MAX_RATIO, sigmas: float = GLOBAL_SIGMAS,
                        direct_offset: float = 1.0, ambient=None, ambient_sigma=None) -> np.ndarray:
    """Pixels that receive more light over other paths (inter-reflection) than straight from the
    projector, so that the bounce decides their coarse phases and fringe order; returns the bool
    mask of pixels to remove.

    Why this test (direct/global separation, Nayar et al. 2006): with patterns a + b cos (a = b =
    1/2) a pixel's offset is A = (d + g) / 2 (d direct, g global light) whatever the frequency,
    while a fringe that a bounce blurs away (`direct_freqs`) keeps only the direct light's
    modulation, B = d / 2 (times the pixel's footprint MTF, ~1 at 8 periods). So g / d = (A - B) /
    B. Coarse fringes survive a bounce (1 period on 912 px: 98%), and a bounce phasor of relative
    size g_K g / d shifts the coarse phase by up to asin(g_K g / d); the unwrapping stage 1 -> 8
    fails beyond pi / 8 (g / d > 0.39 in the worst phase, which cost 10-19% of the correct part
    pixels; measured bounce phasors are mostly not in quadrature). On 16 real renders of bins
    (benchmarks/results/sl_truth.md: the demo's wall lit at grazing incidence with floor light
    bounced onto it, the original rig, metal parts) the limit 0.7 left at most 0.05% of the valid
    pixels more than 5 mm off away from depth edges (1.0: 0.08%, 0.5: 0.01%) for 0.8 points of
    the correct part pixels (0.5: 3.3 points). A pixel lit *only* by bounced light has B = g_K g / 2, so g / d =
    1 / g_K - 1 >= 1 and is removed too (a projector-shadowed wall). The multipath filter's
    ratio test misses both: the wall's fine and coarse modulations differ by less than its 0.6.

    Ambient light (structured_light.ambient "scene": the hall's lights in every frame) raises A
    as global light does and leaves every B alone (a constant in all N samples is the DC term of
    the least-squares fit, sl/phase.py), so A alone cannot tell a hall light from bounced projector
    light. Real scanners take a projector-off capture for this; `ambient` is that capture (DN
    above black, in the offset's units: sl.exposure.projector_off) and is taken off A first, its
    noise `ambient_sigma` added to sigma_A below. Without it (None) A is the projector's light alone,
    as the fringe renders without ambient light hold.

    With a projector gamma the emitted profile's mean and first harmonic differ: direct light
    alone has A / B = `direct_offset` (`direct_offset_ratio`), and g / d = A / (direct_offset B) - 1.
    A valid pixel is removed when

        A - (1 + max_ratio) c B > sigmas * sqrt((1 + max_ratio)^2 c^2 sigma_B^2 + sigma_A^2),  c = direct_offset,

    B = max over `direct_freqs` of B_K, sigma_B = sqrt(2/N) sigma_I, sigma_A = sigma_I / sqrt(F N)
    (dark pixels are not removed for noise alone; sigma_I at the full offset, ambient included,
    and with `ambient` sigma_A^2 + ambient_sigma^2). modulation: (F, H, W); offset: (H, W) mean A;
    direct_freqs: (F,) bool (`direct_frequencies`); noise_sigma: a number, an (H, W) array or a
    callable sigma(signal) such as SensorModel.noise_sigma."""
    B = np.asarray(modulation)
    sel = np.asarray(direct_freqs, bool)
    Bd = B[sel].max(axis=0).astype(np.float64)
    A = np.asarray(offset, np.float64)
    sig = noise_sigma(np.maximum(A, 0)) if callable(noise_sigma) else noise_sigma
    sig = np.asarray(sig, np.float64)
    k = (1.0 + float(max_ratio)) * float(direct_offset)
    if ambient is None:
        tol = sigmas * sig * np.sqrt(k * k * 2.0 / int(steps) + 1.0 / (B.shape[0] * int(steps)))
    else:                     # the projector-off capture's own noise adds to that of A
        A = A - np.asarray(ambient, np.float64)
        s_off = np.asarray(ambient_sigma if ambient_sigma is not None else 0.0, np.float64)
        tol = sigmas * np.sqrt(sig * sig * (k * k * 2.0 / int(steps) + 1.0 / (B.shape[0] * int(steps)))
                               + s_off * s_off)
    with np.errstate(invalid="ignore"):
        return np.asarray(valid, bool) & (A - k * Bd > tol)


def global_direct_ratio(modulation, offset, direct_freqs, *, direct_offset: float = 1.0, ambient=None) -> np.ndarray:
    """Global / direct light per pixel, g / d = (A - c B) / (c B) (float64; NaN where B <= 0): the
    quantity `global_light_filter` tests, without its noise margin (same arguments)."""
    B = np.asarray(modulation)[np.asarray(direct_freqs, bool)].max(axis=0).astype(np.float64) * float(direct_offset)
    A = np.asarray(offset, np.float64)
    if ambient is not None:
        A = A - np.asarray(ambient, np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(B > 0, (A - B) / B, np.nan)


# -- bounce islands: small regions where bounced light can decide the order -------------------------
ISLAND_PIXELS = 20               # px: regions smaller than this (at 320 x 240, scaled with the image area)
ISLAND_REFERENCE_PIXELS = 320 * 240   # the image size ISLAND_PIXELS was measured at
ISLAND_GLOBAL_RATIO = 0.45       # mean g / d above which a region's bounce may have decided its order (doc below)


def island_pixels(shape) -> int:
    """The region size below which `bounce_island_filter` removes a region, for an (H, W) image:
    ISLAND_PIXELS at 320 x 240, scaled with the image area above it (a region of the scene is
    judged alike at any resolution: 540 px at 1920 x 1080), never fewer than ISLAND_PIXELS (an
    island made by per-pixel noise does not shrink with the image)."""
    H, W = shape
    return max(ISLAND_PIXELS, int(round(ISLAND_PIXELS * H * W / ISLAND_REFERENCE_PIXELS)))


def bounce_island_filter(keep, agree, global_ratio, *, max_pixels: int | None = None,
                         ratio: float = ISLAND_GLOBAL_RATIO) -> np.ndarray:
    """Small regions of kept pixels in bounced light: islands of wrong fringe orders; returns the
    bool mask of pixels to remove.

    Why. Where bounced light is a large share of a pixel's light (a bin wall lit at grazing
    incidence beside a bright floor; an aluminium peg beside its highlight) it keeps the coarse
    fringe (98% of the 1-period modulation) and turns the coarse phase: a bounce phasor of relative
    size 0.98 g / d turns it by up to asin(0.98 g / d), past the 1 -> 8 stage's pi / 8 from g / d =
    0.39 on. The decoder cannot see that (the frequencies fit the wrong order as well as the
    right one: confidence ~1); the global-light filter keeps such pixels up to g / d = 0.7 plus its
    noise margin (~0.4 more at 60 DN of modulation); and neighbours wrong by the same whole fringe
    keep each other in the edge filter. What is left is a small region one 8-period fringe
    (100-330 mm) off the surface around it, in light that is about half bounce or more. A real
    scanner with (1, 8, 64) fringes decodes the same wrong orders where the bounce's own bias is
    near the limit (aluminium parts at 0.6 m path-traced at 64 paths per pixel: 29 such pixels, a
    1-2 px band along a peg's highlight and a wall corner), and its speckle filter removes small
    regions (module `sl.regions`). Removed: the kept pixels of regions (`sl.regions.region_labels`
    over `keep` and `agree`) of fewer than `max_pixels` pixels (`island_pixels` of the image when
    None) whose mean g / d is above `ratio` (the mean: one pixel's g / d carries noise, 0.15 at
    40 DN of modulation, and most islands have 1-6 pixels). Small regions in direct light (a
    sparse wall in good light, a thin part edge) stay.

    The numbers, from the 16 renders of benchmarks/results/sl_truth.md, the aluminium case at 16
    and 64 paths per pixel and the metal cases at 640 x 480: 20 px removed every pixel > 5 mm off
    away from depth edges that lay in a region of 1-15 pixels at 320 x 240 (12 px left 15 pixels of
    the band in the 64-path render; 30 px removed the same). `ratio`: 0.39 (the worst-case bound
    above) cost up to 0.64 points of the parts' pixels within 1 mm (steel, 640 x 480); 0.45 up to
    0.49 (aluminium, fast mode) and left 3 of the 47 wrong-order pixels of aluminium in render mode
    at 640 x 480; the majority of pixels above 0.5 up to 0.42 and left 11 of them.

    keep: (H, W) bool, the pixels kept so far; agree: `neighbour_agreement`; global_ratio: (H, W)
    g / d (`global_direct_ratio`)."""
    from .regions import region_labels

    keep = np.asarray(keep, bool)
    n = island_pixels(keep.shape) if max_pixels is None else int(max_pixels)
    labels, sizes = region_labels(keep, agree)
    g = np.asarray(global_ratio, np.float64)[keep]
    total = np.bincount(labels[keep], weights=np.where(np.isfinite(g), g, 0.0), minlength=int(labels.max()) + 1)
    return keep & (sizes < n) & (total[labels] > float(ratio) * sizes)     # the region's mean g / d


# -- global reflection filter: row-coded patterns (epipolar consistency) ----------------------------
ROW_SIGMAS = 5.0                 # noise part of the row tolerance, in sigmas of the decoded row
ROW_MIN_PX = 2.0                 # projector px always allowed (benchmarks/results/sl_materials.md)


def row_from_phase(row_phase, proj_height: int, periods: float = 1.0) -> np.ndarray:
    """Projector row (pixel centres at integers) coded by `periods` periods of row fringes over
    the projector height (`fringe_patterns(axis='y')`): y = phase / 2 pi * height / periods, known
    modulo one period (height / periods rows)."""
    return np.asarray(row_phase, np.float64) * (float(proj_height) / float(periods) / (2.0 * np.pi))


def projector_rows(points_cam, P_proj_cam) -> np.ndarray:
    """Rows at which the projector sees camera-frame points (H, W, 3): NaN where a point is NaN
    or behind the projector."""
    X = np.asarray(points_cam, np.float64)
    P = np.asarray(P_proj_cam, np.float64)
    w = X @ P[2, :3] + P[2, 3]
    with np.errstate(invalid="ignore", divide="ignore"):
        y = (X @ P[1, :3] + P[1, 3]) / w
    return np.where(w > 0, y, np.nan)


def row_residual(measured_row, predicted_row, period: float) -> np.ndarray:
    """Signed difference measured - predicted row, wrapped to [-period/2, period/2) (the row code
    repeats every `period` = height / periods rows)."""
    p = float(period)
    return np.mod(np.asarray(measured_row, np.float64) - predicted_row + p / 2.0, p) - p / 2.0


def reflection_filter(residual, row_modulation, proj_height: int, steps: int, noise_sigma, valid, *,
                      periods: float = 1.0, checkable=None, sigmas: float = ROW_SIGMAS,
                      min_px: float = ROW_MIN_PX) -> np.ndarray:
    """Pixels whose light left the projector from another row than the row at which the projector
    sees their decoded point: light that reached the camera over a mirror path (the scanners'
    global "reflection filter"); returns the bool mask of pixels to remove.

    Why this test: vertical fringes code only the projector column, so a pixel that sees only a
    mirror image of a lit surface point W decodes W's column, every frequency sharp and
    consistent, and triangulates a ghost G on its own camera ray (multipath_filter cannot see it:
    one path). G lies in W's column plane but, unless the mirror keeps the light in the pixel's
    epipolar plane, not on W's projector ray: the row the projector sees G at differs from W's row,
    which `periods` periods of row fringes (`steps` extra patterns) measure. Direct light always
    agrees (G = W). The row code is *fine* on purpose, and unwrapped by the prediction (only the
    residual within one period matters): a diffuse bounce averages a fine pattern away (Nayar et
    al. 2006), so inter-reflected light in a bin does not bias it -- one period over the height
    kept 94% of its modulation after a bounce, and its bias removed 2-7% of the correct pixels of
    the bin scenes at any useful tolerance (benchmarks/results/sl_materials.md). Not caught: a
    ghost whose row mismatch is within the tolerance of a whole number of periods (probability
    ~ 2 tol periods / height: 5-10% at 8 periods), and, by any single projector-camera check, mirror
    paths inside the epipolar plane (the ghost lies on W's projector ray).

    A valid pixel is removed when |row measured - row predicted| (wrapped to one period) exceeds

        tol = sqrt((sigmas * sigma_y)^2 + min_px^2),  sigma_y = H_proj / (2 pi periods) * sqrt(2/N) * sigma_I / B_row

    (the least-squares phase noise of the row code). Pixels whose row code cannot be read
    (`checkable` False: saturated, invalid) are kept.

    residual: (H, W) `row_residual` of the measured row (`row_from_phase` of the row code's wrapped
    phase) and the predicted one (`projector_rows`), NaN where unknown; row_modulation: (H, W) the
    row code's modulation; noise_sigma: the sensor noise of one sample at each pixel (a number or
    an (H, W) array, image units)."""
    valid = np.asarray(valid, bool)
    B = np.asarray(row_modulation, np.float64)
    sig = np.asarray(noise_sigma, np.float64)
    period = float(proj_height) / float(periods)
    with np.errstate(invalid="ignore", divide="ignore"):
        sigma_y = period / (2.0 * np.pi) * np.sqrt(2.0 / int(steps)) * sig / B
        tol = np.sqrt((sigmas * sigma_y) ** 2 + float(min_px) ** 2)
        res = np.abs(np.asarray(residual, np.float64))
        bad = res > tol
    ok = np.isfinite(res) & np.isfinite(tol) & (B > 0)
    if checkable is not None:
        ok &= np.asarray(checkable, bool)
    return valid & ok & bad
