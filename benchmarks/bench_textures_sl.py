"""What texture contrast on matte parts does to the structured-light depth error.

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_textures_sl.py [--quick]

One drop of the demo's parts (default.json, seed 0: the same poses in every case, since the
textures are drawn on a stream of their own), two camera poses, structured light on (fast fringe
mode, auto exposure, the industrial sensor, defaults otherwise), RESOLUTION with periods PERIODS
(~5 camera px per finest fringe, as the defaults at 320 px). Every part is matte_plastic (albedo
0.5, roughness 0.6). Cases: untextured, then grey textures drawn per part (every procedural kind,
features 5..20 mm) whose bright colour keeps albedo 0.5 and whose dark colour is 0.5 x (1 - c) for a
contrast c per case. Metrics over the part pixels (mask > 0) against the render's z-buffer
(depth.exr): SL valid fraction, median and p99 |error| (mm) of the valid ones; and the same split
by each pixel's albedo ratio to the untextured case, rho = linear RGB textured / untextured (the
same poses and lights; the RGB is Blender's Standard sRGB, inverted; clipped pixels left out):
"dark" texels rho < 1 - c/2, "bright" ones rho > 1 - c/4.

Writes benchmarks/results/textures_sl.md (with textures_sl_notes.md, the findings) and textures_sl.csv.
About 2.5 min on 2 shared cores.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import cv2
import numpy as np

from harness import RESULTS, ROOT, machine, on_path, parser, preset_dict, run_child, write_rows_csv, write_with_notes

on_path()
from datapipe.io.exr import read_depth, read_exr, read_mask  # noqa: E402

RESOLUTION = [320, 240]
PERIODS = [1, 8, 64]             # the defaults: ~5 camera px per finest fringe at 320 px
CONTRASTS = (None, 0.25, 0.5, 0.9)


def preset(out: Path, contrast) -> dict:
    d = preset_dict(ROOT / "datapipe" / "presets" / "default.json")
    for o in d["objects"]:
        o["material"] = "matte_plastic"
    d["scene"].update(num_renders=2, min_renders_per_scene=2, max_renders_per_scene=2, seed=0)
    if contrast is not None:
        d["scene"]["textures"] = {"targets": ["parts"], "kinds": ["noise", "voronoi", "wave", "brick", "checker"],
                                  "albedo": [0.5, 0.5], "saturation": [0.0, 0.0], "contrast": [contrast, contrast],
                                  "feature_size": [0.005, 0.02]}
    d["camera"]["resolution"] = RESOLUTION
    d["structured_light"].update(enabled=True, periods=PERIODS, fringe_mode="fast")
    d["output"].update(path=str(out), overview=False, legacy_pickle=False)
    return d


def run_case(tmp: Path, contrast) -> dict:
    name = "none" if contrast is None else f"{contrast:g}"
    out = tmp / f"out_{name}"
    p = tmp / f"{name}.json"
    p.write_text(json.dumps(preset(out, contrast)))
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    child = run_child([sys.executable, "-m", "datapipe", "run", str(p)], env=env, stdout=subprocess.DEVNULL)
    if child.returncode:
        raise RuntimeError(f"datapipe run of {p} failed (exit {child.returncode})")
    wall = child.wall_s
    maps = []              # per render: (|error| mm, NaN where not valid or off the parts; linear RGB)
    for sj in sorted(out.glob("scene.*/scene.json")):
        scene = json.loads(sj.read_text())
        for r in scene["renders"]:
            files = {k: sj.parent / v for k, v in r["files"].items()}
            z, mask = read_depth(files["depth"]), read_mask(files["mask"])
            sl = read_exr(files["sl_depth"])
            sl = sl["Z"] if "Z" in sl else next(iter(sl.values()))
            err = np.where((mask > 0) & np.isfinite(sl) & (sl > 0) & np.isfinite(z), np.abs(sl - z) * 1000.0, np.nan)
            err[mask <= 0] = -1.0                                   # off the parts
            rgb8 = cv2.imread(str(files["rgb"]), cv2.IMREAD_COLOR).astype(np.float64)
            maps.append((err, _linear(rgb8 / 255.0).mean(axis=2), rgb8.max(axis=2) >= 255))
    return {"name": name, "contrast": contrast, "maps": maps, "wall_s": wall}


def _linear(v):
    """Inverse of the sRGB encoding (IEC 61966-2-1)."""
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def _stats(e: np.ndarray) -> tuple[float, float]:
    return (float(np.median(e)), float(np.percentile(e, 99))) if e.size else (float("nan"), float("nan"))


def summarise(case: dict, base: dict) -> dict:
    part = np.concatenate([(m[0] != -1).ravel() for m in case["maps"]])
    err = np.concatenate([m[0].ravel() for m in case["maps"]])
    valid = part & np.isfinite(err)
    row = {"contrast": case["name"], "part_px": int(part.sum()), "valid_parts": float(valid.sum() / part.sum())}
    row["median_mm"], row["p99_mm"] = _stats(err[valid])
    if case["contrast"] is not None:
        c = case["contrast"]
        rho = np.concatenate([(m[1] / np.maximum(b[1], 1e-6)).ravel() for m, b in zip(case["maps"], base["maps"])])
        clip = np.concatenate([(m[2] | b[2]).ravel() for m, b in zip(case["maps"], base["maps"])])
        dark = valid & ~clip & (rho < 1 - c / 2)
        bright = valid & ~clip & (rho > 1 - c / 4)
        row["dark_share"] = float(dark.sum() / max(valid.sum(), 1))
        row["dark_median_mm"], row["dark_p99_mm"] = _stats(err[dark])
        row["bright_median_mm"], row["bright_p99_mm"] = _stats(err[bright])
    row["wall_s"] = case["wall_s"]
    return row


def main() -> None:
    args = parser(__doc__, quick="untextured and contrast 0.75 only").parse_args()
    cases = (None, 0.75) if args.quick else CONTRASTS
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        runs = [run_case(Path(tmp), c) for c in cases]
    for run in runs:
        rows.append(summarise(run, runs[0]))
        print(rows[-1], flush=True)
    base = rows[0]
    for r in rows:
        r["median_vs_none"] = r["median_mm"] / base["median_mm"]
        r["p99_vs_none"] = r["p99_mm"] / base["p99_mm"]
    write_rows_csv(RESULTS / "textures_sl.csv", rows, list(rows[-1]))
    lines = ["# Structured light on textured matte parts", "",
             f"Machine: {machine()}, shared with other jobs; Blender (bpy) Cycles CPU, "
             f"{RESOLUTION[0]}x{RESOLUTION[1]}, periods {PERIODS}, fast fringe mode, auto exposure. Generated by "
             "`benchmarks/bench_textures_sl.py` (scenes: its docstring); raw rows in `textures_sl.csv`. "
             "Errors over the SL-valid part pixels against the z-buffer; the same drop and camera poses in "
             "every case (textures are drawn on their own stream).", "",
             "| contrast | part px | valid_parts | median_mm | p99_mm | median / untextured | p99 / untextured "
             "| dark share | dark median / p99 | bright median / p99 | wall_s |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        split = (f"{r['dark_share']:.2f} | {r['dark_median_mm']:.3f} / {r['dark_p99_mm']:.2f} | "
                 f"{r['bright_median_mm']:.3f} / {r['bright_p99_mm']:.2f}") if "dark_share" in r else "- | - | -"
        lines.append(f"| {r['contrast']} | {r['part_px']} | {r['valid_parts']:.3f} | {r['median_mm']:.3f} | "
                     f"{r['p99_mm']:.2f} | {r['median_vs_none']:.2f} | {r['p99_vs_none']:.2f} | {split} | "
                     f"{r['wall_s']:.0f} |")
    write_with_notes(RESULTS / "textures_sl.md", lines)


if __name__ == "__main__":
    main()
