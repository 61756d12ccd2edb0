"""The run's own files read back during the run (the BOP export copies OUT/models/ and converts each
render's maps) are read only through OUT's handle and only when the run's manifest records that
very file with that content (datapipe/io/guard.py `open_own`, datapipe/io/files.py `own_file`), on
the fake world (tests/fake_world.py, no Blender).

Found by benchmarks/fuzz_outdir.py --seed 34 (trials 8 and 11): `models/` or a model in it replaced
by a link after the run wrote it ended in a DataPipeError of the BOP writer ("no models_info.json",
"object id 1 has no model"), because the writer read OUT/models/ by path: a link there was followed,
and had it led to a folder of valid models, those would have been copied into the dataset as the
run's, with exit 0 (cases `models_folder`, `model_file`). The same held for a render map the BOP
export converts (`render_map`: a link at rgb.png put the linked picture into bop/ as the run's,
exit 0), for a file of the user's put in place of a model (`user_model`), and on --resume for
bop/models/ and the chunk's JSON files. Each mid-run case compares the victim folder's hash tree
before and after and checks that nothing of the victim's reached OUT.
Every test here fails on the code before the change (checked against main at 2c519f3).
"""
import json
import os
import shutil

import cv2
import numpy as np
import pytest

import fixtures_native as fx
from fake_world import BoxWorld, Crash
from datapipe.engine.pipeline import Pipeline
from datapipe.io import layout, outdir
from datapipe.io.models import model_filename, write_models
from test_outdir_safety import finished, one_run  # noqa: F401 (fixtures)
from test_run_loop import run, small_cfg
from tree_hash import hashes

pytestmark = pytest.mark.usefixtures("remembered_model_analysis")   # box models analysed once (tests/model_memo.py)


def _victim(tmp_path):
    """A folder outside OUT that looks like the run's own: valid models (the boxes twice as large)
    and a picture of the render's size, so that reading it would not fail by itself."""
    v = tmp_path / "victim"
    write_models(v / "models", {k: (m[0] * 2.0, *m[1:]) for k, m in fx.box_meshes(1).items()})
    cv2.imwrite(str(v / "mine.png"), np.full((48, 64, 3), 77, np.uint8))
    return v


def _first_scene(e, pipe) -> bool:
    return e.stage == "scene" and e.scene == pipe.scene_ids[0]


def _after_first_render(e, pipe) -> bool:    # its maps are written; the BOP export reads them at the scene's end
    return e.stage == "render" and e.scene == pipe.scene_ids[0] and e.render == 0


def _link(out, rel, target, away):
    os.rename(out / rel, away)
    (out / rel).symlink_to(target)


def _user_model(out, rel, target, away):
    """The user's own model (a valid PLY, not the run's) where the run's was."""
    os.rename(out / rel, away)
    shutil.copyfile(target, out / rel)


# case -> (when, what is changed (rel to OUT), its replacement in the victim folder, how, the message's fix
# once it is moved away: --resume remakes a scene that lacks a file; models/ is written only when a run
# starts, after --resume has caught up the BOP export of the scenes already complete, hence --force)
READ_BACK = {
    "models_folder": (_first_scene, layout.MODELS_DIR, lambda v: v / "models", _link, "force"),
    "model_file": (_first_scene, f"{layout.MODELS_DIR}/{model_filename(1)}",
                   lambda v: v / "models" / model_filename(1), _link, "force"),
    "user_model": (_first_scene, f"{layout.MODELS_DIR}/{model_filename(1)}",
                   lambda v: v / "models" / model_filename(1), _user_model, "force"),
    # the fuzz's own two (seed 34): a link to a file, one to nothing (a DataPipeError of the BOP writer before)
    "models_folder_to_a_file": (_first_scene, layout.MODELS_DIR, lambda v: v / "mine.png", _link, "force"),
    "model_file_to_nothing": (_first_scene, f"{layout.MODELS_DIR}/{model_filename(1)}", lambda v: v / "gone",
                              _link, "force"),
    "render_map": (_after_first_render, "scene.0001/render.0001/rgb.png", lambda v: v / "mine.png", _link,
                   "resume"),
}


@pytest.mark.parametrize("case", sorted(READ_BACK))
def test_a_file_the_run_reads_back_changed_during_the_run_is_refused_never_read(tmp_path, case):
    when, rel, target_of, change, then = READ_BACK[case]
    cfg = small_cfg(tmp_path)
    out = tmp_path / "OUT"
    victim = _victim(tmp_path)
    victim_before = hashes(victim)
    pipe = Pipeline(cfg, out, world=BoxWorld.factory())
    changed = False
    with pytest.raises(outdir.OutputStateError) as ei:
        for e in pipe.run():
            if not changed and when(e, pipe):
                change(out, rel, target_of(victim), tmp_path / "moved_away")
                changed = True
    msg = str(ei.value)
    assert changed and str(out / rel) in msg and "fix:" in msg, msg
    assert hashes(victim) == victim_before
    theirs = {h for h in victim_before.values() if h != "dir"}
    assert not [p for p, h in hashes(out).items() if h in theirs and not p.startswith(rel)]  # nothing copied in
    # the fix the message gives: move it away, then --resume (or, for models/, --force)
    assert f"--{then}" in msg
    (out / rel).unlink()
    _, events = run(cfg, out, **{then: True})
    assert events[-1].stage == "done"


def test_resume_never_reads_a_users_model_beside_the_bop_exports(finished, tmp_path):
    """bop/models/ is read back by --resume's BOP writer: only the models its models_info.json
    lists, each the run's own. A PLY of the user's named like a model beside them is neither read
    (before: read as object 9, a COCO category of the run's; a text file there stopped the run) nor
    changed."""
    cfg, out = finished
    ref = json.loads((out / "bop/train_pbr/000000/scene_gt_coco.json").read_text())["categories"]
    pipe = Pipeline(cfg, out, world=BoxWorld.factory(crash_at=1), force=True)
    with pytest.raises(Crash):
        list(pipe.run())                       # killed after the first scene: bop/models/ is written
    mine = out / layout.BOP_DIR / layout.MODELS_DIR / model_filename(9)
    shutil.copyfile(out / layout.MODELS_DIR / model_filename(1), mine)
    before = hashes(out)[str(mine.relative_to(out))]
    _, events = run(cfg, out, resume=True)
    assert events[-1].stage == "done"
    assert json.loads((out / "bop/train_pbr/000000/scene_gt_coco.json").read_text())["categories"] == ref
    assert hashes(out)[str(mine.relative_to(out))] == before


def test_resume_refuses_a_users_file_in_place_of_a_bop_chunk_file(finished, tmp_path):
    """--resume's BOP writer reads the chunk's JSON files back (to add the next scenes' images):
    one of the user's in place of the run's is refused, naming it, and left as it is (before: read
    as the run's, and a file that is not JSON stopped the run with "delete it")."""
    cfg, out = finished
    pipe = Pipeline(cfg, out, world=BoxWorld.factory(crash_at=1), force=True)
    with pytest.raises(Crash):
        list(pipe.run())                       # killed after the first scene: the chunk's files are written
    theirs = out / "bop/train_pbr/000000/scene_gt.json"
    os.rename(theirs, tmp_path / "moved_away")
    theirs.write_text("my notes on the ground truth, not JSON")
    before = hashes(out)[str(theirs.relative_to(out))]
    with pytest.raises(outdir.OutputStateError) as ei:
        run(cfg, out, resume=True)
    assert str(theirs) in str(ei.value) and "fix:" in str(ei.value)
    assert hashes(out)[str(theirs.relative_to(out))] == before
