"""Generated file-system changes made in the output folder while a run writes (issue #33): the run
must never write outside OUT, never change a file it did not write, and stop, if it stops, with
DataPipe's own OutputStateError naming the path (CLI exit 1) — never a traceback, never a hang.

    .venv/bin/python benchmarks/fuzz_outdir.py [--n 20] [--seed 33] [--verbose] [--trial K]

`--verbose` prints each trial's mode, the event its changes came at and the changes; `--trial K`
replays the trials up to K (they draw the random numbers K starts from), prints K's and keeps its folder.

Each trial runs the run loop on the fake world of the tests (tests/fake_world.py: numpy boxes, no
Blender; 5 renders of 64 x 48 in 4 scenes, native + BOP) as a fresh run, a `--resume` after a
crash, or a `--force` over a finished run, and at a random event (before the models, between
renders, between scenes) makes 1-3 changes: a symbolic link to a victim folder (or a file in it)
outside OUT at a path the run writes or will write (a temporary file, a scene or render folder,
`models/`, `bop/`, a render map, `scene.json`), a run folder renamed away and replaced by such a
link, or a file of the user's at a layout name (exact, or one that only looks like the layout's).
Checked after every trial: the victim's hash tree (tests/tree_hash.py) is unchanged, each user file
is unchanged, and the run ended "done", with OutputStateError naming a changed path and a fix, or
with an OSError naming its file (both exit 1 in the CLI); each trial has 60 s. On main before
issue #33 (e769423), the default run had 4 trials of 20 with the victim changed and 7 errors
raised through a link (e.g. IsADirectoryError writing manifest.json through a link at its
temporary name). Writes benchmarks/results/fuzz_outdir.md.
"""
from __future__ import annotations

import collections
import hashlib
import os
import random
import shutil
import signal
import sys
import tempfile
import traceback
from pathlib import Path

from harness import RESULTS, ROOT, Stopwatch, parser, write_with_notes

sys.path.insert(0, str(ROOT / "tests"))     # the fake world and its fixtures
sys.path.append(str(ROOT))                  # PYTHONPATH first: another checkout can be measured

from fake_world import BoxWorld, Crash  # noqa: E402
from tree_hash import hashes  # noqa: E402
from test_run_loop import small_cfg  # noqa: E402
from datapipe.engine.pipeline import Pipeline  # noqa: E402
from datapipe.errors import OutputStateError  # noqa: E402
from datapipe.io import layout  # noqa: E402

# where a change may be made (relative to OUT); {s} a scene folder, {r} a render folder
TARGETS = ["run.json.tmp", "manifest.json.tmp", "output_dict.pickle.tmp", "models", "models/models_info.json.tmp",
           "models/obj_000001.ply", "bop", "bop/train_pbr", "sheets", "{s}", "{s}/scene.json", "{s}/scene.json.tmp",
           "{s}/{r}", "{s}/{r}/rgb.png", "{s}/{r}/rgb.tmp.png", "{s}/{r}/depth.exr", "{s}/{r}/depth.exr.tmp.exr",
           "{s}/{r}/mask.exr"]
USER_NAMES = ["{s}/{r}/rgb.png", "{s}/{r}/rgb.original.png", "{s}/scene.json.bak", "{s}/notes.txt",
              "models/README_cad.txt", "models/obj_000009.ply", "bop/test_targets_bop19.json", "sheets/mine.txt",
              "run.json.tmp", "{s}/{r}/depth.exr"]


class Hang(Exception):
    pass


def _victim(root: Path) -> Path:
    v = root / "victim"
    (v / "sub").mkdir(parents=True)
    (v / "precious.txt").write_text("the victim's file")
    (v / "sub" / "rgb.png").write_text("the victim's image")
    return v


def _fill(rng: random.Random, pattern: str) -> str:
    return pattern.format(s=layout.scene_name(rng.randrange(4)), r=layout.render_name(rng.randrange(2)))


def change(rng: random.Random, out: Path, victim: Path, work: Path, user: dict, planted: list,
           log: list) -> None:
    """One random change in OUT (see the module doc); user files are remembered in `user` with
    their hash, planted paths in `planted`."""
    kind = rng.choice(["link", "link", "replace_with_link", "user_file"])
    if kind == "user_file":
        rel = _fill(rng, rng.choice(USER_NAMES))
        p = out / rel
        if p.exists() or p.is_symlink() or not _makeable(out, p.parent):
            return
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(f"the user's {rel}")
        user[rel] = hashlib.sha256(p.read_bytes()).hexdigest()     # as tests/tree_hash.py hashes it
        planted.append(str(p))
        log.append(f"user file {rel}")
        return
    rel = _fill(rng, rng.choice(TARGETS))
    p = out / rel
    if not _makeable(out, p.parent):
        return
    target = rng.choice([victim, victim / "sub", victim / "precious.txt", victim / "gone"])
    if p.is_symlink():
        return
    if p.exists():
        if kind != "replace_with_link":
            return
        os.rename(p, work / f"moved_{len(planted)}")
    p.parent.mkdir(parents=True, exist_ok=True)
    p.symlink_to(target)
    planted.append(str(p))
    log.append(f"{kind} {rel} -> {target.relative_to(work)}")


def _makeable(out: Path, folder: Path) -> bool:
    """No link on the way from OUT to `folder` (the fuzzer itself must not write through one)."""
    p = folder
    while p != out:
        if p.is_symlink():
            return False
        p = p.parent
    return True


def trial(rng: random.Random, work: Path, story: list | None = None) -> tuple[str, str]:
    """One run with changes; returns (outcome, detail). `story` (when given) receives what was done:
    the mode, the event the changes came at and each change."""
    cfg = small_cfg(work)
    out = work / "OUT"
    victim = _victim(work)
    mode = rng.choice(["fresh", "resume", "force"])
    if mode == "resume":
        try:
            list(Pipeline(cfg, out, world=BoxWorld.factory(crash_at=rng.randrange(1, 5))).run())
        except Crash:
            pass
    elif mode == "force":
        list(Pipeline(cfg, out, world=BoxWorld.factory()).run())
    user, planted, log = {}, [], []
    if story is not None:
        story.append(f"mode {mode}")
    victim_before = hashes(victim)
    at = rng.randrange(0, 12)
    n_changes = rng.randint(1, 3)
    pipe = Pipeline(cfg, out, world=BoxWorld.factory(), resume=mode == "resume", force=mode == "force")
    outcome, detail = "done", ""
    try:
        for k, ev in enumerate(pipe.run()):
            if k == at:
                for _ in range(n_changes):
                    change(rng, out, victim, work, user, planted, log)
                if story is not None:
                    story += [f"at event {k} ({ev.stage}, scene {ev.scene}, render {ev.render}):", *log]
    except OutputStateError as e:
        named = any(p in str(e) for p in planted) and "fix:" in str(e)
        outcome, detail = ("refused, naming the path", "") if named else ("refused without a path", str(e)[:160])
    except Hang:
        raise
    except OSError as e:                 # the CLI: exit 1 with the file's name (cli._os_error)
        outcome, detail = ("OS error naming the file", "") if e.filename else ("OS error without a file", str(e))
    except Exception as e:  # noqa: BLE001 - the point: anything else is a defect
        frame = traceback.extract_tb(e.__traceback__)[-1]
        outcome, detail = "traceback", f"{type(e).__name__} at {Path(frame.filename).name}:{frame.lineno}: {e}"[:200]
    if hashes(victim) != victim_before:
        return "data loss (victim changed)", f"{mode}, changes {planted}"
    now = hashes(out, ())
    for rel, h in user.items():
        if now.get(rel) != h:
            return "data loss (user file changed)", f"{mode}, {rel}"
    return outcome, detail if outcome != "done" else ""


def main() -> None:
    ap = parser(__doc__, quick="--n 3")
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--seed", type=int, default=33)
    ap.add_argument("--out", default=None, help="the report (default benchmarks/results/fuzz_outdir.md)")
    ap.add_argument("--trial", type=int, default=None,
                    help="stop after trial K (the trials before it run too: they draw the random numbers it "
                         "starts from), print what it did and keep its folder; no report is written")
    ap.add_argument("--verbose", action="store_true", help="print each trial's mode, event and changes")
    args = ap.parse_args()
    if args.quick:
        args.n = 3
    args.out = args.out or str(RESULTS / "fuzz_outdir.md")
    rng = random.Random(args.seed)
    counts, bad = collections.Counter(), []

    def on_alarm(*_):
        raise Hang()
    signal.signal(signal.SIGALRM, on_alarm)
    clock = Stopwatch().start()
    for i in range(args.n if args.trial is None else args.trial + 1):
        work = Path(tempfile.mkdtemp(prefix=f"fuzz_outdir_{i}_"))
        story: list[str] = []
        signal.alarm(60)
        try:
            outcome, detail = trial(rng, work, story)
        except Hang:
            outcome, detail = "hang (> 60 s)", ""
        finally:
            signal.alarm(0)
        counts[outcome] += 1
        if outcome not in ("done", "refused, naming the path", "OS error naming the file"):
            bad.append(f"trial {i}: {outcome}: {detail}")
        if args.verbose or i == args.trial:
            print(f"trial {i}: {outcome}{': ' + detail if detail else ''}", *story, sep="\n  ", flush=True)
        if i == args.trial:
            print(f"its folder: {work}")
            return
        shutil.rmtree(work, ignore_errors=True)
    wall = clock.stop().wall_s
    lines = ["# Mid-run file-system changes in the output folder", "",
             f"`benchmarks/fuzz_outdir.py --n {args.n} --seed {args.seed}`: the fake world's run loop (no Blender) "
             "with 1-3 random changes at a random event (see the script's docstring); "
             f"{wall:.0f} s wall on the project's shared 2-core machine.", "",
             "| outcome | trials |", "|---|---:|",
             *[f"| {k} | {v} |" for k, v in sorted(counts.items())], "",
             f"Data loss (the victim outside OUT or a user's file changed), tracebacks, hangs: "
             f"**{sum(v for k, v in counts.items() if k.startswith(('data loss', 'traceback', 'hang')))}**.",
             *(["", *[f"- {b}" for b in bad[:30]]] if bad else [])]
    write_with_notes(Path(args.out), lines)          # the hand-written fuzz_outdir_notes.md appended
    print("\n".join(lines))


if __name__ == "__main__":
    main()
