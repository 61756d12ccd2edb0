"""RGB quality per CPU second: samples, adaptive sampling and OpenImageDenoise against a
1024-sample reference of the same frame; persistent data across the renders of a scene.

    .venv/bin/python benchmarks/bench_rgb_quality.py [--quick] [--cache DIR] [--report-only]

Frame: the demo preset's bin (seed 0, scene 0, camera pose 0, 320x240 as shipped), cropped to its
central 160x120 pixels with Blender's render border (the pixels keep the demo's size; the crop
holds bin floor, walls and parts; a quarter of the pixels keeps the 1024-sample reference
affordable on 2 shared cores). Every setting renders that crop with the product's Renderer
(`render.samples`, `render.adaptive_threshold`, `render.denoise`), seed 1234; the reference is
1024 samples, no adaptive sampling, no denoising, seed 99 (another seed: its own noise is
independent of the candidates'). Quality: PSNR (dB) and SSIM (grey, Gaussian window sigma 1.5,
Wang et al. 2004) of the 8-bit sRGB rgb.png against the reference's. Cost: process CPU seconds of
`Renderer.render` (Cycles + denoiser + reading/writing files), min of 2 calls.

Persistent data: 3 consecutive renders of one scene (poses 0..2) with and without
`render.persistent_data`, CPU seconds of each.

Writes benchmarks/results/rgb_quality.md, rgb_quality.csv and rgb_quality.png.
"""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from harness import Stopwatch, cached_renders, clocked, log_x_frame, on_path, sweep_parser, write_rows_csv, write_with_notes

on_path()
from bench_sl_render import build_world  # noqa: E402
from datapipe import config as C  # noqa: E402

SEED, REF_SEED, REF_SAMPLES = 1234, 99, 1024
BORDER = (0.25, 0.75, 0.25, 0.75)          # min_x, max_x, min_y, max_y: the central half of each axis
TODAY = {"samples": 32, "adaptive": 0.0, "denoise": False}


def plan(quick: bool):
    P = []
    for s in ((8, 32) if quick else (4, 8, 16, 32, 64, 128)):
        for dn in (False, True):
            P.append({"samples": s, "adaptive": 0.0, "denoise": dn})
    for thr in (() if quick else (0.1, 0.05, 0.02, 0.01)):
        for s in (64, 256):
            for dn in (False, True):
                P.append({"samples": s, "adaptive": thr, "denoise": dn})
    return P


def key(c) -> str:
    return f"s{c['samples']}_a{c['adaptive']:g}_d{int(c['denoise'])}"


def apply(renderer, c) -> None:
    """The Renderer's Cycles settings for case `c`, via the config it reads (setup re-applies them)."""
    r = renderer.cfg.render
    r.samples, r.adaptive_threshold, r.denoise = c["samples"], c["adaptive"], c["denoise"]
    renderer._setup_cycles()


def render_all(cases, cache: Path, log):
    meta_path = cache / "renders.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    todo = [c for c in cases if key(c) not in meta]
    if not todo and "reference" in meta and "persistent" in meta:
        return meta
    tmp = Path(tempfile.mkdtemp(prefix="rgbbench_"))
    cfg, bscene, camera, renderer, T = build_world("bin", (320, 240), tmp)
    cfg.render.threads = 0
    rd = bscene.render
    rd.use_border, rd.use_crop_to_border = True, True
    rd.border_min_x, rd.border_max_x, rd.border_min_y, rd.border_max_y = BORDER
    if "reference" not in meta:
        apply(renderer, {"samples": REF_SAMPLES, "adaptive": 0.0, "denoise": False})
        out, wall, cpu = clocked(lambda: renderer.render(tmp / "ref", REF_SEED))
        np.save(cache / "reference.npy", out.rgb)
        meta["reference"] = {"wall": wall, "cpu": cpu, "shape": list(out.rgb.shape)}
        meta_path.write_text(json.dumps(meta, indent=1))
        log(f"  reference: {wall:.1f} s wall, {cpu:.1f} CPU s, {out.rgb.shape}")
    for c in todo:
        apply(renderer, c)
        runs = []
        for _ in range(2):
            out, wall, cpu = clocked(lambda: renderer.render(tmp / "c", SEED))
            runs.append((cpu, wall))
        cpu, wall = min(runs)
        np.save(cache / f"{key(c)}.npy", out.rgb)
        meta[key(c)] = {"wall": wall, "cpu": cpu}
        meta_path.write_text(json.dumps(meta, indent=1))
        log(f"  {key(c)}: {wall:.1f} s wall, {cpu:.1f} CPU s")
    if "persistent" not in meta:
        apply(renderer, TODAY)
        res = {}
        for pd in (False, True):
            bscene.render.use_persistent_data = pd
            times = []
            for pose in range(3):
                camera.set_pose(pose)
                _, wall, cpu = clocked(lambda: renderer.render(tmp / "p", SEED))
                times.append(cpu)
            res[str(pd)] = times
            log(f"  persistent data {pd}: {times}")
        bscene.render.use_persistent_data = False
        meta["persistent"] = res
        meta_path.write_text(json.dumps(meta, indent=1))
    return meta


# ------------------------------------------------------------------------------------------------
# metrics (numpy)

def psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float("inf") if mse == 0 else float(10 * np.log10(255.0 ** 2 / mse))


def ssim(a: np.ndarray, b: np.ndarray, sigma: float = 1.5) -> float:
    """Mean SSIM of the grey images (Wang et al. 2004: Gaussian window, K1 0.01, K2 0.03, L 255)."""
    import cv2

    x, y = (im.astype(np.float64).mean(axis=-1) for im in (a, b))
    blur = lambda m: cv2.GaussianBlur(m, (11, 11), sigma)  # noqa: E731
    mx, my = blur(x), blur(y)
    sxx, syy, sxy = blur(x * x) - mx * mx, blur(y * y) - my * my, blur(x * y) - mx * my
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2
    m = ((2 * mx * my + c1) * (2 * sxy + c2)) / ((mx * mx + my * my + c1) * (sxx + syy + c2))
    return float(m.mean())


def evaluate(cases, meta, cache: Path):
    ref = np.load(cache / "reference.npy")
    rows = []
    for c in cases:
        if key(c) not in meta:
            continue
        img = np.load(cache / f"{key(c)}.npy")
        rows.append({**c, "cpu_s": meta[key(c)]["cpu"], "wall_s": meta[key(c)]["wall"],
                     "psnr_db": psnr(img, ref), "ssim": ssim(img, ref)})
    return rows


def pareto(rows):
    """Rows not dominated in (cpu_s min, psnr_db max), sorted by cost."""
    out, best = [], -np.inf
    for r in sorted(rows, key=lambda r: (r["cpu_s"], -r["psnr_db"])):
        if r["psnr_db"] > best:
            out.append(r)
            best = r["psnr_db"]
    return out


def label(r) -> str:
    return f"{r['samples']}{' a' + format(r['adaptive'], 'g') if r['adaptive'] else ''}{' +dn' if r['denoise'] else ''}"


def plot(rows, front, chosen, path):
    import cv2

    W, H, m = 960, 600, 80
    xs = np.log10([r["cpu_s"] for r in rows])
    ys = np.array([r["psnr_db"] for r in rows])
    x0, x1 = np.floor(xs.min() * 4) / 4, np.ceil(xs.max() * 4) / 4
    y0, y1 = np.floor(ys.min()) - 1, np.ceil(ys.max()) + 1
    font = cv2.FONT_HERSHEY_SIMPLEX
    img, px = log_x_frame((W, H), m, (x0, x1), (y0, y1), (0.2, 0.3, 0.5, 1, 2, 3, 5, 10, 20, 30, 50))
    for v in range(int(y0), int(y1) + 1, 2):
        p = px(x0, v)
        cv2.line(img, (m, p[1]), (W - m, p[1]), (235, 235, 235), 1)
        cv2.putText(img, f"{v}", (m - 30, p[1] + 4), font, 0.4, (0, 0, 0), 1)
    p38 = px(x0, 38.0)
    cv2.line(img, (m, p38[1]), (W - m, p38[1]), (0, 140, 0), 1)
    today = next((r for r in rows if all(r[k] == v for k, v in TODAY.items())), None)
    if today is not None:
        pt = px(np.log10(today["cpu_s"]), y0)
        cv2.line(img, (pt[0], m), (pt[0], H - m), (0, 140, 0), 1)
    cv2.putText(img, "RGB PSNR vs 1024-sample reference (dB) against CPU s per render (log), demo bin crop 160x120",
                (m, m - 40), font, 0.45, (0, 0, 0), 1)
    cv2.putText(img, "blue: no denoiser, red: OpenImageDenoise; line: Pareto front; green: 38 dB and today's "
                "32 samples; ring: default", (m, m - 20), font, 0.42, (0, 0, 0), 1)
    poly = np.array([px(np.log10(r["cpu_s"]), r["psnr_db"]) for r in front], np.int32)
    cv2.polylines(img, [poly], False, (90, 90, 90), 1)
    for i, r in enumerate(rows):
        p = px(xs[i], ys[i])
        col = (0, 0, 210) if r["denoise"] else (200, 90, 0)
        cv2.circle(img, p, 4, col, -1)
        cv2.putText(img, label(r), (p[0] + 6, p[1] - 4 + 12 * (i % 2)), font, 0.33, col, 1)
        if r is chosen:
            cv2.circle(img, p, 11, (0, 160, 0), 2)
    cv2.imwrite(str(path), img)


def report(rows, meta, out_dir: Path, elapsed: float):
    out_dir.mkdir(parents=True, exist_ok=True)
    write_rows_csv(out_dir / "rgb_quality.csv", rows)
    front = pareto(rows)
    D = C.RenderConfig()
    chosen = next((r for r in rows if r["samples"] == D.samples and r["adaptive"] == D.adaptive_threshold
                   and r["denoise"] == D.denoise), None)
    today = next((r for r in rows if all(r[k] == v for k, v in TODAY.items())), None)
    plot(rows, front, chosen, out_dir / "rgb_quality.png")
    ref = meta["reference"]
    L = ["# RGB quality per CPU second\n",
         "Generated by `benchmarks/bench_rgb_quality.py` (hand-written findings at the end). The demo's bin "
         "(pose 0, 320x240) cropped to its central 160x120 px; reference: "
         f"{REF_SAMPLES} samples, another seed ({ref['cpu']:.0f} CPU s). CPU seconds of this shared 2-core machine "
         f"(min of 2 calls). Bench time {elapsed / 60:.1f} min. `adaptive`: Cycles noise threshold (0 = off), "
         "`samples` then the maximum. `pareto`: not dominated in (CPU s, PSNR).\n",
         "| samples | adaptive | denoise | CPU s | wall s | PSNR dB | SSIM | pareto |", "|---|---|---|---|---|---|---|---|"]
    fr = {id(r) for r in front}
    for r in sorted(rows, key=lambda r: (r["adaptive"], r["denoise"], r["samples"])):
        mark = " (default)" if r is chosen else (" (today)" if r is today else "")
        L.append(f"| {r['samples']}{mark} | {r['adaptive']:g} | {'OIDN' if r['denoise'] else '-'} | {r['cpu_s']:.2f} | "
                 f"{r['wall_s']:.2f} | {r['psnr_db']:.2f} | {r['ssim']:.4f} | {'yes' if id(r) in fr else ''} |")
    if chosen is not None and today is not None:
        L.append(f"\nDefault: {label(chosen)} - {chosen['psnr_db']:.2f} dB, SSIM {chosen['ssim']:.4f}, "
                 f"{chosen['cpu_s']:.2f} CPU s ({chosen['cpu_s'] / today['cpu_s']:.2f}x today's {today['cpu_s']:.2f} s "
                 f"at {today['psnr_db']:.2f} dB); on the Pareto front: {'yes' if id(chosen) in fr else 'NO'}.\n")
    pd = meta.get("persistent")
    if pd:
        L += ["\n## Persistent data (3 renders of one scene, poses 0..2, today's RGB settings, full 320x240 crop "
              "as above)\n", "| persistent data | CPU s per render | total |", "|---|---|---|"]
        for k, v in pd.items():
            L.append(f"| {k} | {', '.join(f'{x:.2f}' for x in v)} | {sum(v):.2f} |")
    L.append("\n![rgb quality](rgb_quality.png)\n")
    write_with_notes(out_dir / "rgb_quality.md", L)


def main(argv=None):
    a = sweep_parser(__doc__, "datapipe_rgb_quality", quick="samples 8 and 32 only").parse_args(argv)
    log = lambda s: print(s, flush=True)  # noqa: E731
    clock = Stopwatch().start()
    cases = plan(a.quick)
    meta = cached_renders(a, cases, render_all, log)
    rows = evaluate(cases, meta, a.cache)
    report(rows, meta, a.out, clock.stop().wall_s)
    for r in pareto(rows):
        log(f"pareto: {label(r)} {r['cpu_s']:.2f} CPU s {r['psnr_db']:.2f} dB")


if __name__ == "__main__":
    main()
