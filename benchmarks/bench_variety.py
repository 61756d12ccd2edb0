"""Does structured light still decode on the parts when camera, light and bin vary?

    .venv/bin/python benchmarks/bench_variety.py [--renders 20] [--res 160 120] [--out DIR]

Two runs of the demo preset (structured light on, as shipped) with the same seed and the same
number of renders, one render per scene:

- "pose pool": the preset's six fixed camera poses, the fixed key light, the preset's bin;
- "varied": the `bin_view` camera sampler with its default ranges, the default `lighting` ranges and
  bin size / wall height drawn per scene (scale 0.8..1.2 and 0.7..1.3).

Per render: the valid fraction of the structured-light depth on the parts (instance mask > 0), on
the whole image, and the median |SL - z-buffer| on parts valid in both. Writes
benchmarks/results/variety.md (tables) and variety_grid.png (`datapipe show --grid` of the varied
run).
"""
from __future__ import annotations

import json
import platform
import shutil
import tempfile
from pathlib import Path

import numpy as np

from harness import RESULTS, Stopwatch, on_path, parser

on_path()
from datapipe import config as C  # noqa: E402


def make_config(n: int, res, varied: bool) -> C.Config:
    cfg = C.default_config()
    cfg.scene.num_renders = n
    cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 1
    cfg.camera.resolution = list(res)
    cfg.render.samples = 16
    cfg.output.legacy_pickle = cfg.output.overview = False
    cfg.structured_light.enabled = True
    if varied:
        cfg.camera.sampler = C.CameraSamplerConfig(kind="bin_view")
        cfg.lighting = C.LightingConfig()
        cfg.scene.bin_size_scale, cfg.scene.bin_wall_scale = [0.8, 1.2], [0.7, 1.3]
    return cfg


def run(cfg: C.Config, out: Path) -> float:
    import bpy
    from datapipe.engine.pipeline import Pipeline
    bpy.ops.wm.read_factory_settings(use_empty=True)
    with Stopwatch() as t:
        for ev in Pipeline(cfg, out).run():
            if ev.stage == "render":
                print(ev.line(), flush=True)
    return t.wall_s


def measure(out: Path) -> list[dict]:
    from datapipe.io.exr import read_depth, read_mask
    import cv2
    rows = []
    for sj in sorted(out.glob("scene.*/scene.json")):
        sc = json.loads(sj.read_text())
        for r in sc["renders"]:
            f = {k: sj.parent / v for k, v in r["files"].items()}
            mask = read_mask(f["mask"]) > 0
            valid = cv2.imread(str(f["sl_valid"]), cv2.IMREAD_GRAYSCALE) > 0
            z, s = read_depth(f["depth"]), read_depth(f["sl_depth"])
            both = mask & valid & np.isfinite(z) & np.isfinite(s)
            cam = r.get("camera_sampler") or {}
            light = sc.get("lighting") or {}
            rows.append({
                "render": f"{sc['name']}/{r['name']}", "parts_px": int(mask.sum()),
                "valid_parts": float(valid[mask].mean()) if mask.any() else float("nan"),
                "valid_image": float(valid.mean()),
                "med_err_mm": float(np.median(np.abs(s[both] - z[both]))) * 1000 if both.any() else float("nan"),
                "distance": cam.get("distance"), "tilt": cam.get("tilt_deg"),
                "power": light.get("key_power"), "ambient": light.get("ambient")})
    return rows


def _f(v, fmt):
    return "-" if v is None else format(v, fmt)


def report(results: dict, res, n: int, seconds: dict) -> str:
    lines = ["# Scene variety: structured light across sampled poses, light and bins", "",
             f"Demo preset, structured light as shipped, {n} renders (one per scene, seed 0) at {res[0]}x{res[1]}, "
             "16 RGB samples. `valid on parts`: share of instance-mask pixels with a structured-light depth; "
             "`median |err|`: SL minus z-buffer depth on parts valid in both. Made by "
             "`benchmarks/bench_variety.py` on " + platform.node() + ".", "",
             "| run | renders | valid on parts (mean) | min | max | valid on image (mean) | median abs err on parts (mm, mean) | run s |",
             "|---|---|---|---|---|---|---|---|"]
    for name, rows in results.items():
        vp = np.array([r["valid_parts"] for r in rows if r["parts_px"] > 0])
        lines.append(f"| {name} | {len(rows)} | {vp.mean():.3f} | {vp.min():.3f} | {vp.max():.3f} | "
                     f"{np.mean([r['valid_image'] for r in rows]):.3f} | "
                     f"{np.nanmean([r['med_err_mm'] for r in rows]):.2f} | {seconds[name]:.0f} |")
    for name, rows in results.items():
        lines += ["", f"## {name}: per render", "",
                  "| render | part px | valid on parts | valid on image | median abs err mm | distance m | tilt deg | key W | ambient |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for r in rows:
            lines.append(f"| {r['render']} | {r['parts_px']} | {r['valid_parts']:.3f} | {r['valid_image']:.3f} | "
                         f"{r['med_err_mm']:.2f} | {_f(r['distance'], '.3f')} | {_f(r['tilt'], '.1f')} | "
                         f"{_f(r['power'], '.0f')} | {_f(r['ambient'], '.3f')} |")
    lines += ["", "![grid of the varied run](variety_grid.png)", ""]
    return "\n".join(lines[:8] + _observations(results) + lines[8:])


def _rank_corr(a, b) -> float:
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1])


def _observations(results: dict) -> list[str]:
    """What the numbers say, computed here (not written by hand), so a re-run keeps it true."""
    if "varied" not in results or "pose pool" not in results:
        return []
    v, p = results["varied"], results["pose pool"]
    vp = [r["valid_parts"] for r in v]
    worst = min(v, key=lambda r: r["valid_parts"])
    return ["", "Observations:", "",
            f"- Structured light decodes on the parts across the sampled poses, lights and bins: "
            f"{np.mean(vp):.3f} of part pixels valid on average against {np.mean([r['valid_parts'] for r in p]):.3f} "
            f"for the fixed pose pool, with {sum(x >= 0.5 for x in vp)} of {len(vp)} varied renders at 0.5 or more.",
            f"- The lowest ({worst['render']}, {worst['valid_parts']:.3f}) is among the closest views "
            f"({worst['distance']:.2f} m): the projector (0.15 m beside the camera, toed in 8.5 deg, so its image "
            "and the camera's overlap best near 1 m) leaves a strip of the camera view unlit at short range, and "
            "parts in it read NO_LIGHT. Rank correlation of valid-on-image with distance over the varied renders: "
            f"{_rank_corr([r['valid_image'] for r in v], [r['distance'] for r in v]):+.2f}.",
            f"- Depth error on valid part pixels stays put (median |err| {np.nanmean([r['med_err_mm'] for r in p]):.2f} "
            f"mm with the pool, {np.nanmean([r['med_err_mm'] for r in v]):.2f} mm varied): the light draws do not reach "
            "the fringe images (their view layers use a black world and the projector alone)."]


def main():
    # quick at 320x240: the default 160x120 is refused by the gate (the finest fringe 2.5 camera px)
    ap = parser(__doc__, quick="--renders 2 --res 320 240")
    ap.add_argument("--renders", type=int, default=20)
    ap.add_argument("--res", type=int, nargs=2, default=[160, 120])
    ap.add_argument("--out", default=None, help="keep the runs here (default: a temporary folder)")
    ap.add_argument("--report-only", action="store_true", help="re-measure the runs kept in --out, no rendering")
    a = ap.parse_args()
    if a.quick:
        a.renders, a.res = 2, [320, 240]
    base = Path(a.out) if a.out else Path(tempfile.mkdtemp(prefix="bench_variety_"))
    results, seconds = {}, {}
    for name, varied in (("pose pool", False), ("varied", True)):
        out = base / name.replace(" ", "_")
        if a.report_only:
            t = out / "wall_seconds.txt"
            seconds[name] = float(t.read_text()) if t.is_file() else float("nan")
        else:
            if out.exists():
                shutil.rmtree(out)
            seconds[name] = run(make_config(a.renders, a.res, varied), out)
            (out / "wall_seconds.txt").write_text(f"{seconds[name]:.1f}\n")
        results[name] = measure(out)
    RESULTS.mkdir(parents=True, exist_ok=True)
    from datapipe.show import make_grid
    make_grid(base / "varied", 12, RESULTS / "variety_grid.png")
    (RESULTS / "variety.md").write_text(report(results, a.res, a.renders, seconds))
    print((RESULTS / "variety.md").read_text())


if __name__ == "__main__":
    main()
