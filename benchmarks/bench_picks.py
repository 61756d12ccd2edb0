"""A pick sequence of 10 steps from 80 parts (issue #29's acceptance line), through the CLI:

    PYTHONPATH=$PWD .venv/bin/python benchmarks/bench_picks.py [--resume-check]

The demo's parts (peg, nut, bracket: 27 + 27 + 26) in the default bin, `scene.picks` = 7 per step
from the top until 10 remain: 80, 73, ..., 10 (11 scenes, one render each at 64 x 48, 1 sample, no
structured light: what is measured is the drop and the settles). Per step: parts, parts lost, the
independent check's interpenetrating pairs (checks/physics_check.py: deeper than its tolerance),
below the floor, floating, frames, and whether a removed part is in a later step's ground truth.
`--resume-check` also runs it again, killed (SIGKILL) at the first progress line of scene.0005
that names its parts (mid-sequence: the pile and its first steps written, scene.0005 in progress),
resumes with --resume and compares every file byte for byte with the uninterrupted run.

Writes benchmarks/results/picks.md.
"""
from __future__ import annotations

import json
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

from harness import RESULTS, on_path, parser, run_child

on_path("tests")
from cli_runs import kill_at_scene, small_config  # noqa: E402
from datapipe import config as C  # noqa: E402


def preset(quick: bool = False) -> C.Config:
    """80 demo parts, 7 picked per step from the top until 10 remain (11 scenes); quick: 20 parts,
    5 per step until 10 remain (3 scenes)."""
    cfg = small_config(3 if quick else 11, (64, 48))
    cfg.output.overview = False
    for o, n in zip(cfg.objects, (7, 7, 6) if quick else (27, 27, 26)):
        o.min_instances = o.max_instances = n
    cfg.scene.picks = C.PicksConfig(per_step=5 if quick else 7, order="top", until=10)
    return cfg


def files(d: Path) -> dict:
    return {f.relative_to(d): f.read_bytes() for f in d.rglob("*")
            if f.is_file() and f.name not in ("run.json", "overview.png") and f.suffix != ".log"}


def main(argv=None) -> None:
    ap = parser(__doc__, quick="20 parts, 5 per step: 3 scenes (about a minute), printed only")
    ap.add_argument("--resume-check", action="store_true")
    args = ap.parse_args(argv)
    tmp = Path(tempfile.mkdtemp(prefix="bench_picks_"))
    C.save(preset(args.quick), tmp / "p.json")
    cmd = [sys.executable, "-m", "datapipe", "run", str(tmp / "p.json")]
    full = tmp / "full"
    child = run_child(cmd + ["--out", str(full), "--quiet"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    if child.returncode:
        raise RuntimeError(f"datapipe run failed (exit {child.returncode})")
    wall, cpu = child.wall_s, child.cpu_s
    docs = [json.loads(p.read_text()) for p in sorted(full.glob("scene.*/scene.json"))]
    steps = json.loads((full / "run.json").read_text())["stats"]["steps"]
    rows, removed, leaks = [], set(), 0
    for d in docs:
        s = d["simulation"]
        removed |= set(d["picks"]["removed"])
        seen = {o["name"] for o in d["objects"]} | {o["name"] for r in d["renders"] for o in r["objects"]}
        leaks += len(removed & seen)
        rows.append((d["name"], d["picks"]["step"], len(d["picks"]["removed"]), len(d["objects"]), len(s["removed"]),
                     len(s["interpenetrating_pairs"]), s["max_interpenetration_mm"], len(s["below_floor"]),
                     len(s["floating"]), s["frames"], s["settled"]))
    lines = ["# Pick sequence: 10 steps from 80 parts (`benchmarks/bench_picks.py`)", "",
             "Demo parts (27 pegs, 27 nuts, 26 brackets) in the default bin, `scene.picks` 7 per step from the top "
             "until 10 remain; one 64 x 48 render per step, 1 sample, no structured light. Checks by "
             "`checks/physics_check.py` on the model meshes at the settled poses.", "",
             "| scene | step | removed | parts | lost | interpenetrating pairs | max depth mm | below floor | "
             "floating | frames | settled |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    lines += ["| " + " | ".join(str(v) for v in r) + " |" for r in rows]
    sim = steps.get("simulation", {})
    lines += ["", f"Removed parts found in a later step's ground truth: {leaks}.",
              f"Whole run (one process, CLI): {wall:.0f} s wall, {cpu:.0f} s CPU; simulation (the drop and the "
              f"{sim.get('n', 0) - 1} settles after picks): {sim.get('wall_s', float('nan')):.0f} s wall, "
              f"{sim.get('cpu_s', float('nan')):.0f} s CPU (run.json stats.steps.simulation; the machine's 2 cores "
              "are shared, so wall > CPU).", ""]
    if args.resume_check:
        part = tmp / "part"
        killed = kill_at_scene(cmd + ["--out", str(part)], "scene.0002" if args.quick else "scene.0005",
                               600) == -signal.SIGKILL
        done = sorted(p.parent.name for p in part.glob("scene.*/scene.json"))
        r = subprocess.run(cmd + ["--out", str(part), "--resume"], capture_output=True, text=True)
        same = r.returncode == 0 and files(full) == files(part)
        lines += [f"Killed (SIGKILL) at scene.0005's first progress line naming its parts (killed: {killed}; "
                  f"scene.json files then: {len(done)}), resumed with --resume: exit {r.returncode}, every file byte for byte the "
                  f"same as the uninterrupted run's (run.json and logs aside): {same}.", ""]
    text = "\n".join(lines)
    print(text)
    if args.quick:              # a smoke run of 20 parts: printed (above the table: not the 80)
        print("(--quick: 20 parts, 5 per step until 10 remain; results/picks.md not written)")
        return
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "picks.md").write_text(text)


if __name__ == "__main__":
    main(sys.argv[1:])
