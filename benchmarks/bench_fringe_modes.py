"""Fringe modes side by side: "render" (every pattern path-traced) against "fast" (one flat-lit
render, patterns synthesised), depth error against run time, and whole demo runs.

    .venv/bin/python benchmarks/bench_fringe_modes.py [--quick] [--cache DIR] [--report-only] [--no-demo]

Scenes and metrics as in bench_sl_render.py (its build_world and metrics are reused): the demo
preset's bin (seed 0, scene 0, pose 0) and the floor alone, 320x240 and 640x480, shipped
structured-light defaults, `industrial` sensor; errors against the z-buffer of the same pose. Each
fast-mode fringe call is timed twice (min of process CPU seconds; the machine is shared). The native render
is the preset's 32-sample RGB/depth render of the same pose.

Demo runs: the demo preset (4 renders, 320x240) in one process each - structured light off and
fast (and render with --demo-render) - timed end to end, with the annotations' valid fractions.

Writes benchmarks/results/sl_fringe_modes.md, .csv and sl_fringe_modes.png.
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from harness import (ROOT, Stopwatch, cached_renders, clocked, column_table, log_x_frame, on_path, sweep_parser,
                     write_rows_csv, write_with_notes)

on_path()
from bench_sl_render import RES, SEED, metrics, open_worlds  # noqa: E402
from datapipe import config as C  # noqa: E402
from datapipe import sl  # noqa: E402
from datapipe.config.plan import FringePlan  # noqa: E402
from datapipe.core import structured_light as SLM  # noqa: E402

MODES = ("render", "fast")
# variant -> fringe mode, Cycles seed offset, fast mode's bounce_min_gain (None: shipped)
VARIANTS = {"render": ("render", 0, None), "render_seed2": ("render", 1, None), "fast": ("fast", 0, None),
            "fast_k1": ("fast", 0, 0.5), "fast_offset": ("fast", 0, 2.0)}
WITHIN = 0.05          # acceptance: fast within 5% of render on valid, median, p99, > 5 mm


def key(scene, res, mode, samples):
    return f"{scene}_{res}_{mode}_s{samples}"


def plan(quick: bool):
    D = C.StructuredLightConfig()
    P = [("bin", "320", v, D.samples) for v in VARIANTS]
    if not quick:
        P += [("bin", "640", v, D.samples) for v in ("render", "fast", "fast_k1", "fast_offset")]   # render: see notes
        P += [("plane", "320", v, D.samples) for v in ("render", "fast")]
    return P


def render_all(cases, cache: Path, log):
    meta_path = cache / "renders.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    todo_by_world: dict = {}
    for c in cases:
        todo_by_world.setdefault(c[:2], []).extend([c] if key(*c) not in meta else [])
    for todo, tmp, (cfg, bscene, camera, renderer, T) in open_worlds(todo_by_world, meta, cache, log, "fmbench_"):
        for variant, (mode, dseed, min_gain) in VARIANTS.items():
            mcs = [c for c in todo if c[2] == variant]
            if not mcs:
                continue
            cfg2 = cfg.copy()
            cfg2.structured_light.enabled = True
            cfg2.structured_light.fringe_mode = mode
            slc = SLM.StructuredLightCamera(cfg2, bscene, camera, renderer,
                                            FringePlan.from_config(cfg2, bounce_min_gain=min_gain))
            slc.setup()
            for c in mcs:
                slc.set_samples(c[3])
                runs = []
                for _ in range(1 if mode == "render" else 2):      # the long render mode: one call
                    (stack, _), wall, cpu = clocked(lambda: slc.render_fringes(tmp / "fringes", SEED + dseed, T))
                    runs.append((cpu, wall))
                cpu, wall = min(runs)
                np.savez_compressed(cache / f"{key(*c)}.npz", rad=stack)
                meta[key(*c)] = {"wall": wall, "cpu": cpu}
                meta_path.write_text(json.dumps(meta, indent=1))
                log(f"  {key(*c)}: {wall:.1f} s wall, {cpu:.1f} CPU s")
            slc.teardown()
    return meta


def decode_all(cases, meta, cache: Path):
    rows = []
    for c in cases:
        scene_kind, res, variant, samples = c
        if key(*c) not in meta:
            continue
        nat = np.load(cache / f"native_{scene_kind}_{res}.npz")
        cfg = C.default_config()
        cfg.camera.resolution = list(RES[res])
        scanner = sl.Scanner.from_config(cfg)
        rad = np.load(cache / f"{key(*c)}.npz")["rad"]
        scanner.scan(rad, SEED, nat["K"], nat["T"])         # warm the triangulation cache
        scan, dec_s, _ = clocked(lambda: scanner.scan(rad, SEED, nat["K"], nat["T"]))
        m = metrics(scan.result, scan, nat["depth"])
        r, n = meta[key(*c)], meta[f"native_{scene_kind}_{res}"]
        rows.append({"scene": scene_kind, "res": "x".join(map(str, RES[res])), "mode": variant, "samples": samples,
                     "fringe_cpu_s": r["cpu"], "fringe_wall_s": r["wall"], "decode_s": dec_s,
                     "native_cpu_s": n["cpu"], "fringe_over_native": (r["cpu"] + dec_s) / n["cpu"], **m})
    return rows


DEMO_SCRIPT = r"""
import json, sys, time
import bpy
from datapipe import config as C
from datapipe.engine.pipeline import Pipeline
spec = json.loads(sys.argv[1])
cfg = C.default_config()
cfg.render.threads = 2
cfg.structured_light.enabled = spec["sl"]
if spec["sl"]:
    cfg.structured_light.fringe_mode = spec["mode"]
bpy.ops.wm.read_factory_settings(use_empty=True)
t0, c0 = time.perf_counter(), time.process_time()
stages = {}
for ev in Pipeline(cfg, spec["out"]).run():
    for k, v in (ev.seconds or {}).items():
        stages[k] = stages.get(k, 0.0) + v
wall, cpu = time.perf_counter() - t0, time.process_time() - c0
print("RESULT " + json.dumps({"wall": wall, "cpu": cpu, "stages": stages}))
"""


def demo_runs(log, with_render: bool = False):
    out = []
    for sl_on, mode in ((False, "-"), (True, "fast")) + (((True, "render"),) if with_render else ()):
        d = Path(tempfile.mkdtemp(prefix="fmdemo_")) / "out"
        spec = {"sl": sl_on, "mode": mode, "out": str(d)}
        p = subprocess.run([sys.executable, "-c", DEMO_SCRIPT, json.dumps(spec)], cwd=ROOT, capture_output=True,
                           text=True, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
        line = next((ln for ln in p.stdout.splitlines() if ln.startswith("RESULT ")), None)
        if line is None:
            raise RuntimeError(p.stdout[-2000:] + p.stderr[-2000:])
        res = json.loads(line[7:])
        valid = []
        for sj in sorted(d.glob("scene.*/scene.json")):
            for r in json.loads(sj.read_text())["renders"]:
                if "structured_light" in r:
                    valid.append(r["structured_light"]["valid_fraction"])
        res.update(sl=sl_on, mode=mode, valid=valid)
        out.append(res)
        log(f"  demo sl={sl_on} {mode}: {res['wall']:.1f} s wall, {res['cpu']:.1f} CPU s, valid {valid}")
    return out


# ------------------------------------------------------------------------------------------------
# report

COLS = [("scene", "{}"), ("res", "{}"), ("mode", "{}"), ("samples", "{}"), ("fringe_cpu_s", "{:.2f}"),
        ("decode_s", "{:.2f}"), ("native_cpu_s", "{:.1f}"), ("fringe_over_native", "{:.2f}"), ("valid", "{:.3f}"),
        ("median_mm", "{:.3f}"), ("rmse_mm", "{:.3f}"), ("p99_mm", "{:.2f}"), ("out5", "{:.4f}"),
        ("sigma_meas_mm", "{:.3f}"), ("sigma_theo_mm", "{:.3f}"), ("ratio", "{:.2f}")]


def table(rows, cols=COLS) -> str:
    return column_table(rows, cols)


def compare(rows):
    """fast vs render at the default samples, per scene/res: relative differences of the acceptance
    metrics (valid fraction, median, p99, > 5 mm)."""
    D = C.StructuredLightConfig()
    out = []
    for scene in ("bin", "plane"):
        for res in ("320x240", "640x480"):
            pair = {r["mode"]: r for r in rows if r["scene"] == scene and r["res"] == res
                    and r["samples"] == D.samples}
            if "render" not in pair:
                continue
            rr = pair["render"]
            for v, f in pair.items():
                if v == "render":
                    continue
                d = {"scene": scene, "res": res, "variant": v, "speedup": rr["fringe_cpu_s"] / f["fringe_cpu_s"]}
                for k in ("valid", "median_mm", "p99_mm", "out5"):
                    d[k] = (f[k] - rr[k]) / rr[k] if rr[k] else (0.0 if f[k] == rr[k] else float("inf"))
                d["out5_abs"] = f["out5"] - rr["out5"]
                out.append(d)
    return out


def plot(rows, path):
    import cv2

    pts = [r for r in rows if r["scene"] == "bin"]
    W, H, m = 900, 560, 80
    xs = np.log10([r["fringe_cpu_s"] + r["decode_s"] for r in pts])
    ys = np.array([r["rmse_mm"] for r in pts])
    x0, x1 = np.floor(xs.min() * 2) / 2, np.ceil(xs.max() * 2) / 2
    y0, y1 = 0.0, max(ys.max() * 1.15, 0.1)
    font = cv2.FONT_HERSHEY_SIMPLEX
    img, px = log_x_frame((W, H), m, (x0, x1), (y0, y1), (0.3, 0.5, 1, 2, 3, 5, 10, 20, 30, 50, 100))
    for v in np.linspace(y0, y1, 6):
        p = px(x0, v)
        cv2.putText(img, f"{v:.2f}", (m - 45, p[1] + 4), font, 0.4, (0, 0, 0), 1)
    cv2.putText(img, "bin scene: depth RMSE vs z-buffer (mm) against fringe render + decode CPU s (log)",
                (m, m - 40), font, 0.5, (0, 0, 0), 1)
    cv2.putText(img, "blue 320x240, red 640x480; dots: render mode, squares: fast mode; dashed: native render",
                (m, m - 20), font, 0.42, (0, 0, 0), 1)
    colours = {"320x240": (200, 90, 0), "640x480": (0, 0, 210)}
    for res, col in colours.items():
        nat = [r["native_cpu_s"] for r in pts if r["res"] == res]
        if nat:
            p = px(np.log10(nat[0]), y0)
            for yy in range(m, H - m, 12):
                cv2.line(img, (p[0], yy), (p[0], yy + 6), col, 1)
    for i, r in enumerate(pts):
        p = px(xs[i], ys[i])
        col = colours[r["res"]]
        if r["mode"].startswith("fast"):
            cv2.rectangle(img, (p[0] - 5, p[1] - 5), (p[0] + 5, p[1] + 5), col, -1)
        else:
            cv2.circle(img, p, 5, col, -1)
        cv2.putText(img, f"{r['mode']} s{r['samples']}", (p[0] + 8, p[1] - 6), font, 0.38, col, 1)
    cv2.imwrite(str(path), img)


def report(rows, demo, out_dir: Path, elapsed: float):
    out_dir.mkdir(parents=True, exist_ok=True)
    write_rows_csv(out_dir / "sl_fringe_modes.csv", rows)
    plot(rows, out_dir / "sl_fringe_modes.png")
    L = ["# Fringe modes: render vs fast\n",
         "Generated by `benchmarks/bench_fringe_modes.py` (hand-written findings at the end). Shipped "
         "structured-light defaults, `industrial` sensor, shipped decoder; CPU seconds of this shared 2-core "
         f"machine (min of 2 calls in fast mode, 1 in render mode). Bench time {elapsed / 60:.1f} min.\n",
         "`fringe_cpu_s`: the fringe Cycles call(s) (+ the synthesis in fast mode); `fringe_over_native`: "
         "(fringe + decode) / the native 32-sample render of the same pose.\n",
         table(rows), "\n## fast vs render (relative difference, fast - render)\n",
         "| scene | res | variant | speed-up | valid | median | p99 | > 5 mm (rel) | > 5 mm (abs, points) |",
         "|---|---|---|---|---|---|---|---|---|"]
    for d in compare(rows):
        L.append(f"| {d['scene']} | {d['res']} | {d['variant']} | {d['speedup']:.1f}x | {d['valid']:+.1%} | {d['median_mm']:+.1%} | "
                 f"{d['p99_mm']:+.1%} | {d['out5']:+.0%} | {d['out5_abs'] * 100:+.3f} |")
    if demo:
        base = next(d for d in demo if not d["sl"])
        L += ["\n## Demo preset runs (4 renders, 320x240, one process each)\n",
              "| structured light | wall s | CPU s | CPU vs no SL | structured_light stage s | valid fractions |",
              "|---|---|---|---|---|---|"]
        for d in demo:
            L.append(f"| {d['mode'] if d['sl'] else 'off'} | {d['wall']:.1f} | {d['cpu']:.1f} | "
                     f"{d['cpu'] / base['cpu']:.2f}x | {d['stages'].get('structured_light', 0.0):.1f} | "
                     f"{', '.join(f'{v:.3f}' for v in d['valid']) or '-'} |")
    L.append("\n![fringe modes](sl_fringe_modes.png)\n")
    write_with_notes(out_dir / "sl_fringe_modes.md", L)


def main(argv=None):
    ap = sweep_parser(__doc__, "datapipe_fringe_modes", quick="the 320x240 bin only")
    ap.add_argument("--no-demo", action="store_true")
    ap.add_argument("--demo-render", action="store_true", help="also a demo run in render mode (slow)")
    a = ap.parse_args(argv)
    log = lambda s: print(s, flush=True)  # noqa: E731
    clock = Stopwatch().start()
    cases = plan(a.quick)
    meta = cached_renders(a, cases, render_all, log)
    rows = decode_all(cases, meta, a.cache)
    demo_path = a.cache / "demo.json"
    if not a.no_demo and not a.report_only:
        demo_path.write_text(json.dumps(demo_runs(log, a.demo_render)))
    demo = json.loads(demo_path.read_text()) if demo_path.is_file() else []
    report(rows, demo, a.out, clock.stop().wall_s)
    for d in compare(rows):
        log(str(d))


if __name__ == "__main__":
    main()
