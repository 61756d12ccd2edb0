"""Does a GPU render give the scanner the same data as a CPU render? The demo's scene (the embedded
default config of `python -m datapipe demo`: 4 renders at 320 x 240, structured light on) made twice
in separate processes, `render.device` CPU and GPU, the same seed; then per render:

- the scanner against its own render's z-buffer, for each device: the share of the image with
  scanner depth, median and 99th percentile of |scanner - z-buffer|, the share of valid pixels more
  than 5 mm off, all and away from depth edges (a z-buffer step over 5 mm between 4-neighbours,
  dilated by 2 px), as `bench_sl_truth.py` counts them;
- the two devices against each other: the largest difference of the parts' poses (the drop runs on
  the CPU in both: it must be 0), of the z-buffers where both have depth, the RGB images' PSNR
  (two Monte-Carlo estimates of one image: they differ by render noise, not by a bias), and the
  share of pixels where one device's scanner has depth and the other's has not;
- wall and CPU seconds of each process (the GPU one includes the kernels' first load: on a card
  without precompiled kernels in Blender's wheel, the driver compiles them once per machine).

Which Cycles backend rendered is read from run.json (`render_device`, written for GPU runs). Without a GPU, Cycles
falls back to the CPU (one line on stderr) and the table says so.

    python benchmarks/bench_gpu_parity.py [--renders 4] [--keep DIR]

Writes benchmarks/results/gpu_parity.md (with the hand-written gpu_parity_notes.md, if any).
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from harness import RESULTS, ROOT, machine, md_table, parser, run_child, today, write_with_notes

sys.path.insert(0, str(ROOT))
from datapipe.config import default_config  # noqa: E402
from datapipe.reader import read_run  # noqa: E402

EDGE_STEP_M = 0.005     # a z-buffer step over this between 4-neighbours is a depth edge
EDGE_PX = 2             # pixels within this of a depth edge are "at an edge" (as bench_sl_truth.py)
OFF_M = 0.005           # "far off": the project's 5 mm line


def preset(device: str, renders: int) -> dict:
    cfg = default_config()
    cfg.render.device = device
    cfg.scene.num_renders = renders
    return cfg.to_dict()


def make_run(device: str, renders: int, out: Path, work: Path) -> dict:
    pf = work / f"preset_{device.lower()}.json"
    pf.write_text(json.dumps(preset(device, renders), indent=1))
    with open(work / f"stderr_{device.lower()}.txt", "w") as err:
        child = run_child([sys.executable, "-m", "datapipe", "run", str(pf), "--out", str(out), "--quiet"],
                          cwd=ROOT, stdout=subprocess.DEVNULL, stderr=err)
    log = (work / f"stderr_{device.lower()}.txt").read_text()
    if child.returncode != 0:
        raise RuntimeError(f"{device} run failed (exit {child.returncode}):\n{log[-3000:]}")
    rec = json.loads((out / "run.json").read_text())
    return {"wall_s": child.wall_s, "cpu_s": child.cpu_s, "log": log,
            "backend": rec.get("render_device", "CPU")}


def edge_mask(z: np.ndarray) -> np.ndarray:
    """Pixels within EDGE_PX of a z-buffer step over EDGE_STEP_M (or of a pixel without depth)."""
    import cv2
    zf = np.where(np.isfinite(z), z, 0.0)
    step = np.zeros(z.shape, bool)
    dx = np.abs(np.diff(zf, axis=1)) > EDGE_STEP_M
    dy = np.abs(np.diff(zf, axis=0)) > EDGE_STEP_M
    step[:, 1:] |= dx
    step[:, :-1] |= dx
    step[1:] |= dy
    step[:-1] |= dy
    step |= ~np.isfinite(z)
    k = np.ones((2 * EDGE_PX + 1, 2 * EDGE_PX + 1), np.uint8)
    return cv2.dilate(step.astype(np.uint8), k) > 0


def scanner_stats(r) -> dict:
    z, s = r.depth, r.sl_depth
    both = np.isfinite(z) & np.isfinite(s)
    err = np.abs(s - z)[both]
    off = both & (np.abs(np.where(both, s - z, 0)) > OFF_M)
    away = off & ~edge_mask(z)
    n = max(int(both.sum()), 1)
    return {"valid": float(np.isfinite(s).mean()), "median_mm": float(np.median(err)) * 1e3 if err.size else np.nan,
            "p99_mm": float(np.percentile(err, 99)) * 1e3 if err.size else np.nan,
            "off": float(off.sum()) / n, "off_away": int(away.sum())}


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    peak = 255.0 if a.dtype == np.uint8 else 1.0
    return float("inf") if mse == 0 else 10 * np.log10(peak ** 2 / mse)


def compare(cpu_dir: Path, gpu_dir: Path) -> list[dict]:
    rows = []
    for rc, rg in zip(read_run(cpu_dir).renders, read_run(gpu_dir).renders):
        pose = max((float(np.abs(np.asarray(a["T_cam_obj"]) - np.asarray(b["T_cam_obj"])).max())
                    for a, b in zip(rc.objects, rg.objects)), default=0.0)
        zc, zg = rc.depth, rg.depth
        zb = np.isfinite(zc) & np.isfinite(zg)
        sc, sg = np.isfinite(rc.sl_depth), np.isfinite(rg.sl_depth)
        rows.append({"render": f"{rc.scene}/{rc.name}", "cpu": scanner_stats(rc), "gpu": scanner_stats(rg),
                     "pose_diff": pose, "parts": (len(rc.objects), len(rg.objects)),
                     "z_diff_mm": float(np.abs(zc - zg)[zb].max()) * 1e3 if zb.any() else np.nan,
                     "z_cover_diff": float((np.isfinite(zc) != np.isfinite(zg)).mean()),
                     "rgb_psnr": psnr(rc.rgb, rg.rgb), "sl_cover_diff": float((sc != sg).mean())})
    return rows


def report(rows: list[dict], runs: dict, command: str) -> list[str]:
    out = [f"# GPU against CPU renders: the same data for the scanner? (bench_gpu_parity.py)", "",
           f"Generated by `{command}` on {machine()}, {today()}. The demo's scene (embedded default "
           f"config), {len(rows)} renders, made once with `render.device` CPU and once GPU, the same seed, "
           "each in its own process.", ""]
    out += md_table(["device", "Cycles backend", "wall s", "CPU s"],
                    [[d, runs[d]["backend"], f"{runs[d]['wall_s']:.1f}", f"{runs[d]['cpu_s']:.1f}"] for d in runs])
    out += ["", "Scanner against the z-buffer of its own render (`off` = share of valid pixels > 5 mm off; "
            "`off away` = how many of those are more than 2 px from a depth edge):", ""]
    out += md_table(["render", "device", "scanner depth", "median mm", "p99 mm", "off", "off away"],
                    [[r["render"], d, f"{r[k]['valid']:.3f}", f"{r[k]['median_mm']:.3f}", f"{r[k]['p99_mm']:.2f}",
                      f"{r[k]['off']:.3%}", r[k]["off_away"]] for r in rows for d, k in (("CPU", "cpu"), ("GPU", "gpu"))])
    out += ["", "The two devices against each other:", ""]
    out += md_table(["render", "parts", "max pose difference", "max z-buffer difference mm",
                     "z-buffer coverage differs", "RGB PSNR dB", "scanner coverage differs"],
                    [[r["render"], "/".join(map(str, r["parts"])), f"{r['pose_diff']:.2e}", f"{r['z_diff_mm']:.3f}",
                      f"{r['z_cover_diff']:.4%}", f"{r['rgb_psnr']:.1f}", f"{r['sl_cover_diff']:.3%}"] for r in rows])
    fallback = [ln for ln in runs["GPU"]["log"].splitlines() if "finds no GPU" in ln]
    if fallback:
        out += ["", f"No GPU here: the GPU run rendered on the CPU (`{fallback[0].strip()}`)."]
    return out


def main(argv=None) -> int:
    ap = parser(__doc__, quick=None)
    ap.add_argument("--renders", type=int, default=4, help="renders of the demo scene (default 4, as the demo)")
    ap.add_argument("--keep", default=None, help="keep both runs in this folder")
    args = ap.parse_args(argv)
    command = "python benchmarks/bench_gpu_parity.py" + "".join(
        f" {a}" for a in (argv if argv is not None else sys.argv[1:]))
    with tempfile.TemporaryDirectory(prefix="bench_gpu_parity_") as tmp:
        base = Path(args.keep) if args.keep else Path(tmp)
        base.mkdir(parents=True, exist_ok=True)
        runs = {}
        for device in ("CPU", "GPU"):
            print(f"{device} run ...", file=sys.stderr, flush=True)
            runs[device] = make_run(device, args.renders, base / device.lower(), base)
            print(f"  {runs[device]['wall_s']:.1f} s wall, backend {runs[device]['backend']}", file=sys.stderr, flush=True)
        rows = compare(base / "cpu", base / "gpu")
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_with_notes(RESULTS / "gpu_parity.md", report(rows, runs, command))
    return 0


if __name__ == "__main__":
    sys.exit(main())
