"""Issue #12: the CLI never loses a user's data, fails before any work, and refuses useless presets.

In-process `cli.main` calls (the preflight imports the meshes with bpy, so these live here); one
message with the field path or file path and the fix, never a traceback, and nothing written or
removed when a check fails. Numbers in test names refer to the issue's defect list.
"""
import errno
import json
import math
import pickle

import pytest

from datapipe import cli, config as C
from datapipe.io import outdir
from datapipe.io import layout
from datapipe.io.files import write_bytes_atomic, write_json_atomic
from datapipe.draws.seeds import scene_seed


def main(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, out, err


def tree(d):
    return sorted(str(p.relative_to(d)) for p in d.rglob("*"))


def save(cfg, path):
    C.save(cfg, path)
    return path


def fake_earlier_run(out, cfg):
    """What a finished run leaves (run.json, scene folder, pickle), listed in its manifest."""
    out.mkdir()
    m = outdir.Manifest.start(out, resume=False)
    with m.writing():                     # written as a run writes: through the folder, recorded
        write_json_atomic(out / "run.json", {"config_identity": layout.config_identity(cfg.to_dict()),
                                                    "status": "complete", "scenes_done": []})
        write_bytes_atomic(out / "scene.0001" / "render.0001" / "rgb.png", b"png")
        write_json_atomic(out / "scene.0001" / "scene.json", {      # a scene killed before it was complete
            "scene_id": 0, "name": "scene.0001", "seed": scene_seed(cfg.scene.seed, 0), "renders": [],
            "complete": False})
        write_bytes_atomic(out / "output_dict.pickle", pickle.dumps({}))
        m.update()
    m.close()


def test_1_force_never_removes_a_foreign_folder(tmp_path, capsys):
    x = tmp_path / "x"
    x.mkdir()
    (x / "run.json").write_text("{}")
    (x / "thesis.txt").write_text("keep")
    code, _, err = main(capsys, "run", C.presets_dir() / "default.json", "--out", x, "--force")
    assert code == 2 and "refusing to empty" in err and "manifest" in err
    assert tree(x) == ["run.json", "thesis.txt"] and (x / "thesis.txt").read_text() == "keep"


def test_1_force_removes_exactly_the_manifest(tmp_path):
    out = tmp_path / "o"
    (tmp_path / "o").mkdir()
    (out / "notes.txt").write_text("mine, before the run")
    (out / "scene.0001").mkdir()                # foreign before the run started: stays foreign
    m = outdir.Manifest.start(out, resume=False)
    with m.writing():                           # written as a run writes: through the folder, recorded
        write_json_atomic(out / "run.json", {"status": "complete"})
        write_bytes_atomic(out / "scene.0002" / "render.0001" / "rgb.png", b"x")
        m.update()
    m.close()
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "victim.txt").write_text("never")
    (out / "models").symlink_to(outside)        # a link the run's layout name points outside OUT
    outdir.Manifest.load(out).update()
    (out / "scene.0002" / "later.txt").write_text("added by the user after the run")
    m = outdir.check_force(out)
    assert "notes.txt" not in m.files and "scene.0001" not in m.files
    m.remove_listed()
    # the link at `models` is the user's, not the run's (issue #33: by record, not by name): kept, not followed
    assert tree(out) == ["models", "notes.txt", "scene.0001", "scene.0002", "scene.0002/later.txt"]
    assert (out / "models").is_symlink() and (outside / "victim.txt").read_text() == "never"


def test_2_force_with_a_broken_mesh_removes_nothing(tmp_path, capsys):
    cfg = C.default_config()
    out = tmp_path / "o"
    fake_earlier_run(out, cfg)
    before = tree(out)
    bad = tmp_path / "garbage.obj"
    bad.write_text("this is not an OBJ\n\x00\x01")
    cfg.objects[0].filepath = str(bad)
    code, _, err = main(capsys, "run", save(cfg, tmp_path / "p.json"), "--out", out, "--force")
    assert code == 2 and "objects[0].filepath" in err and "fix:" in err
    assert tree(out) == before


@pytest.mark.parametrize("lo,hi,n,fragment", [(0, 0, 4, "scene.min_renders_per_scene"),
                                              (3, 2, 4, "scene.min_renders_per_scene"),
                                              (1, 1, 10**9, "scene.num_renders")])
def test_3_plan_bounds_checked_before_the_plan_is_drawn(tmp_path, capsys, lo, hi, n, fragment):
    cfg = C.default_config()
    cfg.scene.min_renders_per_scene, cfg.scene.max_renders_per_scene, cfg.scene.num_renders = lo, hi, n
    p = save(cfg, tmp_path / "p.json")
    for cmd in (["validate", p], ["run", p, "--out", tmp_path / "o"]):
        code, _, err = main(capsys, *cmd)
        assert code == 2 and fragment in err
    assert not (tmp_path / "o").exists()


def _obj(path, text):
    path.write_text(text)
    return str(path)


CASES_5_6 = {   # defects 5 and 6: validate said OK, the run failed or made a useless dataset
    "mesh_no_faces": (lambda c, t: setattr(c.objects[0], "filepath", _obj(t / "v.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\n")),
                      "objects[0].filepath", "0 faces"),
    "mesh_empty": (lambda c, t: setattr(c.objects[0], "filepath", _obj(t / "e.obj", "")), "objects[0].filepath", ""),
    "scale_1e6": (lambda c, t: setattr(c.objects[0], "scale", 1e6), "objects[0].scale", "drop zone"),
    "scale_tiny": (lambda c, t: setattr(c.objects[0], "scale", 2e-6), "objects[0].scale", "px on the camera"),
    "outputs_empty": (lambda c, t: setattr(c.render, "outputs", []), "render.outputs", "no outputs"),
    "light_inf": (lambda c, t: setattr(c.render, "light_power", math.inf), "render.light_power", "finite"),
    "proj_rot_nan": (lambda c, t: (setattr(c.structured_light, "enabled", True),
                                   setattr(c.projector, "rotation", [0, math.nan, 0])), "projector.rotation", "NaN"),
    "steps_1e5": (lambda c, t: (setattr(c.structured_light, "enabled", True),
                                setattr(c.structured_light, "steps", 100000)), "structured_light.steps", "more than"),
    "periods_64px": (lambda c, t: (setattr(c.structured_light, "enabled", True),
                                   setattr(c.structured_light, "periods", [1, 300]),
                                   setattr(c.camera, "resolution", [64, 48])), "structured_light.periods", "camera px"),
    "focal_1e-9": (lambda c, t: setattr(c.camera, "focal_length", 1e-9), "camera.focal_length", "deg across"),
}


@pytest.mark.parametrize("case", sorted(CASES_5_6))
def test_5_6_validate_and_run_refuse_the_same_presets(tmp_path, capsys, case):
    mutate, path, fragment = CASES_5_6[case]
    cfg = C.default_config()
    mutate(cfg, tmp_path)
    p = save(cfg, tmp_path / "p.json")              # NaN/Infinity: Python's JSON literals
    code, _, err = main(capsys, "validate", p)
    assert code == 2 and path in err and fragment.replace("camera px", "camera pixels") in err, err
    code, _, err2 = main(capsys, "run", p, "--out", tmp_path / "o")
    assert code == 2 and path in err2
    assert not (tmp_path / "o").exists()


def test_8_corrupt_state_and_os_errors_are_one_message(tmp_path, capsys, monkeypatch):
    cfg = C.default_config()
    p = save(cfg, tmp_path / "p.json")
    out = tmp_path / "o"
    fake_earlier_run(out, cfg)
    (out / "run.json").write_text('{"status": "runn')                        # torn by hand
    code, _, err = main(capsys, "run", p, "--out", out, "--resume")
    assert code == 1 and str(out / "run.json") in err and "corrupt" in err and "fix:" in err
    # a file where a folder is needed
    (tmp_path / "file").write_text("x")
    code, _, err = main(capsys, "run", p, "--out", tmp_path / "file" / "sub")
    assert code == 1 and str(tmp_path / "file") in err and "fix:" in err
    # disk full at the first write
    from datapipe.engine import pipeline

    def full(self, status):
        raise OSError(errno.ENOSPC, "No space left on device", str(self.out / "run.json"))
    monkeypatch.setattr(pipeline.Pipeline, "_write_run_file", full)
    code, _, err = main(capsys, "run", p, "--out", tmp_path / "o2")
    assert code == 1 and "No space left" in err and "free disk space" in err
    assert err.count("error:") == 1
    # show on a folder whose scene.json is not ours
    (tmp_path / "foreign" / "scene.0001").mkdir(parents=True)
    (tmp_path / "foreign" / "scene.0001" / "scene.json").write_text('{"complete": true, "renders": [{"x": 1}]}')
    code, _, err = main(capsys, "show", tmp_path / "foreign")
    assert code == 1 and "not a DataPipe scene.json" in err and "fix:" in err
    (tmp_path / "foreign" / "scene.0001" / "scene.json").write_text('[1, 2]')
    code, _, err = main(capsys, "show", tmp_path / "foreign")
    assert code == 2 and "no complete scene" in err and "fix:" in err


def test_8_legacy_pickle_with_wrong_types_is_a_field_error(tmp_path, capsys):
    d = C.to_legacy_dict(C.default_config())
    d["camera"]["focal_length"] = "abc"
    (tmp_path / "in.pickle").write_bytes(pickle.dumps(d))
    code, _, err = main(capsys, "validate", tmp_path / "in.pickle")
    assert code == 2 and "camera.focal_length" in err
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    code, _, err = main(capsys, "validate", tmp_path / "deep.json")
    assert code == 2 and "nested too deeply" in err


def test_9_a_second_run_on_a_locked_folder_is_refused_with_the_pid(tmp_path, capsys):
    import os
    cfg = C.default_config()
    p = save(cfg, tmp_path / "p.json")
    out = tmp_path / "o"
    fake_earlier_run(out, cfg)
    before = tree(out)
    with outdir.OutLock(out):
        code, _, err = main(capsys, "run", p, "--out", out, "--resume")
        assert code == 1 and f"pid {os.getpid()}" in err and "in use" in err
    assert tree(out) == before                   # released: the lock file is gone again


def test_10_minor_cases(tmp_path, capsys):
    code, _, err = main(capsys, "run", C.presets_dir() / "default.json", "--out", "")
    assert code == 2 and "--out" in err
    cfg = C.default_config()
    cfg.objects[0].filepath = str(tmp_path)
    code, _, err = main(capsys, "validate", save(cfg, tmp_path / "p.json"))
    assert code == 2 and "is a folder" in err


# ------------------------------------------------------------------------------------------------
# Issue #21: the output folder's safety through the real CLI (tiny renders; the rules themselves are
# checked case by case on the fake world in tests/test_outdir_safety.py)

def files(root, skip=("run.json",)):
    """The hash tree of `root`'s files (tests/tree_hash.py), `skip` and folders left out."""
    from tree_hash import hashes
    return {k: v for k, v in hashes(root, skip).items() if v != "dir"}


def tiny_preset(tmp_path):
    cfg = C.default_config()
    cfg.scene.num_renders, cfg.scene.min_renders_per_scene, cfg.scene.max_renders_per_scene = 2, 1, 1
    cfg.camera.resolution = [32, 24]
    cfg.render.samples, cfg.render.threads = 1, 2
    cfg.simulation.max_frames = 60
    cfg.structured_light.enabled = False
    cfg.output.overview = False
    for o in cfg.objects:
        o.min_instances, o.max_instances = 1, 1
    return save(cfg, tmp_path / "tiny.json")


def test_21_force_resume_and_links_keep_user_files(tmp_path, capsys):
    p = tiny_preset(tmp_path)
    out = tmp_path / "OUT"
    assert main(capsys, "run", p, "--out", out, "--quiet")[0] == 0
    ref = files(out, skip=("run.json", "manifest.json"))
    (out / "scene.0001" / "user_notes.txt").write_text("notes")
    (out / "scene.0001" / "render.0001" / "mine").mkdir()
    (out / "scene.0001" / "render.0001" / "mine" / "a.txt").write_text("mine")
    user = {k: v for k, v in files(out).items() if "notes" in k or "mine" in k}
    code, _, err = main(capsys, "run", p, "--out", out, "--force", "--quiet")
    assert code == 0, err
    after = files(out, skip=("run.json", "manifest.json"))
    assert {k: after[k] for k in user} == user and {k: v for k, v in after.items() if k not in user} == ref
    # a link where the run writes: refused before anything is written, the victim untouched
    victim = tmp_path / "victim_models"
    victim.mkdir()
    (victim / "obj_000001.ply").write_text("the victim's model")
    (out / "models").rename(tmp_path / "models_moved")
    (out / "models").symlink_to("../victim_models")
    before, victim_before = files(out, skip=()), files(victim)
    for flag in ("--force", "--resume"):
        code, _, err = main(capsys, "run", p, "--out", out, flag, "--quiet")
        assert code == 1 and str(out / "models") in err and "symbolic link" in err and "fix:" in err
        assert files(out, skip=()) == before and files(victim) == victim_before
    (out / "models").unlink()
    (tmp_path / "models_moved").rename(out / "models")
    # a scene.json that is not this run's: refused on --resume (and --force), nothing changed
    (out / "scene.0002" / "scene.json").write_text('{"my": "own annotations"}')
    (out / "scene.0002" / "mine.txt").write_text("mine")
    before = files(out, skip=())
    for flag in ("--resume", "--force"):
        code, _, err = main(capsys, "run", p, "--out", out, flag, "--quiet")
        assert code == 1 and str(out / "scene.0002" / "scene.json") in err and "fix:" in err
        assert files(out, skip=()) == before


def test_21_a_pass_file_blender_cut_short_is_a_file_error_and_resumes(tmp_path, capsys, monkeypatch):
    """Disk full while Blender writes its pass file: the file's path, exit 1 (not a preset error, not
    a traceback), no scratch or temporary file left; --resume then makes the same files as a clean run."""
    from datapipe.core import compat
    p = tiny_preset(tmp_path)
    ref, out = tmp_path / "ref", tmp_path / "OUT"
    assert main(capsys, "run", p, "--out", ref, "--quiet")[0] == 0
    real = compat.written_files
    cut = []

    def cut_short(directory, basename):
        found = real(directory, basename)
        if found and "scene.0002" in str(directory) and not cut:
            data = found[0].read_bytes()
            found[0].write_bytes(data[: len(data) // 3])
            cut.append(found[0])
        return found
    monkeypatch.setattr(compat, "written_files", cut_short)
    code, _, err = main(capsys, "run", p, "--out", out, "--quiet")
    assert code == 1 and str(cut[0]) in err and "truncated" in err and err.count("error:") == 1
    assert not [f for f in out.rglob("*") if ".tmp" in f.name or f.name.startswith("_")]
    monkeypatch.undo()
    assert main(capsys, "run", p, "--out", out, "--resume", "--quiet")[0] == 0
    assert files(out) == files(ref)


def test_21_take_written_exr_refuses_short_and_incomplete_files(tmp_path):
    import errno
    import numpy as np
    from datapipe.core import compat
    from datapipe.io.exr import write_exr
    full = tmp_path / "full.exr"
    write_exr(full, {"Image.R": np.ones((24, 32)), "Depth.V": np.ones((24, 32))})
    data = full.read_bytes()
    d = tmp_path / "r"
    d.mkdir()
    cases = [(data[: len(data) // 2], ["Image.R"], "truncated"), (data, ["Image.R", "Normal.X"], "lacks Normal.X")]
    for content, expect, words in cases:
        (d / "_passes.exr").write_bytes(content)
        with pytest.raises(OSError) as ei:
            compat.take_written_exr(d, "_passes", "pass", expect=expect)
        assert ei.value.filename == str(d / "_passes.exr") and words in str(ei.value)
        assert ei.value.errno in (errno.EIO, errno.ENOSPC) and list(d.iterdir()) == []
    with pytest.raises(OSError) as ei:
        compat.take_written_exr(d, "_passes", "pass")
    assert ei.value.filename == str(d / "_passes.exr") and "wrote no pass file" in str(ei.value)
