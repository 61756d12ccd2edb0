"""Images per hour per core against views per drop (issue #29 item 4).

Runs `datapipe run` on a copy of a preset (default `datapipe/presets/bin_picking.json`) with one
scene of `--views` renders, optionally at a coarser `--binning` (the device's own 2x2 / 4x4 modes,
fewer pixels) to keep the run short, then reads run.json's `stats.steps` (process CPU seconds per
step, all of Cycles' threads included) and splits them into what a drop costs once (placement +
simulation) and what each view costs (render, structured light, writes, annotations; the scene's
own files are counted with the views, a slight overestimate of their cost). Images per hour per core
at V views per drop = 3600 * V / (drop + V * view): the run's set-up (Blender, meshes, paid once per
run) is left out, as in production.md. Prints a Markdown table; `--out` keeps the run.

    python benchmarks/bench_views.py --binning 4 --views 3
"""
from __future__ import annotations

import json
import os
import sys
import tempfile
from pathlib import Path

from harness import ROOT, md_table, parser, preset_dict, run_child

DROP_STEPS = ("placement", "simulation")
PER_SCENE_IGNORED = ("setup",)


def measure(preset: Path, views: int, binning: int | None, out: Path, seed: int) -> dict:
    d = preset_dict(preset)   # the copy lives elsewhere: absolute mesh paths
    if binning is not None:
        d["binning"] = binning
    s = d["scene"]
    s["num_renders"] = s["min_renders_per_scene"] = s["max_renders_per_scene"] = views
    s["seed"] = seed
    d.setdefault("output", {})["overview"] = False
    tmp = out.parent / "preset.json"
    tmp.write_text(json.dumps(d))
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    child = run_child([sys.executable, "-m", "datapipe", "run", str(tmp), "--out", str(out), "--force", "--quiet"],
                      env=env)
    if child.returncode:
        raise RuntimeError(f"datapipe run of {tmp} failed (exit {child.returncode})")
    run = json.loads((out / "run.json").read_text())
    steps = run["stats"]["steps"]
    drop = sum(steps[k]["cpu_s"] for k in DROP_STEPS if k in steps)
    rest = sum(v["cpu_s"] for k, v in steps.items() if k not in DROP_STEPS + PER_SCENE_IGNORED)
    scene = json.loads((out / "scene.0001" / "scene.json").read_text())
    return {"views": views, "drop_cpu_s": drop, "view_cpu_s": rest / views, "wall_s": child.wall_s,
            "parts": scene["simulation"]["parts"], "resolution": scene["renders"][0]["resolution"],
            "steps": {k: round(v["cpu_s"], 2) for k, v in steps.items()}}


def per_hour(drop: float, view: float, v: int) -> float:
    return 3600.0 * v / (drop + v * view)


def main(argv=None) -> int:
    ap = parser(__doc__, quick="--binning 4 --views 1: the smallest run (about a minute)")
    ap.add_argument("--preset", type=Path, default=ROOT / "datapipe" / "presets" / "bin_picking.json")
    ap.add_argument("--views", type=int, default=3, help="renders of the one measured drop")
    ap.add_argument("--binning", type=int, default=None, help="the device's binning (fewer pixels)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None)
    a = ap.parse_args(argv)
    if a.quick:
        a.binning, a.views = 4, 1
    with tempfile.TemporaryDirectory() as tmp:
        out = a.out or Path(tmp) / "run"
        out.parent.mkdir(parents=True, exist_ok=True)
        m = measure(a.preset, a.views, a.binning, out, a.seed)
    print(f"{a.preset.name}, binning {a.binning}, {m['resolution'][0]} x {m['resolution'][1]}, {m['parts']} parts, "
          f"{a.views} views of one drop, {m['wall_s']:.0f} s wall; CPU s per step: {m['steps']}")
    print(f"drop {m['drop_cpu_s']:.1f} CPU s, each view {m['view_cpu_s']:.1f} CPU s\n")
    one = per_hour(m["drop_cpu_s"], m["view_cpu_s"], 1)
    rates = [(v, per_hour(m["drop_cpu_s"], m["view_cpu_s"], v)) for v in (1, 2, 5, 25)]
    print("\n".join(md_table(["views per drop", "CPU s per image", "images / h / core", "vs 1 view"],
                             [[v, f"{3600 / r:.1f}", f"{r:.1f}", f"{r / one:.2f}x"] for v, r in rates])))
    return 0


if __name__ == "__main__":
    sys.exit(main())
