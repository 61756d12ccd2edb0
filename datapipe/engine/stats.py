"""run.json's `stats`: what a run's scenes record (frames, physics, visible fractions) and what its
processes measured (imports, seconds per stage, wall/CPU/count per step), added up the same way
for one process over --resume calls (engine/pipeline.py) and for shards merged into one run
(engine/distributed.py). No bpy."""
from __future__ import annotations

from ..checks.physics_check import add_to_totals
from ..visibility import VisibStats

STEP_FIELDS = ("wall_s", "cpu_s", "n")


def number(v) -> float:
    """A recorded figure, or 0 where a record (an older or damaged run.json) has none."""
    return v if isinstance(v, (int, float)) and not isinstance(v, bool) else 0


def scene_stats(scenes) -> dict:
    """`frames`, `physics` and `visib_fract` of scene records (scene.json), each scene counted once:
    pass them in scene order."""
    scenes = list(scenes)
    sims = {sc["name"]: sc["simulation"] for sc in scenes if isinstance(sc.get("simulation"), dict)}
    physics: dict = {}
    for name in sorted(sims):
        add_to_totals(physics, sims[name])
    return {"frames": {n: sims[n].get("frames") for n in sorted(sims)}, "physics": physics,
            "visib_fract": VisibStats.of_scenes(scenes).summary()}


def add_measured(total: dict, stats) -> dict:
    """Adds one record's measured figures (`imports`, `seconds`, `steps`; anything missing counts 0)
    into `total`, in place; returns it."""
    stats = stats if isinstance(stats, dict) else {}
    total["imports"] = int(total.get("imports", 0) + number(stats.get("imports")))
    seconds = total.setdefault("seconds", {})
    for k, v in (stats.get("seconds") if isinstance(stats.get("seconds"), dict) else {}).items():
        seconds[k] = float(seconds.get(k, 0.0) + number(v))
    steps = total.setdefault("steps", {})
    for k, v in (stats.get("steps") if isinstance(stats.get("steps"), dict) else {}).items():
        if isinstance(v, dict):
            tot = steps.setdefault(k, {"wall_s": 0.0, "cpu_s": 0.0, "n": 0})
            for f in STEP_FIELDS:
                tot[f] += number(v.get(f))
    return total


def rounded(measured: dict) -> dict:
    """The measured figures as run.json writes them (steps to 0.1 ms, counts as integers)."""
    return {**measured, "steps": {k: {"wall_s": round(float(v["wall_s"]), 4), "cpu_s": round(float(v["cpu_s"]), 4),
                                      "n": int(v["n"])} for k, v in measured.get("steps", {}).items()}}
