"""Coverage of the fringe-order decision against a maximum-likelihood temporal decoder that knows the
true noise (issue #31, item 1). Writes benchmarks/results/sl_coverage.md and .csv.

Stacks (tests/sl/synth.py's analytic ray caster, no bpy; 320x240 camera, 1280x800 projector at 1 m):

- ``dark step``: issue #19's adversarial scene (``synth.dark_step_scene``: a tilted floor, boxes
  with 0.13 m and 0.25 m depth steps and their projector shadows, spheres, a floor patch of albedo
  0.015 and the tall box's top at 0.04), baselines 0.05 m (the step moves the coordinate by about
  one finest period) and 0.15 m;
- ``dark patches``: a box on a plane (depth step, shadow), albedo 0.8 with a vertical ramp
  0.04 -> 0.8 on the left quarter and five patches of 0.04-0.15, baseline 0.15 m.

Noise: ``synth.sensor_stack`` (peak 250 DN, read noise 1-4 DN, shot noise 40 e-/DN), float32, one
seed per case. The decoder runs with its defaults (it estimates the noise from the stack).

Oracle: per lit pixel, the order vector that maximises the likelihood of all frequencies' wrapped
phases (computed here from the noisy stack: N-step least squares) under the *true* phase noise
``sigma_phi = sqrt(2/N) sigma_I / B`` (B the noise-free modulation, sigma_I^2 = read^2 + A/40 at
the noise-free offset A): for every order of the finest frequency the other orders are rounded at
the weighted least-squares coordinate (twice), and the cost ``sum_i (K_i u - c_i - n_i)^2 / v_i``
is minimised. It decides every lit pixel; coverage = share of lit pixels whose coordinate is within
half a finest period of the truth (the oracle's coordinate folded into the decoder's range
``[-0.5, W - 0.5)``, so both meet the same ambiguity at the projector's edge).

Run: ``PYTHONPATH=$PWD python benchmarks/bench_sl_coverage.py`` (about 2 minutes on one core).
"""
from __future__ import annotations

import argparse
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
if "--datapipe" in sys.argv:            # decode with another checkout's datapipe (the baseline column)
    sys.path.insert(0, str(Path(sys.argv[sys.argv.index("--datapipe") + 1]).resolve()))
sys.path.insert(0, str(ROOT / "tests" / "sl"))
sys.path.insert(0, str(ROOT / "benchmarks"))

import synth  # noqa: E402
from harness import write_rows_csv, write_with_notes  # noqa: E402
from datapipe import sl  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
WP, HP = 1280, 800
CAM = (320, 240)
SETS = (((1, 8, 64), 4), ((16, 15), 4), ((1, 16), 4), ((13, 7), 4), ((8, 7), 3))
READS = (1.0, 2.0, 3.0, 4.0)
FULL_SCALE, E_PER_DN = 250.0, 40.0


def scenes():
    """(name, rig baseline, scene, albedo multiplier or None)."""
    return [("dark step 5 cm", 0.05, synth.dark_step_scene(), None),
            ("dark step 15 cm", 0.15, synth.dark_step_scene(), None),
            ("dark patches", 0.15, synth.box_scene(), synth.dark_patch_albedo((CAM[1], CAM[0])))]


def ls_phase(images, F, N):
    """Per frequency: wrapped phase in cycles [0, 1) and modulation (N-step least squares, uniform shifts)."""
    d = 2 * np.pi * np.arange(N) / N
    cyc, mod = [], []
    for i in range(F):
        fr = images[i * N:(i + 1) * N].astype(np.float64)
        C = np.tensordot(np.cos(d), fr, 1)
        S = np.tensordot(np.sin(d), fr, 1)
        cyc.append(np.mod(np.arctan2(-S, C) / (2 * np.pi), 1.0))
        mod.append(2.0 / N * np.hypot(C, S))
    return cyc, mod


def oracle_x(cyc, var, periods):
    """Maximum-likelihood coordinate (pixels) per pixel: 1D arrays in (cycles, cycles^2)."""
    per = np.asarray(periods, float)
    f = int(np.argmax(per))
    best_cost = np.full(cyc[0].shape, np.inf)
    best_u = np.zeros(cyc[0].shape)
    w = [per[i] ** 2 / var[i] for i in range(len(per))]
    wsum = sum(w)
    for nf in range(int(round(per[f]))):
        u = (nf + cyc[f]) / per[f]
        for _ in range(2):
            n = [np.rint(per[i] * u - cyc[i]) if i != f else nf for i in range(len(per))]
            u = sum(per[i] * (cyc[i] + n[i]) / var[i] for i in range(len(per))) / wsum
        cost = sum((per[i] * u - cyc[i] - n[i]) ** 2 / var[i] for i in range(len(per)))
        better = cost < best_cost
        best_cost = np.where(better, cost, best_cost)
        best_u = np.where(better, u, best_u)
    x = best_u * WP
    return np.where(x >= WP - 0.5, x - WP, x)            # the decoder's range [-0.5, W - 0.5)


def circ_err(x, truth):
    """|x - truth| (NaN where either is NaN): a coordinate folded across the projector's edge is wrong
    (its depth is), for the oracle as for the decoder."""
    return np.abs(x - truth)


def run_case(name, baseline, scene, alb, periods, steps, read, seed, decode_kw=None, log=print):
    cam, proj = synth.make_rig(cam_size=CAM, proj_size=(WP, HP), distance=1.0, baseline=baseline)
    gt = synth.render(scene, cam, proj, periods, steps)
    if alb is not None:
        gt.images = gt.images * alb
        gt.albedo = gt.albedo * alb
    stack = synth.sensor_stack(gt, full_scale=FULL_SCALE, read=read, e_per_dn=E_PER_DN, seed=seed)
    F = len(periods)
    half = WP / max(periods) / 2
    lit = gt.lit
    # oracle: the true noise of every pixel and frequency
    cyc, _ = ls_phase(stack, F, steps)
    _, mod0 = ls_phase(gt.images * FULL_SCALE, F, steps)
    a0 = gt.images.reshape(F, steps, *lit.shape).mean(1) * FULL_SCALE
    var = []
    for i in range(F):
        s_i = np.sqrt(read ** 2 + a0[i] / E_PER_DN)
        sphi = np.sqrt(2.0 / steps) * s_i / np.maximum(mod0[i], 1e-9)
        var.append((sphi / (2 * np.pi)) ** 2)
    xo = oracle_x([c[lit] for c in cyc], [v[lit] for v in var], periods)
    oracle = float(np.mean(circ_err(xo, gt.proj_x[lit]) < half))
    t0 = time.process_time()
    res = sl.decode(stack, periods=periods, steps=steps, P_cam=cam.P, P_proj=proj.P, proj_size=proj.size,
                    **(decode_kw or {}))
    cpu = time.process_time() - t0
    right = circ_err(res.proj_x, gt.proj_x) < half          # NaN -> False
    wrong = res.valid & ~right
    row = dict(stack=name, periods="(" + ", ".join(map(str, periods)) + f") x {steps}", read_dn=read, seed=seed,
               lit=int(lit.sum()), oracle=oracle, coverage=float(np.mean((res.valid & right)[lit])),
               wrong_of_valid=float(wrong.sum() / max(1, res.valid.sum())), wrong=int(wrong.sum()),
               shadow_valid=float(res.valid[gt.shadow].mean()) if gt.shadow.any() else 0.0, decode_cpu_s=cpu)
    row["gap"] = row["oracle"] - row["coverage"]
    log(f"{name:16s} {row['periods']:16s} read {read:.0f}: oracle {oracle:.4f} ours {row['coverage']:.4f} "
        f"wrong {row['wrong']} ({row['wrong_of_valid']:.1e}) shadow {row['shadow_valid']:.4f} cpu {cpu:.2f}s")
    return row


def run(sets=SETS, reads=READS, seed=0, names=None, log=print):
    rows = []
    for name, baseline, scene, alb in scenes():
        if names and name not in names:
            continue
        for periods, steps in sets:
            for read in reads:
                rows.append(run_case(name, baseline, scene, alb, periods, steps, read, seed, log=log))
    return rows


def write_report(rows, base_label=None):
    lines = ["# Fringe-order decision vs a maximum-likelihood oracle (issue #31)", "",
             f"Generated by `benchmarks/bench_sl_coverage.py` on {platform.machine()}, numpy {np.__version__}, "
             f"{time.strftime('%Y-%m-%d')}. Stacks, noise and the oracle: see the script's docstring. "
             "`coverage`: lit pixels decoded valid and within half a finest period of the truth; `oracle`: the same "
             "for the maximum-likelihood temporal decoder with the true noise (it decides every lit pixel); "
             "`gap` = oracle - coverage in points; `wrong`: valid pixels half a finest period or more off, share of "
             "the valid ones; `shadow valid`: projector-shadowed pixels with a depth"
             + (f"; `before`: the same stacks decoded by {base_label}" if base_label else "") + ".", ""]
    head = ["stack", "periods", "read DN", "oracle", "coverage", "gap", "wrong / valid", "wrong px", "shadow valid",
            "decode CPU s"]
    if base_label:
        head += ["before: coverage", "before: wrong / valid"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["stack"], r["periods"], f"{r['read_dn']:.0f}", f"{r['oracle']:.4f}", f"{r['coverage']:.4f}",
                 f"{100 * r['gap']:+.2f}", f"{r['wrong_of_valid']:.1e}", str(r["wrong"]), f"{r['shadow_valid']:.4f}",
                 f"{r['decode_cpu_s']:.2f}"]
        if base_label:
            cells += [f"{r['before_coverage']:.4f}", f"{r['before_wrong_of_valid']:.1e}"]
        lines.append("| " + " | ".join(cells) + " |")
    over = [r for r in rows if r["gap"] > 0.015]
    lines += ["", f"Cases more than 1.5 points below the oracle: {len(over)} of {len(rows)}"
              + (" (" + "; ".join(f"{r['stack']} {r['periods']} read {r['read_dn']:.0f}: {100 * r['gap']:.2f}"
                                  for r in over) + ")" if over else "")
              + f". Largest wrong share: {max(r['wrong_of_valid'] for r in rows):.1e}; "
              f"largest shadow-valid share: {max(r['shadow_valid'] for r in rows):.4f}.", ""]
    write_with_notes(RESULTS / "sl_coverage.md", lines)
    write_rows_csv(RESULTS / "sl_coverage.csv", rows)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="read noise 2 DN only, no report")
    ap.add_argument("--stack", action="append", help="only this stack (repeatable)")
    ap.add_argument("--datapipe", type=Path, help="decode with this checkout's datapipe; writes --json, no report")
    ap.add_argument("--json", type=Path, help="rows as JSON (with --datapipe)")
    ap.add_argument("--baseline", type=Path, help="a checkout (e.g. main: git worktree) decoded alongside: the "
                    "'before' columns")
    args = ap.parse_args(argv)
    rows = run(reads=(2.0,) if args.quick else READS, names=args.stack)
    if args.datapipe:
        import json
        args.json.write_text(json.dumps(rows))
        return 0
    base_label = None
    if args.baseline:
        import json
        import subprocess
        import tempfile
        with tempfile.TemporaryDirectory() as d:
            out = Path(d) / "rows.json"
            cmd = [sys.executable, __file__, "--datapipe", str(args.baseline), "--json", str(out)]
            if args.quick:
                cmd.append("--quick")
            for st in args.stack or []:
                cmd += ["--stack", st]
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL)
            base = json.loads(out.read_text())
        rev = subprocess.run(["git", "-C", str(args.baseline), "rev-parse", "--short", "HEAD"], capture_output=True,
                             text=True).stdout.strip()
        base_label = f"`{args.baseline.name}`@{rev}" if rev else f"`{args.baseline.name}`"
        for r, b in zip(rows, base):
            r["before_coverage"] = b["coverage"]
            r["before_wrong_of_valid"] = b["wrong_of_valid"]
    if not args.quick:
        write_report(rows, base_label)
    return 0


if __name__ == "__main__":
    sys.exit(main())
