"""Issue #33, part A, on the fake world (tests/fake_world.py, no Blender): a file is the run's only by
the record of the run's manifest, never by its name; a symbolic link made at any moment during the
run is refused at the next write through it (OutputStateError: exit 1, naming the link), never
followed; the output folder's lock is held by one process at a time.

Each case compares a hash tree (tests/tree_hash.py) of the user's files and of a victim folder
outside OUT, before and after. Every test here fails on the code before the change (checked
against main at e769423: --force deleted the four files, --resume overwrote and adopted, the links
were followed with exit 0, the lock was held twice).
"""
import os
import subprocess
import sys
from pathlib import Path

import pytest

from fake_world import BoxWorld, Crash
from datapipe.engine.pipeline import Pipeline
from datapipe.io import layout, outdir
from test_outdir_safety import _victim, finished, one_run  # noqa: F401 (fixtures)
from test_run_loop import run, small_cfg
from tree_hash import hashes

pytestmark = pytest.mark.usefixtures("remembered_model_analysis")   # box models analysed once (tests/model_memo.py)

ROOT = Path(__file__).resolve().parents[1]


def user_files(out, names: dict) -> dict:
    for rel, text in names.items():
        p = out / rel
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(text)
    return {rel: hashes(out)[rel] for rel in names}


# ------------------------------------------------------------------------------------------------
# 1. --force removes only what the run wrote, whatever the name of the rest

ISSUE_FORCE_FILES = {           # the issue's four: each at a path whose name looks like the layout's
    "sheets/my_annotations.txt": "mine",
    "bop/test_targets_bop19.json": '[{"im_id": 1, "inst_count": 1, "obj_id": 1, "scene_id": 1}]',
    "models/README_cad.txt": "units: mm",
    "scene.0001/render.0001/rgb.original.png": "the original picture",
}


def test_force_keeps_every_file_the_run_did_not_write_and_says_so(finished, tmp_path):
    cfg, out = finished
    user = user_files(out, ISSUE_FORCE_FILES)
    pipe, events = run(cfg, out, force=True)
    assert events[-1].stage == "done"
    after = hashes(out)
    assert {k: after.get(k) for k in user} == user
    said = next(e.message for e in events if e.message.startswith("--force:"))
    assert all(k in said for k in user), said                       # says what it kept
    assert not set(user) & set(outdir.Manifest.load(out).files)     # never adopted: a later --force keeps them too
    _, events = run(cfg, out, force=True)
    assert {k: hashes(out).get(k) for k in user} == user


def test_force_keeps_a_run_file_the_user_changed_and_refuses_to_overwrite_it(finished):
    """The user edited one of the run's own files: no longer what the run wrote, so --force neither
    removes nor overwrites it: refused before anything is removed."""
    cfg, out = finished
    (out / "scene.0001" / "render.0001" / "rgb.png").write_bytes(b"edited by the user")
    before = hashes(out)
    with pytest.raises(outdir.OutputStateError) as ei:
        run(cfg, out, force=True)
    assert str(out / "scene.0001" / "render.0001" / "rgb.png") in str(ei.value) and "fix:" in str(ei.value)
    assert hashes(out) == before


def test_force_removes_exactly_the_recorded_files(finished):
    cfg, out = finished
    user = user_files(out, ISSUE_FORCE_FILES)
    m = outdir.Manifest.load(out)
    removed, kept = outdir.remove_run_files(m)
    assert sorted(kept) == sorted(user) and removed > 0
    assert {k: v for k, v in hashes(out).items() if v != "dir"} == user


# ------------------------------------------------------------------------------------------------
# 2. --resume refuses a file it did not write where it would write, and never adopts one

def crashed_run(tmp_path):
    cfg = small_cfg(tmp_path)
    out = tmp_path / "OUT"
    with pytest.raises(Crash):
        run(cfg, out, world=BoxWorld.factory(crash_at=3))
    return cfg, out


def test_resume_refuses_a_users_file_where_it_would_write(tmp_path):
    cfg, out = crashed_run(tmp_path)
    todo = [p for p in (out / layout.scene_name(i) for i in range(4)) if not layout.scene_complete(p)]
    last = layout.scene_name(3)                                     # not made yet
    user = user_files(out, {f"{last}/render.0001/rgb.png": "my own picture", "models/part_source.step": "STEP"})
    assert todo
    before = hashes(out)
    with pytest.raises(outdir.OutputStateError) as ei:
        run(cfg, out, resume=True)
    msg = str(ei.value)
    assert str(out / last / "render.0001" / "rgb.png") in msg and "fix:" in msg and "never overwrites" in msg
    assert hashes(out) == before
    # the user moves the picture away: --resume finishes, keeps the rest, adopts nothing
    (out / last / "render.0001" / "rgb.png").rename(tmp_path / "rgb.png")
    _, events = run(cfg, out, resume=True)
    assert events[-1].stage == "done"
    assert hashes(out)["models/part_source.step"] == user["models/part_source.step"]
    assert "models/part_source.step" not in outdir.Manifest.load(out).files
    _, events = run(cfg, out, force=True)
    assert hashes(out)["models/part_source.step"] == user["models/part_source.step"]


def test_a_file_put_during_the_run_where_it_writes_is_refused_at_that_write(tmp_path):
    """No check before the run could see it: the write itself refuses to replace it."""
    cfg = small_cfg(tmp_path)
    out = tmp_path / "OUT"
    pipe = Pipeline(cfg, out, world=BoxWorld.factory())
    target = out / layout.scene_name(1) / "scene.json"
    with pytest.raises(outdir.OutputStateError) as ei:
        for e in pipe.run():
            if e.stage == "scene" and e.scene == 1:
                target.parent.mkdir(parents=True, exist_ok=True)
                target.write_text('{"mine": 1}')
    assert str(target) in str(ei.value) and "never overwrites" in str(ei.value)
    assert target.read_text() == '{"mine": 1}'


# ------------------------------------------------------------------------------------------------
# 3. a link made during the run is refused at that write, never followed

def plant_link(link: Path, target: Path, away: Path) -> None:
    if link.is_dir() and not link.is_symlink():
        os.rename(link, away)
    elif link.exists() or link.is_symlink():
        link.unlink()
    link.symlink_to(target)


def _two_render_scene(pipe) -> int:
    return next(i for i, n in enumerate(pipe.plan) if n >= 2)


MID_RUN = {   # where the link is made (rel to OUT) -> (when, link, target in the victim folder)
    "temporary_file": (lambda e, p: e.stage == "render", lambda p: layout.RUN_FILE + ".tmp",
                       lambda v: v / "scene.json"),
    "scene_folder": (lambda e, p: e.stage == "scene_done", lambda p: layout.scene_name(1), lambda v: v),
    "render_folder": (lambda e, p: e.stage == "render" and e.scene == _two_render_scene(p) and e.render == 0,
                      lambda p: f"{layout.scene_name(_two_render_scene(p))}/render.0002", lambda v: v / "sub"),
    "models": (lambda e, p: e.stage == "setup", lambda p: layout.MODELS_DIR, lambda v: v),
    "made_scene_folder": (lambda e, p: e.stage == "render" and e.scene == _two_render_scene(p) and e.render == 0,
                          lambda p: layout.scene_name(_two_render_scene(p)), lambda v: v),
}


@pytest.mark.parametrize("case", sorted(MID_RUN))
def test_a_link_made_during_the_run_is_refused_and_never_followed(tmp_path, case):
    when, link_of, target_of = MID_RUN[case]
    cfg = small_cfg(tmp_path)
    out = tmp_path / "OUT"
    victim = _victim(tmp_path)
    victim_before = hashes(victim)
    pipe = Pipeline(cfg, out, world=BoxWorld.factory())
    link = None
    with pytest.raises(outdir.OutputStateError) as ei:
        for e in pipe.run():
            if link is None and when(e, pipe):
                link = out / link_of(pipe)
                plant_link(link, target_of(victim), tmp_path / "moved_away")
    msg = str(ei.value)
    assert link is not None and str(link) in msg and "symbolic link" in msg and "fix:" in msg
    assert hashes(victim) == victim_before


# ------------------------------------------------------------------------------------------------
# 4. one lock: processes hammering acquire/release never hold it together

def test_the_lock_is_never_held_twice(tmp_path):
    """A small version of benchmarks/lock_stress.py (>= 10,000 acquisitions there): 3 processes,
    3,000 acquisitions in all. Before the change (release unlinked the file, acquire did not check
    what it locked) it overlapped 84 times in ~16,000."""
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "lock_stress.py"), "--procs", "3",
                        "--acquisitions", "3000", "--out", str(tmp_path / "OUT")],
                       capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(ROOT)}, timeout=120)
    assert r.returncode == 0, r.stderr
    line = r.stdout.strip().splitlines()[-1]
    assert line.startswith("acquisitions 3") and line.endswith("double holders 0"), line


def test_a_folder_made_by_a_run_killed_at_once_is_still_the_runs(tmp_path):
    """A kill between making a folder and recording it would leave a folder of the run's that no
    record names: the resumed run finds it there, never records it, so its manifest differs from an
    uninterrupted run's and --force leaves the folder behind (seen once in the killed-run test under
    load). The guard records a folder before it makes it, as it records a file before its rename."""
    from datapipe.io.guard import OutGuard

    class Kill(BaseException):
        pass

    class Ledger:
        def __init__(self, die):
            self.dirs, self.die = [], die

        def record_dir(self, rel):
            if self.die:
                raise Kill          # the process dies before this record reaches the journal
            self.dirs.append(rel)

    out = tmp_path / "out"
    out.mkdir()
    first = Ledger(die=True)
    with pytest.raises(Kill):
        OutGuard(out, first).make_dirs(out / "scene.0001")
    resumed = Ledger(die=False)
    OutGuard(out, resumed).make_dirs(out / "scene.0001" / "render.0001")
    assert resumed.dirs == ["scene.0001", "scene.0001/render.0001"]   # both made, and recorded, by the resumed call
    assert (out / "scene.0001" / "render.0001").is_dir()
