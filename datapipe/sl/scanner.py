"""The structured-light scanner as one pure pipeline: linear radiance of the fringe images ->
exposure -> sensor model (seeded) -> decode -> projector-border and edge/speckle filters -> maps.

No Blender: the Blender side (core/structured_light.py) renders the fringe radiance and hands it
here; tests and benchmarks feed synthetic or saved radiance the same way.

    scanner = Scanner.from_config(cfg)                       # or Scanner(periods, steps, ...)
    scan = scanner.scan(radiance, seed, K_cam, T_world_cam)  # -> Scan: .result (DecodeResult), .sigma_z, ...
    scan.maps(debug=False)   # {"sl_depth": {"Z": ...}, "sl_valid": uint8, ["sl_debug": channels]}
    scan.summary()           # what scene.json records: unwrap method, valid fraction, reason counts, ...

Validity (what "valid" means)
-----------------------------
1. decoder: modulation above the sensor-noise floor, consistent fringe orders, not saturated, and
   fringe contrast B/A >= MIN_CONTRAST (0.5; the decoder's default is 0.05). Direct light has
   B/A ~0.9; a pixel lit mostly by light reflected from another surface (e.g. the projector's
   shadow next to a bin wall, seen through the glossy floor) has ~0.2-0.4 and the phase of the
   other surface.
2. projector border: pixels within BORDER_PX camera pixel of the projector image's left/right
   edge (their sub-samples straddle the edge of the lit area).
3. edge / speckle filter (`sl.filters.edge_speckle_filter`): a camera pixel that straddles a depth
   edge mixes the fringes of both surfaces and, where the mixture unwraps consistently, decodes to
   a depth between them (a "flying pixel"); multi-path light can shift a few pixels by whole
   fringes. A valid pixel needs EDGE_MIN_SUPPORT of its 8 neighbours to agree within

    tol_pq = EDGE_SIGMAS * sqrt(sigma_p^2 + sigma_q^2) + EDGE_SLOPE * Z_p * pixel_angle * |q - p|

   (`sigma` the per-pixel theoretical depth noise, `pixel_angle` = 1/f_camera [rad per px]).
Pixels removed by 2. and 3. get reason FILTERED (7), depth NaN.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..geometry import T_cam_proj, projection_matrix, projector_intrinsics
from .decode import DecodeResult, Reason, decode
from .filters import edge_speckle_filter
from .metrics import pixel_depth_sigma
from .sensor import SensorModel
from .unwrap import plan_unwrap

MIN_CONTRAST = 0.5               # decode(min_contrast=): fringe contrast B/A below this = global light
BORDER_PX = 1.0                  # camera px kept free at the projector image's left/right border
FILTERED = int(Reason.FILTERED)  # reason code of pixels removed by the border and edge/speckle filters
REASON_NAMES = {r.value: r.name for r in Reason}


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

    def maps(self, debug: bool = False) -> dict:
        """The per-render outputs by kind (the native layout names their files): depth channels,
        the 8-bit validity image and, with `debug`, the decoder's intermediate channels."""
        res = self.result
        out = {"sl_depth": {"Z": res.depth}, "sl_valid": res.valid.astype(np.uint8) * 255}
        if debug:
            ch = {"phase": res.phase, "offset": res.offset, "proj_x": res.proj_x,
                  "reason": res.reason.astype(np.float32), "order_error": res.order_error,
                  "confidence": res.confidence, "sigma_z": self.sigma_z.astype(np.float32)}
            for k, (w, m) in enumerate(zip(res.wrapped, res.modulation)):
                ch[f"wrapped_{k}"], ch[f"modulation_{k}"] = w, m
            out["sl_debug"] = ch
        return out

    def summary(self) -> dict:
        res = self.result
        counts = np.bincount(res.reason.ravel(), minlength=max(REASON_NAMES) + 1)
        return {"unwrap": res.method, "valid_fraction": float(res.valid.mean()),
                "reasons": {REASON_NAMES[i]: int(counts[i]) for i in sorted(REASON_NAMES)},
                "median_sigma_z": _nanmedian(self.sigma_z)}


class Scanner:
    """Fringe radiance -> depth, as a real structured-light sensor does it (see the module doc).

    `K_proj`, `T_cam_proj`: the projector's intrinsics and its pose in the camera frame (OpenCV);
    `sensor`: a SensorModel or a preset name; `exposure`: gain on the radiance before the sensor."""

    def __init__(self, periods: Sequence[float], steps: int, proj_size: tuple[int, int], K_proj, T_cam_proj_, *,
                 unwrap: str = "auto", sensor: SensorModel | str = "industrial", exposure: float = 1.0,
                 min_contrast: float = MIN_CONTRAST, border_px: float = BORDER_PX, edge_filter: bool = True,
                 projector_gamma: float = 1.0):
        self.periods, self.steps = list(periods), int(steps)
        self.proj_size = tuple(int(v) for v in proj_size)
        self.K_proj = np.asarray(K_proj, dtype=np.float64)
        self.T_cam_proj = np.asarray(T_cam_proj_, dtype=np.float64)
        self.unwrap = unwrap
        self.sensor = SensorModel.preset(sensor) if isinstance(sensor, str) else sensor
        self.exposure = float(exposure)
        self.min_contrast = float(min_contrast)
        self.border_px = float(border_px)
        self.edge_filter = bool(edge_filter)
        self.projector_gamma = float(projector_gamma)     # the decoder corrects its phase ripple
        plan_unwrap(self.periods, unwrap)          # refuse an ambiguous period set before any render

    @classmethod
    def from_config(cls, cfg, **overrides) -> "Scanner":
        """The scanner a Config describes (structured_light + projector sections)."""
        s = cfg.structured_light
        kw = dict(unwrap=s.unwrap, sensor=s.sensor, exposure=s.exposure, projector_gamma=s.projector_gamma)
        kw.update(overrides)
        return cls(s.periods, s.steps, cfg.projector.resolution, projector_intrinsics(cfg), T_cam_proj(cfg), **kw)

    def projector_matrix(self, T_world_cam) -> np.ndarray:
        """P_proj (3x4) for the camera pose `T_world_cam` (OpenCV)."""
        T_world_proj = np.asarray(T_world_cam, dtype=np.float64) @ self.T_cam_proj
        return self.K_proj @ np.linalg.inv(T_world_proj)[:3]

    def scan(self, radiance, seed: int, K_cam, T_world_cam) -> Scan:
        """(F*N, H, W) linear radiance (frequency-major) seen from `T_world_cam` -> Scan."""
        t0 = time.perf_counter()
        model = self.sensor
        radiance = np.clip(np.asarray(radiance, dtype=np.float32), 0.0, None) * self.exposure
        dn, saturation = model.apply(radiance, seed)
        P_cam = projection_matrix(K_cam, T_world_cam)
        P_proj = self.projector_matrix(T_world_cam)
        res = decode(dn, periods=self.periods, steps=self.steps, P_cam=P_cam, P_proj=P_proj,
                     proj_size=self.proj_size, unwrap=self.unwrap, noise_sigma=model.noise_sigma,
                     saturation=saturation, min_contrast=self.min_contrast, projector_gamma=self.projector_gamma)
        sigma_z = pixel_depth_sigma(res, model.noise_sigma, self.proj_size[0], self.steps)
        filtered = np.zeros(res.valid.shape, bool)
        if self.edge_filter:
            filtered = self._filter(res, sigma_z, float(np.asarray(K_cam)[0, 0]))
        sigma_z[~res.valid] = np.nan
        return Scan(res, sigma_z, filtered, P_cam, P_proj, model, time.perf_counter() - t0)

    def _filter(self, res: DecodeResult, sigma_z: np.ndarray, fx: float) -> np.ndarray:
        """Projector-border and edge/speckle filters; removed pixels become FILTERED, NaN."""
        margin = self.border_px * float(self.K_proj[0, 0]) / fx + 0.5
        with np.errstate(invalid="ignore"):
            filtered = res.valid & ((res.proj_x < margin - 0.5)
                                    | (res.proj_x > self.proj_size[0] - 0.5 - margin))
        filtered |= edge_speckle_filter(res.depth, res.valid & ~filtered, sigma_z, 1.0 / fx)
        res.valid &= ~filtered
        res.depth[filtered] = np.nan
        res.proj_x[filtered] = np.nan
        res.phase[filtered] = np.nan
        res.reason[filtered] = FILTERED
        return filtered


def _nanmedian(a) -> float | None:
    a = np.asarray(a)
    a = a[np.isfinite(a)]
    return float(np.median(a)) if a.size else None
