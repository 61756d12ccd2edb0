"""What a view's fringe renders cost that buys no depth quality: `structured_light.samples` and the
Cycles settings the fringe layers path-trace with, against the z-buffer of `bin_picking.json`
(issue #29 item 4).

    .venv/bin/python benchmarks/bench_fringe_settings.py [--quick] [--cache DIR] [--report-only]

Frame: `datapipe/presets/bin_picking.json` at the Zivid 2+ M60's 4x4 binning (612 x 512; quadrature
fringes as shipped, HDR auto, reflection filter auto, the industrial sensor model), scene 0 of
seed 0 (~89 steel and matte plastic parts, `scene.fill`), the first drawn `bin_view` camera pose.
The native render runs once (its pixel-centre z-buffer is the truth); then the product's
`StructuredLightCamera.process` (fringe render + sensor model + decode + filters) runs per case
with one setting changed on `scene.cycles` (or `structured_light.samples`). The preset's case runs
at three Cycles seeds: their spread is the tolerance. Quality: the decoded depth's median and p99
|error| (mm) against the z-buffer on pixels valid in both, the valid share of the image, the share
off by more than 5 mm (`sl.depth_error_stats`), and the median per-pixel theoretical sigma_z (what
the confidence map says). Cost: process CPU seconds of the fringe call (`last_seconds`: render) and
of the whole `process` call (all threads).

Writes benchmarks/results/fringe_settings.md and fringe_settings.csv.
"""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from harness import Stopwatch, cached_renders, clocked, on_path, slug, sweep_parser, write_rows_csv, write_with_notes

on_path()
from datapipe import sl  # noqa: E402
from bench_view_settings import bin_world  # noqa: E402

BASE_SEEDS = (1234, 2345, 3456)
SEED = BASE_SEEDS[0]
BASE = "baseline (preset)"
# case -> ({scene.cycles property: value}, structured_light.samples or None)
CASES = {
    BASE: ({}, None),
    "structured_light.samples 2": ({}, 2),
    "structured_light.samples 3": ({}, 3),
    "max_bounces 3": ({"max_bounces": 3}, None),
    "max_bounces 2": ({"max_bounces": 2}, None),
    "max_bounces 1": ({"max_bounces": 1}, None),
    "caustics off": ({"caustics_reflective": False, "caustics_refractive": False}, None),
    "pattern BLUE_NOISE": ({"sampling_pattern": "BLUE_NOISE"}, None),
}
QUICK = (BASE, "max_bounces 2")


def render_all(names, cache: Path, log):
    meta_path = cache / "renders.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    todo = [n for n in names if n not in meta]
    if not todo and "truth" in meta:
        return meta
    tmp = Path(tempfile.mkdtemp(prefix="fringeset_"))
    world, T = bin_world(tmp, structured_light=True)   # the native render: the truth's z-buffer only
    cy = world.blend.scene.cycles
    out = world.renderer.render(tmp / "native", SEED)
    np.save(cache / "z.npy", out.depth)
    meta["truth"] = {"shape": list(out.depth.shape), "max_bounces": cy.max_bounces}
    meta_path.write_text(json.dumps(meta, indent=1))
    captured = {}
    scan0 = world.sl.scanner.scan

    def keep(*a, **k):
        captured["scan"] = s = scan0(*a, **k)
        return s

    world.sl.scanner.scan = keep
    defaults = {k: getattr(cy, k) for k in ("max_bounces", "caustics_reflective", "caustics_refractive",
                                            "sampling_pattern")}
    samples0 = world.sl.samples
    for n in todo:
        props, samples = CASES[n]
        for k, v in defaults.items():
            setattr(cy, k, v)
        for k, v in props.items():
            setattr(cy, k, v)
        world.sl.set_samples(samples0 if samples is None else samples)
        runs = []
        for s in (BASE_SEEDS if n == BASE else (SEED,)):
            _, wall, cpu = clocked(lambda: world.sl.process(tmp / "fr", s, T))
            scan = captured["scan"]
            np.savez_compressed(cache / f"{slug(n)}_{s}.npz", depth=scan.result.depth, valid=scan.result.valid,
                                sigma_z=scan.sigma_z)
            runs.append({"seed": s, "cpu": cpu, "wall": wall, "render_wall": world.sl.last_seconds["render"],
                         "layer_samples": world.sl.layer_samples})
        meta[n] = {"runs": runs, "cycles": {k: getattr(cy, k) for k in defaults}, "sl_samples": world.sl.samples}
        meta_path.write_text(json.dumps(meta, indent=1))
        log(f"  {n}: {[(r['seed'], round(r['cpu'], 1)) for r in runs]}, layer samples {runs[0]['layer_samples']}")
    world.sl.set_samples(samples0)
    return meta


def evaluate(names, meta, cache: Path):
    z = np.load(cache / "z.npy")
    rows = []
    for n in names:
        if n not in meta:
            continue
        for r in meta[n]["runs"]:
            f = np.load(cache / f"{slug(n)}_{r['seed']}.npz")
            st = sl.depth_error_stats(f["depth"], z, valid=f["valid"])
            sz = f["sigma_z"][f["valid"] & np.isfinite(f["sigma_z"])]
            rows.append({"case": n, "seed": r["seed"], "process_cpu_s": r["cpu"], "layer_samples": r["layer_samples"],
                         "valid": float(f["valid"].mean()), "median_mm": st["median_abs"] * 1e3,
                         "p99_mm": st["p99"] * 1e3, "out5": st["outlier_fraction"],
                         "sigma_z_mm": float(np.median(sz)) * 1e3 if sz.size else float("nan")})
    return rows


def report(rows, meta, out_dir: Path, elapsed: float):
    write_rows_csv(out_dir / "fringe_settings.csv", rows, float_fmt=".5g")
    base = [r for r in rows if r["case"] == BASE]
    spread = {k: (min(r[k] for r in base), max(r[k] for r in base)) for k in ("median_mm", "p99_mm", "valid",
                                                                              "process_cpu_s")}
    bcpu = float(np.median([r["process_cpu_s"] for r in base]))
    L = ["# A view's fringe renders: settings against depth quality\n",
         "Generated by `benchmarks/bench_fringe_settings.py` (hand-written findings at the end). `bin_picking.json` "
         "at binning 4 (612 x 512, quadrature fringes), scene 0, first drawn camera pose; truth: the native render's "
         "z-buffer. Each row: one `StructuredLightCamera.process` call (fringe render, sensor model, decode, filters) "
         "with the named setting changed; the preset at three seeds. Machine: 2 cores shared with other work."
         + (f" Bench time {elapsed / 60:.1f} min." if elapsed else "") + "\n",
         "Tolerance (the preset's spread over its seeds): median " + f"{spread['median_mm'][0]:.4f}-"
         f"{spread['median_mm'][1]:.4f} mm, p99 {spread['p99_mm'][0]:.3f}-{spread['p99_mm'][1]:.3f} mm, valid "
         f"{spread['valid'][0]:.4f}-{spread['valid'][1]:.4f}; CPU {spread['process_cpu_s'][0]:.1f}-"
         f"{spread['process_cpu_s'][1]:.1f} s.\n",
         "| case | seed | layer samples | process CPU s | vs preset | valid | median mm | p99 mm | > 5 mm | median sigma_z mm |",
         "|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        L.append(f"| {r['case']} | {r['seed']} | {r['layer_samples']} | {r['process_cpu_s']:.1f} | "
                 f"{r['process_cpu_s'] / bcpu:.2f}x | {r['valid']:.4f} | {r['median_mm']:.4f} | {r['p99_mm']:.3f} | "
                 f"{r['out5']:.4f} | {r['sigma_z_mm']:.4f} |")
    write_with_notes(out_dir / "fringe_settings.md", L)


def main(argv=None):
    a = sweep_parser(__doc__, "datapipe_fringe_settings", quick="the preset and one case").parse_args(argv)
    log = lambda s: print(s, flush=True)  # noqa: E731
    clock = Stopwatch().start()
    names = list(QUICK if a.quick else CASES)
    meta = cached_renders(a, names, render_all, log)
    rows = evaluate(names, meta, a.cache)
    report(rows, meta, a.out, None if a.report_only else clock.stop().wall_s)
    for r in rows:
        log(f"{r['case']} {r['seed']}: {r['process_cpu_s']:.1f} CPU s, valid {r['valid']:.4f}, median "
            f"{r['median_mm']:.4f} mm, p99 {r['p99_mm']:.3f} mm")


if __name__ == "__main__":
    main()
