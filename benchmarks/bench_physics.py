"""Physics on stiff and extreme parts: lost parts, interpenetration, floating, settling, cost.

    .venv/bin/python benchmarks/bench_physics.py [--quick] [--baseline /path/to/other/checkout]

Cases (procedural parts from tests/physics_parts.py and the demo assets), each a few scenes at the
default settings unless the case says otherwise; every result is measured independently of Bullet
by datapipe.checks.physics_check on the model meshes at the final poses (pairs deeper than 0.5 mm, parts
under the floor, parts more than 2 mm from everything). `--baseline` also times the demo scenes
with another checkout's simulation (e.g. main before this change) for the cost comparison.

Writes benchmarks/results/physics.md and physics.csv. `--drop-only` measures only the drop cost
against parts (the bin_picking.json pile of steel pegs, nuts and brackets with 10/40/80/120 parts,
`time.process_time` of `drop_scene`, the independent check included) and replaces that section of
physics.md; `--cases "A|B"` runs only the cases whose label contains one of these and prints their table
(physics.md and physics.csv keep the full run's).
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

from harness import RESULTS, ROOT, Stopwatch, md_table, on_path, parser, preset_dict, write_rows_csv

on_path("tests")

import bpy  # noqa: E402
import numpy as np  # noqa: E402
from mathutils import Matrix  # noqa: E402

import physics_parts  # noqa: E402
from datapipe.config import ObjectEntry, assets_dir, default_config, loads, presets_dir  # noqa: E402
from datapipe.core.objects import ObjectManager  # noqa: E402
from datapipe.core.scene import BlendScene  # noqa: E402
from datapipe.core.simulation import Simulation, drop_scene, plan_substeps  # noqa: E402
from datapipe.draws.seeds import scene_rng  # noqa: E402

ASSETS = assets_dir()
COLUMNS = ["case", "scene", "parts", "lost", "pairs>0.5mm", "max_depth_mm", "below_floor", "floating>2mm",
           "frames", "settled", "unsettled", "substeps", "sim_s"]


def entry(path, mass, n, shape="AUTO", name=None, restitution=0.1, scale=1.0):
    return ObjectEntry(filepath=str(path), mass=mass, min_instances=n, max_instances=n, name=name or Path(path).stem,
                       collision_shape=shape, restitution=restitution, scale=scale)


# name -> [(part, mass kg, instances, collision shape, scale)]; the sizes of the measurements
# (30 parts a scene: several spawn layers, so drops of up to ~0.2 m). Parts: tests/physics_parts.py
# names, or demo assets as "asset:peg".
CASES = {
    "thin plates 40x40x1 mm + washers": [("plate", 0.012, 15, "AUTO", 1.0), ("washer", 0.004, 15, "AUTO", 1.0)],
    "5 mm pegs + 5 mm nuts": [("peg5", 0.001, 30, "AUTO", 1.0), ("nut5", 0.002, 30, "AUTO", 1.0)],
    "concave U-channel + L-bracket, CONVEX_HULL": [("u_channel", 0.03, 15, "CONVEX_HULL", 1.0),
                                                   ("l_bracket", 0.02, 15, "CONVEX_HULL", 1.0)],
    "concave U-channel + L-bracket, MESH": [("u_channel", 0.03, 15, "MESH", 1.0), ("l_bracket", 0.02, 15, "MESH", 1.0)],
    "concave U-channel + L-bracket, AUTO (= DECOMPOSED)": [("u_channel", 0.03, 15, "AUTO", 1.0),
                                                           ("l_bracket", 0.02, 15, "AUTO", 1.0)],
    "30 nuts, CONVEX_HULL": [("asset:nut", 0.02, 30, "CONVEX_HULL", 1.0)],
    "30 nuts, MESH": [("asset:nut", 0.02, 30, "MESH", 1.0)],
    "1000:1 mass mix (1 kg pegs, 1 g nuts)": [("asset:peg", 1.0, 6, "AUTO", 1.0), ("asset:nut", 0.001, 20, "AUTO", 1.0)],
    "0.3 m part in the default bin": [("asset:peg", 2.0, 4, "AUTO", 6.0)],
}
SCENES = {"30 nuts, CONVEX_HULL": 1, "30 nuts, MESH": 1, "0.3 m part in the default bin": 1}
BEFORE = [k for k in CASES if k not in ("30 nuts, MESH", "concave U-channel + L-bracket, AUTO (= DECOMPOSED)")]


def part_path(parts: dict[str, str], key: str) -> str:
    return str(ASSETS / f"{key[6:]}.obj") if key.startswith("asset:") else parts[key]


def cases(parts: dict[str, str], quick: bool):
    n_scenes = 1 if quick else 2
    yield "demo (default preset)", default_config().objects, 1 if quick else 3, None
    for label, spec in CASES.items():
        entries = [entry(part_path(parts, k), m, n, shape, name=f"{k.replace('asset:', '')}", scale=sc)
                   for k, m, n, shape, sc in spec]
        yield label, entries, SCENES.get(label, n_scenes), None


def run_case(label, entries, n_scenes):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    cfg = default_config()
    cfg.objects = entries
    bs = BlendScene(cfg).setup()
    with Stopwatch() as load:
        om = ObjectManager(cfg, bs).load_sources()
    sim = Simulation(cfg, bs)
    rows = []
    for s in range(n_scenes):
        rng = scene_rng(0, s)
        insts = om.populate(rng)
        res = sim.run(insts, rng)
        c = res.check
        rows.append({"case": label, "scene": s, "parts": len(insts), "lost": len(res.removed),
                     "pairs>0.5mm": len(c.pairs), "max_depth_mm": round(c.max_depth * 1000, 2),
                     "below_floor": len(c.below_floor), "floating>2mm": len(c.floating), "frames": res.frames,
                     "settled": res.settled, "unsettled": len(res.unsettled), "substeps": res.plan.substeps,
                     "sim_s": round(res.seconds, 3)})
        om.clear()
        print(label, rows[-1], flush=True)
    return rows, load.wall_s


def restitution_case():
    """A demo nut dropped flat from 100 mm above the floor: highest rebound per restitution."""
    out = []
    for e in (0.1, 0.5, 0.9):
        bpy.ops.wm.read_factory_settings(use_empty=True)
        cfg = default_config()
        cfg.objects = [entry(ASSETS / "nut.obj", 0.02, 1, restitution=e)]
        cfg.simulation.max_frames = 60
        bs = BlendScene(cfg).setup()
        om = ObjectManager(cfg, bs).load_sources()
        (inst,) = om.populate(np.random.default_rng(0))
        rest_z = bs.floor_z + 0.006
        inst.obj.matrix_world = Matrix.Translation((0.0, 0.0, rest_z + 0.1))
        sim = Simulation(cfg, bs)
        zs = []
        # the same world settings as Simulation.run, stepped here to read the height every frame
        plan = plan_substeps(cfg, bs, [inst], bs.scene.render.fps_base / bs.scene.render.fps)
        sim._configure_world(plan.substeps)
        bs.scene.frame_set(1)
        for f in range(2, 61):
            bs.scene.frame_set(f)
            dg = bpy.context.evaluated_depsgraph_get()
            zs.append(float(inst.obj.evaluated_get(dg).matrix_world.translation.z))
        z = np.array(zs)
        first_contact = int(np.argmax(z < rest_z + 0.002))
        rebound = float(z[first_contact:].max() - rest_z)
        out.append((e, rebound))
    return out


def baseline_demo(checkout: str, n_scenes: int) -> list[dict]:
    """Time the demo scenes with another checkout's simulation (frames, seconds), own process."""
    code = r"""
import json, sys, time, bpy
sys.path.insert(0, sys.argv[1])
from datapipe.config import default_config
from datapipe.core.scene import BlendScene
from datapipe.core.objects import ObjectManager
from datapipe.core.simulation import Simulation
from datapipe.draws.seeds import scene_rng
bpy.ops.wm.read_factory_settings(use_empty=True)
cfg = default_config()
bs = BlendScene(cfg).setup(); om = ObjectManager(cfg, bs).load_sources(); sim = Simulation(cfg, bs)
out = []
for s in range(int(sys.argv[2])):
    rng = scene_rng(0, s); insts = om.populate(rng)
    t = time.perf_counter(); res = sim.run(insts, rng); dt = time.perf_counter() - t
    out.append({"scene": s, "frames": res.frames, "sim_s": dt, "lost": len(res.removed)})
    om.clear()
print("BASELINE" + json.dumps(out))
"""
    p = subprocess.run([sys.executable, "-c", code, checkout, str(n_scenes)], capture_output=True, text=True,
                       timeout=600, env={"PYTHONPATH": checkout, "PATH": "/usr/bin:/bin"})
    line = next(x for x in p.stdout.splitlines() if x.startswith("BASELINE"))
    return json.loads(line[8:])


BEFORE_CASES = r"""
import importlib.util, json, sys, time, bpy, numpy as np
checkout, check_file, parts_json, assets = sys.argv[1:5]
sys.path.insert(0, checkout)
spec = importlib.util.spec_from_file_location("physics_check", check_file)
pc = importlib.util.module_from_spec(spec); sys.modules["physics_check"] = pc; spec.loader.exec_module(pc)
from datapipe.config import ObjectEntry, default_config
from datapipe.core.scene import BlendScene
from datapipe.core.objects import ObjectManager
from datapipe.core.simulation import Simulation
from datapipe.draws.seeds import scene_rng
parts = json.loads(parts_json)
specs = json.loads(sys.argv[6])
def path(k):
    return assets + "/" + k[6:] + ".obj" if k.startswith("asset:") else parts[k]
cases = {label: [ObjectEntry(filepath=path(k), mass=m, min_instances=n, max_instances=n, scale=sc,
                             collision_shape="CONVEX_HULL" if shape == "AUTO" else shape, name=k.replace("asset:", ""))
                 for k, m, n, shape, sc in spec] for label, spec in specs.items()}
out = []
for label, entries in cases.items():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    cfg = default_config(); cfg.objects = entries
    bs = BlendScene(cfg).setup(); om = ObjectManager(cfg, bs).load_sources(); sim = Simulation(cfg, bs)
    for s in range(int(sys.argv[5])):
        rng = scene_rng(0, s); insts = om.populate(rng)
        t = time.perf_counter(); res = sim.run(insts, rng); dt = time.perf_counter() - t
        ps = [pc.Part(i.name, *om.model_mesh(i.entry_index)[:2], res.poses[i.name]) for i in res.kept]
        c = pc.check_scene(ps, bs.floor_z, (bs.drop_zone_center, bs.drop_zone_half))
        out.append({"case": label, "scene": s, "parts": len(insts), "lost": len(res.removed),
                    "pairs>0.5mm": len(c.pairs), "max_depth_mm": round(c.max_depth * 1000, 2),
                    "below_floor": len(c.below_floor), "floating>2mm": len(c.floating), "frames": res.frames,
                    "settled": res.settled, "unsettled": None, "substeps": cfg.simulation.substeps, "sim_s": round(dt, 3)})
        om.clear()
print("BEFORE" + json.dumps(out))
"""


def before_cases(checkout: str, parts: dict, n_scenes: int) -> list[dict]:
    """The issue's cases with another checkout's simulation (e.g. main before this change), checked
    by this checkout's physics_check."""
    p = subprocess.run([sys.executable, "-c", BEFORE_CASES, checkout, str(ROOT / "datapipe" / "physics_check.py"),
                        json.dumps(parts), str(ASSETS), str(n_scenes), json.dumps({k: CASES[k] for k in BEFORE})],
                       capture_output=True, text=True,
                       timeout=900, env={"PYTHONPATH": checkout, "PATH": "/usr/bin:/bin"})
    line = next((x for x in p.stdout.splitlines() if x.startswith("BEFORE")), None)
    if line is None:
        raise RuntimeError(p.stderr[-2000:])
    return json.loads(line[6:])


DROP_PARTS = (10, 40, 120)
DROP_SEEDS = (0, 1, 2, 3, 4)
DROP_HEADING = "## Drop cost: parts against CPU seconds"


def dense_drop(n_parts: int, seed: int) -> dict:
    """bin_picking.json's pile with `n_parts` steel parts split over its three meshes (as
    bench_production.py's cells), dropped in stages by `drop_scene`; CPU seconds of the drop."""
    pre = presets_dir() / "bin_picking.json"
    p = preset_dict(pre)
    p["scene"].pop("fill", None)
    for k, o in enumerate(p["objects"]):
        o["min_instances"] = o["max_instances"] = n_parts // 3 + (1 if k < n_parts % 3 else 0)
        o["material"] = "steel"
    cfg = loads(json.dumps(p))
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bs = BlendScene(cfg).setup()
    om = ObjectManager(cfg, bs).load_sources()
    sim = Simulation(cfg, bs)
    with Stopwatch() as t:
        res, _ = drop_scene(om, sim, scene_rng(seed, 0), 1234)
    c = res.check
    row = {"parts": n_parts, "seed": seed, "cpu_s": round(t.cpu_s, 2), "kept": len(res.kept), "lost": len(res.removed),
           "pairs": len(c.pairs), "max_depth_mm": round(c.max_depth * 1000, 2), "below_floor": len(c.below_floor),
           "floating": len(c.floating), "frames": res.frames, "stages": res.stages, "settled": res.settled,
           "unsettled": len(res.unsettled), "substeps": res.plan.substeps}
    print("drop", row, flush=True)
    return row


def drop_section(rows: list[dict]) -> list[str]:
    L = [DROP_HEADING, "",
         "`bench_physics.py --drop-only`: the `bin_picking.json` pile (steel pegs, nuts, brackets in equal "
         "shares, no `scene.fill`), dropped in stages by `drop_scene`; `CPU s` is `time.process_time` of the "
         "whole drop (stages, freezing, the independent check). Checks as above (pairs deeper than 0.5 mm, "
         "below the floor, floating > 2 mm).", ""]
    return L + md_table(
        ["parts", "seed", "CPU s", "lost", "pairs > 0.5 mm", "max depth mm", "below floor", "floating > 2 mm",
         "frames", "stages", "settled", "unsettled", "substeps"],
        [[r["parts"], r["seed"], f"{r['cpu_s']:.2f}", r["lost"], r["pairs"], f"{r['max_depth_mm']:.2f}",
          r["below_floor"], r["floating"], r["frames"], r["stages"], r["settled"], r["unsettled"], r["substeps"]]
         for r in rows])


def replace_drop_section(rows: list[dict]) -> None:
    """Put the drop table into physics.md in place of its previous one (before the notes, if any)."""
    path = RESULTS / "physics.md"
    text = path.read_text() if path.exists() else "# Physics on extreme parts\n"
    lines = text.rstrip("\n").split("\n")
    if DROP_HEADING in lines:
        a = lines.index(DROP_HEADING)
        b = next((i for i in range(a + 1, len(lines)) if lines[i].startswith("## ")), len(lines))
        lines[a:b] = drop_section(rows) + [""]
    else:
        lines += [""] + drop_section(rows)
    path.write_text("\n".join(lines).rstrip("\n") + "\n")


def main():
    ap = parser(__doc__, quick="1 scene per case, 1 demo scene (several minutes: Blender drops)")
    ap.add_argument("--baseline", help="another checkout (e.g. main before this change) to time the demo with")
    ap.add_argument("--drop-only", action="store_true", help="only the drop cost against parts (replaces its section)")
    ap.add_argument("--cases", help="only the cases whose label contains this")
    args = ap.parse_args()
    RESULTS.mkdir(parents=True, exist_ok=True)
    if args.drop_only:
        replace_drop_section([dense_drop(n, s) for n in DROP_PARTS for s in DROP_SEEDS])
        return
    total = Stopwatch().start()
    rows = []
    csv_path = RESULTS / "physics.csv" if not args.cases else Path(tempfile.gettempdir()) / "physics_cases.csv"
    with tempfile.TemporaryDirectory() as tmp:
        parts = physics_parts.write_all(tmp)
        loads = {}
        for label, entries, n, _ in cases(parts, args.quick):
            if args.cases and not any(c in label for c in args.cases.split("|")):
                continue
            r, loads[label] = run_case(label, entries, n)
            rows += r
        before = before_cases(args.baseline, parts, 1) if args.baseline else []
    write_rows_csv(csv_path, rows, COLUMNS)
    if args.cases:                      # a subset: printed above, physics.md keeps the full run
        print("\n".join(_table(rows)[1]))
        return
    rest = restitution_case()
    base = baseline_demo(args.baseline, 3 if not args.quick else 1) if args.baseline else None
    drops = [] if args.cases else [dense_drop(n, s) for n in DROP_PARTS for s in DROP_SEEDS]
    total.stop()
    write_md(rows, loads, rest, base, total.wall_s, before, drops)


def _table(rows, loads=None):
    by_case: dict[str, list[dict]] = {}
    for r in rows:
        by_case.setdefault(r["case"], []).append(r)
    L = ["| case | scenes | parts | lost | pairs > 0.5 mm | max depth mm | below floor | floating > 2 mm | "
         "max frames | settled | unsettled | substeps | sim s/scene |" + (" load s |" if loads else ""),
         "|---|---|---|---|---|---|---|---|---|---|---|---|---|" + ("---|" if loads else "")]
    for case, rs in by_case.items():
        uns = "-" if rs[0]["unsettled"] is None else str(sum(r["unsettled"] for r in rs))
        L.append(f"| {case} | {len(rs)} | {sum(r['parts'] for r in rs)} | {sum(r['lost'] for r in rs)} | "
                 f"{sum(r['pairs>0.5mm'] for r in rs)} | {max(r['max_depth_mm'] for r in rs):.2f} | "
                 f"{sum(r['below_floor'] for r in rs)} | {sum(r['floating>2mm'] for r in rs)} | "
                 f"{max(r['frames'] for r in rs)} | {sum(bool(r['settled']) for r in rs)}/{len(rs)} | "
                 f"{uns} | {max(r['substeps'] for r in rs)} | "
                 f"{np.mean([r['sim_s'] for r in rs]):.2f} |" + (f" {loads[case]:.2f} |" if loads else ""))
    return by_case, L


def write_md(rows, loads, rest, base, total_s, before=(), drops=()):
    by_case, table = _table(rows, loads)
    L = ["# Physics on extreme parts", "",
         "`benchmarks/bench_physics.py` (defaults: substeps chosen per scene, AUTO collision shapes unless the case "
         "names one). Per case the sums over its scenes; depth, frames and substeps are the maxima; `sim s` is the "
         "mean simulation wall time per scene (2 shared CPU cores: +-30%). Measured independently of Bullet "
         "(`datapipe/checks/physics_check.py`: model meshes at the final poses).", "",
         ]
    L += table
    if before:
        L += ["", "## The same cases before (baseline checkout: fixed 10 substeps, 0.5 mm margins, 5 frames under "
              "5 mm/s = at rest, Blender's triangle-mesh shape for MESH)", ""] + _table(before)[1]
    L += ["", "## Restitution", "", "A demo nut dropped flat from 100 mm; highest rebound after the first contact.", "",
          "| restitution e | rebound mm |", "|---|---|"]
    L += [f"| {e} | {r * 1000:.1f} |" for e, r in rest]
    if base:
        demo = by_case.get("demo (default preset)", [])
        L += ["", "## Demo cost against the baseline checkout", "", "| scene | frames before | frames now | "
              "sim s before | sim s now |", "|---|---|---|---|---|"]
        for b, r in zip(base, demo):
            L.append(f"| {b['scene']} | {b['frames']} | {r['frames']} | {b['sim_s']:.3f} | {r['sim_s']:.3f} |")
        tb, tn = sum(b["sim_s"] for b in base), sum(r["sim_s"] for r in demo[:len(base)])
        L.append(f"| total | {sum(b['frames'] for b in base)} | {sum(r['frames'] for r in demo[:len(base)])} | "
                 f"{tb:.3f} | {tn:.3f} ({(tn / tb - 1) * 100:+.0f}%) |")
    if drops:
        L += [""] + drop_section(drops)
    L += ["", f"Benchmark wall time {total_s:.0f} s."]
    (RESULTS / "physics.md").write_text("\n".join(L) + "\n")
    print("\n".join(L))


if __name__ == "__main__":
    main()
