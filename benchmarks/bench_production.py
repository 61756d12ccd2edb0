"""Production cost of one render: wall and CPU seconds per stage and peak memory, over resolution
(640 x 480, 1280 x 1024, a device's full resolution), part count (10, 40, 120), material (diffuse,
shiny) and fringe mode (fast, render; quadrature on shiny parts); renders per hour per core; how each stage grows with pixels
and parts.

    .venv/bin/python benchmarks/bench_production.py            # the full grid: 3 x 3 x (2 x 2 + 1) = 45 cells (hours)
    .venv/bin/python benchmarks/bench_production.py --quick    # 640 x 480 complete, 4 larger cells (~70 min on 2 shared cores)
    .venv/bin/python benchmarks/bench_production.py --cells 1280x1024:40:shiny:render full:40:diffuse:fast
    .venv/bin/python benchmarks/bench_production.py --report   # the report again from production.csv

Each cell is one `python -m datapipe run PRESET --out DIR --quiet` of a copy of
`datapipe/presets/bin_picking.json` (the Zivid 2+ M60, structured light on, the shipped samples)
with one render, `scene.fill` replaced by fixed part counts, one material for every part and the
fringe mode forced; in its own process, one after another. Per stage the run's own
`run.json` `stats.steps` (wall and process CPU seconds, Cycles' and numpy's threads included); the
whole process's wall, CPU (os.wait4: user + system) and peak resident memory (ru_maxrss); the
machine's load average before and after (timings are noisy on a shared machine). Each finished
cell is appended to production.csv at once, so an interrupted run keeps what it measured and
`--resume` skips those cells. Writes benchmarks/results/production.md, production.csv and
production.png; with `--gpu` (Cycles on the GPU, where there is one) production_gpu.*.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from harness import (RESULTS, ROOT, append_row_csv, log_x_frame, machine, parser, preset_dict, read_rows_csv,
                     run_child, write_with_notes)

BASE_PRESET = ROOT / "datapipe" / "presets" / "bin_picking.json"
DEVICE = "zivid2plus_m60"
FULL = "full"                   # the device's full resolution (binning 1)
RESOLUTIONS = ("640x480", "1280x1024", FULL)
PARTS = (10, 40, 120)
MATERIALS = {"diffuse": "matte_plastic", "shiny": "steel"}
MODES = ("fast", "render", "quadrature")     # quadrature: shiny parts only (auto gives diffuse ones fast)
# the stages of a render as run.json's stats.steps names them (datapipe/engine/progress.py), in order
STAGES = ("placement", "simulation", "render", "write", "fringes", "decode", "maps", "annotate")
STAGE_LABELS = {"placement": "placing", "simulation": "simulation", "render": "native render",
                "write": "writing", "fringes": "fringe renders", "decode": "decode",
                "maps": "SL maps", "annotate": "annotations"}
SCENE_STAGES = ("placement", "simulation")      # once per scene, shared by its renders


def cell_key(res: str, parts: int, material: str, mode: str) -> str:
    return f"{res}:{parts}:{material}:{mode}"


def full_grid() -> list[tuple]:
    return [(r, n, m, f) for r in RESOLUTIONS for n in PARTS for m in MATERIALS for f in MODES if _useful(m, f)]


def _useful(material: str, mode: str) -> bool:
    return not (mode == "quadrature" and material == "diffuse")


def quick_grid() -> list[tuple]:
    """Every part count, material and mode at 640 x 480 (the part-count and mode scaling); a few
    cells at 1280 x 1024 and the full resolution (the pixel scaling)."""
    cells = [("640x480", n, m, f) for n in PARTS for m in MATERIALS for f in MODES if _useful(m, f)]
    cells += [("1280x1024", 40, "diffuse", "fast"), ("1280x1024", 40, "shiny", "render")]
    cells += [(FULL, 40, "diffuse", "fast"), (FULL, 40, "shiny", "render")]
    return cells


def parse_cell(text: str) -> tuple:
    try:
        res, n, mat, mode = text.split(":")
        cell = (res, int(n), mat, mode)
    except ValueError:
        raise SystemExit(f"--cells {text!r}: expected RES:PARTS:MATERIAL:MODE, e.g. 640x480:40:shiny:render")
    if res != FULL and not (res.count("x") == 1 and all(p.isdigit() for p in res.split("x"))):
        raise SystemExit(f"--cells {text!r}: resolution WxH or {FULL!r}")
    if mat not in MATERIALS or mode not in MODES:
        raise SystemExit(f"--cells {text!r}: material one of {sorted(MATERIALS)}, mode one of {MODES}")
    return cell


def preset(res: str, parts: int, material: str, mode: str, samples: int | None, seed: int,
           gpu: bool = False) -> dict:
    """bin_picking.json with one render, `parts` parts split over its three meshes, one material, the
    fringe mode forced, at `res` (the device's lens; `full`: binning 1)."""
    p = preset_dict(BASE_PRESET)
    p["device"], p["binning"] = DEVICE, 1
    if res != FULL:
        p.setdefault("camera", {})["resolution"] = [int(v) for v in res.split("x")]
    s = p["scene"]
    s.pop("fill", None)
    s.update(num_renders=1, min_renders_per_scene=1, max_renders_per_scene=1, seed=seed)
    for k, o in enumerate(p["objects"]):
        o["min_instances"] = o["max_instances"] = parts // 3 + (1 if k < parts % 3 else 0)
        o["material"] = MATERIALS[material]
    p["structured_light"]["fringe_mode"] = mode
    if samples is not None:
        p["render"]["samples"] = samples
    if gpu:
        p["render"]["device"] = "GPU"
    p["output"].update(overview=False)
    return p


def run_cell(cell: tuple, args) -> dict:
    res, parts, material, mode = cell
    with tempfile.TemporaryDirectory(prefix="bench_production_") as d:
        pf, out = Path(d) / "preset.json", Path(d) / "out"
        pf.write_text(json.dumps(preset(res, parts, material, mode, args.samples, args.seed, args.gpu), indent=1))
        cmd = [sys.executable, "-m", "datapipe", "run", str(pf), "--out", str(out), "--quiet"]
        load0 = os.getloadavg()
        with open(Path(d) / "stderr.txt", "w") as err:
            child = run_child(cmd, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=err,
                              env={**os.environ, "PYTHONPATH": str(ROOT)})
        load1 = os.getloadavg()
        if child.returncode != 0:
            raise RuntimeError(f"cell {cell_key(*cell)} failed (exit {child.returncode}):\n"
                               f"{(Path(d) / 'stderr.txt').read_text()[-3000:]}")
        rec = json.loads((out / "run.json").read_text())
        scene = json.loads(next(out.glob("scene.*/scene.json")).read_text())
    steps = rec["stats"]["steps"]
    r0 = scene["renders"][0]
    sl = r0.get("structured_light") or {}
    W, H = r0["resolution"]
    row = {"cell": cell_key(*cell), "res": res, "width": W, "height": H, "pixels": W * H, "parts": parts,
           "parts_kept": len(scene["objects"]), "material": material, "mode": sl.get("fringe_mode", mode),
           "reflection_filter": sl.get("reflection_filter"), "hdr": json.dumps(sl.get("hdr")),
           "sl_valid": round(float(sl.get("valid_fraction", float("nan"))), 4),
           "cycles_device": rec.get("render_device", "CPU"),    # run.json names it for render.device GPU runs
           "samples": rec["config"]["render"]["samples"], "sl_samples": rec["config"]["structured_light"]["samples"],
           "sim_frames": scene["simulation"].get("frames"), "sim_stages": scene["simulation"].get("stages"),
           "process_wall_s": round(child.wall_s, 2), "process_cpu_s": round(child.cpu_s, 2),
           "peak_rss_mib": round(child.peak_rss_mib, 1),
           "load_before": round(load0[0], 2), "load_after": round(load1[0], 2)}
    for k in ("setup", *STAGES):
        v = steps.get(k, {})
        row[f"{k}_wall_s"] = round(float(v.get("wall_s", 0.0)), 3)
        row[f"{k}_cpu_s"] = round(float(v.get("cpu_s", 0.0)), 3)
    row["render_cpu_total_s"] = round(sum(row[f"{k}_cpu_s"] for k in STAGES), 2)
    row["render_wall_total_s"] = round(sum(row[f"{k}_wall_s"] for k in STAGES), 2)
    # what the steps leave out: interpreter and bpy start, preflight (mesh imports), world setup, run.json
    row["overhead_cpu_s"] = round(row["process_cpu_s"] - row["render_cpu_total_s"], 2)
    row["overhead_wall_s"] = round(row["process_wall_s"] - row["render_wall_total_s"], 2)
    return row


# -- scaling ---------------------------------------------------------------------------------------
def slope(xs, ys) -> float | None:
    """Least-squares slope of log y over log x (cost ~ x^slope); None with fewer than 2 distinct x."""
    xs, ys = np.asarray(xs, float), np.asarray(ys, float)
    ok = (xs > 0) & (ys > 0)
    if len(set(xs[ok])) < 2:
        return None
    return float(np.polyfit(np.log(xs[ok]), np.log(ys[ok]), 1)[0])


def scaling(rows: list[dict], along: str, fixed: tuple[str, ...]) -> dict:
    """Per stage: the log-log slopes of CPU seconds against `along` over each group of rows equal in
    `fixed`, as {stage: [(group, slope, n rows)]}."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault(tuple(r[k] for k in fixed), []).append(r)
    out: dict[str, list] = {}
    for stage in (*STAGES, "render_cpu_total", "peak_rss"):
        col = {"render_cpu_total": "render_cpu_total_s", "peak_rss": "peak_rss_mib"}.get(stage, f"{stage}_cpu_s")
        for g, rs in sorted(groups.items(), key=lambda kv: str(kv[0])):
            s = slope([r[along] for r in rs], [r[col] for r in rs])
            if s is not None:
                out.setdefault(stage, []).append((g, s, len(rs)))
    return out


def extrapolate_full(rows: list[dict], pix_slopes: dict) -> list[dict]:
    """Full-resolution cells not measured, stage by stage from the largest measured resolution of
    the same parts/material/mode: scene stages unchanged, pixel stages x (pixels ratio)^(the median
    measured slope of that stage in the same fringe mode, else in any mode, else 1). Marked derived."""
    full_px = 2448 * 2048
    have = {r["cell"] for r in rows}
    derived = []
    def exponent(st: str, mode: str) -> float:
        same = [s for g, s, _ in pix_slopes.get(st, []) if g[2] == mode]
        anym = [s for _, s, _ in pix_slopes.get(st, [])]
        return float(np.median(same or anym)) if (same or anym) else 1.0
    for (res, n, m, f) in full_grid():
        if res != FULL or cell_key(res, n, m, f) in have:
            continue
        src = [r for r in rows if r["parts"] == n and r["material"] == m and r["mode"] == f and r["res"] != FULL]
        if not src:
            continue
        b = max(src, key=lambda r: r["pixels"])
        ratio = full_px / b["pixels"]
        d = {"cell": cell_key(res, n, m, f), "from": b["cell"]}
        for st in STAGES:
            e = 0.0 if st in SCENE_STAGES else exponent(st, f)
            d[f"{st}_cpu_s"] = b[f"{st}_cpu_s"] * ratio ** e
        d["render_cpu_total_s"] = sum(d[f"{st}_cpu_s"] for st in STAGES)
        derived.append(d)
    return derived


# -- report ----------------------------------------------------------------------------------------
def shared_drop_cpu(r: dict, renders_per_scene: float = 2.0) -> float:
    """CPU seconds per render when a scene's drop is shared by `renders_per_scene` renders."""
    scene = sum(r[f"{s}_cpu_s"] for s in SCENE_STAGES)
    return r["render_cpu_total_s"] - scene + scene / renders_per_scene


def fmt(v, nd=1) -> str:
    return "-" if v is None else f"{v:.{nd}f}"


def write_report(rows: list[dict], command: str, stem: str = "production", gpu: bool = False) -> None:
    rows = sorted(rows, key=lambda r: (r["pixels"], r["parts"], r["material"], r["mode"]))
    measured_by = sorted({r.get("command") or "not recorded" for r in rows})
    L = ["# Production benchmark: one render of a dense bin, stage by stage", "",
         f"Cells measured by {', '.join(f'`{c}`' for c in measured_by)} (`benchmarks/bench_production.py`; the full grid of "
         f"{len(full_grid())} cells is its default). Machine: {machine()}. "
         + ("Cycles on the GPU (`render.device: GPU`; the decode and the simulation stay on the CPU); the "
            "backend that rendered (run.json `render_device`; CPU: Cycles found no GPU): "
            + ", ".join(sorted({str(r.get("cycles_device") or "not recorded") for r in rows})) + "."
            if gpu else "Cycles on the CPU. No GPU was lent when this was made: the same table on a GPU "
            "is `--gpu` (writes production_gpu.md)."), "",
         "Each cell is one `python -m datapipe run` of `presets/bin_picking.json` (Zivid 2+ M60 lens, "
         "projector, HDR auto, reflection filter auto, sensor model) with one render, fixed part counts "
         "(split over peg, nut, bracket) instead of `scene.fill`, every part `matte_plastic` (diffuse) or "
         "`steel` (shiny), the fringe mode forced, the overview sheet off; "
         f"Cycles {rows[0]['samples'] if rows else '?'} samples (denoised) for the native render, "
         f"{rows[0]['sl_samples'] if rows else '?'} point samples per pixel for the fringes (the preset's). "
         "Stage times are the run's own `run.json` `stats.steps` (wall and process CPU seconds, every "
         "thread); the process's CPU and peak memory come from `os.wait4` of the child. `overhead` is the "
         "rest of the process: Python and bpy start, preflight (mesh imports), Blender scene setup, "
         "run.json; a production run pays it once, not per render. Cells run one after another on a "
         "machine shared with other jobs: the load average (1 min) before and after each cell is given; "
         "CPU seconds are the comparable figure, wall seconds depend on the load.", "",
         "## Measured cells", "",
         "CPU seconds per stage (wall in the next table). `per render` = the stages' sum (the drop "
         "included: one render per scene); renders/h/core = 3600 / that CPU; `at 2/scene`: the same "
         "with placement and simulation shared by two renders, as `bin_picking.json` (1-3 renders per "
         "scene) has on average (derived from the same cell).", "",
         "| resolution | parts | material | mode | " + " | ".join(STAGE_LABELS[s] for s in STAGES)
         + " | per render CPU s | wall s | renders/h/core | at 2/scene | overhead CPU s | peak RSS GiB | SL valid "
         "| load before/after |",
         "|" + "---|" * (4 + len(STAGES) + 8)]
    for r in rows:
        L.append(f"| {r['width']}x{r['height']} | {r['parts_kept']}/{r['parts']} | {r['material']} | {r['mode']} | "
                 + " | ".join(fmt(r[f"{s}_cpu_s"]) for s in STAGES)
                 + f" | {r['render_cpu_total_s']:.1f} | {r['render_wall_total_s']:.1f} | "
                 f"{3600 / r['render_cpu_total_s']:.0f} | {3600 / shared_drop_cpu(r):.0f} | {r['overhead_cpu_s']:.1f} | "
                 f"{r['peak_rss_mib'] / 1024:.2f} | {r['sl_valid']:.2f} | {r['load_before']:.1f}/{r['load_after']:.1f} |")
    L += ["", "Wall seconds per stage (same cells):", "",
          "| resolution | parts | material | mode | " + " | ".join(STAGE_LABELS[s] for s in STAGES)
          + " | process wall s | process CPU s |", "|" + "---|" * (4 + len(STAGES) + 2)]
    for r in rows:
        L.append(f"| {r['width']}x{r['height']} | {r['parts']} | {r['material']} | {r['mode']} | "
                 + " | ".join(fmt(r[f"{s}_wall_s"]) for s in STAGES)
                 + f" | {r['process_wall_s']:.0f} | {r['process_cpu_s']:.0f} |")
    pix = scaling(rows, "pixels", ("parts", "material", "mode"))
    par = scaling(rows, "parts_kept", ("res", "material", "mode"))
    L += ["", "## How each stage grows", "",
          "Log-log slope of CPU seconds (peak memory in the last row) (cost ~ x^slope: 1 = linear, 0 = flat), fitted over the measured "
          "cells that differ only in pixels (at fixed parts, material, mode) or only in parts kept (at "
          "fixed resolution, material, mode); median over such groups, with the range and the number "
          "of groups.", "",
          "| stage | vs pixels: median slope (range, groups) | vs parts: median slope (range, groups) |",
          "|---|---|---|"]

    def cellfmt(v):
        if not v:
            return "not measured"
        s = [x for _, x, _ in v]
        return f"{np.median(s):.2f} ({min(s):.2f} to {max(s):.2f}, {len(s)})"
    for st in (*STAGES, "render_cpu_total", "peak_rss"):
        label = STAGE_LABELS.get(st) or {"render_cpu_total": "per render (sum)", "peak_rss": "peak RSS (memory)"}[st]
        L.append(f"| {label} | {cellfmt(pix.get(st))} | {cellfmt(par.get(st))} |")
    derived = extrapolate_full(rows, pix)
    if derived:
        L += ["", "## Derived, not measured: the device's full resolution (2448 x 2048)", "",
              "Stage by stage from the largest measured resolution of the same parts, material and mode: "
              "placement and simulation unchanged, every other stage times (pixel ratio)^(its median "
              "measured slope against pixels in the same fringe mode). Estimates only: the exponents come "
              "from few groups, and a 640 x 480 source extrapolates 16x in pixels.", "",
              "| cell | from | " + " | ".join(STAGE_LABELS[s] for s in STAGES) + " | per render CPU s | renders/h/core |",
              "|" + "---|" * (2 + len(STAGES) + 2)]
        for d in derived:
            L.append(f"| {d['cell']} | {d['from']} | " + " | ".join(fmt(d[f'{s}_cpu_s']) for s in STAGES)
                     + f" | {d['render_cpu_total_s']:.0f} | {3600 / d['render_cpu_total_s']:.0f} |")
    write_with_notes(RESULTS / f"{stem}.md", L)


def plot(rows: list[dict], path: Path) -> None:
    """CPU seconds per render against pixels (log-log), one line per parts/material/mode group."""
    import cv2
    if not rows:
        return
    W, H, m = 860, 520, 70
    ys = [np.log10(r["render_cpu_total_s"]) for r in rows]
    xs = [np.log10(r["pixels"]) for r in rows]
    x0, x1 = min(xs) - 0.15, max(xs) + 0.15
    y0, y1 = min(ys) - 0.1, max(ys) + 0.1
    img, px = log_x_frame((W, H), m, (x0, x1), (y0, y1), (3e5, 1e6, 3e6, 1e7))
    font = cv2.FONT_HERSHEY_SIMPLEX
    for v in (10, 20, 50, 100, 200, 500, 1000, 2000, 5000):
        if y0 <= np.log10(v) <= y1:
            p = px(x0, np.log10(v))
            cv2.line(img, (m, p[1]), (W - m, p[1]), (225, 225, 225), 1)
            cv2.putText(img, f"{v}", (m - 45, p[1] + 4), font, 0.4, (0, 0, 0), 1)
    cv2.putText(img, "CPU s per render (all stages, log) against camera pixels (log); one render of a dense bin",
                (m, m - 40), font, 0.5, (0, 0, 0), 1)
    cv2.putText(img, "colour: parts 10 blue, 40 green, 120 red; circles diffuse, squares shiny; "
                "filled render mode, open fast", (m, m - 20), font, 0.4, (0, 0, 0), 1)
    colours = {10: (200, 90, 0), 40: (0, 150, 0), 120: (0, 0, 210)}
    groups: dict[tuple, list] = {}
    for r in rows:
        groups.setdefault((r["parts"], r["material"], r["mode"]), []).append(r)
    for (n, mat, mode), rs in groups.items():
        col = colours.get(n, (90, 90, 90))
        pts = [px(np.log10(r["pixels"]), np.log10(r["render_cpu_total_s"]))
               for r in sorted(rs, key=lambda r: r["pixels"])]
        for a, b in zip(pts, pts[1:]):
            cv2.line(img, a, b, col, 1)
        fill = -1 if mode == "render" else 2
        for p in pts:
            if mat == "shiny":
                cv2.rectangle(img, (p[0] - 5, p[1] - 5), (p[0] + 5, p[1] + 5), col, fill)
            else:
                cv2.circle(img, p, 6, col, fill)
    cv2.putText(img, "camera pixels", (W // 2 - 40, H - 25), font, 0.45, (0, 0, 0), 1)
    cv2.imwrite(str(path), img)


def main(argv=None) -> int:
    ap = parser(__doc__, quick="640x480 complete plus 4 larger cells (~70 min on 2 shared cores)")
    ap.add_argument("--cells", nargs="+", help="explicit cells RES:PARTS:MATERIAL:MODE (RES WxH or 'full')")
    ap.add_argument("--samples", type=int, default=None, help="native Cycles samples (default: the preset's)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--resume", action="store_true", help="keep production.csv's cells and run the others")
    ap.add_argument("--report", action="store_true", help="only write the report from production.csv")
    ap.add_argument("--gpu", action="store_true", help="Cycles on the GPU; results in production_gpu.*")
    args = ap.parse_args(argv)
    command = "python benchmarks/bench_production.py" + "".join(
        f" {a}" for a in (argv if argv is not None else sys.argv[1:]))
    RESULTS.mkdir(parents=True, exist_ok=True)
    stem = "production_gpu" if args.gpu else "production"
    csv_path = RESULTS / f"{stem}.csv"
    if not args.report:
        cells = [parse_cell(c) for c in args.cells] if args.cells else (quick_grid() if args.quick else full_grid())
        done = {r["cell"] for r in read_rows_csv(csv_path)} if args.resume else set()
        if not args.resume and csv_path.is_file():
            csv_path.unlink()
        for cell in cells:
            if cell_key(*cell) in done:
                continue
            print(f"cell {cell_key(*cell)} (load {os.getloadavg()[0]:.1f}) ...", file=sys.stderr, flush=True)
            row = {**run_cell(cell, args), "command": command}
            append_row_csv(csv_path, row)
            write_report(read_rows_csv(csv_path), command, stem, args.gpu)     # what is measured so far
            print(f"  {row['render_cpu_total_s']:.0f} CPU s per render, {row['process_wall_s']:.0f} s wall, "
                  f"{row['peak_rss_mib'] / 1024:.2f} GiB", file=sys.stderr, flush=True)
    rows = read_rows_csv(csv_path)
    write_report(rows, command, stem, args.gpu)
    plot(rows, RESULTS / f"{stem}.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
