"""Decoder speed at 1080p (issue #31): today's decoder, main's decoder when this speed pass began
and OpenCV, in one run; main's recorded figure beside them.

Run as a script (not a test):  .venv/bin/python benchmarks/bench_sl_speed.py [--repeat 7] [--also COMMIT]

Stack: issue #19's adversarial bin-like scene (tests/sl/synth.py `dark_step_scene`: tilted floor,
boxes 0.13 / 0.25 m high, two spheres, projector shadows, a dark box top of albedo 0.04 beside the
tall step), camera 1920x1080 at 1 m, projector 1280x800, baseline 5 cm; read 1 DN + shot noise
(40 e-/DN), rounded to uint8; periods (1, 8, 64) x 4. Main's decoder is the package as of commit
MAIN, extracted with `git archive` into a temporary folder and imported under another name, so both
run in this process on the same stack, in turns (round robin), CPU time (`time.process_time`, all
threads) and wall time, median of `--repeat` runs. The recorded figure is the "today" row of
benchmarks/results/sl_speed.csv at MAIN (measured in another run, under another load). OpenCV:
`structured_light.SinusoidalPattern` PSP on the 3 images of K = 64 plus its spatial `unwrapPhaseMap`
(its design: 3 images, one period set, relative phase, no depth). `--also COMMIT` adds the decoder as
of COMMIT (e.g. where a later speed round began) to the timings, the stage table and the
same-outputs table, so a round's gain is measured in one run.

Writes benchmarks/results/sl_speed.md and sl_speed.csv (with the hand-written sl_speed_notes.md).
"""
from __future__ import annotations

import argparse
import csv
import gc
import importlib
import io
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "sl"))
sys.path.insert(0, str(ROOT / "benchmarks"))

import synth  # noqa: E402
from harness import write_rows_csv, write_with_notes  # noqa: E402
from datapipe import sl  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
MAIN = "6927a1b"            # main when this speed pass began (issue #31 item 3)
PERIODS, STEPS = (1, 8, 64), 4
NEW, OLD = "today's decoder", f"main (git {MAIN})"
STAGES = ("setup + noise fit", "slabs (per-pixel decode)", "pooled order decision",
          "spatial neighbour pass + re-triangulation", "assemble")


def frozen_decoder(commit: str, tmp: Path, name: str):
    """`datapipe` as of `commit`, importable beside today's (package renamed `name`)."""
    tar = subprocess.run(["git", "-C", str(ROOT), "archive", commit, "datapipe"], check=True,
                         capture_output=True).stdout
    sub = tmp / name
    sub.mkdir()
    subprocess.run(["tar", "-x", "-C", str(sub)], input=tar, check=True)
    (sub / "datapipe").rename(tmp / name / name)
    sys.path.insert(0, str(sub))
    return importlib.import_module(f"{name}.sl")


def recorded_figure(commit: str) -> str:
    """CPU ms (median and best) of the "today" row of sl_speed.csv as recorded at `commit`."""
    text = subprocess.run(["git", "-C", str(ROOT), "show", f"{commit}:benchmarks/results/sl_speed.csv"],
                          check=True, capture_output=True, text=True).stdout
    row = next(r for r in csv.DictReader(io.StringIO(text)) if r["decoder"] == "today")
    return f"{float(row['cpu_med']):.0f} ({float(row['cpu_best']):.0f})"


def stack_1080p():
    cam, proj = synth.make_rig(cam_size=(1920, 1080), proj_size=(1280, 800), distance=1.0, baseline=0.05)
    gt = synth.render(synth.dark_step_scene(), cam, proj, PERIODS, STEPS)
    u8 = np.clip(np.rint(synth.sensor_stack(gt, seed=0)), 0, 255).astype(np.uint8)
    return u8, gt, cam, proj


def opencv_run(u8_3, proj_size, cam_size, K=64):
    p = cv2.structured_light.SinusoidalPattern.Params()
    p.width, p.height = proj_size
    p.nbrOfPeriods = K
    p.methodId = cv2.structured_light.PSP
    pat = cv2.structured_light.SinusoidalPattern.create(p)
    wrapped, mask = pat.computePhaseMap(list(u8_3))
    return pat.unwrapPhaseMap(wrapped, cam_size, shadowMask=mask)


def round_robin(fns: dict, repeat: int) -> dict:
    """Median and best CPU / wall ms of each callable, run in turns after one warm-up each."""
    for f in fns.values():
        f()
    t = {k: ([], []) for k in fns}
    for _ in range(repeat):
        for k, f in fns.items():
            gc.collect()
            c0, w0 = time.process_time(), time.perf_counter()
            f()
            t[k][0].append((time.process_time() - c0) * 1e3)
            t[k][1].append((time.perf_counter() - w0) * 1e3)
    return {k: dict(cpu_med=float(np.median(c)), cpu_best=min(c), wall_med=float(np.median(w)), wall_best=min(w))
            for k, (c, w) in t.items()}


def _setup(setup, images, kw):
    """The decoder's set-up: the named options object where the package has one, else main's 22
    positional arguments (the defaults of `decode`)."""
    if hasattr(setup, "DecodeOptions"):
        return setup.prepare_decode(images, setup.DecodeOptions(**kw))
    return setup.prepare_decode(images, kw["periods"], kw["steps"], kw["P_cam"], kw["P_proj"], kw["proj_size"],
                                "auto", None, None, None, 0.05, 1e-3, None, None, 1e-3, None, None, "x", True,
                                None, True, 1.0)


def stages(pkg: str, images, kw, repeat):
    """CPU ms of a decoder's steps (median; STAGES), for package `pkg` (``datapipe`` or a frozen
    copy with the same step modules); the pooled order decision timed by wrapping
    ``orders.pooled_orders`` where ``decode_neighbours`` calls it."""
    setup = importlib.import_module(f"{pkg}.sl.decode_setup")
    slab = importlib.import_module(f"{pkg}.sl.decode_slab")
    nb = importlib.import_module(f"{pkg}.sl.decode_neighbours")
    dec = importlib.import_module(f"{pkg}.sl.decode")
    pooled, spent = nb.pooled_orders, [0.0]

    def timed(*a, **k):
        c0 = time.process_time()
        try:
            return pooled(*a, **k)
        finally:
            spent[0] += time.process_time() - c0

    acc = {k: [] for k in STAGES}
    nb.pooled_orders = timed
    try:
        for _ in range(repeat + 1):
            spent[0] = 0.0
            c = [time.process_time()]
            st = _setup(setup, images, kw)
            c.append(time.process_time())
            H, W = st.shape
            out = slab.DecodeMaps.allocate(H, W, len(st.plan.periods))
            st.tri.coefficients
            coefs = st.plan.stage_coefs()
            rows = max(1, (1 << 16) // W)
            with np.errstate(all="ignore"):
                for r0 in range(0, H, rows):
                    slab.decode_slab(st, out, r0, min(H, r0 + rows), coefs)
                c.append(time.process_time())
                nb.neighbour_pass(st, out)
            c.append(time.process_time())
            dec._assemble(st, out)
            c.append(time.process_time())
            ms = [(b - a) * 1e3 for a, b in zip(c[:-1], c[1:])]
            for k, v in zip(STAGES, (ms[0], ms[1], spent[0] * 1e3, ms[2] - spent[0] * 1e3, ms[3])):
                acc[k].append(v)
    finally:
        nb.pooled_orders = pooled
    return {k: float(np.median(v[1:])) for k, v in acc.items()}


def same_maps(a, b, lit) -> dict:
    """How two decoders' results differ: reason codes, valid masks (and their agreement over the lit
    pixels), NaN depths, the largest depth, confidence and wrapped-phase differences, modulation
    values not equal (main's cv2.magnitude rounds 1 ulp differently by its buffers' alignment)."""
    return dict(reason=int(np.sum(a.reason != b.reason)), valid=int(np.sum(a.valid != b.valid)),
                agree=float(np.mean((a.valid == b.valid)[lit])),
                nan=int(np.sum(np.isnan(a.depth) != np.isnan(b.depth))),
                depth=float(np.nanmax(np.abs(a.depth - b.depth))),
                confidence=float(np.max(np.abs(a.confidence - b.confidence))),
                modulation=int(np.sum(a.modulation != b.modulation)),
                phase=float(max(np.max(np.abs(x.astype(np.float64) - y)) for x, y in zip(a.wrapped, b.wrapped))))


def write_report(times, quality, same, st, recorded, repeat, refs):
    md = [
        "# Decoder speed, 1920x1080 (1, 8, 64) x 4 uint8 (issue #31)",
        "",
        f"Machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores (shared with other jobs), "
        f"numpy {np.__version__}, OpenCV {cv2.__version__}, load average {os.getloadavg()[0]:.1f} at the end of the run "
        "(other engineers' jobs: wall times are inflated by it, CPU times less). Generated by `benchmarks/bench_sl_speed.py` "
        f"(stack and method in its module doc). Median (best) of {repeat} runs in turns; CPU = process time of "
        "all threads, the figure other jobs on this shared machine inflate least.",
        "",
        "| decoder | CPU ms | wall ms | correct / lit | wrong / decoded |",
        "|---|---|---|---|---|",
        f"| main's recorded figure (benchmarks/results/sl_speed.csv at git {MAIN}, another run) | {recorded} | - | - | - |",
    ]
    for k, t in times.items():
        q = quality.get(k)
        qs = f"{q[0]:.4f} | {q[1]} / {q[2]}" if q else "- | -"
        md.append(f"| {k} | {t['cpu_med']:.0f} ({t['cpu_best']:.0f}) | {t['wall_med']:.0f} ({t['wall_best']:.0f}) | {qs} |")
    md += ["", "Where the CPU time goes (median ms, same stack, same run; `decode`'s own steps timed one by one, the "
           "pooled decision by a timer around `orders.pooled_orders`):", "",
           "| stage | " + " | ".join(f"{k} CPU ms" for k in st) + " |", "|---|" + "---|" * len(st)]
    md += [f"| {k} | " + " | ".join(f"{v[k]:.0f}" for v in st.values()) + " |" for k in STAGES]
    md += ["| sum | " + " | ".join(f"{sum(v.values()):.0f}" for v in st.values()) + " |", "",
           f"Same outputs: today's maps against {refs}'s on this stack:", "",
           "| noise, against | reason codes differing | valid differing | valid agreement (lit) | NaN depth differing "
           "| max depth difference m | max confidence difference | max wrapped phase difference rad "
           "| modulation values differing |", "|---|---|---|---|---|---|---|---|---|"]
    md += [f"| {k} | {v['reason']} | {v['valid']} | {v['agree']:.6f} | {v['nan']} | {v['depth']:.1e} | "
           f"{v['confidence']:.1e} | {v['phase']:.1e} | {v['modulation']} |" for k, v in same.items()] + [""]
    write_with_notes(RESULTS / "sl_speed.md", md)
    print("\n".join(md))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--also", default=None, help="another commit's decoder to time and compare beside")
    args = ap.parse_args()
    u8, gt, cam, proj = stack_1080p()
    kw = dict(periods=PERIODS, steps=STEPS, P_cam=cam.P, P_proj=proj.P, proj_size=proj.size)
    u8_3 = np.clip(np.rint(synth.sensor_stack(synth.render(synth.dark_step_scene(), cam, proj, (64,), 3),
                                              seed=1)), 0, 255).astype(np.uint8)
    with tempfile.TemporaryDirectory() as tmp:
        old = frozen_decoder(MAIN, Path(tmp), "datapipe_main")
        decoders = {NEW: sl.decode, OLD: old.decode}
        refs = {OLD: "datapipe_main"}
        if args.also:
            also = f"git {args.also}"
            decoders[also] = frozen_decoder(args.also, Path(tmp), "datapipe_also").decode
            refs[also] = "datapipe_also"
        fns = {}
        for name, dec in decoders.items():
            fns[name] = lambda dec=dec: dec(u8, **kw)
            fns[name + ", no neighbour pass"] = lambda dec=dec: dec(u8, **kw, spatial=False)
        fns["OpenCV PSP + unwrapPhaseMap (3 images, K = 64)"] = lambda: opencv_run(u8_3, proj.size, cam.size)
        times = round_robin(fns, args.repeat)
        half = proj.size[0] / max(PERIODS) / 2
        quality = {}
        for name, dec in decoders.items():
            for spatial in (True, False):
                r = dec(u8, **kw, spatial=spatial)
                right = np.abs(r.proj_x - gt.proj_x) < half
                quality[name if spatial else name + ", no neighbour pass"] = (
                    float(np.mean((r.valid & right)[gt.lit])), int(np.sum(r.valid & ~right)), int(r.valid.sum()))
        # the same maps as each reference's? with the noise given and fitted from the stack
        same = {f"{label}, {ref}": same_maps(sl.decode(u8, **kw, **extra), decoders[ref](u8, **kw, **extra), gt.lit)
                for ref in refs
                for label, extra in (("noise given (noise_sigma=1.2)", dict(noise_sigma=1.2)), ("noise fitted", {}))}
        st = {NEW: stages("datapipe", u8, kw, args.repeat)}
        st.update({ref: stages(pkg, u8, kw, args.repeat) for ref, pkg in refs.items()})
    rows = [dict(decoder=k, **{m: round(v, 1) for m, v in t.items()},
                 correct_of_lit=quality.get(k, (np.nan,))[0]) for k, t in times.items()]
    write_rows_csv(RESULTS / "sl_speed.csv", rows)
    write_report(times, quality, same, st, recorded_figure(MAIN), args.repeat, " and ".join(refs))


if __name__ == "__main__":
    main()
