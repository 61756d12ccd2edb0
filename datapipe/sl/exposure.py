"""Exposure control as structured-light scanners do it: auto exposure and HDR fusion (pure numpy).

The sensor model (:mod:`.sensor`) turns *linear* radiance into digital numbers, so an exposure is
just a scale on the radiance before it: one Cycles render serves every exposure, and an HDR
sequence costs sensor-model work only, not rendering.

Auto exposure (:func:`auto_exposure`)
    Real scanners meter the projected pattern itself. Here: per pixel the peak of the fringe stack
    (A + B: ambient + projector), over the pixels the projector visibly modulates (peak - trough
    >= ``LIT_SWING`` x peak: ambient-only pixels do not count); the ``AUTO_PERCENTILE`` of those
    peaks is put at ``AUTO_TARGET`` of the full well. With 99 / 0.8 at most ~1% of the lit pixels
    can clip, and the metered pixels keep a 20% margin (the shot noise at 80% of a 10 ke- well
    is 1%, so they do not reach the well by noise). A scene too dark to meter falls back to
    ``FALLBACK_EXPOSURE``; the result is clamped to ``EXPOSURE_LIMITS`` (a real exposure-time
    range spans ~1000x, Mech-Mind 0.1-99 ms).

HDR (:func:`capture` with several exposures)
    Every exposure gets the sensor model with its own noise (independent random streams of one
    seed). Fusion is per pixel, as multi-exposure scanners do it: the highest exposure in which the
    pixel decodes (signal grows as the exposure, noise at most as its square root, so that is the
    highest-SNR usable one), rescaled to the units of the *reference* exposure (DN at the base
    exposure), with that exposure's noise sigma rescaled the same way. "Decodes": with `steps`
    given, every group of `steps` images (one fringe frequency) keeps >= 3 unclipped samples --
    the decoder fits the phase without the clipped ones, which keep the fused saturation level so
    it knows them; without `steps`, no sample may clip. Moving a pixel with one clipped sample to
    a 4x shorter exposure would cost it 2-4x its SNR. Pixels saturated in every exposure keep the
    lowest one; the fused saturation level (the lowest exposure's, rescaled) is the highest of all.
    One exposure: no fusion work at all (the sensor model's own output, byte for byte).

Auto HDR (:func:`auto_hdr`, ``hdr="auto"``)
    Like a scanner's capture assistant, from the one render: auto exposure leaves ~1% of the lit
    pixels clipped, but on shiny parts those are the highlights, i.e. the parts (blooming holes).
    Shorter exposures are added (x 1/4 each, at most ``AUTO_HDR_MAX`` in all) while more than
    ``AUTO_HDR_CLIP`` of the lit pixels would still clip; a scene with fewer keeps its single
    exposure and costs nothing more. Longer exposures are not added: at the fused images' lower
    noise the coarse fringes' multipath bias becomes significant and dark parts lost more to
    INCONSISTENT than they gained (benchmarks/results/sl_materials.md).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

from ._errors import bad_value
from .sensor import SensorModel

__all__ = ["AUTO_PERCENTILE", "AUTO_TARGET", "Capture", "ProjectorOff", "auto_exposure", "auto_hdr", "capture",
           "exposure_set", "lit_pixels", "projector_off",
           "check_exposure", "check_hdr", "exposure_problem", "hdr_problem"]

AUTO_PERCENTILE = 99.0           # % of the metered (lit) pixels' peaks ...
AUTO_TARGET = 0.8                # ... at this fraction of the full well
LIT_SWING = 0.2                  # peak - trough >= this x peak: the projector visibly modulates the pixel
DARK_FRACTION = 1e-3             # peaks below this x the brightest (99.9th percentile) are not metered
FALLBACK_EXPOSURE = 0.5          # nothing to meter (no lit pixel): the shipped fixed exposure
EXPOSURE_LIMITS = (1e-3, 1e3)    # auto exposure is clamped to this range
AUTO_HDR_CLIP = 0.002            # share of the lit pixels allowed to clip before a shorter exposure is added
AUTO_HDR_STEP = 0.25             # each added exposure is this x the previous one
AUTO_HDR_MAX = 3                 # exposures at most (Mech-Mind: 1-3; Zivid: "shiny scenes typically need 3")


def exposure_problem(value) -> tuple[str, str] | None:
    """(what is wrong, the fix) when `value` is neither a positive finite number nor 'auto'."""
    fix = 'give a number > 0 or "auto"'
    if isinstance(value, str):
        return None if value == "auto" else (f"unknown mode {value!r}", fix)
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        return f"must be a number or \"auto\", got {type(value).__name__}", fix
    if not (np.isfinite(value) and value > 0):
        return f"must be > 0, got {value!r}", fix
    return None


def hdr_problem(factors) -> tuple[str, str] | None:
    """(what is wrong, the fix) unless `factors` is None/empty, "auto" or distinct positive numbers."""
    fix = 'give relative exposure factors, e.g. [0.25, 1, 4], "auto", or leave it empty'
    if factors is None or factors == "auto":
        return None
    if isinstance(factors, str):
        return f"unknown mode {factors!r}", fix
    if not isinstance(factors, (list, tuple)):
        return f"must be a list of numbers, got {type(factors).__name__}", fix
    for i, f in enumerate(factors):
        if isinstance(f, str) or exposure_problem(f) is not None:
            return f"factor {i} ({f!r}) is not a number > 0", fix
    if len(set(factors)) != len(factors):
        return f"repeats a factor: {list(factors)}", "list each factor once"
    return None


def check_exposure(value, arg: str = "exposure") -> float | str:
    """A positive finite number (as float) or the string 'auto'; else SLValueError."""
    p = exposure_problem(value)
    if p is not None:
        raise bad_value(arg, *p)
    return value if isinstance(value, str) else float(value)


def check_hdr(factors, arg: str = "hdr") -> list[float] | str | None:
    """None (one exposure) for None/empty, "auto", else the factors as floats; SLValueError if bad."""
    p = hdr_problem(factors)
    if p is not None:
        raise bad_value(arg, *p)
    if factors == "auto":
        return "auto"
    return [float(f) for f in factors] if factors else None


def exposure_set(base: float, hdr: Sequence[float] | None) -> list[float]:
    """The absolute exposures of one capture: [base] or base x each HDR factor (in the given order)."""
    return [float(base)] if not hdr else [float(base) * float(f) for f in hdr]


def lit_pixels(radiance, ambient=None) -> tuple[np.ndarray, np.ndarray]:
    """(per-pixel fringe peak, lit mask) of an (F*N, H, W) stack: the pixels the projector visibly
    modulates, not lost in the dark (module doc). One pass over the stack, shared by auto exposure
    and auto HDR. `ambient`: the (H, W) projector-off radiance already contained in `radiance`
    (structured_light.ambient "scene"): the swing and darkness tests then compare with the
    projector's own peak (peak - ambient), so a bright hall light does not hide the lit pixels
    from the metering (with 4x the projector's peak in ambient light, swing / peak < LIT_SWING
    everywhere); the metered value stays the total peak, what clips."""
    x = np.asarray(radiance)
    if x.ndim != 3 or x.shape[0] < 2:
        raise bad_value("radiance", f"has shape {x.shape}", "pass the (F*N, H, W) fringe stack")
    peak = x.max(axis=0).astype(np.float64)
    swing = peak - x.min(axis=0)
    own = peak if ambient is None else np.maximum(peak - np.asarray(ambient, np.float64), 0.0)
    bright = np.percentile(own, 99.9) if own.size else 0.0
    lit = np.isfinite(peak) & (own > DARK_FRACTION * bright) & (swing >= LIT_SWING * own) & (bright > 0)
    return peak, lit


def auto_exposure(radiance, sensor: SensorModel, *, percentile: float = AUTO_PERCENTILE,
                  target: float = AUTO_TARGET, lit=None) -> float:
    """Exposure (scale on linear radiance) that puts the metered fringe peaks at `target` of the
    sensor's full well (see the module doc). `radiance`: the (F*N, H, W) linear fringe stack;
    `lit`: its `lit_pixels` when already known."""
    if not 0 < target <= 1:
        raise bad_value("target", f"must be in (0, 1], got {target}", "give a fraction of the full well")
    if not 0 < percentile <= 100:
        raise bad_value("percentile", f"must be in (0, 100], got {percentile}", "give a percentile")
    peak, lit = lit_pixels(radiance) if lit is None else lit
    fw = sensor.full_well
    if fw is None or not np.isfinite(fw):
        return 1.0                                  # nothing can clip: the sensor's unit exposure
    if not lit.any():
        return FALLBACK_EXPOSURE
    metered = float(np.percentile(peak[lit], percentile))
    e = target * (fw / sensor.electrons_per_unit) / metered
    return float(np.clip(e, *EXPOSURE_LIMITS))


def auto_hdr(radiance, sensor: SensorModel, base: float, *, steps: int | None = None, clip: float = AUTO_HDR_CLIP,
             step: float = AUTO_HDR_STEP, most: int = AUTO_HDR_MAX, lit=None) -> list[float]:
    """Relative exposure factors for `base` (see the module doc): [1], or [1, 1/4, ...] while more
    than `clip` of the lit pixels would not decode for clipping at the shortest exposure so far
    (`steps`: images per frequency, see `decodable`; `lit`: `lit_pixels` when already known)."""
    fw = sensor.full_well
    if fw is None or not np.isfinite(fw):
        return [1.0]
    x = np.asarray(radiance)
    _, lit = lit_pixels(x) if lit is None else lit
    if not lit.any():
        return [1.0]
    clips_at = (fw / sensor.electrons_per_unit) / float(base)      # radiance that fills the well at factor 1
    samples = x[:, lit]                                            # (n, lit pixels)
    factors = [1.0]
    while len(factors) < most and \
            float(np.mean(~decodable(samples * factors[-1] >= clips_at, steps))) > clip:
        factors.append(factors[-1] * float(step))
    return factors


@dataclass
class Capture:
    """What the camera hands the decoder: images and how to read them."""
    images: np.ndarray                            # (F*N, H, W): uint DN (one exposure) or float32 DN
                                                  # at the reference exposure (fused)
    noise_sigma: Callable | np.ndarray            # decode(noise_sigma=): sigma(signal) or (H, W) map
    saturation: float                             # decode(saturation=)
    exposures: list                               # absolute exposures used
    reference: float                              # exposure whose DN units `images` are in
    chosen: np.ndarray | None = None              # (H, W) uint8 index into `exposures` (fused only)


def _stream(seed, k: int):
    """Exposure k's random stream: exposure 0 uses the seed itself (a single exposure gives the
    sensor model's bytes for that seed), the others independent streams derived from it."""
    if k == 0:
        return seed
    base = int(seed) if not isinstance(seed, np.random.Generator) else int(seed.integers(2 ** 63))
    return np.random.default_rng(np.random.SeedSequence([base & 0xFFFFFFFFFFFFFFFF, k]))


def capture(radiance, sensor: SensorModel, exposures: Sequence[float], seed,
            reference: float | None = None, steps: int | None = None) -> Capture:
    """Apply the sensor model at each exposure and fuse (see the module doc).

    radiance: (F*N, H, W) linear, non-negative. exposures: absolute scales (> 0). reference: the
    exposure whose DN units the fused images are in (default: the first). steps: images per
    frequency (fusion keeps a pixel at an exposure where each frequency has >= 3 unclipped
    samples); None: no clipped sample allowed."""
    exposures = [float(e) for e in exposures]
    if not exposures:
        raise bad_value("exposures", "is empty", "give at least one exposure")
    for i, e in enumerate(exposures):
        check_exposure(e, f"exposures[{i}]")
    ref = exposures[0] if reference is None else float(check_exposure(reference, "reference"))
    x = np.clip(np.asarray(radiance, dtype=np.float32), 0.0, None)
    if len(exposures) == 1:
        dn, sat = sensor.apply(x * np.float32(exposures[0]), seed)
        return Capture(dn, sensor.noise_sigma, sat, exposures, exposures[0])
    return _fuse(x, sensor, exposures, seed, ref, steps)


def decodable(clipped: np.ndarray, steps: int | None) -> np.ndarray:
    """(H, W) bool from per-sample clipping (n, H, W): every group of `steps` images keeps >= 3
    unclipped samples (no clipped sample at all when `steps` is None or does not divide n)."""
    n = clipped.shape[0]
    if not steps or n % int(steps) or int(steps) < 3:
        return ~clipped.any(axis=0)
    per = clipped.reshape((n // int(steps), int(steps)) + clipped.shape[1:]).sum(axis=1)
    return (per <= int(steps) - 3).all(axis=0)


def _fuse(x, sensor: SensorModel, exposures, seed, ref: float, steps: int | None = None) -> Capture:
    """Highest unsaturated exposure per pixel, rescaled to `ref` units (one exposure in memory at
    a time besides the fused stack)."""
    black = np.float32(sensor.black_level)
    fused = np.empty(x.shape, np.float32)
    sigma = np.empty(x.shape[1:], np.float32)
    chosen = np.full(x.shape[1:], 255, np.uint8)
    order = sorted(range(len(exposures)), key=lambda k: -exposures[k])
    sat_fused = None
    for rank, k in enumerate(order):
        dn, sat = sensor.apply(x * np.float32(exposures[k]), _stream(seed, k))
        if sat_fused is None:       # the lowest exposure's level, rescaled: the highest of all
            sat_fused = (sat - black) * (ref / min(exposures)) + black if np.isfinite(sat) else np.inf
        open_ = chosen == 255
        clipped = dn >= sat if np.isfinite(sat) else None
        if rank < len(order) - 1 and clipped is not None:
            take = open_ & decodable(clipped, steps)
        else:
            take = open_                                # saturated everywhere: the lowest exposure
        if not take.any():
            continue
        scale = np.float32(ref / exposures[k])
        vals = dn[:, take].astype(np.float32)
        sigma[take] = sensor.noise_sigma(vals.mean(axis=0)) * scale
        vals = (vals - black) * scale + black
        if clipped is not None:
            vals[clipped[:, take]] = np.float32(sat_fused)     # the decoder leaves these samples out
        fused[:, take] = vals
        chosen[take] = k
    return Capture(fused, sigma, float(sat_fused), list(exposures), ref, chosen)


@dataclass
class ProjectorOff:
    """The projector-off capture (structured_light.ambient "scene"): what the camera reads with the
    projector dark, at each pixel's exposure, in the DN units of the fringe capture's reference
    exposure, black level removed, and its noise sigma (the sensor's, at that signal)."""
    signal: np.ndarray          # (H, W) float32 DN above black
    sigma: np.ndarray           # (H, W) float32 DN


def projector_off(ambient, sensor: SensorModel, cap: Capture, seed) -> ProjectorOff:
    """Take the projector-off capture of `ambient` ((H, W) linear radiance) as real scanners do
    beside the fringes (one more frame: shot, read and quantisation noise of its own, from random
    streams that no fringe capture uses), at the exposure `cap` chose for each pixel (HDR: the
    fused one), rescaled to `cap.reference` like the fused fringes."""
    x = np.clip(np.asarray(ambient, np.float32), 0.0, None)[None]
    base = int(seed) if not isinstance(seed, np.random.Generator) else int(seed.integers(2 ** 63))
    black = np.float32(sensor.black_level)
    signal = np.zeros(x.shape[1:], np.float32)
    sigma = np.zeros(x.shape[1:], np.float32)
    for k, e in enumerate(cap.exposures):
        take = np.ones(x.shape[1:], bool) if cap.chosen is None else cap.chosen == k
        if not take.any():
            continue
        rng = np.random.default_rng(np.random.SeedSequence([base & 0xFFFFFFFFFFFFFFFF, OFF_STREAM, k]))
        dn = sensor.apply(x * np.float32(e), rng)[0][0][take].astype(np.float32)
        scale = np.float32(cap.reference / e)
        sigma[take] = sensor.noise_sigma(dn) * scale
        signal[take] = (dn - black) * scale
    return ProjectorOff(signal, sigma)


OFF_STREAM = 0x0FF           # the projector-off capture's random streams: SeedSequence([seed, OFF_STREAM, k])
