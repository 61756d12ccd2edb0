"""Golden snapshot of the seeded demo's annotations: a change of output is a visible diff.

What runs: the demo preset (`config.default_config()`, seed 0, structured light on, the same
objects, plan, camera poses, projector and simulation) made cheap for `make test`: camera
resolution 80x60 (the demo's 320x240 / 4) with fringe periods [1, 4, 16] (the demo's 5 camera px per
finest fringe), 4 Cycles samples (demo: 32), 2 render threads, and
`output.formats = ["native", "bop"]` so the BOP annotations come from the run itself. The full
demo takes minutes on two shared cores; this takes about half a minute.

What is compared: each `scene.NNNN/scene.json` and `bop/train_pbr/000000/scene_gt.json` against
tests/snapshots/demo_small/, as data: the same keys, list lengths, strings, ids and pixel counts,
and numbers within tolerances set by the physics (poses to 1e-6 m and 1e-6 per rotation entry,
structured-light class counts to 0.5% of the image; the table and its reasons are in
tests/snapshot_compare.py), so the snapshot holds on every CPU and still fails on a real change
(tests/test_snapshot_compare.py plants both kinds). Masked before comparing, because it is not the
dataset's content but where it was made: the absolute path of the datapipe package inside object
`filename` values (it depends on the checkout; written as `<datapipe>/`). Timings never enter these
files (the pipeline keeps them in run.json).

When a change alters the output ON PURPOSE (new fields, other poses, other valid fractions),
regenerate and commit the new files with the reason in the commit message:

    DATAPIPE_UPDATE_SNAPSHOTS=1 python -m pytest -q tests/blender/test_snapshot.py
"""
import os
import sys
from pathlib import Path

import pytest

from datapipe import config as C
from datapipe.engine.pipeline import Pipeline

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from snapshot_compare import compare_texts  # noqa: E402

SNAPSHOTS = Path(__file__).resolve().parents[1] / "snapshots" / "demo_small"
PACKAGE = Path(C.__file__).resolve().parents[1]      # datapipe/ (C is the datapipe.config package)
UPDATE = os.environ.get("DATAPIPE_UPDATE_SNAPSHOTS") == "1"


def snapshot_config() -> C.Config:
    cfg = C.default_config()
    cfg.camera.resolution = [80, 60]
    cfg.structured_light.periods = [1, 4, 16]     # finest fringe 5 camera px, as the demo's [1, 8, 64] at
                                                  # 320 px (64 periods at 80 px are 1.25 px: validate refuses)
    cfg.render.samples = 4
    cfg.render.threads = 2
    cfg.output.formats = ["native", "bop"]
    cfg.output.overview = False
    return cfg


def _normalised(path: Path) -> str:
    """The file's text with the package's absolute path written as `<datapipe>`."""
    return path.read_text().replace(str(PACKAGE) + os.sep, "<datapipe>/")


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)     # module scope runs before the per-test reset
    out = tmp_path_factory.mktemp("snapshot") / "out"
    events = list(Pipeline(snapshot_config(), out).run())
    assert events[-1].stage == "done", events[-1]
    return out


def _files(out: Path) -> dict[str, Path]:
    files = {f"{p.parent.name}.json": p for p in sorted(out.glob("scene.*/scene.json"))}
    files["bop_scene_gt.json"] = out / "bop" / "train_pbr" / "000000" / "scene_gt.json"
    return files


def test_demo_annotations_match_the_snapshot(demo_run):
    files = _files(demo_run)
    assert len(files) >= 3, sorted(files)
    if UPDATE:
        SNAPSHOTS.mkdir(parents=True, exist_ok=True)
        for old in SNAPSHOTS.glob("*.json"):
            old.unlink()
        for name, p in files.items():
            (SNAPSHOTS / name).write_text(_normalised(p))
        pytest.skip(f"snapshots rewritten in {SNAPSHOTS}: review the diff and commit it")
    expected = sorted(p.name for p in SNAPSHOTS.glob("*.json"))
    assert expected, f"no snapshots in {SNAPSHOTS}: run with DATAPIPE_UPDATE_SNAPSHOTS=1 once"
    assert sorted(files) == expected, "the run made other files than the snapshot holds"
    diffs = [line for name, p in files.items()
             for line in compare_texts(_normalised(p), (SNAPSHOTS / name).read_text(), name)]
    assert not diffs, (f"{len(diffs)} difference(s) from tests/snapshots/demo_small/:\n  " + "\n  ".join(diffs[:30])
                       + "\nif the change is on purpose, regenerate with DATAPIPE_UPDATE_SNAPSHOTS=1 "
                         "(see this file's docstring)")
