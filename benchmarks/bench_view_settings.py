"""What a view's native RGB render costs that buys no quality: Cycles' per-render settings one at a
time against a 1024-sample reference of the same frame of `bin_picking.json` (issue #29 item 4).

    .venv/bin/python benchmarks/bench_view_settings.py [--quick] [--cache DIR] [--report-only]

Frame: `datapipe/presets/bin_picking.json` at the Zivid 2+ M60's 4x4 binning (612 x 512), scene 0
of seed 0 (the shipped drop: ~89 steel and matte plastic parts, `scene.fill`), the first drawn
`bin_view` camera pose, cropped with Blender's render border to its central 306 x 256 pixels (bin
floor, walls and the pile; a quarter of the pixels keeps the 1024-sample reference affordable on 2
shared cores). The product's Renderer renders every case with the preset's settings as they were before
this study (16 samples, the scene's tabulated Sobol pattern, OpenImageDenoise, max_bounces 4; the
preset now renders them with BLUE_NOISE, from this study) and ONE Cycles property changed on `scene.cycles` after the
Renderer's setup, at three seeds (1234, 2345, 3456); the reference is 1024 samples, no adaptive
sampling, no denoiser, seed 99 (its noise independent of the candidates'). Quality: PSNR (dB) and
SSIM of the 8-bit sRGB rgb.png against the reference's (bench_rgb_quality.py's metrics), mean of
the three seeds; the spread of the baseline's three seeds is the tolerance a setting's loss is held
to. Cost: process CPU seconds of `Renderer.render` (Cycles' path tracing + denoiser + EXR read-back,
all threads), median of the three seeds.

Writes benchmarks/results/view_settings.md and view_settings.csv.
"""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from harness import (Stopwatch, cached_renders, clocked, on_path, preset_dict, slug, sweep_parser, write_rows_csv,
                     write_with_notes)

on_path()
from bench_rgb_quality import psnr, ssim  # noqa: E402
from datapipe import config as C  # noqa: E402

SEEDS, REF_SEED, REF_SAMPLES = (1234, 2345, 3456), 99, 1024
BORDER = (0.25, 0.75, 0.25, 0.75)
BASE = "baseline (preset)"

# case name -> {scene.cycles property: value} set after the Renderer's setup (the preset's values
# otherwise: samples 16, OIDN, prefilter ACCURATE, quality HIGH, albedo + normal, max_bounces 4)
CASES = {
    BASE: {},
    "no denoiser": {"use_denoising": False},
    "prefilter FAST": {"denoising_prefilter": "FAST"},
    "prefilter NONE": {"denoising_prefilter": "NONE"},
    "quality BALANCED": {"denoising_quality": "BALANCED"},
    "quality FAST": {"denoising_quality": "FAST"},
    "passes RGB_ALBEDO": {"denoising_input_passes": "RGB_ALBEDO"},
    "passes RGB": {"denoising_input_passes": "RGB"},
    "prefilter FAST + quality BALANCED": {"denoising_prefilter": "FAST", "denoising_quality": "BALANCED"},
    "samples 12": {"samples": 12},
    "samples 8": {"samples": 8},
    "adaptive 0.05": {"use_adaptive_sampling": True, "adaptive_threshold": 0.05, "adaptive_min_samples": 0},
    "adaptive 0.1": {"use_adaptive_sampling": True, "adaptive_threshold": 0.1, "adaptive_min_samples": 0},
    "pattern BLUE_NOISE": {"sampling_pattern": "BLUE_NOISE"},
    "pattern AUTOMATIC": {"sampling_pattern": "AUTOMATIC"},
    "pattern BLUE_NOISE, samples 15": {"sampling_pattern": "BLUE_NOISE", "samples": 15},
    "pattern BLUE_NOISE, samples 14": {"sampling_pattern": "BLUE_NOISE", "samples": 14},
    "pattern BLUE_NOISE, samples 12": {"sampling_pattern": "BLUE_NOISE", "samples": 12},
    "max_bounces 3": {"max_bounces": 3},
    "max_bounces 2": {"max_bounces": 2},
}
QUICK = (BASE, "prefilter FAST")
# --view N (N > 0): another drawn camera pose of the same pile, only blue noise at 16, 15 and 14
# samples (a second frame for what the first one's sweep found: the presets adopted it at 16)
OTHER_VIEW = (BASE, "pattern BLUE_NOISE", "pattern BLUE_NOISE, samples 15", "pattern BLUE_NOISE, samples 14")
VIEW = {"index": 0}                   # the camera pose drawn for render VIEW of scene 0 (main sets it)


def bin_world(tmp: Path, binning: int = 4, view: int = 0, structured_light: bool = False):
    """(world, camera pose): bin_picking.json's world at `binning`, scene 0 dropped, the camera at the
    pose drawn for render `view`; the native render at the preset's settings before this study (16
    samples, the scene's own sampling pattern: the study adopted BLUE_NOISE)."""
    import bpy
    from datapipe.core.world import BlenderWorld
    from datapipe.draws.seeds import scene_rng

    bpy.ops.wm.read_factory_settings(use_empty=True)
    d = preset_dict(C.presets_dir() / "bin_picking.json")
    d["binning"] = binning
    d["render"]["samples"] = 16
    d["render"]["sampling_pattern"] = "SCENE"
    d["structured_light"]["enabled"] = structured_light
    d["output"]["overview"] = False
    cfg = C.loads(json.dumps(d))
    world = BlenderWorld(cfg, tmp / "world")
    world.setup()
    seed = cfg.scene.seed
    world.start_scene(0, seed, scene_rng(seed, 0), 1)
    T, _ = world.variety.place_camera(None, seed, 0, view)
    return world, T


def build(tmp: Path, binning: int = 4, crop: bool = True):
    """The native render only, the camera at render VIEW's pose, cropped to the central BORDER."""
    world, _ = bin_world(tmp, binning, VIEW["index"])
    if not crop:
        return world
    rd = world.blend.scene.render
    rd.use_border, rd.use_crop_to_border = True, True
    rd.border_min_x, rd.border_max_x, rd.border_min_y, rd.border_max_y = BORDER
    return world


def apply(world, props: dict) -> dict:
    """The preset's Cycles settings (the Renderer's setup), then `props`; returns what Cycles reads back."""
    world.renderer._setup_cycles()
    cy = world.blend.scene.cycles
    cy.sampling_pattern = "TABULATED_SOBOL"     # a new scene's, the baseline's: the Renderer leaves it (SCENE)
    for k, v in props.items():
        setattr(cy, k, v)
    return {k: getattr(cy, k) for k in ("samples", "use_denoising", "denoising_prefilter", "denoising_quality",
                                        "denoising_input_passes", "sampling_pattern", "max_bounces",
                                        "use_adaptive_sampling", "adaptive_threshold")}


def render_all(names, cache: Path, log):
    meta_path = cache / "renders.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    todo = [n for n in names if n not in meta]
    if not todo and "reference" in meta:
        return meta
    tmp = Path(tempfile.mkdtemp(prefix="viewset_"))
    world = build(tmp)
    if "reference" not in meta:
        apply(world, {"samples": REF_SAMPLES, "use_denoising": False})
        out, wall, cpu = clocked(lambda: world.renderer.render(tmp / "ref", REF_SEED))
        np.save(cache / "reference.npy", out.rgb)
        meta["reference"] = {"wall": wall, "cpu": cpu, "shape": list(out.rgb.shape)}
        meta_path.write_text(json.dumps(meta, indent=1))
        log(f"  reference: {wall:.1f} s wall, {cpu:.1f} CPU s, {out.rgb.shape}")
    for n in todo:
        readback = apply(world, CASES[n])
        cpus, walls = [], []
        for s in SEEDS:
            out, wall, cpu = clocked(lambda: world.renderer.render(tmp / "c", s))
            np.save(cache / f"{slug(n)}_{s}.npy", out.rgb)
            cpus.append(cpu)
            walls.append(wall)
        meta[n] = {"cpu": cpus, "wall": walls, "cycles": readback}
        meta_path.write_text(json.dumps(meta, indent=1))
        log(f"  {n}: CPU s {[round(c, 2) for c in cpus]}, {readback}")
    return meta


def evaluate(names, meta, cache: Path):
    ref = np.load(cache / "reference.npy")
    rows = []
    for n in names:
        if n not in meta:
            continue
        ps, ss = [], []
        for s in SEEDS:
            img = np.load(cache / f"{slug(n)}_{s}.npy")
            ps.append(psnr(img, ref))
            ss.append(ssim(img, ref))
        rows.append({"case": n, "cpu_s": float(np.median(meta[n]["cpu"])), "cpu_min": min(meta[n]["cpu"]),
                     "cpu_max": max(meta[n]["cpu"]), "psnr_db": float(np.mean(ps)), "psnr_min": min(ps),
                     "psnr_max": max(ps), "ssim": float(np.mean(ss)), "ssim_min": min(ss), "ssim_max": max(ss)})
    return rows


def report(rows, meta, out_dir: Path, elapsed: float):
    stem = f"view_settings{'_view' + str(VIEW['index']) if VIEW['index'] else ''}"
    write_rows_csv(out_dir / f"{stem}.csv", rows, float_fmt=".5g")
    base = next(r for r in rows if r["case"] == BASE)
    tol_db = base["psnr_max"] - base["psnr_min"]
    tol_ssim = base["ssim_max"] - base["ssim_min"]
    ref = meta["reference"]
    L = ["# A view's native render: Cycles settings against quality\n",
         "Generated by `benchmarks/bench_view_settings.py` (hand-written findings at the end). "
         "`bin_picking.json` at binning 4 (612 x 512), scene 0, the camera pose drawn for render "
         f"{VIEW['index']}, central 306 x 256 px; "
         f"reference: {REF_SAMPLES} samples, no denoiser, seed {REF_SEED} ({ref['cpu']:.0f} CPU s). Each case: the "
         "preset's former settings (16 samples, tabulated Sobol, OIDN prefilter ACCURATE, quality HIGH, albedo + normal, max_bounces 4) with "
         "the named Cycles property changed; seeds " + ", ".join(map(str, SEEDS)) + ". CPU s: median of the seeds "
         "(range); PSNR/SSIM: mean of the seeds (range). Machine: 2 cores shared with other work."
         + (f" Bench time {elapsed / 60:.1f} min." if elapsed else "") + "\n",
         f"Tolerance (the baseline's spread over its seeds): PSNR {tol_db:.2f} dB, SSIM {tol_ssim:.4f}.\n",
         "| case | CPU s (range) | vs baseline | PSNR dB (range) | dPSNR | SSIM (range) | dSSIM | within tolerance |",
         "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        dp, ds = r["psnr_db"] - base["psnr_db"], r["ssim"] - base["ssim"]
        ok = dp >= -tol_db and ds >= -tol_ssim
        L.append(f"| {r['case']} | {r['cpu_s']:.2f} ({r['cpu_min']:.2f}-{r['cpu_max']:.2f}) | "
                 f"{r['cpu_s'] / base['cpu_s']:.2f}x | {r['psnr_db']:.2f} ({r['psnr_min']:.2f}-{r['psnr_max']:.2f}) | "
                 f"{dp:+.2f} | {r['ssim']:.4f} ({r['ssim_min']:.4f}-{r['ssim_max']:.4f}) | {ds:+.4f} | "
                 f"{'yes' if ok else 'no'} |")
    L.append(f"\nBaseline read back: {meta[BASE]['cycles']}\n")
    write_with_notes(out_dir / f"{stem}.md", L)


FEWER = "pattern BLUE_NOISE, samples 15"          # what one sample less would save (not adopted)


def timing_ab(rounds: int, log) -> None:
    """The whole frame at the shipped binning 2 (1224 x 1024): the baseline and 15 samples of blue noise
    (not adopted), rendered in turns (`rounds` each, the same seed), so the machine's load falls on both alike;
    prints each render's CPU seconds and the medians."""
    tmp = Path(tempfile.mkdtemp(prefix="viewset_ab_"))
    world = build(tmp, binning=2, crop=False)
    cpu = {BASE: [], FEWER: []}
    for _ in range(rounds):
        for n in cpu:
            apply(world, CASES[n])
            _, wall, c = clocked(lambda: world.renderer.render(tmp / "ab", SEEDS[0]))
            cpu[n].append(c)
            log(f"  {n}: {c:.1f} CPU s ({wall:.0f} s wall)")
    for n, v in cpu.items():
        log(f"{n}: median {np.median(v):.1f} CPU s of {[round(x, 1) for x in v]}")
    log(f"15 blue-noise samples / baseline: {np.median(cpu[FEWER]) / np.median(cpu[BASE]):.3f}")


def main(argv=None):
    ap = sweep_parser(__doc__, "datapipe_view_settings", quick="the baseline and one case")
    ap.add_argument("--timing-ab", type=int, default=0, metavar="ROUNDS", help="instead of the sweep: the "
                    "baseline and blue noise at 15 samples on the whole 1224 x 1024 frame, in turns, ROUNDS each")
    ap.add_argument("--view", type=int, default=0, help="another camera pose of the pile (the pose drawn for "
                    "that render index), only blue noise at 16, 15 and 14 samples; cache and files *_viewN")
    a = ap.parse_args(argv)
    VIEW["index"] = a.view
    if a.view:
        a.cache = a.cache.with_name(f"{a.cache.name}_view{a.view}")
    log = lambda s: print(s, flush=True)  # noqa: E731
    if a.timing_ab:
        return timing_ab(a.timing_ab, log)
    clock = Stopwatch().start()
    names = list(QUICK if a.quick else OTHER_VIEW if a.view else CASES)
    meta = cached_renders(a, names, render_all, log)
    rows = evaluate(names, meta, a.cache)
    report(rows, meta, a.out, None if a.report_only else clock.stop().wall_s)
    for r in rows:
        log(f"{r['case']}: {r['cpu_s']:.2f} CPU s, {r['psnr_db']:.2f} dB, SSIM {r['ssim']:.4f}")


if __name__ == "__main__":
    main()
