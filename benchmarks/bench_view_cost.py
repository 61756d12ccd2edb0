"""Where a view's CPU goes: each Cycles call of a run split into Cycles' own phases (issue #29).

Runs the Pipeline in this process on a copy of `datapipe/presets/bin_picking.json` (one scene of
`--views` views, optionally at the device's `--binning`, `render.persistent_data` from
`--persistent-data`) and listens to `bpy.app.handlers.render_stats`: every status line Cycles
prints ("Synchronizing object | ...", "Updating Geometry BVH ... | Building BVH", "Sample 3/16",
"Denoising", "Compositing") starts a phase, and the process CPU seconds (`time.process_time`: all
threads) until the next line are that phase's. Phases: sync (scene export to Cycles: objects,
meshes, shaders, images, lights, kernels), bvh (building the BVHs), path tracing (the samples),
denoise, output (compositing and the File Output's EXR). Per view it prints the native render's and
the fringe call's phases, and run.json's steps (decode, writing, annotations).

    python benchmarks/bench_view_cost.py --views 3 [--persistent-data] [--binning 4] [--no-denoise] [--json out.json]
        [--samples 16 --sampling-pattern SCENE]   (the settings before the view study, for an A/B)
"""
from __future__ import annotations

import argparse
import contextlib
import json
import resource
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import bpy  # noqa: E402

from datapipe.config import loads, presets_dir  # noqa: E402
from datapipe.engine.progress import Tracker  # noqa: E402
from datapipe.engine.pipeline import Pipeline  # noqa: E402
from harness import preset_dict  # noqa: E402

PHASES = ("sync", "bvh", "path tracing", "denoise", "output")


def phase_of(text: str) -> str:
    if "BVH" in text:
        return "bvh"
    if "Sample " in text or "Rendered " in text:
        return "path tracing"
    if "Denois" in text and "kernels" not in text:
        return "denoise"
    if "Compositing" in text or "Finished" in text:
        return "output"
    return "sync"


class CallLog:
    """CPU seconds per (view, call kind, phase), from the status lines of each Cycles call."""

    def __init__(self):
        self.cpu = defaultdict(float)          # (view, kind, phase) -> CPU s
        self.view = 0
        self._cur = None                       # (kind, phase, t0)

    def on_stats(self, *args):
        text = next((a for a in args if isinstance(a, str)), "")
        now = time.process_time()
        kind, phase, t0 = self._cur
        self.cpu[(self.view, kind, phase)] += now - t0
        self._cur = (kind, phase_of(text), now)

    @contextlib.contextmanager
    def call(self, tracker: Tracker, step: str, what: str):
        if step == "render":
            self.view += 1
        self._cur = (step, "sync", time.process_time())
        bpy.app.handlers.render_stats.append(self.on_stats)
        try:
            with ORIGINAL_CYCLES(tracker, step, what):
                yield
        finally:
            bpy.app.handlers.render_stats.remove(self.on_stats)
            kind, phase, t0 = self._cur
            self.cpu[(self.view, kind, phase)] += time.process_time() - t0


ORIGINAL_CYCLES = Tracker.cycles      # the run's tracker wraps every Cycles call: timed here by phase


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one view at the device's 4x4 binning (612 x 512): a check "
                    "that the script runs, not a measurement")
    ap.add_argument("--views", type=int, default=3)
    ap.add_argument("--binning", type=int, default=None)
    ap.add_argument("--persistent-data", action="store_true")
    ap.add_argument("--no-denoise", action="store_true", help="the native render without OpenImageDenoise "
                    "(to measure the denoiser's share; not the preset's output)")
    ap.add_argument("--samples", type=int, default=None, help="the native render's samples instead of the preset's")
    ap.add_argument("--sampling-pattern", default=None, help="render.sampling_pattern instead of the preset's "
                    "(SCENE: the settings before issue #29's view study, with --samples 16)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", type=Path, default=None, help="also write the numbers here")
    a = ap.parse_args(argv)
    if a.quick:
        a.views, a.binning = 1, 4 if a.binning is None else a.binning
    pre = presets_dir() / "bin_picking.json"
    d = preset_dict(pre)
    if a.binning is not None:
        d["binning"] = a.binning
    s = d["scene"]
    s["num_renders"] = s["min_renders_per_scene"] = s["max_renders_per_scene"] = a.views
    s["seed"] = a.seed
    d["render"]["persistent_data"] = a.persistent_data
    if a.no_denoise:
        d["render"]["denoise"] = False
    if a.samples is not None:
        d["render"]["samples"] = a.samples
    if a.sampling_pattern is not None:
        d["render"]["sampling_pattern"] = a.sampling_pattern
    d["output"]["overview"] = False
    cfg = loads(json.dumps(d))
    log = CallLog()
    Tracker.cycles = lambda tracker, step, what: log.call(tracker, step, what)
    with tempfile.TemporaryDirectory() as tmp:
        c0, t0 = time.process_time(), time.perf_counter()
        for _ in Pipeline(cfg, Path(tmp) / "run").run():
            pass
        cpu, wall = time.process_time() - c0, time.perf_counter() - t0
        run = json.loads((Path(tmp) / "run" / "run.json").read_text())
    steps = {k: round(v["cpu_s"], 2) for k, v in run["stats"]["steps"].items()}
    res = cfg.camera.resolution
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20        # KiB on Linux -> GiB
    print(f"bin_picking.json, {res[0]} x {res[1]}, {a.views} views, persistent data {a.persistent_data}, "
          f"denoise {cfg.render.denoise}, {cfg.render.samples} samples, pattern {cfg.render.sampling_pattern}: "
          f"{cpu:.1f} CPU s, {wall:.0f} s wall, peak RSS {rss:.2f} GiB; run.json steps (CPU s): {steps}\n")
    print("| view | call | " + " | ".join(PHASES) + " | call CPU s |")
    print("|---|---|" + "---|" * (len(PHASES) + 1))
    rows = []
    for v in range(1, log.view + 1):
        for kind in ("render", "fringes"):
            vals = [log.cpu.get((v, kind, p), 0.0) for p in PHASES]
            if sum(vals) == 0:
                continue
            rows.append({"view": v, "call": kind, **dict(zip(PHASES, vals))})
            print(f"| {v} | {kind} | " + " | ".join(f"{x:.1f}" for x in vals) + f" | {sum(vals):.1f} |")
    if a.json:
        a.json.write_text(json.dumps({"views": a.views, "persistent_data": a.persistent_data, "resolution": res,
                                      "denoise": cfg.render.denoise,
                                      "samples": cfg.render.samples, "sampling_pattern": cfg.render.sampling_pattern,
                                      "cpu_s": cpu, "wall_s": wall, "peak_rss_gib": rss, "steps": steps, "calls": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
