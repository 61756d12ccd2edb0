"""Is `confidence` calibrated? The reliability curve of the structured-light decoder (issue #19).

Run as a script:  .venv/bin/python benchmarks/bench_sl_confidence.py [--quick]

`DecodeResult.confidence` claims: among pixels with confidence >= c, at most 1 - c have a wrong
fringe order. Checked on the adversarial stacks of tests/sl/synth.py (`dark_step_scene`: tilted
floor, boxes with 0.13 / 0.25 m steps, spheres, projector shadows, a floor patch of albedo 0.015
and a box top of albedo 0.04), periods (1, 8, 64) x 4, read + shot noise (read sigma 1, 2, 4 DN,
40 e- per DN, full scale 250 DN), baselines 5 cm (the step moves the coordinate by ~one fine
period: the neighbour pass's trap) and 15 cm, 640 x 480, no noise model passed in (the decoder's own
per-pixel estimate), two noise seeds each. Two decodes per stack:

* default (`max_wrong` 1e-3, neighbour pass on): the valid pixels, VALID and NEIGHBOUR_ORDER;
* every order kept (`max_wrong=1`, no neighbour pass): the temporal confidence over its whole range.

Writes benchmarks/results/sl_confidence.md, .csv and sl_confidence.png (observed wrong share against
the bound 1 - c, log-log: calibrated points lie on or below the diagonal).
"""
from __future__ import annotations


import cv2
import numpy as np

from harness import RESULTS, log_x_frame, on_path, parser, write_rows_csv, write_with_notes

on_path("tests/sl")
import synth  # noqa: E402
from datapipe import sl  # noqa: E402

PERIODS = (1, 8, 64)
WP = 1280
BOUNDS = (0.5, 0.2, 0.1, 0.05, 0.02, 1e-2, 5e-3, 2e-3, 1e-3, 1e-4, 1e-5)   # 1 - c


def reliability(conf, wrong, mask):
    """Per bound b = 1 - c: (pixels with confidence >= c, wrong among them)."""
    c, w = conf[mask], wrong[mask]
    return [(b, int(np.sum(c >= 1 - b)), int(np.sum(w & (c >= 1 - b)))) for b in BOUNDS]


def run(res_px=(640, 480), reads=(1.0, 2.0, 4.0), seeds=(0, 1), baselines=(0.05, 0.15)):
    rows, totals = [], {}
    for b in baselines:
        cam, proj = synth.make_rig(cam_size=res_px, proj_size=(WP, 800), distance=1.0, baseline=b)
        gt = synth.render(synth.dark_step_scene(), cam, proj, PERIODS, 4)
        kw = dict(periods=PERIODS, steps=4, P_cam=cam.P, P_proj=proj.P, proj_size=proj.size)
        for read in reads:
            for seed in seeds:
                stack = synth.sensor_stack(gt, read=read, seed=seed)
                for mode, extra in (("default", {}), ("every order", dict(max_wrong=1.0, spatial=False))):
                    res = sl.decode(stack, **kw, **extra)
                    wrong = ~(np.abs(res.proj_x - gt.proj_x) < WP / max(PERIODS) / 2)   # NaN truth: wrong
                    filled = res.reason == sl.Reason.NEIGHBOUR_ORDER
                    for b_, n, w in reliability(res.confidence, wrong, res.valid):
                        rows.append(dict(baseline_m=b, read_dn=read, seed=seed, decode=mode, bound=b_,
                                         pixels=n, wrong=w, filled=int(filled.sum()),
                                         valid=int(res.valid.sum())))
                        key = (mode, read, b_)
                        t = totals.setdefault(key, [0, 0])
                        t[0] += n
                        t[1] += w
                print(f"b={b} read={read} seed={seed} done", flush=True)
    return rows, totals


def draw(path, totals, reads):
    W, H, m = 900, 640, 70
    img, px = log_x_frame((W, H), m, (-5.5, 0.0), (-7.0, 0.0), [1e-5, 1e-4, 1e-3, 1e-2, 0.1, 1])
    font = cv2.FONT_HERSHEY_SIMPLEX
    for e in range(-7, 1):
        p = px(-5.5, e)
        cv2.line(img, (m, p[1]), (W - m, p[1]), (235, 235, 235), 1)
        cv2.putText(img, "0" if e == -7 else f"1e{e}", (8, p[1] + 5), font, 0.42, (0, 0, 0), 1)
    cv2.line(img, px(-5.5, -5.5), px(0.0, 0.0), (0, 0, 0), 1, cv2.LINE_AA)
    cv2.putText(img, "bound 1 - c (log)", (W // 2 - 60, H - 25), font, 0.5, (0, 0, 0), 1)
    cv2.putText(img, "wrong share among confidence >= c (log; 0 drawn at 1e-7)", (m, 30), font, 0.5, (0, 0, 0), 1)
    colours = {("default", 1.0): (200, 40, 20), ("default", 2.0): (30, 140, 30), ("default", 4.0): (30, 30, 200),
               ("every order", 1.0): (230, 150, 150), ("every order", 2.0): (150, 220, 150),
               ("every order", 4.0): (150, 150, 240)}
    ly = m + 15
    for (mode, read), col in colours.items():
        if read not in reads:
            continue
        pts = []
        for b in BOUNDS:
            n, w = totals.get((mode, read, b), (0, 0))
            if n:
                pts.append(px(np.log10(b), np.log10(w / n) if w else -7.0))
        for a, c in zip(pts[:-1], pts[1:]):
            cv2.line(img, a, c, col, 1, cv2.LINE_AA)
        for p in pts:
            cv2.circle(img, p, 4, col, -1, cv2.LINE_AA)
        cv2.circle(img, (W - m - 250, ly), 4, col, -1, cv2.LINE_AA)
        cv2.putText(img, f"{mode}, read {read:g} DN", (W - m - 238, ly + 5), font, 0.42, (0, 0, 0), 1)
        ly += 20
    cv2.imwrite(str(path), img)


def main():
    args = parser(__doc__, quick="one seed, 320 x 240").parse_args()
    reads = (1.0, 2.0, 4.0)
    res_px, seeds = ((320, 240), (0,)) if args.quick else ((640, 480), (0, 1))
    rows, totals = run(res_px, reads, seeds)
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_rows_csv(RESULTS / "sl_confidence.csv", rows)
    draw(RESULTS / "sl_confidence.png", totals, reads)
    lines = ["# Is the decoder's confidence calibrated? (reliability curve)", "",
             f"Generated by `benchmarks/bench_sl_confidence.py`. Stacks: `synth.dark_step_scene()` at "
             f"{res_px[0]} x {res_px[1]}, periods {PERIODS} x 4, read + shot noise (read sigma 1 / 2 / 4 DN, "
             f"40 e- per DN, full scale 250 DN), baselines 5 and 15 cm, seeds {list(seeds)}, no noise model passed "
             "in. Claim: among pixels with confidence >= c at most 1 - c have a wrong fringe order. Pooled "
             "over baselines and seeds; 'default' counts the valid pixels (VALID and NEIGHBOUR_ORDER), "
             "'every order' decodes with `max_wrong=1, spatial=False` (every decoded pixel, temporal "
             "confidence only). Plot: `sl_confidence.png`.", "",
             "| decode | read DN | bound 1 - c | pixels with conf >= c | wrong | wrong share | within bound |",
             "|---|---|---|---|---|---|---|"]
    worst = 0.0
    for mode in ("default", "every order"):
        for read in reads:
            for b in BOUNDS:
                n, w = totals.get((mode, read, b), (0, 0))
                if not n:
                    continue
                share = w / n
                worst = max(worst, share / b)
                lines.append(f"| {mode} | {read:g} | {b:g} | {n} | {w} | {share:.2e} | "
                             f"{'yes' if share <= b else '**no**'} |")
    lines += ["", f"Largest observed share / bound: {worst:.3f} (calibrated: <= 1)."]
    write_with_notes(RESULTS / "sl_confidence.md", lines)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
