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

Oracle (``tests/sl/ml_oracle.py``): per lit pixel, the order vector that maximises the likelihood of
all frequencies' wrapped phases (computed here from the noisy stack: N-step least squares) under the
*true* phase noise ``sigma_phi = sqrt(2/N) sigma_I / B`` (B the noise-free modulation,
sigma_I^2 = read^2 + A/40 at the noise-free offset A): for every order of the finest frequency the
other orders are rounded at the weighted least-squares coordinate (twice), and the cost
``sum_i (K_i u - c_i - n_i)^2 / v_i`` is minimised. It decides every lit pixel; coverage = share of
lit pixels whose coordinate is within half a finest period of the truth (the oracle's coordinate
folded into the decoder's range ``[-0.5, W - 0.5)``, so both meet the same ambiguity at the
projector's edge). Its posterior (flat prior over the order vectors, ``ml_oracle.decide``) gives the
probability that the decided coordinate is within half a finest period of the truth; the *sure*
oracle keeps only pixels where that is >= 1 - 1e-4, so its expected wrong share is <= 0.01%, the
issue's limit for the decoder: the like-for-like comparison.

Run: ``PYTHONPATH=$PWD python benchmarks/bench_sl_coverage.py`` (about 3 minutes on one core).
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

import ml_oracle  # noqa: E402
import synth  # noqa: E402
from harness import write_rows_csv, write_with_notes  # noqa: E402
from datapipe import sl  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
WP, HP = 1280, 800
CAM = (320, 240)
SETS = (((1, 8, 64), 4), ((16, 15), 4), ((1, 16), 4), ((13, 7), 4), ((8, 7), 3))
READS = (1.0, 2.0, 3.0, 4.0)
FULL_SCALE, E_PER_DN = 250.0, 40.0
SURE_RISK = 1e-4          # the sure oracle's posterior risk: issue #31's 0.01% wrong orders
CAL_BINS = (0.0, 0.5, 0.9, 0.99, 0.999, 1 - SURE_RISK, 1.1)    # posterior bins of the calibration table


def scenes():
    """(name, rig baseline, scene, albedo multiplier or None)."""
    return [("dark step 5 cm", 0.05, synth.dark_step_scene(), None),
            ("dark step 15 cm", 0.15, synth.dark_step_scene(), None),
            ("dark patches", 0.15, synth.box_scene(), synth.dark_patch_albedo((CAM[1], CAM[0])))]


def fold(u):
    """Projector column (pixels) of a coordinate in projector widths, folded into the decoder's range
    [-0.5, W - 0.5)."""
    x = u * WP
    return np.where(x >= WP - 0.5, x - WP, x)


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
    cyc, _ = ml_oracle.ls_phase(stack, F, steps)
    var = ml_oracle.true_phase_var(gt.images, F, steps, read, E_PER_DN, FULL_SCALE)
    uo, post = ml_oracle.decide([c[lit] for c in cyc], [v[lit] for v in var], periods)
    oright = circ_err(fold(uo), gt.proj_x[lit]) < half
    sure = post >= 1 - SURE_RISK
    oracle = float(np.mean(oright))
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
    row["oracle_wrong"] = 1.0 - oracle                       # it decides every lit pixel
    row["oracle_sure"] = float(np.mean(sure & oright))
    row["oracle_sure_wrong"] = float(np.sum(sure & ~oright) / max(1, sure.sum()))
    row["gap_sure"] = row["oracle_sure"] - row["coverage"]
    b = np.digitize(post, CAL_BINS) - 1                      # per posterior bin: pixels, summed posterior, right
    row["calibration"] = [[int(np.sum(b == k)), float(post[b == k].sum()), int(oright[b == k].sum())]
                          for k in range(len(CAL_BINS) - 1)]
    log(f"{name:16s} {row['periods']:16s} read {read:.0f}: oracle {oracle:.4f} ours {row['coverage']:.4f} "
        f"sure {row['oracle_sure']:.4f} ({row['oracle_sure_wrong']:.1e}) wrong {row['wrong']} "
        f"({row['wrong_of_valid']:.1e}) shadow {row['shadow_valid']:.4f} cpu {cpu:.2f}s")
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
             "`gap` = oracle - coverage in points; `oracle wrong`: the oracle's decided pixels that are wrong (all lit "
             "pixels are decided); `sure oracle`: the oracle keeping only pixels whose posterior of being right is "
             ">= 1 - 1e-4 (expected wrong share <= 0.01%), lit pixels kept and right; `sure wrong`: its kept pixels "
             "that are wrong; `sure gap` = sure oracle - coverage in points; `wrong`: valid pixels half a finest "
             "period or more off, share of the valid ones; `shadow valid`: projector-shadowed pixels with a depth"
             + (f"; `before`: the same stacks decoded by {base_label}" if base_label else "") + ".", ""]
    head = ["stack", "periods", "read DN", "oracle", "coverage", "gap", "oracle wrong", "sure oracle", "sure wrong",
            "sure gap", "wrong / valid", "wrong px", "shadow valid", "decode CPU s"]
    if base_label:
        head += ["before: coverage", "before: wrong / valid"]
    lines += ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        cells = [r["stack"], r["periods"], f"{r['read_dn']:.0f}", f"{r['oracle']:.4f}", f"{r['coverage']:.4f}",
                 f"{100 * r['gap']:+.2f}", f"{r['oracle_wrong']:.1e}", f"{r['oracle_sure']:.4f}",
                 f"{r['oracle_sure_wrong']:.1e}", f"{100 * r['gap_sure']:+.2f}", f"{r['wrong_of_valid']:.1e}",
                 str(r["wrong"]), f"{r['shadow_valid']:.4f}",
                 f"{r['decode_cpu_s']:.2f}"]
        if base_label:
            cells += [f"{r['before_coverage']:.4f}", f"{r['before_wrong_of_valid']:.1e}"]
        lines.append("| " + " | ".join(cells) + " |")
    def below(key, what):
        over = [r for r in rows if r[key] > 0.015]
        return (f"Cases more than 1.5 points below {what}: {len(over)} of {len(rows)}"
                + (" (" + "; ".join(f"{r['stack']} {r['periods']} read {r['read_dn']:.0f}: {100 * r[key]:.2f}"
                                    for r in over) + ")" if over else "") + ". ")
    lines += ["", below("gap", "the oracle") + below("gap_sure", "the sure oracle")
              + f"Largest wrong share: {max(r['wrong_of_valid'] for r in rows):.1e}; "
              f"largest shadow-valid share: {max(r['shadow_valid'] for r in rows):.4f}; the sure oracle's largest "
              f"wrong share: {max(r['oracle_sure_wrong'] for r in rows):.1e}.", ""]
    cal = np.sum([r["calibration"] for r in rows], 0)
    lines += ["The oracle's posterior against what happened, all cases pooled (lit pixels; a calibrated posterior "
              "has `right` = `mean posterior` within the binomial spread):", "",
              "| posterior | pixels | mean posterior | right | wrong pixels |", "|---|---|---|---|---|"]
    for k, (n, psum, nright) in enumerate(cal):
        span = f"[{CAL_BINS[k]:g}, " + ("1]" if k == len(cal) - 1 else f"{CAL_BINS[k + 1]:g})")
        lines.append(f"| {span} | {int(n)} | "
                     + (f"{psum / n:.6f} | {nright / n:.6f} | {int(n - nright)} |" if n else "- | - | 0 |"))
    lines.append("")
    write_with_notes(RESULTS / "sl_coverage.md", lines)
    write_rows_csv(RESULTS / "sl_coverage.csv", [{k: v for k, v in r.items() if k != "calibration"} for r in rows])


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
