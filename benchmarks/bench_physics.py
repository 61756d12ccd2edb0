"""Physics on stiff and extreme parts: lost parts, interpenetration, floating, settling, cost.

    .venv/bin/python benchmarks/bench_physics.py [--quick] [--baseline /path/to/other/checkout]

Cases (procedural parts from tests/physics_parts.py and the demo assets), each a few scenes at the
default settings unless the case says otherwise; every result is measured independently of Bullet
by datapipe.physics_check on the model meshes at the final poses (pairs deeper than 0.5 mm, parts
under the floor, parts more than 2 mm from everything). `--baseline` also times the demo scenes
with another checkout's simulation (e.g. main before this change) for the cost comparison.

Writes benchmarks/results/physics.md and physics.csv.
"""
from __future__ import annotations

import argparse
import csv
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

import bpy  # noqa: E402
import numpy as np  # noqa: E402
from mathutils import Matrix  # noqa: E402

import physics_parts  # noqa: E402
from datapipe.config import ObjectEntry, assets_dir, default_config  # noqa: E402
from datapipe.core.objects import ObjectManager  # noqa: E402
from datapipe.core.scene import BlendScene  # noqa: E402
from datapipe.core.simulation import Simulation, plan_substeps  # noqa: E402
from datapipe.seeds import scene_rng  # noqa: E402

ASSETS = assets_dir()
COLUMNS = ["case", "scene", "parts", "lost", "pairs>0.5mm", "max_depth_mm", "below_floor", "floating>2mm",
           "frames", "settled", "unsettled", "substeps", "sim_s"]


def entry(path, mass, n, shape="AUTO", name=None, restitution=0.1, scale=1.0):
    return ObjectEntry(filepath=str(path), mass=mass, min_instances=n, max_instances=n, name=name or Path(path).stem,
                       collision_shape=shape, restitution=restitution, scale=scale)


def cases(parts: dict[str, str], quick: bool):
    n_scenes = 1 if quick else 3
    demo = default_config().objects
    yield "demo (default preset)", demo, n_scenes, None
    yield "thin plates 40x40x1 mm + washers", [entry(parts["plate"], 0.012, 6), entry(parts["washer"], 0.004, 6)], \
        n_scenes, None
    yield "5 mm pegs + 5 mm nuts", [entry(parts["peg5"], 0.001, 10), entry(parts["nut5"], 0.002, 10)], n_scenes, None
    for shape in ("CONVEX_HULL", "MESH", "DECOMPOSED"):
        yield f"concave U-channel + L-bracket, {shape}", [entry(parts["u_channel"], 0.03, 5, shape),
                                                          entry(parts["l_bracket"], 0.02, 5, shape)], n_scenes, None
    for shape in ("CONVEX_HULL", "MESH"):
        yield f"30 nuts, {shape}", [entry(ASSETS / "nut.obj", 0.02, 30, shape)], max(1, n_scenes - 1), None
    yield "1000:1 mass mix (1 kg pegs, 1 g nuts)", [entry(ASSETS / "peg.obj", 1.0, 4),
                                                     entry(ASSETS / "nut.obj", 0.001, 8)], n_scenes, None
    yield "0.3 m part in the default bin", [entry(ASSETS / "peg.obj", 2.0, 4, scale=6.0, name="bigpeg")], 1, None


def run_case(label, entries, n_scenes, writer):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    cfg = default_config()
    cfg.objects = entries
    bs = BlendScene(cfg).setup()
    t0 = time.perf_counter()
    om = ObjectManager(cfg, bs).load_sources()
    load_s = time.perf_counter() - t0
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
        writer.writerow(rows[-1])
    return rows, load_s


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
from datapipe.seeds import scene_rng
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


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--baseline", help="another checkout (e.g. main before this change) to time the demo with")
    args = ap.parse_args()
    RESULTS.mkdir(parents=True, exist_ok=True)
    t_start = time.perf_counter()
    rows = []
    with tempfile.TemporaryDirectory() as tmp, open(RESULTS / "physics.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, COLUMNS)
        w.writeheader()
        parts = physics_parts.write_all(tmp)
        loads = {}
        for label, entries, n, _ in cases(parts, args.quick):
            r, loads[label] = run_case(label, entries, n, w)
            rows += r
    rest = restitution_case()
    base = baseline_demo(args.baseline, 3 if not args.quick else 1) if args.baseline else None
    write_md(rows, loads, rest, base, time.perf_counter() - t_start)


def write_md(rows, loads, rest, base, total_s):
    by_case: dict[str, list[dict]] = {}
    for r in rows:
        by_case.setdefault(r["case"], []).append(r)
    L = ["# Physics on extreme parts", "",
         "`benchmarks/bench_physics.py` (defaults: substeps chosen per scene, AUTO collision shapes unless the case "
         "names one). Per case the sums over its scenes; depth, frames and substeps are the maxima; `sim s` is the "
         "mean simulation wall time per scene (2 shared CPU cores: +-30%). Measured independently of Bullet "
         "(`datapipe/physics_check.py`: model meshes at the final poses).", "",
         "| case | scenes | parts | lost | pairs > 0.5 mm | max depth mm | below floor | floating > 2 mm | "
         "max frames | settled | unsettled | substeps | sim s/scene | load s |",
         "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for case, rs in by_case.items():
        L.append(f"| {case} | {len(rs)} | {sum(r['parts'] for r in rs)} | {sum(r['lost'] for r in rs)} | "
                 f"{sum(r['pairs>0.5mm'] for r in rs)} | {max(r['max_depth_mm'] for r in rs):.2f} | "
                 f"{sum(r['below_floor'] for r in rs)} | {sum(r['floating>2mm'] for r in rs)} | "
                 f"{max(r['frames'] for r in rs)} | {sum(bool(r['settled']) for r in rs)}/{len(rs)} | "
                 f"{sum(r['unsettled'] for r in rs)} | {max(r['substeps'] for r in rs)} | "
                 f"{np.mean([r['sim_s'] for r in rs]):.2f} | {loads[case]:.2f} |")
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
    L += ["", f"Benchmark wall time {total_s:.0f} s."]
    (RESULTS / "physics.md").write_text("\n".join(L) + "\n")
    print("\n".join(L))


if __name__ == "__main__":
    main()
