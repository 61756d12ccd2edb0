"""The structured-light scanner as one pure pipeline: linear radiance of the fringe images ->
exposure (fixed / auto / HDR) -> sensor model (seeded) -> decode -> multipath, projector-border and
edge/speckle filters -> maps.

No Blender: the Blender side (core/structured_light.py) renders the fringe radiance and hands it
here; tests and benchmarks feed synthetic or saved radiance the same way.

    scanner = Scanner.from_config(cfg)                       # or Scanner(periods, steps, ...)
    scan = scanner.scan(radiance, seed, K_cam, T_world_cam)  # -> Scan: .result (DecodeResult), .sigma_z, ...
    scan.maps(debug=False)   # {"sl_depth": {"Z": ...}, "sl_valid": uint8, ["sl_debug": channels]}
    scan.summary()           # what scene.json records: unwrap method, valid fraction, reason counts, ...

Validity (what "valid" means)
-----------------------------
0. exposure (`sl.exposure`): a fixed number, or "auto" (the default): metered per render from the
   fringe radiance (99th percentile of the lit pixels' peaks at 80% of the full well); with `hdr`
   factors one sensor-model capture per exposure (independent noise), fused per pixel (highest
   unsaturated exposure, rescaled, with its noise); `hdr="auto"` adds shorter exposures per render
   while highlights clip (`sl.exposure.auto_hdr`). `Scan.exposure` is the base exposure used, the
   summary's `hdr` the factors used.
0'. ambient light (`scan(ambient=...)`, structured_light.ambient "scene"): the scene's own lights
   with the projector off, added to every image before 0. (its shot noise and clipping; exposure
   and HDR meter the sum), and taken once more as a projector-off capture that 1b'. subtracts.
1. decoder: modulation above the sensor-noise floor, consistent fringe orders, not saturated. The
   noise is the sensor model's own, per pixel (shot + read + quantisation at the pixel's signal and
   exposure; with HDR the fused exposure's, rescaled), never a global estimate from the images
   (`DecodeResult.extras["noise_model"]` says so).
   Contrast B/A >= MIN_CONTRAST = 0.05 is only a sanity floor: ambient light (the key light on a
   part) lowers B/A without harming the phase; a fixed 0.5 discarded lit parts near the camera.
1b. multipath / reflection filter (`sl.filters.multipath_filter`, reason MULTIPATH = 8): the
   frequencies' modulations disagree beyond the noise (min_K B_K < 0.6 max_K B_K): light of a
   second path pulls the coarse phase and so the fringe order (e.g. the projector's shadow next to
   a bin wall, lit by the wall). On the demo bin it removes what B/A >= 0.5 removed, without
   punishing ambient light (benchmarks/results/sl_materials.md).
1b'. global-light filter (`sl.filters.global_light_filter`, reason MULTIPATH too): more light
   over other paths than straight from the projector (offset - modulation of the frequencies a
   bounce blurs away > 0.7 x that modulation): the bounce keeps the coarse fringes and decides the
   order (a bin wall lit at grazing incidence beside a bright floor; a surface lit by bounced light
   alone). Runs with the multipath filter (benchmarks/results/sl_truth.md).
1c. global reflection filter (`sl.filters.reflection_filter`, reason REFLECTION = 10): only when
   the radiance stack carries `steps` row-coded images after the F*N fringe images (ROW_PERIODS
   periods of row fringes over the projector height; the Blender side renders them when
   `structured_light.reflection_filter` is "global", or "auto" on a scene with shiny surfaces):
   the projector row the row code measures must be the row the projector sees the decoded point
   at. A pixel that sees only a mirror image of a lit surface decodes a consistent but wrong
   column (a ghost point); its light left the projector from another row. Mirror paths inside the
   pixel's epipolar plane keep the row and stay (no single projector-camera check sees them).
2. projector border: pixels within BORDER_PX camera pixel of the projector image's left/right
   edge (their sub-samples straddle the edge of the lit area).
3. edge / speckle filter (`sl.filters.edge_speckle_filter`): a camera pixel that straddles a depth
   edge mixes the fringes of both surfaces and, where the mixture unwraps consistently, decodes to
   a depth between them (a "flying pixel"); multi-path light can shift a few pixels by whole
   fringes. A valid pixel needs EDGE_MIN_SUPPORT of its 8 neighbours to agree within

    tol_pq = EDGE_SIGMAS * sqrt(sigma_p^2 + sigma_q^2) + EDGE_SLOPE * Z_p * pixel_angle * |q - p|

   (`sigma` the per-pixel theoretical depth noise, `pixel_angle` = 1/f_camera [rad per px]); and a
   pixel that test keeps alone among at least EDGE_MIN_SUPPORT kept neighbours, none agreeing with
   it: the middle of a small island of wrong orders whose rim the test removed.
Pixels removed by 2. and 3. get reason FILTERED (7), depth NaN.
4. bounce islands (`sl.filters.bounce_island_filter`, with the multipath filter; reason MULTIPATH):
   of what 3. kept, regions of agreeing pixels (`sl.regions`) smaller than 20 px at 320x240 (the
   same share of a larger image) whose light is about half bounce or more (mean g / d > 0.45, the
   global-light filter's measure): islands of wrong fringe orders whose coarse
   phase the bounce turned, which 1b'. (0.7 and a noise margin) and 3. (they agree with each
   other) leave (benchmarks/results/sl_truth.md: aluminium parts at 0.6 m).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..geometry import T_cam_proj, projection_matrix, projector_intrinsics
from ._errors import bad_value
from .decode import decode
from .decode_result import DecodeResult, Reason
from .exposure import (Capture, ProjectorOff, auto_exposure, auto_hdr, capture, check_exposure, check_hdr, exposure_set,
                       lit_pixels, projector_off)
from .filters import (bounce_island_filter, direct_frequencies, direct_offset_ratio, edge_speckle_filter,
                      global_direct_ratio, global_light_filter, multipath_filter, neighbour_agreement, projector_rows,
                      reflection_filter, row_from_phase, row_residual)
from .gamma import correct_cycles, gamma_phase_lut
from .gray_image import fringe_mean
from .metrics import pixel_depth_sigma
from .patterns import fringe_patterns, phase_shifts
from .phase import phase_shift
from .sensor import SensorModel
from .triangulate import Triangulator
from .unwrap import UnwrapPlan, as_plan

MIN_CONTRAST = 0.05              # decode(min_contrast=): a sanity floor; global light is the multipath filter's
BORDER_PX = 1.0                  # camera px kept free at the projector image's left/right border
FILTERED = int(Reason.FILTERED)  # reason code of pixels removed by the border and edge/speckle filters
MULTIPATH = int(Reason.MULTIPATH)  # reason code of pixels removed by the multipath filter
REFLECTION = int(Reason.REFLECTION)  # reason code of pixels removed by the global reflection filter
ROW_PERIODS = [8]                # the row code: 8 periods over the projector height, unwrapped by the
                                 # decoded point's predicted row (sl.filters.reflection_filter)


@dataclass
class RowCode:
    """The global reflection filter's row code, read: what `reflection_filter` tests."""
    residual: np.ndarray        # float32 projector rows, measured - predicted (one period), NaN unknown
    modulation: np.ndarray      # the row code's modulation
    noise_sigma: np.ndarray     # sensor noise of one sample per pixel
    readable: np.ndarray        # bool: enough unclipped, finite samples


@dataclass
class Scan:
    """One scan: the decoder's result after the filters, and what it took."""
    result: DecodeResult        # depth (m, NaN = no data), valid, reason, phases, ...
    sigma_z: np.ndarray         # per-pixel theoretical depth sigma (m), NaN where invalid
    filtered: np.ndarray        # bool: removed by the border / edge / speckle filters
    P_cam: np.ndarray
    P_proj: np.ndarray
    sensor: SensorModel
    seconds: float              # wall time of sensor model + decode + filters
    capture: Capture | None = None   # the exposures used (.exposures, .reference = base, .chosen per pixel)
    exposure_mode: str = "fixed"     # "fixed" or "auto"
    multipath: np.ndarray | None = None   # bool: removed by the multipath filter
    reflection: np.ndarray | None = None  # bool: removed by the global reflection filter (None: no row code)
    row_residual: np.ndarray | None = None  # float32 projector rows, measured - predicted (row code only)
    ambient: ProjectorOff | None = None   # the projector-off capture (scan(ambient=...) only)

    @property
    def exposure(self) -> float:
        """The base exposure used (auto: the metered one)."""
        return float(self.capture.reference) if self.capture is not None else float("nan")

    def maps(self, debug: bool = False) -> dict:
        """The per-render outputs by kind (the native layout names their files): depth channels,
        the 8-bit validity image and, with `debug`, the decoder's intermediate channels."""
        res = self.result
        out = {"sl_depth": {"Z": res.depth}, "sl_valid": res.valid.astype(np.uint8) * 255}
        if debug:
            ch = {"phase": res.phase, "offset": res.offset, "proj_x": res.proj_x,
                  "reason": res.reason.astype(np.float32), "order_error": res.order_error,
                  "confidence": res.confidence, "sigma_z": self.sigma_z.astype(np.float32)}
            if self.row_residual is not None:      # why a pixel is REFLECTION: its row code disagrees
                ch["row_residual"] = self.row_residual
            if self.ambient is not None:           # the projector-off capture (DN above black)
                ch["ambient"] = self.ambient.signal
            for k, (w, m) in enumerate(zip(res.wrapped, res.modulation)):
                ch[f"wrapped_{k}"], ch[f"modulation_{k}"] = w, m
            out["sl_debug"] = ch
        return out

    def gray(self) -> np.ndarray:
        """The scanner's grey image: the mean of the captured column-fringe frames (sl.gray_image)."""
        n = len(self.result.periods) * int(self.result.steps)
        return fringe_mean(self.capture.images, n, self.sensor.adc_bits)

    def summary(self) -> dict:
        res = self.result
        cap = self.capture
        factors = [e / cap.reference for e in cap.exposures] if cap is not None and len(cap.exposures) > 1 else []
        out = {"unwrap": res.method, "valid_fraction": float(res.valid.mean()),
               "reasons": res.reason_counts(),
               "median_sigma_z": _nanmedian(self.sigma_z), "exposure": self.exposure,
               "exposure_mode": self.exposure_mode, "hdr": [float(f) for f in factors],
               "reflection_filter": ("global" if self.reflection is not None
                                     else "local" if self.multipath is not None else "off")}
        if self.ambient is not None:       # only with ambient light: a scan without it keeps its record
            out["ambient_to_projector"] = self.ambient_to_projector()
        return out

    def ambient_to_projector(self) -> float | None:
        """Median over the valid pixels of the projector-off signal over the projector's own mean
        light (offset - black - ambient: half its peak with patterns 1/2 + 1/2 cos); None
        without a projector-off capture or a valid pixel."""
        if self.ambient is None:
            return None
        v = self.result.valid
        own = self.result.offset[v].astype(np.float64) - self.sensor.black_level - self.ambient.signal[v]
        with np.errstate(divide="ignore", invalid="ignore"):
            return _nanmedian(np.where(own > 0, self.ambient.signal[v] / own, np.nan))


class Scanner:
    """Fringe radiance -> depth, as a real structured-light sensor does it (see the module doc).

    `K_proj`, `T_cam_proj`: the projector's intrinsics and its pose in the camera frame (OpenCV);
    `sensor`: a SensorModel or a preset name; `exposure`: gain on the radiance before the sensor,
    or "auto"; `hdr`: relative exposure factors fused per pixel (empty: one exposure), or "auto"
    (shorter exposures added per render while highlights clip: sl.exposure.auto_hdr);
    `multipath_filter`: the local reflection filter; `row_check`: the global one, applied when
    the radiance carries the row-coded images (`row_images`); `unwrap`: a method name or the
    periods' UnwrapPlan made beforehand (a run's FringePlan), planned once here for every scan."""

    def __init__(self, periods: Sequence[float], steps: int, proj_size: tuple[int, int], K_proj, T_cam_proj_, *,
                 unwrap: str | UnwrapPlan = "auto", sensor: SensorModel | str = "industrial", exposure: float | str = "auto",
                 hdr: Sequence[float] | str = (), min_contrast: float = MIN_CONTRAST, border_px: float = BORDER_PX,
                 edge_filter: bool = True, multipath_filter: bool = True, row_check: bool = True,
                 projector_gamma: float = 1.0, camera_pixels=None):
        self.periods, self.steps = list(periods), int(steps)
        self.proj_size = tuple(int(v) for v in proj_size)
        self.K_proj = np.asarray(K_proj, dtype=np.float64)
        self.T_cam_proj = np.asarray(T_cam_proj_, dtype=np.float64)
        self.unwrap_plan = as_plan(self.periods, unwrap)   # refuses an ambiguous period set before any render
        self.unwrap = unwrap if isinstance(unwrap, str) else unwrap.method    # the method as configured
        self.sensor = SensorModel.preset(sensor) if isinstance(sensor, str) else sensor
        self.exposure = check_exposure(exposure)
        self.hdr = check_hdr(hdr if isinstance(hdr, str) else list(hdr)) or []
        self.multipath_filter = bool(multipath_filter)
        self.row_check = bool(row_check)
        self.min_contrast = float(min_contrast)
        self.border_px = float(border_px)
        self.edge_filter = bool(edge_filter)
        self.projector_gamma = float(projector_gamma)     # the decoder corrects its phase ripple
        # a distorting camera lens: each pixel's ideal (undistorted) coordinates, (H, W, 2); the decoder
        # triangulates their rays (datapipe.lens.RenderGrid.ideal_pixels); None: a pinhole camera
        self.camera_pixels = camera_pixels

    @classmethod
    def from_config(cls, cfg, **overrides) -> "Scanner":
        """The scanner a Config describes (structured_light + projector sections)."""
        s = cfg.structured_light
        kw = dict(unwrap=s.unwrap, sensor=s.sensor, exposure=s.exposure, hdr=s.hdr, projector_gamma=s.projector_gamma,
                  multipath_filter=s.reflection_filter != "off", row_check=s.reflection_filter != "off")
        grid = _lens_grid(cfg)
        if grid is not None:
            kw["camera_pixels"] = grid.ideal_pixels()
        kw.update(overrides)
        return cls(s.periods, s.steps, cfg.projector.resolution, projector_intrinsics(cfg), T_cam_proj(cfg), **kw)

    def projector_matrix(self, T_world_cam) -> np.ndarray:
        """P_proj (3x4) for the camera pose `T_world_cam` (OpenCV)."""
        T_world_proj = np.asarray(T_world_cam, dtype=np.float64) @ self.T_cam_proj
        return self.K_proj @ np.linalg.inv(T_world_proj)[:3]

    @property
    def n_fringe(self) -> int:
        """Images of the column-coded fringes (F*N); a stack may carry `row_images` more."""
        return len(self.periods) * self.steps

    @property
    def row_images(self) -> int:
        """Row-coded images the global reflection filter reads (after the fringe images)."""
        return len(ROW_PERIODS) * self.steps

    def row_patterns(self, gamma: float = 1.0) -> np.ndarray:
        """The row code as projector images ((N, H_proj, W_proj) float32), for the Blender side."""
        Wp, Hp = self.proj_size
        return fringe_patterns(Wp, Hp, ROW_PERIODS, self.steps, axis="y", gamma=gamma)

    def scan(self, radiance, seed: int, K_cam, T_world_cam, ambient=None) -> Scan:
        """(F*N, H, W) linear radiance (frequency-major) seen from `T_world_cam` -> Scan. With
        `row_images` more images after them (the row code), the global reflection filter runs.

        `ambient`: (H, W) linear radiance of the scene's own lights with the projector off
        (structured_light.ambient "scene"; None: the projector's light alone). Light is linear, so
        it is added to every image before exposure and sensor (its shot noise, its clipping; auto
        exposure and HDR meter the sum), and taken once more as the projector-off capture real
        scanners take, which the global-light filter subtracts from the offset."""
        t0 = time.perf_counter()
        model = self.sensor
        radiance = np.clip(np.asarray(radiance, dtype=np.float32), 0.0, None)
        n = self.n_fringe
        if radiance.ndim != 3 or radiance.shape[0] not in (n, n + self.row_images):
            raise bad_value("radiance", f"has shape {radiance.shape}",
                            f"pass the {n} fringe images (frequency-major), optionally followed by the "
                            f"{self.row_images} row-coded images")
        if ambient is not None:
            ambient = np.clip(np.asarray(ambient, dtype=np.float32), 0.0, None)
            if ambient.shape != radiance.shape[1:]:
                raise bad_value("ambient", f"has shape {ambient.shape}",
                                f"pass one (H, W) = {radiance.shape[1:]} projector-off image")
            radiance += ambient[None]       # np.clip made `radiance` our own copy
        lit = lit_pixels(radiance[:n], ambient) if "auto" in (self.exposure, self.hdr) else None   # one metering pass
        base = auto_exposure(radiance[:n], model, lit=lit) if self.exposure == "auto" else self.exposure
        factors = auto_hdr(radiance[:n], model, base, steps=self.steps, lit=lit) if self.hdr == "auto" else self.hdr
        cap = capture(radiance, model, exposure_set(base, factors), seed, reference=base, steps=self.steps)
        off = projector_off(ambient, model, cap, seed) if ambient is not None else None
        P_cam = projection_matrix(K_cam, T_world_cam)
        P_proj = self.projector_matrix(T_world_cam)
        tri = None
        if self.camera_pixels is not None:
            h, w = radiance.shape[1:]
            tri = Triangulator.cached(P_cam, P_proj, (w, h), self.proj_size, pixels=self.camera_pixels)
        res = decode(cap.images[:n], periods=self.periods, steps=self.steps, P_cam=P_cam, P_proj=P_proj,
                     proj_size=self.proj_size, unwrap=self.unwrap_plan, noise_sigma=cap.noise_sigma,
                     saturation=cap.saturation, min_contrast=self.min_contrast, projector_gamma=self.projector_gamma,
                     triangulator=tri, stack_checks=False)   # stack and geometry made here from one config
        res.extras["noise_model"] = {          # never a global estimate: the sensor's own per-pixel noise
            "kind": "sensor", "source": "sensor model: shot + read + quantisation at each pixel's signal"
            + (", per pixel at its HDR exposure after fusion" if cap.chosen is not None else
               f", exposure {cap.reference:.4g}")}
        sigma_z = pixel_depth_sigma(res, cap.noise_sigma, self.proj_size[0], self.steps)
        multipath = global_ratio = None
        if self.multipath_filter:
            direct = direct_frequencies(res.periods, self.proj_size[0])
            c = direct_offset_ratio(self.projector_gamma, self.steps)
            multipath = multipath_filter(res.modulation, res.offset, res.periods, self.steps, cap.noise_sigma,
                                         res.valid)
            multipath |= global_light_filter(res.modulation, res.offset, direct, self.steps, cap.noise_sigma, res.valid,
                                             direct_offset=c, ambient=None if off is None else off.signal,
                                             ambient_sigma=None if off is None else off.sigma)
            _remove(res, multipath, MULTIPATH)
            global_ratio = global_direct_ratio(res.modulation, res.offset, direct, direct_offset=c,
                                               ambient=None if off is None else off.signal)
        reflection = residual = None
        if self.row_check and cap.images.shape[0] > n:
            code = self.row_code(res, cap)
            residual = code.residual
            reflection = reflection_filter(residual, code.modulation, self.proj_size[1], self.steps, code.noise_sigma,
                                           res.valid, periods=ROW_PERIODS[0], checkable=code.readable)
            _remove(res, reflection, REFLECTION)
        filtered = np.zeros(res.valid.shape, bool)
        if self.edge_filter:
            filtered, islands = self._filter(res, sigma_z, float(np.asarray(K_cam)[0, 0]), global_ratio)
            if islands is not None:
                multipath |= islands
        sigma_z[~res.valid] = np.nan
        return Scan(res, sigma_z, filtered, P_cam, P_proj, model, time.perf_counter() - t0, cap,
                    "auto" if self.exposure == "auto" else "fixed", multipath, reflection, residual, off)

    def row_code(self, res: DecodeResult, cap: Capture) -> RowCode:
        """Read the row-coded images of `cap` (after the fringe images) against the rows at which the
        projector sees the decoded points of `res` (see the module doc)."""
        rows = phase_shift(cap.images[self.n_fringe:], saturation=cap.saturation)
        phase = rows.phase
        if self.projector_gamma != 1.0:
            lut = gamma_phase_lut(self.projector_gamma, phase_shifts(self.steps))
            phase = correct_cycles(phase / np.float32(2 * np.pi), lut) * np.float32(2 * np.pi)
        sig = cap.noise_sigma
        sig = sig(np.maximum(rows.offset.astype(np.float64), 0)) if callable(sig) else sig
        predicted = projector_rows(res.points, self.K_proj @ np.linalg.inv(self.T_cam_proj)[:3])
        Hp, K = self.proj_size[1], ROW_PERIODS[0]
        readable = ~(rows.saturated | rows.invalid)
        with np.errstate(invalid="ignore"):
            residual = row_residual(row_from_phase(phase, Hp, K), predicted, Hp / K).astype(np.float32)
        residual[~readable] = np.nan
        return RowCode(residual, rows.modulation, np.broadcast_to(np.asarray(sig, np.float64), readable.shape),
                       readable)

    def _filter(self, res: DecodeResult, sigma_z: np.ndarray, fx: float, global_ratio=None):
        """Projector-border and edge/speckle filters (removed pixels become FILTERED, NaN), then,
        given the light split `global_ratio` (g / d), the bounce-island filter on what they kept
        (MULTIPATH). Returns (filtered, islands); islands None without `global_ratio`."""
        margin = self.border_px * float(self.K_proj[0, 0]) / fx + 0.5
        with np.errstate(invalid="ignore"):
            filtered = res.valid & ((res.proj_x < margin - 0.5)
                                    | (res.proj_x > self.proj_size[0] - 0.5 - margin))
        agree = neighbour_agreement(res.depth, res.valid & ~filtered, sigma_z, 1.0 / fx)
        filtered |= edge_speckle_filter(res.depth, res.valid & ~filtered, sigma_z, 1.0 / fx, agree=agree)
        _remove(res, filtered, FILTERED)
        islands = None
        if global_ratio is not None:
            islands = bounce_island_filter(res.valid, agree, global_ratio)
            _remove(res, islands, MULTIPATH)
        return filtered, islands


def _lens_grid(cfg):
    """The camera's lens remap (datapipe/lens.py) when it distorts, else None."""
    from .. import lens
    from ..geometry import camera_intrinsics
    c = cfg.camera
    if lens.coefficients(getattr(c, "distortion", None)) is None:
        return None
    return lens.render_grid(camera_intrinsics(c), c.distortion, tuple(int(v) for v in c.resolution))


def _remove(res: DecodeResult, mask: np.ndarray, reason: int) -> None:
    """Drop `mask` pixels from a DecodeResult with `reason` (depth, projector column, phase NaN)."""
    res.valid &= ~mask
    for a in (res.depth, res.proj_x, res.phase):
        a[mask] = np.nan
    res.reason[mask] = reason


def _nanmedian(a) -> float | None:
    a = np.asarray(a)
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else None
