"""Pipeline cost by stage, mesh reads per run, settling, and memory across consecutive scenes.

    .venv/bin/python benchmarks/bench_pipeline.py [--quick]

Writes benchmarks/results/pipeline.md, pipeline.csv and pipeline_memory.png. Each case runs in its
own process (bpy is one per process) so the numbers do not leak between cases.
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
from pathlib import Path

from harness import RESULTS, ROOT, Stopwatch, parser, write_rows_csv

CASE_SCRIPT = r"""
import json, sys, time, resource
import bpy
from datapipe import config as C
from datapipe.engine.pipeline import Pipeline
spec = json.loads(sys.argv[1])
cfg = C.default_config()
cfg.scene.num_renders = spec["renders"]
cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = spec["per_scene"]
cfg.camera.resolution = spec["res"]
cfg.render.samples = spec["samples"]
cfg.render.threads = 2
cfg.structured_light.enabled = spec.get("sl", False)
for o, n in zip(cfg.objects, spec["parts"]):
    o.min_instances = o.max_instances = n
bpy.ops.wm.read_factory_settings(use_empty=True)
def rss_mb():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS"):
            return int(line.split()[1]) / 1024
rows = []
t0 = time.perf_counter()
pipe = Pipeline(cfg, spec["out"])
for ev in pipe.run():
    if ev.stage == "scene_done":
        rows.append({"scene": ev.scene, "rss_mb": rss_mb(), "t": time.perf_counter() - t0,
                     "objects": len(bpy.data.objects), "meshes": len(bpy.data.meshes),
                     "materials": len(bpy.data.materials), "images": len(bpy.data.images)})
rec = json.load(open(spec["out"] + "/run.json"))
print("RESULT" + json.dumps({"stats": rec["stats"], "scenes": rows, "wall": time.perf_counter() - t0,
                             "max_frames": cfg.simulation.max_frames,
                             "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}))
"""


def run_case(name, **spec):
    with tempfile.TemporaryDirectory() as d:
        spec["out"] = str(Path(d) / "out")
        with Stopwatch() as t:
            r = subprocess.run([sys.executable, "-c", CASE_SCRIPT, json.dumps(spec)], capture_output=True, text=True,
                               cwd=ROOT)
        if r.returncode != 0:
            raise SystemExit(f"case {name} failed:\n{r.stderr[-3000:]}")
        res = json.loads(r.stdout.split("RESULT", 1)[1])
        res["process_wall"] = t.wall_s
        res["name"], res["spec"] = name, spec
        return res


def plot_memory(rows, path):
    import cv2
    import numpy as np
    W, H, m = 640, 360, 60
    img = np.full((H, W, 3), 255, np.uint8)
    xs = [r["scene"] + 1 for r in rows]
    ys = [r["rss_mb"] for r in rows]
    lo, hi = 0, max(ys) * 1.2
    def px(x, y):
        return (int(m + (x - 1) / max(1, max(xs) - 1) * (W - 2 * m)), int(H - m - (y - lo) / (hi - lo) * (H - 2 * m)))
    cv2.line(img, (m, H - m), (W - m, H - m), (0, 0, 0), 1)
    cv2.line(img, (m, m), (m, H - m), (0, 0, 0), 1)
    for k in range(5):
        y = lo + (hi - lo) * k / 4
        cv2.putText(img, f"{y:.0f}", (5, px(1, y)[1] + 4), cv2.FONT_HERSHEY_SIMPLEX, 0.4, (0, 0, 0), 1)
    pts = np.array([px(x, y) for x, y in zip(xs, ys)], np.int32)
    cv2.polylines(img, [pts], False, (200, 60, 0), 2)
    for p in pts:
        cv2.circle(img, tuple(int(v) for v in p), 3, (200, 60, 0), -1)
    cv2.putText(img, "resident memory (MB) after each scene", (m, 30), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (0, 0, 0), 1)
    cv2.putText(img, "scene", (W // 2, H - 20), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)
    cv2.imwrite(str(path), img)


def main():
    args = parser(__doc__, quick="smaller cases (for a smoke run)").parse_args()
    q = args.quick
    cases = [
        run_case("demo (320x240, 32 spp)", renders=4, per_scene=2, res=[320, 240], samples=32, parts=[3, 3, 2]),
        run_case("demo + structured light (as shipped)", renders=4, per_scene=2, res=[320, 240], samples=32,
                 parts=[3, 3, 2], sl=True),
        run_case("heavy (50 parts, 640x480, 64 spp)", renders=2 if q else 4, per_scene=2,
                 res=[640, 480] if not q else [320, 240], samples=64 if not q else 16, parts=[20, 20, 10]),
        run_case("20 scenes (50 parts, 64x48, 1 spp)", renders=6 if q else 20, per_scene=1, res=[64, 48],
                 samples=1, parts=[20, 20, 10]),
    ]
    RESULTS.mkdir(parents=True, exist_ok=True)
    stages = ["setup", "placement", "simulation", "render", "structured_light", "write"]
    lines = ["# Pipeline cost by stage", "",
             "One process per case, this 2-core machine (noisy: compare ratios within a row). `setup` includes "
             "the one-time mesh import; `render` is Cycles' own time for the native layer; `write` is reading its "
             "EXR back and writing the output files; `overhead` = (setup + placement + simulation + write) / total.", "",
             "| case | renders | scenes | mesh files read | " + " | ".join(f"{s} s" for s in stages)
             + " | total s | overhead | frames simulated (cap) |",
             "|---" * (len(stages) + 7) + "|"]
    csv_rows = []
    for c in cases:
        st = c["stats"]
        secs = st["seconds"]
        total = sum(secs.get(s, 0.0) for s in stages)
        over = (total - secs.get("render", 0.0) - secs.get("structured_light", 0.0)) / total
        frames = list(st["frames"].values())
        lines.append(f"| {c['name']} | {c['spec']['renders']} | {len(frames)} | {st['imports']} | "
                     + " | ".join(f"{secs.get(s, 0.0):.2f}" for s in stages)
                     + f" | {total:.2f} | {over:.1%} | {min(frames)}–{max(frames)} ({c['max_frames']}) |")
        csv_rows.append({"case": c["name"], **{s: round(secs.get(s, 0.0), 4) for s in stages},
                         "imports": st["imports"], "frames": frames, "overhead": round(over, 4)})
    mem = cases[-1]["scenes"]
    lines += ["", "## Memory across consecutive scenes (last case)", "",
              "| scene | RSS MB | objects | meshes | materials | images |", "|---|---|---|---|---|---|"]
    lines += [f"| {r['scene'] + 1} | {r['rss_mb']:.0f} | {r['objects']} | {r['meshes']} | {r['materials']} | "
              f"{r['images']} |" for r in mem]
    growth = mem[-1]["rss_mb"] - mem[1]["rss_mb"] if len(mem) > 2 else 0.0
    lines += ["", f"RSS growth from scene 2 to scene {len(mem)}: {growth:+.1f} MB; peak RSS "
              f"{cases[-1]['peak_rss_mb']:.0f} MB.", "", "![memory](pipeline_memory.png)"]
    (RESULTS / "pipeline.md").write_text("\n".join(lines) + "\n")
    write_rows_csv(RESULTS / "pipeline.csv", csv_rows)
    plot_memory(mem, RESULTS / "pipeline_memory.png")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
