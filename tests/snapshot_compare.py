"""Compare a run's annotation JSON with a stored snapshot: numbers within tolerances set by the
physics and the rendering, everything else exactly. No bpy (tests/test_snapshot_compare.py plants
changes into the stored snapshot without Blender; tests/blender/test_snapshot.py uses it on a run).

Why tolerances, and these ones. The same code on another CPU does not give the same last digits:
Bullet and Blender keep poses in float32 (one ulp of a coordinate near 0.8 m is 6e-8 m), BLAS and
libm differ, and Cycles' kernels (SSE/AVX2/NEON) change float rounding, hence some Monte-Carlo
path decisions. Measured: poses 1.4e-8 m apart between two x86-64 machines; structured-light class
counts up to 11 px apart at 80x60 (BAD_ORDER 82 vs 93, VALID 3076 vs 3078, valid fraction 0.0015)
with identical poses, while reruns on one machine are identical.

    poses           1e-6 m on translations (1e-3 in BOP's mm), 1e-6 on rotation-matrix entries (an
                    angle of ~1e-6 rad): 16 float32 ulps at the bin, 70x the measured spread, and
                    1/100 of the scanner's depth noise (0.13 mm) -- any real change of the
                    simulation, the frames or the camera moves a pose by millimetres.
    pixel counts    exact (visible pixels of a part: the instance mask is geometry, not noise).
    SL class counts 0.5% of the image (24 px at 80x60) per class, valid fraction 0.005: 2x the
                    measured cross-CPU spread (11 px); a real decoder change moves more (the
                    INCONSISTENT threshold 0.15 -> 0.25 moved VALID by 51-109 px, INCONSISTENT by
                    110-170 px on these renders).
    SL noise stats  exposure 0.1% (p99 of the lit peaks; measured 4e-8), median sigma_z 0.5%
                    (measured 0.18%; the threshold change above moved it 0.3-1.7%).
    rounded values  physics values written rounded (impact speed to 1e-4 m/s, depths to 1e-3 mm)
                    may flip their last written digit: one rounding unit more.
    other floats    relative 1e-6 (intrinsics, projector matrices: config values through float32).
Strings, booleans, integers other than SL class counts, keys and list lengths: exact. An int where
the snapshot has a float (or the reverse) is a difference (the file format changed).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass

SL_PIXELS_FRACTION = 0.005          # of the image, per SL class count and for the valid fraction


@dataclass(frozen=True)
class Tol:
    abs: float = 0.0
    rel: float = 0.0
    what: str = "exact"

    def ok(self, got: float, want: float) -> bool:
        return abs(got - want) <= self.abs + self.rel * abs(want)


EXACT = Tol()
TRANSLATION = Tol(abs=1e-6, what="1e-6 m")
TRANSLATION_MM = Tol(abs=1e-3, what="1e-3 mm")
ROTATION = Tol(abs=1e-6, what="1e-6 (rotation entry)")
OTHER_FLOAT = Tol(rel=1e-6, what="relative 1e-6")
ROUNDED = {"impact_speed": Tol(abs=1e-4 + 1e-6, what="1e-4 m/s (rounded)"),
           "speed": Tol(abs=1e-5 + 1e-6, what="1e-5 m/s (rounded)"),
           "max_interpenetration_mm": Tol(abs=2e-3, what="2e-3 mm (rounded)"),
           "depth_mm": Tol(abs=2e-3, what="2e-3 mm (rounded)"),
           # visible / silhouette pixels, both exact counts, written to 1e-4
           "visib_fract": Tol(abs=1e-4 + 1e-9, what="1e-4 (rounded)")}
SL_STATS = {"exposure": Tol(rel=1e-3, what="relative 1e-3"),
            "median_sigma_z": Tol(rel=5e-3, what="relative 5e-3")}
POSES = {"T_cam_obj", "cam2obj_pose", "T_world_cam", "T_world_blcam", "T_cam_proj"}   # 4x4, metres


def tolerance(path: tuple, n_pixels: int) -> Tol:
    """The tolerance of the number at `path` (keys and list indices from the file's root)."""
    keys = [p for p in path if isinstance(p, str)]
    key = keys[-1] if keys else ""
    if key in POSES and len(path) >= 2 and isinstance(path[-2], int) and isinstance(path[-1], int):
        row, col = path[-2], path[-1]
        return EXACT if row == 3 else TRANSLATION if col == 3 else ROTATION
    if key == "cam_R_m2c":
        return ROTATION
    if key == "cam_t_m2c":
        return TRANSLATION_MM
    if "structured_light" in keys:
        if len(keys) >= 2 and keys[-2] == "reasons":
            return Tol(abs=SL_PIXELS_FRACTION * n_pixels, what=f"{SL_PIXELS_FRACTION:.1%} of the image")
        if key == "valid_fraction":
            return Tol(abs=SL_PIXELS_FRACTION, what=f"{SL_PIXELS_FRACTION} (of the image)")
        if key in SL_STATS:
            return SL_STATS[key]
    if key in ROUNDED:
        return ROUNDED[key]
    return OTHER_FLOAT


def _where(path: tuple) -> str:
    out = ""
    for p in path:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out


def _pixels(render: object) -> int:
    try:
        w, h = render["resolution"]
        return int(w) * int(h)
    except (KeyError, TypeError, ValueError):
        return 0                                  # no resolution: SL counts compared exactly


def differences(got: object, want: object, path: tuple = (), n_pixels: int = 0) -> list[str]:
    """Every place where `got` differs from `want` beyond its tolerance, as readable lines."""
    if isinstance(want, dict) and "resolution" in want:
        n_pixels = _pixels(want)
    if type(got) is not type(want):
        return [f"{_where(path)}: got {got!r} ({type(got).__name__}), want {want!r} ({type(want).__name__})"]
    if isinstance(want, dict):
        out = [f"{_where(path + (k,))}: missing" for k in want if k not in got]
        out += [f"{_where(path + (k,))}: not in the snapshot" for k in got if k not in want]
        for k in want:
            if k in got:
                out += differences(got[k], want[k], path + (k,), n_pixels)
        return out
    if isinstance(want, list):
        if len(got) != len(want):
            return [f"{_where(path)}: {len(got)} entries, want {len(want)}"]
        return [line for i, (g, w) in enumerate(zip(got, want)) for line in differences(g, w, path + (i,), n_pixels)]
    if isinstance(want, (int, float)) and not isinstance(want, bool):
        tol = tolerance(path, n_pixels) if (isinstance(want, float) or "reasons" in path) else EXACT
        if isinstance(want, float) and not (math.isfinite(got) and math.isfinite(want)):
            same = got == want or (math.isnan(got) and math.isnan(want))
        else:
            same = tol.ok(got, want)
        return [] if same else [f"{_where(path)}: got {got!r}, want {want!r} (tolerance {tol.what})"]
    return [] if got == want else [f"{_where(path)}: got {got!r}, want {want!r}"]


def compare_texts(got: str, want: str, name: str) -> list[str]:
    """Differences between two JSON texts (the file `name`), each line prefixed with the name."""
    return [f"{name}: {line}" for line in differences(json.loads(got), json.loads(want), ())]
