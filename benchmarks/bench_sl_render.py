"""Structured-light camera in Blender: depth error against run time.

    .venv/bin/python benchmarks/bench_sl_render.py [--quick] [--cache DIR] [--report-only]

Two fixed scenes: the demo preset's bin (seed 0, scene 0, camera pose 0: straight down from 0.8 m,
8 parts) and a plane (the preset's floor alone, Z = 0.8 m). Each scene is rendered once per
(resolution, fringe samples, pattern set, render variant) with `StructuredLightCamera.render_fringes`
(the product's own fringe call) and the stack is cached (npz, --cache); every sensor preset,
exposure and decoder setting then reuses it, so one factor is varied at a time around the base
point without re-rendering. The native RGB/depth render is timed separately (same scene,
resolution, and the preset's 32 samples) for the fringe/native cost ratio.

Times: wall seconds and process CPU seconds (Cycles uses both cores; the machine is shared, so CPU
seconds are the steadier measure of work and the ratios use them). Decode seconds cover the sensor
model, the decoder and the edge filter with the triangulation coefficients cached (as for repeated
camera poses). Errors: SL depth against the z-buffer depth of the same render, on pixels valid in
both; `sigma_meas` is 1.4826 * MAD of that error; `sigma_theo` the median per-pixel noise limit
(docs/STRUCTURED_LIGHT.md: sigma_phi = sqrt(2/N) sigma_I / B per frequency, K^2-weighted, times |dZ/dx|), and
`ratio` = 1.4826 * MAD(error / per-pixel sigma) (1.0 = at the physical limit).

Writes benchmarks/results/sl_render.md, sl_render.csv, sl_render_pareto.png. Rendered stacks and
per-render timings stay in the cache folder, so an interrupted run resumes and --report-only
re-decodes without Blender.
"""
from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np

from harness import (Stopwatch, cached_renders, clocked, column_table, machine, on_path, sweep_parser, write_rows_csv,
                     write_with_notes)

on_path()
from datapipe import config as C  # noqa: E402
from datapipe import sl  # noqa: E402
from datapipe.core import structured_light as SLM  # noqa: E402
from datapipe.draws.seeds import scene_rng  # noqa: E402
from datapipe.sl.scanner import FILTERED, MIN_CONTRAST  # noqa: E402

SEED = 1234                       # render seed (Cycles + sensor model) of every case
SENSORS = ("ideal", "industrial", "industrial_8bit")
RES = {"320": (320, 240), "640": (640, 480)}
D = C.StructuredLightConfig()     # the shipped defaults: the base point
BASE = dict(periods=tuple(D.periods), steps=D.steps, samples=D.samples, variant="default")
FIXED_EXPOSURE = 0.5              # the fixed exposure this benchmark varies around (the config's default is
                                  # now "auto": metered per render, benchmarks/results/sl_materials.md)
EXPOSURES = (0.25, 0.35, 0.5, 0.7, 1.0)
LIGHT_FACTORS = (0.25, 1, 2)      # robustness metric: x1/4 light (dark parts, ~1.1 m), x2 (bright parts)
# decoder settings on the same images: (label, min_contrast, edge filter, multipath filter)
DECODER_SETTINGS = (("decoder defaults (contrast 0.05), no filter", 0.05, False, False),
                    ("contrast 0.5, no filter", 0.5, False, False),
                    ("contrast 0.05 + edge filter", 0.05, True, False),
                    ("contrast 0.5 + edge filter (former default)", 0.5, True, False),
                    ("contrast 0.05 + multipath + edge filter (shipped)", MIN_CONTRAST, True, True))
VARIANTS = {"default": {},                                         # 2x2 point samples (shipped)
            "filter1.5": {"supersample": 1, "filter_width": 1.5},  # Cycles' default pixel filter
            "noreg": {"indirect_blur_px": 0.0}}                    # inter-reflections not regularised


def case(scene, res, periods=None, steps=None, samples=None, variant=None, tag=""):
    c = dict(BASE)
    c.update({k: v for k, v in dict(periods=periods, steps=steps, samples=samples, variant=variant).items()
              if v is not None})
    c.update(scene=scene, res=res, tag=tag)
    c["periods"] = tuple(c["periods"])
    return c


def plan(quick: bool):
    """One factor at a time around BASE (+ a few combined candidates)."""
    P = [case("bin", "320", tag="base")]
    if quick:
        P += [case("bin", "320", samples=16, tag="samples"), case("plane", "320", tag="base"),
              case("bin", "640", tag="base")]
        return _unique(P)
    for s in (4, 8, 16, 32):
        P.append(case("bin", "320", samples=s, tag="samples"))
    for n in (3, 4, 6, 8):
        P.append(case("bin", "320", steps=n, tag="steps"))
    for per, n in (((1, 6, 36), None), ((1, 4, 16, 64), None), ((70, 64, 59), None), ((64, 63), None),
                   ((8, 7), 3), ((1, 16), None)):
        P.append(case("bin", "320", periods=per, steps=n, tag="periods"))
    for s in (4, 16):
        P.append(case("bin", "320", samples=s, variant="filter1.5", tag="filter"))
    for s in (4, 16):
        P.append(case("bin", "320", samples=s, variant="noreg", tag="indirect"))
    P += [case("bin", "320", periods=(1, 6, 36), samples=8, tag="combined"),
          case("bin", "320", steps=3, samples=8, tag="combined")]
    for s in (4, 8):
        P.append(case("bin", "640", samples=s, tag="resolution"))
    P += [case("bin", "640", steps=3, tag="resolution"), case("bin", "640", periods=(1, 6, 36), tag="resolution")]
    for s in (4, 16):
        P.append(case("plane", "320", samples=s, tag="plane"))
        P.append(case("plane", "320", samples=s, variant="filter1.5", tag="plane"))
    for per, n in (((1, 6, 36), None), ((70, 64, 59), None), ((8, 7), 3)):
        P.append(case("plane", "320", periods=per, steps=n, tag="plane"))
    P.append(case("plane", "320", steps=3, tag="plane"))
    P.append(case("plane", "640", tag="plane"))
    return _unique(P)


def _unique(P):
    seen, out = set(), []
    for c in P:
        k = key(c)
        if k not in seen:
            seen.add(k)
            out.append(c)
    return out


def key(c) -> str:
    return (f"{c['scene']}_{c['res']}_p{'-'.join(map(str, c['periods']))}_n{c['steps']}_s{c['samples']}"
            f"_{c['variant']}")


def is_base(c) -> bool:
    return all(c[k] == BASE[k] for k in ("periods", "steps", "samples", "variant"))


# ------------------------------------------------------------------------------------------------
# rendering (bpy)

def build_world(scene_kind: str, res: tuple[int, int], tmp: Path):
    import bpy
    from datapipe.core.camera import BlendCamera
    from datapipe.core.world import BlenderWorld
    from datapipe.core.renderer import Renderer
    from datapipe.core.scene import BlendScene

    bpy.ops.wm.read_factory_settings(use_empty=True)
    cfg = C.default_config()
    cfg.camera.resolution = list(res)
    cfg.structured_light.enabled = False           # the world without SL; SL is added per pattern set
    if scene_kind == "bin":
        world = BlenderWorld(cfg, tmp / "world")
        world.setup()
        world.start_scene(0, cfg.scene.seed, scene_rng(cfg.scene.seed, 0), 1)
        camera, renderer, bscene = world.camera, world.renderer, world.blend.scene
    else:
        cfg.scene.make_bin = False
        blend = BlendScene(cfg).setup()
        bscene = blend.scene
        camera = BlendCamera(cfg, bscene).setup()
        renderer = Renderer(cfg, bscene, camera).setup()
    T = camera.set_pose(0)
    return cfg, bscene, camera, renderer, T


def cache_native_render(renderer, camera, T, cfg, tmp: Path, cache: Path, nkey: str, meta: dict,
                        meta_path: Path) -> tuple[float, float]:
    """The native render timed (best of 2), its depth/mask/pose cached as `nkey`.npz and its times
    in `meta` (written at once, so a killed sweep keeps it); returns (wall s, CPU s)."""
    runs = []
    for _ in range(2):
        out, wall, cpu = clocked(lambda: renderer.render(tmp / "native", SEED))
        runs.append((cpu, wall))
    cpu, wall = min(runs)
    np.savez_compressed(cache / f"{nkey}.npz", depth=out.depth, mask=out.mask, T=T, K=camera.K)
    meta[nkey] = {"wall": wall, "cpu": cpu, "samples": cfg.render.samples}
    meta_path.write_text(json.dumps(meta, indent=1))
    return wall, cpu


def open_worlds(todo_by_world: dict, meta: dict, cache: Path, log, prefix: str):
    """For each (scene kind, resolution) with renders still to make: the world built in a fresh
    temporary folder and its native render cached (timed, once); yields (todo, tmp, (cfg, bscene,
    camera, renderer, T)). Shared by the sweeps that cache their fringe renders."""
    for (scene_kind, res), todo in todo_by_world.items():
        nkey = f"native_{scene_kind}_{res}"
        if not todo and nkey in meta:
            continue
        tmp = Path(tempfile.mkdtemp(prefix=prefix))
        log(f"building {scene_kind} {res}")
        world = build_world(scene_kind, RES[res], tmp)
        if nkey not in meta:
            cfg, _, camera, renderer, T = world
            wall, cpu = cache_native_render(renderer, camera, T, cfg, tmp, cache, nkey, meta, cache / "renders.json")
            log(f"  native {scene_kind} {res}: {wall:.1f} s wall, {cpu:.1f} CPU s")
        yield todo, tmp, world


def render_all(cases, cache: Path, log):
    from datapipe.core.structured_light import StructuredLightCamera

    meta_path = cache / "renders.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    todo_by_world: dict = {}
    for c in cases:
        todo_by_world.setdefault((c["scene"], c["res"]), []).extend([c] if key(c) not in meta else [])
    for todo, tmp, (cfg, bscene, camera, renderer, T) in open_worlds(todo_by_world, meta, cache, log, "slbench_"):
        by_pat: dict = {}
        for c in todo:
            by_pat.setdefault((c["periods"], c["steps"]), []).append(c)
        for (periods, steps), pcs in by_pat.items():
            cfg2 = cfg.copy()
            cfg2.structured_light.enabled = True
            cfg2.structured_light.periods = list(periods)
            cfg2.structured_light.steps = steps
            slc = StructuredLightCamera(cfg2, bscene, camera, renderer)
            slc.setup()
            for c in pcs:
                v = VARIANTS[c["variant"]]
                slc.supersample = v.get("supersample", SLM.FRINGE_SUPERSAMPLE)
                slc.filter_width = v.get("filter_width", SLM.FRINGE_FILTER_WIDTH)
                slc.set_indirect_blur(v.get("indirect_blur_px", SLM.INDIRECT_BLUR_PX))
                slc.set_samples(c["samples"])
                (stack, _), wall, cpu = clocked(lambda: slc.render_fringes(tmp / "fringes", SEED))
                np.savez_compressed(cache / f"{key(c)}.npz", rad=stack)
                meta[key(c)] = {"wall": wall, "cpu": cpu, "images": int(stack.shape[0])}
                meta_path.write_text(json.dumps(meta, indent=1))
                log(f"  {key(c)}: {wall:.1f} s wall, {cpu:.1f} CPU s")
            slc.teardown()
    return meta


# ------------------------------------------------------------------------------------------------
# decoding and metrics (numpy only)

def metrics(res, scan, z) -> dict:
    v = res.valid & np.isfinite(z)
    st = sl.depth_error_stats(res.depth, z, valid=res.valid)
    e = (res.depth - z)[v].astype(np.float64)
    s = scan.sigma_z[v].astype(np.float64)
    ok = np.isfinite(s) & (s > 0)
    mad = lambda a: float(1.4826 * np.median(np.abs(a - np.median(a)))) if a.size else float("nan")  # noqa: E731
    return {
        "valid": float(res.valid.mean()), "valid_of_surface": float(res.valid[np.isfinite(z)].mean()),
        "median_mm": st["median_abs"] * 1e3, "rmse_mm": st["rmse"] * 1e3, "p99_mm": st["p99"] * 1e3,
        "out5": st["outlier_fraction"], "sigma_meas_mm": mad(e) * 1e3,
        "sigma_theo_mm": float(np.median(s[ok])) * 1e3 if ok.any() else float("nan"),
        "ratio": mad(e[ok] / s[ok]) if ok.any() else float("nan"),
        "miss1mm": float(1.0 - np.mean(res.valid & (np.abs(res.depth - z) <= 1e-3))),
        "saturated": float(np.mean(res.reason == sl.Reason.SATURATED)),
        "filtered": float(np.mean(res.reason == FILTERED)),
    }


def decode_all(cases, meta, cache: Path, log):
    rows = []
    for c in cases:
        if key(c) not in meta:
            continue
        nat = np.load(cache / f"native_{c['scene']}_{c['res']}.npz")
        nmeta = meta[f"native_{c['scene']}_{c['res']}"]
        rad = np.load(cache / f"{key(c)}.npz")["rad"]
        cfg = C.default_config()
        cfg.camera.resolution = list(RES[c["res"]])
        cfg.structured_light.periods = list(c["periods"])
        cfg.structured_light.steps = c["steps"]
        scanner = sl.Scanner.from_config(cfg)
        scanner.scan(rad, SEED, nat["K"], nat["T"])      # warm the triangulation cache
        settings = [(s, FIXED_EXPOSURE, "shipped") for s in SENSORS]
        if c["scene"] == "bin":       # light levels for the robustness metric (dark parts / bright parts)
            settings += [("industrial", FIXED_EXPOSURE * f, f"light x{f:g}") for f in LIGHT_FACTORS if f != 1]
        if is_base(c):
            settings += [("industrial", e, "exposure") for e in EXPOSURES if e != FIXED_EXPOSURE]
            settings += [("industrial", FIXED_EXPOSURE, d[0]) for d in DECODER_SETTINGS[:-1]]
        for sensor, exposure, setting in settings:
            dec = next(((mc, ef, mp) for lab, mc, ef, mp in DECODER_SETTINGS if lab == setting),
                       (MIN_CONTRAST, True, True))
            scanner = sl.Scanner.from_config(cfg, sensor=sensor, exposure=exposure, min_contrast=dec[0],
                                             edge_filter=dec[1], multipath_filter=dec[2])
            scan, wall, _ = clocked(lambda: scanner.scan(rad, SEED, nat["K"], nat["T"]))
            m = metrics(scan.result, scan, nat["depth"])
            r = meta[key(c)]
            row = {"scene": c["scene"], "res": "x".join(map(str, RES[c["res"]])), "tag": c["tag"],
                   "periods": " ".join(map(str, c["periods"])), "steps": c["steps"],
                   "images": r["images"], "samples": c["samples"], "variant": c["variant"],
                   "sensor": sensor, "exposure": exposure, "decoder": setting,
                   "render_s": r["wall"], "render_cpu_s": r["cpu"], "decode_s": wall,
                   "native_s": nmeta["wall"], "native_cpu_s": nmeta["cpu"],
                   "fringe_cpu_s": r["cpu"] + wall, "total_cpu_s": nmeta["cpu"] + r["cpu"] + wall,
                   "fringe_over_native": (r["cpu"] + wall) / nmeta["cpu"], **m}
            rows.append(row)
        log(f"  decoded {key(c)}")
    return rows


# ------------------------------------------------------------------------------------------------
# report

COLS = [("scene", "{}"), ("res", "{}"), ("periods", "{}"), ("steps", "{}"), ("samples", "{}"),
        ("variant", "{}"), ("sensor", "{}"), ("render_cpu_s", "{:.1f}"), ("decode_s", "{:.2f}"),
        ("native_cpu_s", "{:.1f}"), ("fringe_over_native", "{:.2f}"), ("valid", "{:.3f}"),
        ("median_mm", "{:.3f}"), ("rmse_mm", "{:.3f}"), ("p99_mm", "{:.2f}"), ("out5", "{:.4f}"),
        ("sigma_meas_mm", "{:.3f}"), ("sigma_theo_mm", "{:.3f}"), ("ratio", "{:.2f}"), ("miss_robust", "{:.3f}")]


def table(rows, cols=COLS) -> str:
    return column_table(rows, cols)


def pareto(points):
    """Indices of the points not dominated in (x, y), both minimised; sorted by x."""
    idx = sorted(range(len(points)), key=lambda i: (points[i][0], points[i][1]))
    front, best = [], float("inf")
    for i in idx:
        if points[i][1] < best:
            front.append(i)
            best = points[i][1]
    return front


def nondominated(points):
    """Indices of points (tuples, all objectives minimised) that no other point dominates."""
    out = []
    for i, p in enumerate(points):
        if not any(all(a <= b for a, b in zip(q, p)) and any(a < b for a, b in zip(q, p))
                   for j, q in enumerate(points) if j != i):
            out.append(i)
    return out


def label(r) -> str:
    v = {"default": "", "filter1.5": " f1.5", "noreg": " noreg"}[r["variant"]]
    return f"{r['periods'].replace(' ', ',')}x{r['steps']} s{r['samples']}{v}"


def _panel(img, x_off, width, pts, xs, ys, title, ylabel, chosen_keys, yticks, nd3=()):
    import cv2

    H, m = img.shape[0] - 30, 70
    left, right = x_off + m, x_off + width - 20
    x0, x1 = np.floor(xs.min() * 4) / 4, np.ceil(xs.max() * 4) / 4
    y0, y1 = ys.min() - 0.03 * np.ptp(ys) - 1e-3, ys.max() + 0.03 * np.ptp(ys) + 1e-3

    def px(x, y):
        return (int(left + (x - x0) / (x1 - x0) * (right - left)), int(H - m - (y - y0) / (y1 - y0) * (H - 2 * m)))

    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.rectangle(img, (left, m), (right, H - m), (0, 0, 0), 1)
    for v in (1, 2, 3, 5, 10, 20, 30, 50, 100, 200, 300, 500):
        lx = np.log10(v)
        if x0 <= lx <= x1:
            p = px(lx, y0)
            cv2.line(img, (p[0], m), (p[0], H - m), (225, 225, 225), 1)
            cv2.putText(img, f"{v:g}", (p[0] - 8, H - m + 18), font, 0.45, (0, 0, 0), 1)
    for v, lab in yticks:
        if y0 <= v <= y1:
            p = px(x0, v)
            cv2.line(img, (left, p[1]), (right, p[1]), (225, 225, 225), 1)
            cv2.putText(img, lab, (left - 45, p[1] + 4), font, 0.4, (0, 0, 0), 1)
    cv2.putText(img, title, (left, m - 40), font, 0.5, (0, 0, 0), 1)
    cv2.putText(img, ylabel, (left, m - 20), font, 0.42, (0, 0, 0), 1)
    cv2.putText(img, "fringe render + decode, CPU s per render (log)", (left + 60, H - m + 40), font, 0.45,
                (0, 0, 0), 1)
    colours = {"320x240": (200, 90, 0), "640x480": (0, 0, 210)}
    for res_name, col in colours.items():
        sel = [i for i, r in enumerate(pts) if r["res"] == res_name]
        front = pareto([(xs[i], ys[i]) for i in sel])
        poly = np.array([px(xs[sel[j]], ys[sel[j]]) for j in front], np.int32)
        if len(poly) > 1:
            cv2.polylines(img, [poly], False, col, 2)
    for i, r in enumerate(pts):
        p = px(xs[i], ys[i])
        col = colours.get(r["res"], (0, 0, 0))
        cv2.circle(img, p, 4, col, -1)
        cv2.putText(img, label(r), (p[0] + 6, p[1] - 4 + 12 * (i % 2)), font, 0.33, col, 1)
        if (r["res"], r["periods"], r["steps"], r["samples"], r["variant"]) in chosen_keys:
            cv2.circle(img, p, 11, (0, 160, 0), 2)
        if id(r) in nd3:
            cv2.rectangle(img, (p[0] - 6, p[1] - 6), (p[0] + 6, p[1] + 6), (0, 0, 0), 1)


def plot(rows, path, chosen_keys):
    """Two panels over the bin scene (industrial sensor): RMSE at nominal light, and the coverage-
    aware robustness metric (`miss_robust`); Pareto fronts per resolution, shipped default ringed."""
    import cv2

    pts = [r for r in rows if r["scene"] == "bin" and r["sensor"] == "industrial" and r["decoder"] == "shipped"
           and np.isfinite(r["rmse_mm"])]
    W, H = 1600, 790
    img = np.full((H, W, 3), 255, np.uint8)
    cv2.putText(img, "lines: 2-D Pareto fronts per resolution; black squares: non-dominated in all three of time, "
                "RMSE and miss (same points in both panels); green ring: shipped default", (70, H - 8),
                cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)
    # non-dominated in all three objectives (cost, RMSE, robust miss), within each resolution
    nd3 = set()
    for res_name in {r["res"] for r in pts}:
        sel = [r for r in pts if r["res"] == res_name and np.isfinite(r.get("miss_robust", np.nan))]
        nd3 |= {id(sel[i]) for i in nondominated([(r["fringe_cpu_s"], r["rmse_mm"], r["miss_robust"])
                                                   for r in sel])}
    xs = np.log10([r["fringe_cpu_s"] for r in pts])
    ys = np.log10([max(r["rmse_mm"], 1e-3) for r in pts])
    _panel(img, 0, W // 2, pts, xs, ys, "bin scene, nominal light: depth RMSE vs z-buffer (mm, log)",
           "blue 320x240, red 640x480", chosen_keys,
           [(np.log10(v), f"{v:g}") for v in (0.3, 0.5, 1, 2, 3, 5)], nd3)
    pts2 = [r for r in pts if np.isfinite(r.get("miss_robust", np.nan))]
    ys2 = np.array([r["miss_robust"] for r in pts2])
    xs2 = np.log10([r["fringe_cpu_s"] for r in pts2])
    _panel(img, W // 2, W // 2, pts2, xs2, ys2, "bin scene: pixels NOT measured within 1 mm (fraction of image),",
           "mean over light x1/4, x1, x2 (dark parts / nominal / bright parts)", chosen_keys,
           [(v, f"{v:.2f}") for v in np.arange(0.40, 0.80, 0.05)], nd3)
    cv2.imwrite(str(path), img)


BASE_PAT = " ".join(map(str, BASE["periods"]))


def is_default(r) -> bool:
    """A row of the shipped base point's render (any scene, resolution, sensor, decoder)."""
    return (r["periods"] == BASE_PAT and r["steps"] == BASE["steps"] and r["samples"] == BASE["samples"]
            and r["variant"] == "default")


def add_robustness(rows) -> None:
    """`miss_robust` per row: mean miss1mm over the light levels of its render (bin scene,
    industrial sensor); NaN where a level is missing or on the plane."""
    groups: dict = {}
    for r in rows:
        if r["scene"] == "bin" and r["sensor"] == "industrial" and (r["decoder"] == "shipped"
                                                                      or r["decoder"].startswith("light")):
            groups.setdefault((r["res"], r["periods"], r["steps"], r["samples"], r["variant"]), []).append(r)
    for r in rows:
        g = groups.get((r["res"], r["periods"], r["steps"], r["samples"], r["variant"]))
        r["miss_robust"] = (float(np.mean([x["miss1mm"] for x in g])) if g and len(g) == len(LIGHT_FACTORS)
                            and r["scene"] == "bin" else float("nan"))


def intro(meta, quick: bool, elapsed: float, rendered: bool) -> list[str]:
    return [
        "# Structured-light camera: depth error against run time\n",
        f"Machine: {machine()}, shared with other jobs; Blender (bpy) Cycles CPU. "
        f"Renders {sum(v['wall'] * (2 if k.startswith('native') else 1) for k, v in meta.items()) / 60:.1f} "
        f"min wall (sum over the cached renders; scene setup and simulation not included); "
        f"{'whole run' if rendered else 'decoding and report (--report-only)'} {elapsed / 60:.1f} min"
        f"{' (--quick)' if quick else ''}. "
        "Generated by `benchmarks/bench_sl_render.py`; raw rows in `sl_render.csv`.\n",
        "Scenes: the demo preset's bin (seed 0, scene 0, 8 parts, camera straight down from 0.8 m) and a "
        "plane (the floor alone at Z = 0.8 m). Projector: preset (912x570, f 16 mm, 0.15 m baseline, "
        f"8.5 deg toe-in). Shipped defaults (base point): periods {BASE['periods']}, {BASE['steps']} steps, "
        f"{BASE['samples']} fringe samples per camera pixel (2x2 point sub-samples), sensor `{D.sensor}`, "
        f"exposure {FIXED_EXPOSURE} (fixed), decoder min_contrast {MIN_CONTRAST} + multipath + edge/speckle "
        "filter. "
        "Native render: 32 samples, RGB + depth + normals + mask.\n",
        "Columns: `render_cpu_s` fringe render (all fringe layers, own Cycles call), `decode_s` sensor "
        "model + decode + filter (wall), `native_cpu_s` the native render, `fringe_over_native` = "
        "(render CPU + decode) / native CPU; errors on pixels valid in both SL and z-buffer; `out5` "
        "fraction of them off by > 5 mm; `valid` fraction of all pixels; `sigma_meas` 1.4826 MAD of "
        "the error, `sigma_theo` median per-pixel noise limit, `ratio` robust sigma of error/limit; "
        "`miss_robust` (bin only) the fraction of image pixels NOT measured to within 1 mm, averaged "
        "over three light levels (exposure x1/4, x1, x2: dark parts or ~1.1 m range, nominal, bright "
        "parts): a coverage-aware error that also punishes pattern sets that fail in dim light or "
        "saturate.\n"]


def targets(ship) -> list[str]:
    """The base point's table and whether it meets the plane's noise and the bin's cost targets."""
    def sel(**kw):
        return [r for r in ship if all(r[k] == v for k, v in kw.items()) and is_default(r)]
    tgt = [f"- Plane {r['res']}: measured sigma {r['sigma_meas_mm']:.3f} mm vs theoretical "
           f"{r['sigma_theo_mm']:.3f} mm, ratio {r['ratio']:.2f} (target <= 1.5): "
           f"{'met' if r['ratio'] <= 1.5 else 'NOT met'}." for r in sel(scene="plane", sensor="industrial")]
    tgt += [f"- Bin 640x480: fringe work {r['fringe_cpu_s']:.1f} CPU s (render {r['render_cpu_s']:.1f} "
            f"+ decode {r['decode_s']:.2f}) vs native {r['native_cpu_s']:.1f} CPU s = "
            f"{r['fringe_over_native']:.2f}x (target <= 4x): "
            f"{'met' if r['fringe_over_native'] <= 4 else 'NOT met'}; wall {r['render_s']:.1f} s vs "
            f"{r['native_s']:.1f} s." for r in sel(scene="bin", sensor="industrial", res="640x480")]
    return ["## Base point and targets\n", table([r for r in ship if is_default(r)]), "\n".join(tgt) + "\n"]


def factor_sections(ship) -> list[str]:
    """One table per factor varied around the base point (industrial sensor)."""
    L = []
    for title, tag in (("Fringe samples", "samples"), ("Phase steps", "steps"), ("Pattern sets", "periods"),
                       ("Pixel filter (shipped 2x2 point samples vs Cycles' 1.5 px Blackman-Harris)", "filter"),
                       ("Inter-reflected light: regularised (shipped) vs plain Monte Carlo (noreg)", "indirect"),
                       ("Combined candidates", "combined"), ("Resolution 640x480", "resolution"),
                       ("Plane", "plane")):
        rs = [r for r in ship if r["tag"] == tag or (tag in ("samples", "steps", "periods", "filter", "indirect")
                                                    and r["tag"] == "base" and r["scene"] == "bin"
                                                    and r["res"] == "320x240")]
        if tag == "plane":
            rs = [r for r in ship if r["scene"] == "plane"]
        if tag == "resolution":
            rs = [r for r in ship if r["scene"] == "bin" and r["res"] == "640x480"]
        rs = [r for r in rs if r["sensor"] == "industrial"]
        if rs:
            L += [f"## {title} (industrial sensor)\n", table(rs)]
    return L


def base_render_sections(rows) -> list[str]:
    """Exposure and decoder settings on the base render (bin 320x240, industrial sensor)."""
    base = [r for r in rows if r["scene"] == "bin" and r["res"] == "320x240" and r["sensor"] == "industrial"
            and is_default(r)]
    L = []
    ex = sorted({r["exposure"]: r for r in base if r["decoder"] in ("shipped", "exposure")
                 or r["decoder"].startswith("light")}.values(), key=lambda r: r["exposure"])
    if ex:
        L.append("## Exposure (bin 320x240, base render, industrial sensor)\n")
        L.append(table(ex, [("exposure", "{}"), ("valid", "{:.3f}"), ("saturated", "{:.4f}"),
                            ("median_mm", "{:.3f}"), ("rmse_mm", "{:.3f}"), ("p99_mm", "{:.2f}"),
                            ("out5", "{:.4f}"), ("sigma_theo_mm", "{:.3f}")]))
    dec = [r for r in base if r["decoder"] != "exposure" and not r["decoder"].startswith("light")]
    if dec:
        L.append("## Decoder settings and edge/speckle filter (bin 320x240, base render, industrial)\n")
        L.append(table(dec, [("decoder", "{}"), ("valid", "{:.3f}"), ("filtered", "{:.4f}"),
                             ("median_mm", "{:.3f}"), ("rmse_mm", "{:.3f}"), ("p99_mm", "{:.2f}"),
                             ("out5", "{:.4f}")]))
    return L


def pareto_lines(ship) -> list[str]:
    L = ["## Pareto plot\n\n![error vs time](sl_render_pareto.png)\n"]
    for res_name in ("320x240", "640x480"):
        sel = [r for r in ship if r["scene"] == "bin" and r["res"] == res_name and r["sensor"] == "industrial"
               and np.isfinite(r["rmse_mm"]) and np.isfinite(r["miss_robust"])]
        if sel:
            nd = nondominated([(r["fringe_cpu_s"], r["rmse_mm"], r["miss_robust"]) for r in sel])
            L.append(f"Non-dominated in (CPU s, RMSE, miss_robust), bin {res_name}: "
                     + "; ".join(f"{label(sel[i])} ({sel[i]['fringe_cpu_s']:.1f} s, {sel[i]['rmse_mm']:.3f} mm, "
                                 f"{sel[i]['miss_robust']:.3f})" for i in sorted(nd, key=lambda i: sel[i]["fringe_cpu_s"]))
                     + ".\n")
    return L


def report(rows, meta, out_dir: Path, quick: bool, elapsed: float, rendered: bool = True):
    out_dir.mkdir(parents=True, exist_ok=True)
    write_rows_csv(out_dir / "sl_render.csv", rows, list(rows[0].keys()))
    add_robustness(rows)
    chosen = {(res, BASE_PAT, BASE["steps"], BASE["samples"], "default") for res in ("320x240", "640x480")}
    plot(rows, out_dir / "sl_render_pareto.png", chosen)
    ship = [r for r in rows if r["decoder"] == "shipped"]
    write_with_notes(out_dir / "sl_render.md", intro(meta, quick, elapsed, rendered) + targets(ship)
                     + factor_sections(ship) + base_render_sections(rows) + pareto_lines(ship))


def main(argv=None):
    ap = sweep_parser(__doc__, "datapipe_sl_bench", quick="four renders only (a smoke test)")
    a = ap.parse_args(argv)
    clock = Stopwatch().start()
    log = lambda s: print(f"[{clock.stop().wall_s:6.0f}s] {s}", flush=True)  # noqa: E731
    cases = plan(a.quick)
    meta = cached_renders(a, cases, render_all, log)
    rows = decode_all(cases, meta, a.cache, log)
    report(rows, meta, a.out, a.quick, clock.stop().wall_s, rendered=not a.report_only)
    log(f"wrote {a.out}/sl_render.md")


if __name__ == "__main__":
    main()
