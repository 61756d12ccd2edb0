"""Structured-light depth against the truth on real Cycles renders: where the wrong points are.

    .venv/bin/python benchmarks/bench_sl_truth.py [--cache DIR] [--no-render] [--cases steel,aluminium]
                                                  [--samples 64] [--res 640x480] [--explain]

Cases (benchmarks/sl_truth_cases.py renders them once and caches them in an ignored folder, so a
decoder change costs the decode alone): the shipped demo (`python -m datapipe demo`: 4 renders),
the original GUI rig with the camera 0.55 m above the bin (legacy pickle defaults, 320x240), the
matte-plastic bin at 0.8 m, steel and aluminium parts at 0.6 m -- each in both fringe modes
("fast": flat-lit render + synthesis; "render": every pattern path-traced). Every case is decoded
by the product's scanner (sl.Scanner.from_config, defaults) on the radiance the product decoded.

Metrics against the z-buffer of the same render: valid fraction; median, p99 of |sl - z|; the
share of valid pixels more than 5 mm off, all and away from depth edges; and where each > 5 mm
pixel lies, first match of: depth edge (a z-buffer step, second difference > 5 mm, +-2 px) /
projector shadow (not lit directly: Blender ray cast towards the projector) / bounce-dominated
(lit directly, but the fast render's flat-lit passes of the same scene have more bounced than
direct light there) / part / bin. Coverage: the share of directly lit part pixels within 1 mm (the
original rig's acceptance) and the share of projector-shadowed pixels that carry depth (all, and
those at least SHADOW_PX from a lit pixel: the ray cast tests the pixel centre, a pixel next to a
lit one is partly lit, as the decoder sees it). Decode
time: the scanner (sensor model + decode + filters) and the global-light filter alone; with
`--baseline DIR` (another checkout, e.g. main) the same scans by its package, side by side in one run.

Writes benchmarks/results/sl_truth.md, sl_truth.csv and sl_truth.png.
"""
from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np

from harness import RESULTS, ROOT, Stopwatch, machine, on_path, parser, today, write_rows_csv, write_with_notes

on_path("tests")
import sl_bench_scenes as S  # noqa: E402
import sl_truth_cases as T  # noqa: E402
from sl_scenes import depth_edges  # noqa: E402

from datapipe import config as C, sl  # noqa: E402
from datapipe.sl import filters as SLF  # noqa: E402

MODES = ("fast", "render")
RIG_CASES = [("gui", 0.55, None), ("default", 0.8, "matte_plastic+bin"), ("default", 0.6, "steel"),
             ("default", 0.6, "aluminium")]
OFF = 5e-3                 # m: a wrong point
PLACES = ("edge", "shadow", "bounce", "part", "bin")
SHADOW_PX = 2              # px: a shadowed pixel this far from every directly lit one is shadowed in full


def scanner_for(key: str, mode: str):
    if key.startswith("demo"):
        cfg = C.default_config()
    else:
        rig, h, mat = next(c for c in RIG_CASES if key.startswith(S.case_key(*c)))
        cfg = S.case_config(rig, h, mat)
    cfg.structured_light.fringe_mode = mode
    return sl.Scanner.from_config(cfg)


def metrics(c: dict, scan, bounce_dominated) -> dict:
    from scipy.ndimage import binary_dilation

    res = scan.result
    z = c["depth"].astype(np.float64)
    v = res.valid & np.isfinite(z)
    err = np.abs(res.depth - z)
    edge = depth_edges(z)
    direct = c["direct"].astype(bool)
    part = c["mask"] > 0
    seen = np.isfinite(z)
    bad = v & (err > OFF)
    place = {"edge": bad & edge}
    left = bad & ~edge
    place["shadow"] = left & ~direct
    left &= direct
    place["bounce"] = left & bounce_dominated if bounce_dominated is not None else np.zeros_like(left)
    left &= ~place["bounce"]
    place["part"], place["bin"] = left & part, left & ~part
    lit_part = direct & part & seen
    shadow = seen & ~direct
    deep = shadow & ~binary_dilation(direct, iterations=SHADOW_PX)   # no sub-sample of the pixel lit
    nv = max(int(v.sum()), 1)
    e = err[v]
    return {"valid": float(v.mean()), "median_mm": float(np.median(e) * 1e3) if e.size else float("nan"),
            "p99_mm": float(np.percentile(e, 99) * 1e3) if e.size else float("nan"),
            "out5": float(bad.sum() / nv), "out5_off_edge": float((bad & ~edge).sum() / nv),
            "p99_off_edge_mm": float(np.percentile(err[v & ~edge], 99) * 1e3),
            "n_out5": int(bad.sum()), **{f"at_{k}": int(place[k].sum()) for k in PLACES},
            "part_ok": float((lit_part & v & (err <= 1e-3)).sum() / max(int(lit_part.sum()), 1)),
            "lit_part_px": int(lit_part.sum()),
            "shadow_valid": float((shadow & v).sum() / max(int(shadow.sum()), 1)), "shadow_px": int(shadow.sum()),
            "deep_shadow_valid": float((deep & v).sum() / max(int(deep.sum()), 1)), "deep_shadow_px": int(deep.sum()),
            "multipath_px": int(scan.multipath.sum()) if scan.multipath is not None else 0}


def flat_passes(cache: Path, key: str, mode: str):
    """The fast render's flat-lit passes (direct, indirect radiance) of the same case and camera
    (any sample count), or None when that render is not cached."""
    fk = re.sub(r"_s\d+(?=_|$)", "", key.replace(f"_{mode}", "_fast"))   # any sample count: the same scene
    if not (cache / f"{fk}.npz").is_file():
        return None
    f = T.load(cache, fk)
    return (f["flat_direct"], f["flat_indirect"]) if "flat_direct" in f else None


def bounce_map(cache: Path, key: str, mode: str):
    """Direct-lit pixels with more bounced than direct light, from the fast render's flat-lit
    passes of the same case (None when that render is not cached)."""
    f = flat_passes(cache, key, mode)
    return None if f is None else f[1] > f[0]


def keys(only=None, samples=None, res=None) -> list[tuple[str, str]]:
    """(cache key, mode) of every case; `only`: substrings, a case is kept when its key holds one;
    `samples`, `res`: the rig cases rendered at that many fringe paths per pixel or at (W, H)
    instead (no demo)."""
    out = []
    for mode in MODES:
        if not samples and not res:
            out += [(T.demo_key(i, mode), mode) for i in range(T.DEMO_RENDERS)]
        out += [(T.rig_key(*c, mode, samples, res), mode) for c in RIG_CASES]
    return [k for k in out if only is None or any(o in k[0] for o in only)]


def explain(c: dict, scan, sc, flat, log=print) -> None:
    """One line per valid pixel > 5 mm off away from depth edges: where (row, column, instance
    mask, directly lit), how far and which way, the projector-column error in fringes of each
    period and each period's own phase error (periods), the confidence and reason, offset,
    modulations, sensor noise, the global-light filter's g / d, the flat-lit passes' bounced /
    direct light and the size of the pixel's region of agreeing kept pixels."""
    from datapipe.sl.regions import region_labels

    res = scan.result
    z = c["depth"].astype(np.float64)
    err = res.depth - z
    bad = res.valid & np.isfinite(z) & (np.abs(err) > OFF) & ~depth_edges(z)
    if not bad.any():
        return
    K = np.asarray(c["K"], np.float64)
    H, W = z.shape
    u, v = np.meshgrid(np.arange(W, dtype=np.float64), np.arange(H, dtype=np.float64))
    Xc = np.stack([(u - K[0, 2]) / K[0, 0] * z, (v - K[1, 2]) / K[1, 1] * z, z, np.ones_like(z)], -1)
    p = Xc @ (sc.K_proj @ np.linalg.inv(sc.T_cam_proj)[:3]).T
    x_true = p[..., 0] / p[..., 2]                          # the z-buffer point's projector column
    Wp = sc.proj_size[0]
    A = res.offset.astype(np.float64)
    sig = scan.capture.noise_sigma
    sig = sig(np.maximum(A, 0)) if callable(sig) else np.broadcast_to(np.asarray(sig, np.float64), A.shape)
    gd = SLF.global_direct_ratio(res.modulation, res.offset, SLF.direct_frequencies(res.periods, Wp))
    agree = SLF.neighbour_agreement(res.depth, res.valid, scan.sigma_z, 1.0 / K[0, 0])
    _, size = region_labels(res.valid, agree)
    for i, j in zip(*np.nonzero(bad)):
        dx = res.proj_x[i, j] - x_true[i, j]
        fringes = " ".join(f"{dx * k / Wp:+.3f}" for k in res.periods)
        phase = " ".join(f"{(w[i, j] / (2 * np.pi) - k * (x_true[i, j] + 0.5) / Wp + 0.5) % 1 - 0.5:+.3f}"
                         for k, w in zip(res.periods, res.wrapped))
        ratio = f"{flat[1][i, j] / flat[0][i, j]:.2f}" if flat is not None and flat[0][i, j] > 0 else "-"
        log(f"    r{i} c{j} mask {int(c['mask'][i, j])} direct {int(c['direct'][i, j])} z {z[i, j] * 1e3:.1f} mm "
            f"err {err[i, j] * 1e3:+.1f} mm | column {dx:+.2f} px = fringes {fringes} | phase error {phase} | "
            f"conf {res.confidence[i, j]:.4f} reason {res.reason[i, j]} | A {A[i, j]:.0f} "
            f"B {' / '.join(f'{b:.0f}' for b in res.modulation[:, i, j])} sigma {sig[i, j]:.1f} DN | "
            f"g/d {gd[i, j]:.2f} bounced/direct {ratio} | region {size[i, j]} px")


def run(cache: Path, log=print, only=None, samples=None, res=None, explain_pixels=False) -> list[dict]:
    rows = []
    for key, mode in keys(only, samples, res):
        if not (cache / f"{key}.npz").is_file():
            log(f"  {key}: not rendered, skipped")
            continue
        c = T.load(cache, key)
        sc = scanner_for(key, mode)
        rad = c["rad"]
        scan = sc.scan(rad, S.SEED, c["K"], c["T"])
        res = scan.result
        with Stopwatch() as filt:
            SLF.global_light_filter(res.modulation, res.offset, SLF.direct_frequencies(res.periods, sc.proj_size[0]),
                                    sc.steps, scan.capture.noise_sigma, np.ones_like(res.valid))
        with Stopwatch() as t_scan:
            sc.scan(rad, S.SEED, c["K"], c["T"])
        filt_s, scan_s = filt.cpu_s, t_scan.cpu_s
        m = metrics(c, scan, bounce_map(cache, key, mode))
        if explain_pixels:
            explain(c, scan, sc, flat_passes(cache, key, mode), log)
        m.update(case=key.replace(f"_{mode}", ""), mode=mode, scan_cpu_s=scan_s, filter_cpu_s=filt_s,
                 baseline_cpu_s=float("nan"),
                 fringe_s=float(c["fringe_s"]))
        rows.append(m)
        log(f"  {key}: valid {m['valid']:.3f} p99 {m['p99_mm']:.2f} mm, > 5 mm {m['out5']:.4f} "
            f"(off edges {m['out5_off_edge']:.4f}), part_ok {m['part_ok']:.3f}, shadow valid {m['shadow_valid']:.4f}")
    return rows


COLS = ("case", "mode", "valid", "median_mm", "p99_mm", "out5", "out5_off_edge", "p99_off_edge_mm", "n_out5",
        *[f"at_{k}" for k in PLACES], "part_ok", "shadow_valid", "deep_shadow_valid", "multipath_px", "scan_cpu_s", "baseline_cpu_s", "filter_cpu_s")


def _fmt(k, v):
    if isinstance(v, str):
        return v
    if isinstance(v, (int, np.integer)):
        return str(v)
    if k in ("out5", "out5_off_edge", "shadow_valid", "deep_shadow_valid"):
        return f"{v * 100:.3f}%"
    if k in ("valid", "part_ok"):
        return f"{v:.3f}"
    return f"{v:.3f}" if k.endswith("_s") or k == "median_mm" else f"{v:.2f}"


def plot(rows, path: Path) -> None:
    """Bars per case: the > 5 mm share off depth edges (log scale, fast and render side by side)."""
    import cv2

    cases = list(dict.fromkeys(r["case"] for r in rows))
    W, H, m = 900, 420, 60
    img = np.full((H, W, 3), 255, np.uint8)
    cv2.rectangle(img, (m, m // 2), (W - m // 2, H - m), (0, 0, 0), 1)
    lo, hi = -5.0, -1.0                       # log10 of the share
    y = lambda s: int(H - m - (np.log10(max(s, 10 ** lo)) - lo) / (hi - lo) * (H - 1.5 * m))  # noqa: E731
    for p in range(int(lo), int(hi) + 1):
        cv2.line(img, (m, y(10.0 ** p)), (W - m // 2, y(10.0 ** p)), (225, 225, 225), 1)
        cv2.putText(img, f"{100 * 10.0 ** p:g}%", (4, y(10.0 ** p) + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
    cv2.line(img, (m, y(1e-3)), (W - m // 2, y(1e-3)), (0, 0, 200), 1)       # the acceptance: 0.1%
    bw = (W - 1.5 * m) / max(len(cases), 1)
    for i, case in enumerate(cases):
        for j, (mode, col) in enumerate((("fast", (200, 120, 0)), ("render", (0, 150, 0)))):
            r = next((r for r in rows if r["case"] == case and r["mode"] == mode), None)
            if r is None:
                continue
            x0 = int(m + i * bw + 4 + j * (bw - 8) / 2)
            cv2.rectangle(img, (x0, y(r["out5_off_edge"])), (int(x0 + (bw - 8) / 2 - 2), H - m), col, -1)
        cv2.putText(img, case[:14], (int(m + i * bw + 2), H - m + 16 + 14 * (i % 2)), cv2.FONT_HERSHEY_SIMPLEX, 0.35,
                    (0, 0, 0), 1)
    cv2.putText(img, "> 5 mm off, away from depth edges (share of valid); blue fast, green render; red line 0.1%",
                (m, 20), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)
    cv2.imwrite(str(path), img)


def scan_cpu(root: Path, cache: Path, reps: int = 3) -> dict:
    """{case key: median CPU seconds of the scan} with the datapipe package of checkout `root`
    (this one or a baseline: `git archive main | tar -x -C DIR`), in a subprocess so that both
    packages can be timed in one run, alternately."""
    import json
    import subprocess

    code = f"""
import json, sys, time
sys.path[:0] = [{str(root)!r}, {str(ROOT / "benchmarks")!r}, {str(ROOT / "tests")!r}]
import numpy as np
import bench_sl_truth as B, sl_truth_cases as T
from pathlib import Path
cache, out = Path({str(cache)!r}), {{}}
for key, mode in B.keys():
    if not (cache / f"{{key}}.npz").is_file():
        continue
    c = T.load(cache, key)
    sc = B.scanner_for(key, mode)
    ts = []
    for _ in range({int(reps)}):
        t0 = time.process_time()
        sc.scan(c["rad"], B.S.SEED, c["K"], c["T"])
        ts.append(time.process_time() - t0)
    out[key] = float(np.median(ts))
print(json.dumps(out))
"""
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def dark_step_rows(log=print) -> list[dict]:
    """The adversarial synthetic stack (sl_bench_scenes.dark_step_stack) decoded with the decoder's
    defaults and no noise model: coverage of the lit pixels, share of decoded pixels a fine period
    or more off (|x - x_true| > T/2), on the dark box top too; decode CPU seconds."""
    out = []
    for size in ((640, 480), (1920, 1080)):
        img, r, cam, proj = S.dark_step_stack(size)
        with Stopwatch() as t:
            res = sl.decode(img, periods=S.DARK_PERIODS, steps=S.DARK_STEPS, P_cam=cam.P, P_proj=proj.P,
                            proj_size=proj.size)
        dt = t.cpu_s
        T_fine = proj.size[0] / max(S.DARK_PERIODS)
        wrong = res.valid & (np.abs(res.proj_x - r.proj_x) > T_fine / 2)
        dark = r.lit & (r.albedo < 0.05)
        out.append({"size": f"{size[0]}x{size[1]}", "coverage": float((res.valid & r.lit).sum() / r.lit.sum()),
                    "wrong": float(wrong.sum() / max(int(res.valid.sum()), 1)),
                    "dark_coverage": float((res.valid & dark).sum() / max(int(dark.sum()), 1)),
                    "dark_wrong": float((wrong & dark).sum() / max(int((res.valid & dark).sum()), 1)),
                    "decode_cpu_s": dt})
        log(f"  dark step {out[-1]}")
    return out


def write_report(rows, dark=()) -> None:
    lines = ["# Structured light against the truth on real renders (bench_sl_truth.py)", "",
             f"Generated by `benchmarks/bench_sl_truth.py` on {machine()}, "
             f"{today()}. Product defaults (sl.Scanner.from_config); 320x240 Cycles CPU renders. "
             "`out5`: share of valid pixels > 5 mm off the z-buffer; `at_*`: where those pixels lie (first match: "
             "depth edge +-2 px / projector shadow (ray cast) / bounce-dominated (flat-lit passes: bounced > direct) / "
             "part / bin); `part_ok`: directly lit part pixels within 1 mm; `shadow_valid`: projector-shadowed "
             "pixels (ray cast from the pixel centre) with depth, `deep_shadow_valid`: the same for the shadowed pixels "
             f"at least {SHADOW_PX} px from every directly lit one (the others are partly lit); CPU seconds of the whole scan (`scan_cpu_s`; `baseline_cpu_s`: the "
             "same scan by the `--baseline` checkout, alternately in the same run) and of the global-light filter alone.", "",
             "| " + " | ".join(COLS) + " |", "|" + "---|" * len(COLS)]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(k, r[k]) for k in COLS) + " |")
    if dark:
        lines += ["", "Adversarial synthetic stack (dark patch beside a depth step, `sl_bench_scenes.dark_step_stack`), "
                  "`sl.decode` defaults, no noise model:", "",
                  "| size | coverage of lit | wrong of decoded | dark coverage | dark wrong | decode CPU s |",
                  "|---|---|---|---|---|---|"]
        lines += [f"| {d['size']} | {d['coverage']:.4f} | {d['wrong'] * 100:.3f}% | {d['dark_coverage']:.4f} | "
                  f"{d['dark_wrong'] * 100:.3f}% | {d['decode_cpu_s']:.3f} |" for d in dark]
    write_with_notes(RESULTS / "sl_truth.md", lines)
    write_rows_csv(RESULTS / "sl_truth.csv", [{k: r[k] for k in COLS} for r in rows])
    plot(rows, RESULTS / "sl_truth.png")


def main(argv=None) -> int:
    ap = parser(__doc__, quick="the demo in fast mode only (one Blender render)")
    ap.add_argument("--cache", type=Path, default=ROOT / "benchmarks" / ".cache" / "sl_truth")
    ap.add_argument("--no-render", action="store_true", help="decode what is cached, render nothing")
    ap.add_argument("--cases", default=None,
                    help="comma-separated substrings of case names (e.g. steel,aluminium): render and decode only "
                         "those, print their rows and write no report (the report holds every case)")
    ap.add_argument("--samples", type=int, default=None,
                    help="with --cases: the rig cases at this many fringe paths per pixel (cached as <key>_sN)")
    ap.add_argument("--res", default=None, help="with --cases: the rig cases at WxH instead of 320x240 (cached as <key>_WxH)")
    ap.add_argument("--explain", action="store_true",
                    help="print every valid pixel > 5 mm off away from depth edges with what the decoder saw there")
    ap.add_argument("--baseline", type=Path, default=None,
                    help="a checkout to time the scan against, side by side (e.g. main: git archive main | tar -x -C DIR)")
    args = ap.parse_args(argv)
    args.cache.mkdir(parents=True, exist_ok=True)
    only = [c for c in args.cases.split(",") if c] if args.cases else None
    if (args.samples or args.res) and only is None:
        ap.error("--samples and --res need --cases (the report holds the default renders)")
    res = tuple(int(v) for v in args.res.lower().split("x")) if args.res else None
    if not args.no_render:
        for mode in MODES[:1] if args.quick else MODES:
            if not (args.samples or res) and (only is None or any(o in T.demo_key(0, mode) for o in only)):
                T.render_demo(args.cache, mode)
            if not args.quick:
                T.render_rig(args.cache, [c for c in RIG_CASES if only is None
                                          or any(o in T.rig_key(*c, mode, args.samples, res) for o in only)], mode,
                             samples=args.samples, res=res)
    rows = run(args.cache, only=only, samples=args.samples, res=res, explain_pixels=args.explain)
    if only is not None:
        return 0
    if args.baseline is not None:
        mine, base = {}, {}
        for _ in range(2):                      # alternately: the machine's load hits both alike
            for d, root in ((mine, ROOT), (base, args.baseline.resolve())):
                for k, v in scan_cpu(root, args.cache).items():
                    d.setdefault(k, []).append(v)
        for r in rows:
            k = f"{r['case']}_{r['mode']}"
            r["scan_cpu_s"] = float(np.median(mine[k]))
            r["baseline_cpu_s"] = float(np.median(base[k])) if k in base else float("nan")
    write_report(rows, dark_step_rows())
    return 0


if __name__ == "__main__":
    sys.exit(main())
