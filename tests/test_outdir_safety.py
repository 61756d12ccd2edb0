"""Issue #21, data safety of the output folder, on the fake world (tests/fake_world.py, no Blender):
writes never leave OUT through a symbolic link, --force and --resume touch only the run's own files
(inside scene folders too), a scene.json that is not the run's is refused, OS errors name their file
and leave no temporary, and --resume gives the bytes of an uninterrupted run (pickle included) with
whole-run statistics.

The check for "nothing else changed" is a hash tree of the user's files (inside OUT and beside it)
taken before and compared after.
"""
import errno
import json
import os
import pickle
import shutil

import numpy as np
import pytest

from fake_world import BoxWorld, Crash
from datapipe import cli
from datapipe.io import outdir
from datapipe.engine.pipeline import Pipeline
from datapipe.errors import DataPipeError
from datapipe.io import files, layout, legacy
from test_run_loop import run, small_cfg
from tree_hash import hashes

pytestmark = pytest.mark.usefixtures("remembered_model_analysis")   # box models analysed once (tests/model_memo.py)


def tmp_leftovers(root) -> list[str]:
    return [str(p) for p in root.rglob("*") if ".tmp" in p.name or p.name.startswith("_")]


@pytest.fixture(scope="module")
def one_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("one_run")
    cfg = small_cfg(tmp)
    _, events = run(cfg, tmp / "ref")
    assert events[-1].stage == "done"
    return cfg, tmp / "ref"


@pytest.fixture
def finished(one_run, tmp_path):
    """A copy of one finished run (test_run_loop's preset: 5 renders in scenes of 1-2) and its preset."""
    cfg, ref = one_run
    shutil.copytree(ref, tmp_path / "ref", symlinks=True)
    return cfg, tmp_path / "ref"


def refused(excinfo, path, code=1) -> str:
    """The refusal's message, checked as the CLI shows it: exit status, the path, a fix."""
    e = excinfo.value
    msg = str(e)
    assert str(path) in msg and "fix:" in msg, msg
    assert isinstance(e, outdir.OutputStateError) == (code == 1)
    return msg


# ------------------------------------------------------------------------------------------------
# 1. --force and --resume keep the user's files inside scene folders

def test_force_keeps_user_files_inside_scene_folders(finished, tmp_path):
    cfg, out = finished
    (out / "scene.0001" / "user_notes.txt").write_text("my notes")
    (out / "scene.0001" / "render.0001" / "mine").mkdir()
    (out / "scene.0001" / "render.0001" / "mine" / "a.txt").write_text("mine")
    (out / "top_notes.txt").write_text("top")
    user = {k: v for k, v in hashes(out).items() if "notes" in k or "mine" in k}
    reference = hashes(out, skip={"run.json", "manifest.json"})     # the manifest now lists the user's files
    _, events = run(cfg, out, force=True)
    assert events[-1].stage == "done"
    after = hashes(out, skip={"run.json", "manifest.json"})
    assert {k: after.get(k) for k in user} == user          # the user's files: kept, unchanged
    assert after == reference                                # and the run's files made again, the same bytes
    m = outdir.Manifest.load(out)
    assert not any(k in m.files for k in user)               # never the run's: a later --force keeps them
    m.remove_listed()
    assert {k: v for k, v in hashes(out).items() if not v == "dir"} == {k: v for k, v in user.items() if v != "dir"}


def test_resume_after_a_crash_keeps_a_file_added_to_the_half_made_scene(tmp_path):
    cfg = small_cfg(tmp_path)
    out = tmp_path / "OUT"
    with pytest.raises(Crash):
        run(cfg, out, world=BoxWorld.factory(crash_at=1))
    sdir = next(p for p in layout.scene_dirs(out) if not layout.scene_complete(p))
    (sdir / "notes.txt").write_text("written between the crash and --resume")
    _, events = run(cfg, out, resume=True)
    assert events[-1].stage == "done" and (sdir / "notes.txt").read_text().startswith("written")
    assert "/".join(sdir.relative_to(out).parts + ("notes.txt",)) not in outdir.Manifest.load(out).files


# ------------------------------------------------------------------------------------------------
# 2. a scene.json that is not this run's is refused, nothing changed

@pytest.mark.parametrize("text", ['{"my": "own annotations"}', "[1, 2]", "not json"])
@pytest.mark.parametrize("flag", ["resume", "force"])
def test_foreign_scene_json_is_refused(finished, text, flag):
    cfg, out = finished
    sdir = out / "scene.0002"
    (sdir / "scene.json").write_text(text)
    (sdir / "mine.txt").write_text("mine")
    before = hashes(out)
    with pytest.raises(outdir.OutputStateError) as ei:
        run(cfg, out, **{flag: True})
    msg = refused(ei, sdir / "scene.json")
    assert "not this run's scene record" in msg
    assert hashes(out) == before


def test_scene_json_of_another_seed_is_refused_on_resume(finished):
    cfg, out = finished
    p = out / "scene.0001" / "scene.json"
    scene = json.loads(p.read_text())
    scene["seed"] += 1
    p.write_text(json.dumps(scene))
    before = hashes(out)
    with pytest.raises(outdir.OutputStateError) as ei:
        run(cfg, out, resume=True)
    assert "seed" in refused(ei, p) and hashes(out) == before


def test_a_file_there_before_the_run_is_never_overwritten(tmp_path):
    """A file at a name the run writes, that manifest.json records as there before the run (foreign)."""
    cfg = small_cfg(tmp_path)
    out = tmp_path / "OUT"
    out.mkdir()
    (out / "scene.0001" / "render.0001").mkdir(parents=True)
    (out / "scene.0001" / "render.0001" / "rgb.png").write_bytes(b"my picture")
    outdir.Manifest.start(out, resume=False)                # what an earlier run found here
    (out / "run.json").write_text(json.dumps({"config_identity": layout.config_identity(cfg.to_dict())}))
    before = hashes(out)
    for flag in ("resume", "force"):
        with pytest.raises(outdir.OutputStateError) as ei:
            run(cfg, out, **{flag: True})
        assert "never overwrites" in refused(ei, out / "scene.0001" / "render.0001" / "rgb.png")
        assert hashes(out) == before


# ------------------------------------------------------------------------------------------------
# 3. no write through a symbolic link

def _victim(tmp_path):
    v = tmp_path / "victim"
    (v / "sub").mkdir(parents=True)
    (v / "obj_000001.ply").write_text("victim's model")
    (v / "sub" / "rgb.png").write_text("victim's image")
    (v / "scene.json").write_text("{}")
    return v


LINKS = {   # what is replaced by a link to the victim folder (or a file in it)
    "models": lambda out, v: ("models", v),
    "scene_folder": lambda out, v: ("scene.0001", v),
    "render_folder": lambda out, v: ("scene.0001/render.0001", v / "sub"),
    "render_file": lambda out, v: ("scene.0001/render.0001/rgb.png", v / "sub" / "rgb.png"),
    "scene_json": lambda out, v: ("scene.0001/scene.json", v / "scene.json"),
    "pickle": lambda out, v: ("output_dict.pickle", v / "obj_000001.ply"),
    "lock": lambda out, v: (outdir.LOCK_FILE, v / "obj_000001.ply"),
}


@pytest.mark.parametrize("flag", ["resume", "force"])
@pytest.mark.parametrize("case", sorted(LINKS))
def test_symlinks_where_the_run_writes_are_refused(finished, tmp_path, case, flag):
    cfg, out = finished
    victim = _victim(tmp_path)
    rel, target = LINKS[case](out, victim)
    link = out / rel
    if link.is_dir() and not link.is_symlink():
        os.rename(link, tmp_path / "moved")
    elif link.exists():
        link.unlink()
    link.symlink_to(target)
    before, victim_before = hashes(out), hashes(victim)
    with pytest.raises(outdir.OutputStateError) as ei:
        run(cfg, out, **{flag: True})
    assert "symbolic link" in refused(ei, link)
    assert hashes(out) == before and hashes(victim) == victim_before


def test_lock_file_link_is_refused_by_the_lock_itself(tmp_path):
    victim = _victim(tmp_path)
    out = tmp_path / "OUT"
    out.mkdir()
    (out / outdir.LOCK_FILE).symlink_to(victim / "obj_000001.ply")
    with pytest.raises(outdir.OutputStateError, match="symbolic link"):
        outdir.OutLock(out).acquire()
    assert (victim / "obj_000001.ply").read_text() == "victim's model"


def test_links_of_the_user_beside_the_runs_files_are_left_alone(finished, tmp_path):
    cfg, out = finished
    victim = _victim(tmp_path)
    (out / "my_link").symlink_to(victim)                                # not a name the run writes
    (out / "scene.0001" / "elsewhere").symlink_to(victim)               # nor this (in a scene folder)
    (out / "scene.0001" / "render.0001" / "mine").symlink_to(victim)    # nor this (in a render folder)
    before = hashes(victim)
    for flag in ("force", "resume", "force"):
        _, events = run(cfg, out, **{flag: True})
        assert events[-1].stage == "done" and hashes(victim) == before
        assert all(p.is_symlink() for p in (out / "my_link", out / "scene.0001" / "elsewhere",
                                               out / "scene.0001" / "render.0001" / "mine"))
    assert not any("elsewhere" in f or "mine" in f for f in outdir.Manifest.load(out).files)


# ------------------------------------------------------------------------------------------------
# 6. OS errors name their file and leave no temporary

def _full_disk_open(real_open, from_write: int = 1):
    """open() whose files, from the `from_write`-th opened for writing on, fail on write as a full
    disk does: OSError(ENOSPC) without a file name."""
    opened = []

    class Full:
        def __init__(self, f):
            self.f = f

        def write(self, data):
            self.f.write(data[: len(data) // 2])
            raise OSError(errno.ENOSPC, "No space left on device")

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

    def fake_open(path, mode="r", *a, **kw):
        f = real_open(path, mode, *a, **kw)
        if "w" not in mode:
            return f
        opened.append(path)
        return Full(f) if len(opened) >= from_write else f
    return fake_open


def test_disk_full_in_atomic_writes_names_the_file_and_removes_the_temporary(tmp_path, monkeypatch):
    monkeypatch.setattr(files, "open", _full_disk_open(open), raising=False)
    target = tmp_path / "run.json"
    with pytest.raises(OSError) as ei:
        files.write_json_atomic(target, {"a": 1})
    assert ei.value.errno == errno.ENOSPC and ei.value.filename == str(target)
    assert list(tmp_path.iterdir()) == []


def test_exr_and_png_writers_on_a_full_disk(tmp_path, monkeypatch):
    import OpenEXR
    from datapipe.io import exr

    def full_exr(self, path):
        open(path, "wb").write(b"\x76\x2f\x31\x01 partial")
        raise RuntimeError(f'Failed to write pixel data to image file "{path}". No space left on device.')
    monkeypatch.setattr(OpenEXR.File, "write", full_exr)
    with pytest.raises(OSError) as ei:
        exr.write_exr(tmp_path / "depth.exr", {"Z": np.zeros((4, 4))})
    assert ei.value.errno == errno.ENOSPC and ei.value.filename == str(tmp_path / "depth.exr")

    import cv2

    def full_png(path, img, *params):
        open(path, "wb").write(b"\x89PNG partial")
        return False
    monkeypatch.setattr(cv2, "imwrite", full_png)
    monkeypatch.setattr(files.shutil, "disk_usage", lambda p: type("U", (), {"free": 0})())
    with pytest.raises(OSError) as ei:
        files.imwrite_atomic(tmp_path / "rgb.png", np.zeros((4, 4, 3), np.uint8))
    assert ei.value.errno == errno.ENOSPC and ei.value.filename == str(tmp_path / "rgb.png")
    assert list(tmp_path.iterdir()) == []


def test_a_truncated_or_garbled_exr_is_a_file_error_naming_it(tmp_path):
    from datapipe.io import exr
    good = tmp_path / "good.exr"
    exr.write_exr(good, {"Z": np.random.default_rng(0).random((64, 64)), "Y": np.ones((64, 64))})
    data = good.read_bytes()
    for n in (len(data) // 2, len(data) - 200, 300, 0):
        bad = tmp_path / f"cut{n}.exr"
        bad.write_bytes(data[:n])
        with pytest.raises(OSError) as ei:
            exr.read_exr(bad)
        assert ei.value.errno == errno.EIO and ei.value.filename == str(bad) and "truncated" in str(ei.value)
    bad.write_bytes(b"garbage" * 100)
    with pytest.raises(OSError, match="truncated or corrupt"):
        exr.read_exr(bad)
    assert set(exr.read_exr(good)) == {"Y", "Z"}


def test_disk_full_mid_run_then_resume(finished, tmp_path, monkeypatch, capsys):
    """The run stops with the file's name (the CLI: exit 1, one line, the fix), no temporary is left,
    and --resume after space is freed ends with the bytes of an uninterrupted run."""
    cfg, ref = finished
    out = tmp_path / "full"
    monkeypatch.setattr(files, "open", _full_disk_open(open, from_write=6), raising=False)   # 2nd scene
    with pytest.raises(OSError) as ei:
        run(cfg, out)
    e = ei.value
    assert e.errno == errno.ENOSPC and os.path.dirname(e.filename).startswith(str(out))
    assert tmp_leftovers(out) == []
    assert cli._os_error(e) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and e.filename in err and "free disk space" in err and "--resume" in err
    monkeypatch.undo()
    _, events = run(cfg, out, resume=True)
    assert events[-1].stage == "done"
    assert hashes(out, skip={"run.json"}) == hashes(ref, skip={"run.json"})


# ------------------------------------------------------------------------------------------------
# 7. --resume: the bytes of an uninterrupted run, whole-run statistics

def test_resume_after_a_crash_gives_the_same_bytes_and_whole_run_stats(finished, tmp_path):
    cfg, ref = finished
    ref_stats = json.loads((ref / layout.RUN_FILE).read_text())["stats"]
    out = tmp_path / "crashed"
    with pytest.raises(Crash):
        run(cfg, out, world=BoxWorld.factory(crash_at=2))
    _, events = run(cfg, out, resume=True)
    assert events[-1].stage == "done"
    assert hashes(out, skip={"run.json"}) == hashes(ref, skip={"run.json"})      # pickle, manifest, BOP too
    stats = json.loads((out / layout.RUN_FILE).read_text())["stats"]
    assert stats["frames"] == ref_stats["frames"] and stats["physics"] == ref_stats["physics"]
    assert stats["visib_fract"] == ref_stats["visib_fract"] and stats["visib_fract"]["instances"] > 0
    assert stats["imports"] == 2 * ref_stats["imports"]          # each call read the mesh files once
    _, events = run(cfg, out, resume=True)                       # resuming a finished run changes nothing
    assert "nothing to do" in events[-1].message
    again = json.loads((out / layout.RUN_FILE).read_text())["stats"]
    assert {k: again[k] for k in ("frames", "physics", "imports", "visib_fract")} == \
        {k: stats[k] for k in ("frames", "physics", "imports", "visib_fract")}
    assert all(again["seconds"][k] >= stats["seconds"][k] for k in stats["seconds"])


def test_cancel_then_resume_counts_the_cancelled_scene_once(finished, tmp_path):
    cfg, ref = finished
    ref_stats = json.loads((ref / layout.RUN_FILE).read_text())["stats"]
    out = tmp_path / "cancelled"
    pipe = Pipeline(cfg, out, world=BoxWorld.factory())
    for ev in pipe.run():
        if ev.stage == "render":
            pipe.cancel()
    _, events = run(cfg, out, resume=True)
    assert events[-1].stage == "done"
    assert hashes(out, skip={"run.json"}) == hashes(ref, skip={"run.json"})
    stats = json.loads((out / layout.RUN_FILE).read_text())["stats"]
    assert stats["frames"] == ref_stats["frames"] and stats["physics"] == ref_stats["physics"]
    assert stats["visib_fract"] == ref_stats["visib_fract"]


def test_the_pickle_bytes_depend_on_the_data_only():
    """Two equal dicts, one with shared strings and one without, pickle to the same bytes."""
    name = "peg_000"
    shared = {"scene.0001": {"render.0001": {"objects_in_scene": [{"name": name, "filename": name}] * 2,
                                             "wrld2cam_pose": np.eye(4)}}}
    copied = pickle.loads(pickle.dumps(shared))
    copied["scene.0001"]["render.0001"]["objects_in_scene"] = [
        {"name": "peg_" + str(0).zfill(3), "filename": "".join(name)} for _ in range(2)]
    assert pickle.dumps(shared, protocol=4) != pickle.dumps(copied, protocol=4)      # the memo differs
    assert legacy.legacy_bytes(shared) == legacy.legacy_bytes(copied)
    loaded = pickle.loads(legacy.legacy_bytes(shared))
    assert loaded["scene.0001"]["render.0001"]["objects_in_scene"][1]["name"] == name


def test_a_malicious_output_pickle_is_still_refused_on_resume(finished):
    cfg, out = finished
    evil = b"cos\nsystem\n(S'echo pwned'\ntR."
    (out / layout.LEGACY_PICKLE).write_bytes(evil)
    (out / "scene.0002" / "scene.json").unlink()                # something to do
    before = hashes(out)
    with pytest.raises(outdir.OutputStateError) as ei:
        run(cfg, out, resume=True)
    assert "refusing" in refused(ei, out / layout.LEGACY_PICKLE)
    assert hashes(out) == before                                # refused before anything is written


@pytest.mark.parametrize("command,folder", [("show", "sheets"), ("bop", "bop")])
def test_show_and_bop_do_not_write_through_a_link_in_the_run_folder(finished, tmp_path, capsys, command, folder):
    cfg, out = finished
    victim = _victim(tmp_path)
    if (out / folder).exists():
        os.rename(out / folder, tmp_path / "moved")
    (out / folder).symlink_to(victim)
    before = hashes(victim)
    assert cli.main([command, str(out)]) == 1
    err = capsys.readouterr().err
    assert str(out / folder) in err and "symbolic link" in err and "Traceback" not in err
    assert hashes(victim) == before


def test_a_copy_that_fills_the_disk_names_the_file_written(tmp_path, monkeypatch):
    """shutil's sendfile copy names the source on ENOSPC; the error must name the file being written."""
    src = tmp_path / "src.ply"
    src.write_bytes(b"x" * 100)

    def full(fsrc, fdst, *a, **kw):
        fdst.write(b"x")
        err = OSError(errno.ENOSPC, "No space left on device")
        err.filename, err.filename2 = fsrc.name, fdst.name
        raise err
    monkeypatch.setattr(files.shutil, "copyfileobj", full)
    monkeypatch.setattr(files.shutil, "_fastcopy_sendfile", full, raising=False)
    monkeypatch.setattr(files.shutil, "_USE_CP_SENDFILE", False, raising=False)
    dst = tmp_path / "out" / "obj_000001.ply"
    dst.parent.mkdir()
    with pytest.raises(OSError) as ei:
        files.copy_atomic(src, dst)
    assert ei.value.filename == str(dst) and list(dst.parent.iterdir()) == []
    with pytest.raises(FileNotFoundError) as ei:
        files.copy_atomic(tmp_path / "missing.ply", dst)               # an unreadable source: its own name
    assert ei.value.filename == str(tmp_path / "missing.ply")


def test_bop_copies_models_info_last(tmp_path, monkeypatch):
    """BOP takes models_info.json for "the models are copied": a copy stopped by a full disk must not
    leave it without the models (found by a disk-full sweep: --resume then failed on a missing model)."""
    import fixtures_native as fx
    from datapipe.io import bop, models
    models.write_models(tmp_path / "models", fx.box_meshes(1))
    real, copied = models.copy_atomic, []

    def copy(src, dst):
        copied.append(os.path.basename(dst))
        return real(src, dst)

    def full(dst, data):                    # models_info.json is written from the bytes read (models.copy_models)
        raise OSError(errno.ENOSPC, "No space left on device", str(dst))
    monkeypatch.setattr(models, "copy_atomic", copy)
    monkeypatch.setattr(models, "write_bytes_atomic", full)
    w = bop.BopWriter(tmp_path / "bop")
    with pytest.raises(OSError):
        w.set_models(tmp_path / "models")
    assert copied == [models.model_filename(i) for i in sorted(fx.box_meshes(1))]      # every model first
    assert not (w.models_dir / layout.MODELS_INFO).exists()


def test_disk_full_at_the_first_record_then_resume(one_run, tmp_path, monkeypatch):
    """Full before run.json could be written: only manifest.json is there, and --resume (what the
    message tells) starts the run instead of refusing a folder "without run.json"."""
    cfg, ref = one_run
    out = tmp_path / "full"
    monkeypatch.setattr(files, "open", _full_disk_open(open, from_write=2), raising=False)
    with pytest.raises(OSError) as ei:
        run(cfg, out)
    assert ei.value.filename == str(out / layout.RUN_FILE) and outdir.meaningful_entries(out) == ["manifest.json"]
    monkeypatch.undo()
    with pytest.raises(DataPipeError, match="not empty"):
        run(cfg, out)
    _, events = run(cfg, out, resume=True)
    assert events[-1].stage == "done" and hashes(out, skip={"run.json"}) == hashes(ref, skip={"run.json"})


def test_a_distributed_run_refuses_links_before_its_shards_start(tmp_path):
    from datapipe.engine import distributed
    victim = _victim(tmp_path)
    out = tmp_path / "OUT"
    out.mkdir()
    for name in ("models", distributed.SHARDS_DIR):
        (out / name).symlink_to(victim)
        with pytest.raises(outdir.OutputStateError) as ei:
            distributed._check_out_dir(out)
        refused(ei, out / name)
        (out / name).unlink()
    distributed._check_out_dir(out)


def test_ctrl_c_while_blender_starts_is_one_line_and_130():
    """Blender's add-on registration meets a KeyboardInterrupt half-way (tracebacks, then a crash);
    the CLI leaves at once instead: nothing is written before the run takes its lock."""
    import subprocess
    import sys
    code = ("import os, signal, time\nfrom datapipe.engine import session\nwith session.leave_on_interrupt():\n"
            "    os.kill(os.getpid(), signal.SIGINT)\n    time.sleep(5)\nprint('not reached')")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60,
                       cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    assert r.returncode == 130 and r.stdout == "" and r.stderr.strip().splitlines() == [
        "datapipe: interrupted while Blender was starting; nothing was written"]
