"""Shiny parts: fringe_mode "quadrature" (white + cos, sin per period, every step mixed) against
"render" (every pattern path-traced), accuracy and cost.

    .venv/bin/python benchmarks/bench_glossy_modes.py [--quick] [--sizes 320,640,1280] [--cache DIR] [--report-only]

Scenes: the steel and aluminium cases of bench_sl_materials.py (sl_bench_scenes.case_config: the
demo's parts dropped into its bin, seed 0, scene 0, camera straight down, default rig, every part
in the material), at 0.6 and 0.8 m, 320x240, and two coloured cases at 0.8 m: copper parts
(not a preset) and steel parts in a blue bin.
Per case, in one process and one Blender scene: the native render at the default preset's
settings (16 samples, denoised, rgb/depth/normals/mask; its z-buffer is the truth), the render
mode's fringes (Cycles seed SEED and SEED + 1: the second is the yardstick of what Cycles noise
alone changes), the quadrature mode with three images per layer (`quadrature_packed`: what ships
for grey materials; forced on copper, which ships unpacked), with one image per layer
(`quadrature_unpacked`: what ships for coloured materials) and its cheaper split
(`quadrature_split`: FringePlan coarse_supersample 1, the 1- and 8-period images at one path per camera
pixel in a second call), all with the row code the product renders on shiny scenes
(reflection_filter "auto" -> global). Each is decoded by the product's scanner (auto exposure,
global reflection filter).

Metrics against the z-buffer: valid fraction (all pixels, part pixels), median / p99 |error|,
pixels > 5 mm, pixels removed by the global reflection filter (reason REFLECTION). Cost: process
CPU seconds of the fringe call(s) (+ the mixing) and of the decode, over the native render's CPU
seconds (this machine is shared: CPU seconds, all in one process, side by side).

Sizes (`--sizes`): the accuracy cases at 320x240; steel at 0.8 m also at 640x512 and 1280x1024
(the issue's size) when asked (render, packed, unpacked; no second seed).

Writes benchmarks/results/sl_glossy_modes.md and sl_glossy_modes.csv.
"""
from __future__ import annotations

import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

from harness import RESULTS, clocked, on_path, parser, write_rows_csv, write_with_notes

on_path()
import sl_bench_scenes as S  # noqa: E402
from datapipe import config as C  # noqa: E402
from datapipe import sl  # noqa: E402

MATERIALS = ("steel", "aluminium")
HEIGHTS = (0.6, 0.8)
SIZES = {"320": (320, 240), "640": (640, 512), "1280": (1280, 1024)}
# coloured cases (not presets): what packing does where light of different colours mixes
# case -> (the parts' material, the bin's or None for the built-in grey)
COLOURED = {"copper": ({"name": "copper", "base_color": [0.95, 0.64, 0.54], "metallic": 1.0, "roughness": 0.25}, None),
            "steel_blue_bin": ("steel", {"name": "blue_bin", "base_color": [0.1, 0.2, 0.6], "roughness": 0.6})}
# variant -> (fringe mode, Cycles seed offset, quadrature mode's coarse_supersample, three images per layer)
VARIANTS = {"render": ("render", 0, None, None), "render_seed2": ("render", 1, None, None),
            "quadrature_packed": ("quadrature", 0, 2, True),     # as shipped for grey materials: 4 layers
            "quadrature_unpacked": ("quadrature", 0, 2, False),  # one image per layer (coloured materials): 9
            "quadrature_split": ("quadrature", 0, 1, True)}      # coarse periods at 1 path per pixel, packed
WITHIN = 0.05          # the acceptance: quadrature within 5% of render


def plan(quick: bool, sizes):
    """(size, material, heights, variants) groups: one Blender scene (one physics drop) each."""
    if quick:
        return [("320", "steel", (0.8,), tuple(VARIANTS))]
    out = [("320", m, HEIGHTS, tuple(VARIANTS)) for m in MATERIALS]
    for m in COLOURED:
        out.append(("320", m, (0.8,), ("render", "render_seed2", "quadrature_packed", "quadrature_unpacked")))
    for s in sizes:
        if s != "320":                 # cost at a real size: one shiny case, no second seed
            out.append((s, "steel", (0.8,), ("render", "quadrature_packed", "quadrature_unpacked")))
    return out


def key(size, material, height, variant):
    return f"{size}_{material}_h{height:.2f}_{variant}"


def cpu(fn):
    out, wall, cpu_s = clocked(fn)
    return out, cpu_s, wall


def render_group(size, material, heights, variants, cache: Path, meta: dict, meta_path: Path, log):
    import bpy

    from datapipe.config.plan import FringePlan
    from datapipe.core import structured_light as SLM
    from datapipe.core.world import BlenderWorld
    from datapipe.draws.seeds import scene_rng

    todo = [(h, v) for h in heights for v in variants if key(size, material, h, v) not in meta]
    if not todo:
        return
    bpy.ops.wm.read_factory_settings(use_empty=True)
    cfg = S.case_config("default", heights[0], None if material in COLOURED else material, res=SIZES[size])
    if material in COLOURED:
        parts, bin_spec = COLOURED[material]
        for o in cfg.objects:
            o.material = parts if isinstance(parts, str) else dict(parts)
        if bin_spec is not None:
            cfg.scene.bin_material = dict(bin_spec)
    d = C.default_config().render                       # the native render a user gets
    cfg.render.samples, cfg.render.outputs, cfg.render.denoise = d.samples, list(d.outputs), d.denoise
    cfg.camera.poses = [C.CameraPose(location=[0.0, 0.0, float(h)]) for h in heights]
    tmp = Path(tempfile.mkdtemp(prefix="glossy_"))
    try:
        world = BlenderWorld(cfg, tmp / "world")
        world.setup()
        world.start_scene(0, cfg.scene.seed, scene_rng(cfg.scene.seed, 0), 1)
        scene = world.blend.scene
        natives = {}
        for k, h in enumerate(heights):
            T = world.camera.set_pose(k)
            out, c, w = cpu(lambda: world.renderer.render(tmp / "native", S.SEED))
            natives[h] = (T, out, c, w)
            np.savez_compressed(cache / f"{size}_{material}_h{h:.2f}_truth.npz", depth=out.depth, mask=out.mask, T=T,
                                K=world.camera.K)
            log(f"  native {size} {material} {h}: {c:.1f} CPU s, {w:.1f} s wall")
        world.sl.teardown()
        for mode, css, pack in [("render", None, None), ("quadrature", 2, True), ("quadrature", 2, False),
                                ("quadrature", 1, True)]:
            vs = [v for v in variants if VARIANTS[v][0] == mode and VARIANTS[v][2:] == (css, pack)
                  and any(key(size, material, h, v) not in meta for h in heights)]
            if not vs:
                continue
            cfg2 = cfg.copy()
            cfg2.structured_light.fringe_mode = mode
            # the variant by argument; packing forced: copper would not pack as shipped (grey_materials)
            plan = FringePlan.from_config(cfg2, packed=pack, coarse_supersample=css)
            slc = SLM.StructuredLightCamera(cfg2, scene, world.camera, world.renderer, plan)
            slc.setup()
            for k, h in enumerate(heights):
                T, _, nat_c, nat_w = natives[h]
                world.camera.set_pose(k)
                slc.set_sharp_glossy(SLM.has_shiny_surface(scene))        # as process() does
                for v in vs:
                    rows = slc.wants_rows()
                    (stack, _), c, w = cpu(lambda: slc.render_fringes(tmp / "fringes", S.SEED + VARIANTS[v][1], T,
                                                                     rows=rows))
                    kk = key(size, material, h, v)
                    np.savez_compressed(cache / f"{kk}.npz", rad=stack)
                    meta[kk] = {"size": size, "material": material, "height": h, "variant": v, "fringe_cpu_s": c,
                                "fringe_wall_s": w, "native_cpu_s": nat_c, "native_wall_s": nat_w, "rows": rows}
                    meta_path.write_text(json.dumps(meta, indent=1))
                    log(f"  {kk}: {c:.1f} CPU s, {w:.1f} s wall ({c / nat_c:.2f}x native)")
            slc.teardown()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)      # the world's scratch renders


def decode(meta: dict, cache: Path) -> list[dict]:
    rows = []
    for kk, m in meta.items():
        size, material, h = m["size"], m["material"], m["height"]
        truth = np.load(cache / f"{size}_{material}_h{h:.2f}_truth.npz")
        cfg = S.case_config("default", h, None if material in COLOURED else material, res=SIZES[size])
        scanner = sl.Scanner.from_config(cfg)
        rad = np.load(cache / f"{kk}.npz")["rad"]
        ref_key = key(size, material, h, "render")
        frames_differ = float("nan")          # share of frame values > 0.1% of the peak off render's
        if ref_key in meta:
            ref = np.load(cache / f"{ref_key}.npz")["rad"]
            if ref.shape == rad.shape:
                frames_differ = float((np.abs(rad - ref) > 1e-3 * np.percentile(ref, 99.9)).mean())
        scan, dec_c, _ = cpu(lambda: scanner.scan(rad, S.SEED, truth["K"], truth["T"]))
        res = scan.result
        z, part = truth["depth"], truth["mask"] > 0
        v = res.valid & np.isfinite(z)
        e = np.abs(res.depth - z)[v]
        rows.append({
            "size": "x".join(map(str, SIZES[size])), "material": material, "height": h, "variant": m["variant"],
            "valid": float(res.valid.mean()), "valid_parts": float(res.valid[part].mean()),
            "median_mm": float(np.median(e) * 1e3), "p99_mm": float(np.percentile(e, 99) * 1e3),
            "out5_px": int((e > 5e-3).sum()),
            "reflection_px": int((res.reason == int(sl.Reason.REFLECTION)).sum()),
            "fringe_cpu_s": m["fringe_cpu_s"], "decode_cpu_s": dec_c, "native_cpu_s": m["native_cpu_s"],
            "sl_over_native": (m["fringe_cpu_s"] + dec_c) / m["native_cpu_s"],
            "fringe_over_native": m["fringe_cpu_s"] / m["native_cpu_s"], "frames_differ": frames_differ,
        })
    return rows


COLS = ("size", "material", "height", "variant", "valid", "valid_parts", "median_mm", "p99_mm", "out5_px",
        "reflection_px", "fringe_cpu_s", "decode_cpu_s", "native_cpu_s", "fringe_over_native", "sl_over_native")


def _fmt(v, k):
    if isinstance(v, str) or isinstance(v, (int, np.integer)):
        return str(v)
    if k in ("valid", "valid_parts", "median_mm"):
        return f"{v:.3f}"
    return f"{v:.2f}"


def table(rows, cols=COLS) -> list[str]:
    out = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    out += ["| " + " | ".join(_fmt(r[k], k) for k in cols) + " |" for r in rows]
    return out


def rel(a, b):
    return (a - b) / b if b else (0.0 if a == b else float("inf"))


def compare(rows) -> list[str]:
    """Each variant against the render mode of the same case: relative differences (the second
    render seed shows what Cycles noise alone gives)."""
    ref = {(r["size"], r["material"], r["height"]): r for r in rows if r["variant"] == "render"}
    out = ["| size | material | height | variant | cost vs render | frames differ | valid | median | p99 | > 5 mm px "
           "| REFLECTION px | valid, median, p99 within 5% |", "|" + "---|" * 12]
    for r in rows:
        b = ref.get((r["size"], r["material"], r["height"]))
        if b is None or r is b:
            continue
        d = {k: rel(r[k], b[k]) for k in ("valid", "median_mm", "p99_mm")}
        ok = all(abs(x) <= WITHIN for x in d.values())
        out.append(f"| {r['size']} | {r['material']} | {r['height']:.2f} | {r['variant']} | "
                   f"{r['fringe_cpu_s'] / b['fringe_cpu_s']:.2f}x | {r['frames_differ']:.2%} | {d['valid']:+.1%} | "
                   f"{d['median_mm']:+.1%} | "
                   f"{d['p99_mm']:+.1%} | {r['out5_px']} vs {b['out5_px']} | {r['reflection_px']} vs "
                   f"{b['reflection_px']} | {'yes' if ok else 'no'} |")
    return out


def report(rows, render_wall: float):
    order = {v: i for i, v in enumerate(VARIANTS)}
    pixels = lambda r: np.prod([int(v) for v in r["size"].split("x")])  # noqa: E731
    rows = sorted(rows, key=lambda r: (pixels(r), r["material"], r["height"], order[r["variant"]]))
    lines = ["# Shiny parts: quadrature vs render fringe mode", "",
             "Generated by `benchmarks/bench_glossy_modes.py` (hand-written findings at the end). Default rig, "
             "shipped structured-light defaults (periods 1, 8, 64, 4 steps, 4 paths per camera pixel, auto "
             "exposure, reflection_filter auto -> global with the row code on these shiny scenes), `industrial` "
             "sensor; process CPU seconds on this shared 2-core machine, each cost ratio over the native render "
             "timed in the same process. "
             f"Renders {render_wall / 60:.1f} min wall in all (cached).", "",
             "`native_cpu_s`: the default preset's native render (16 samples, denoised) of the same pose; "
             "`fringe_over_native`: the fringe call(s) (+ the mixing) over it; `sl_over_native`: with the decode. "
             "`frames differ`: share of the fringe stack's values more than 0.1% of its peak (99.9th percentile) "
             "away from the render mode's (same seed; the second render seed shows Cycles noise).",
             "", *table(rows), "", "## quadrature (and a second render seed) vs render", "", *compare(rows), ""]
    write_with_notes(RESULTS / "sl_glossy_modes.md", lines)
    write_rows_csv(RESULTS / "sl_glossy_modes.csv", [{k: r[k] for k in (*COLS, "frames_differ")} for r in rows])
    return rows


def main(argv=None):
    ap = parser(__doc__, quick="steel at 0.8 m only")
    ap.add_argument("--sizes", default="320", help="comma list of 320, 640, 1280")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "datapipe_bench_glossy")
    ap.add_argument("--report-only", action="store_true")
    a = ap.parse_args(argv)
    a.cache.mkdir(parents=True, exist_ok=True)
    meta_path = a.cache / "renders.json"
    meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {}
    if not a.report_only:
        for g in plan(a.quick, a.sizes.split(",")):
            print(f"group {g}", flush=True)
            render_group(*g, a.cache, meta, meta_path, lambda s: print(s, flush=True))
    natives = {(m["size"], m["material"], m["height"]): m["native_wall_s"] for m in meta.values()}
    rows = report(decode(meta, a.cache), sum(m["fringe_wall_s"] for m in meta.values()) + sum(natives.values()))
    print("\n".join(table(rows)))


if __name__ == "__main__":
    main()
