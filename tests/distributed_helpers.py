"""Helpers shared by the Ray tests with the stand-in runner (tests/test_distributed.py) and with the
real Blender runner (tests/blender/test_distributed_real.py). No bpy."""
from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path

import numpy as np
import pytest

from datapipe.io import legacy as legacy_pickle

TESTS = Path(__file__).resolve().parent


def killing(runner, shard, scenes=1):
    """`runner`, except that shard `shard`'s first attempt is killed once `scenes` scenes are done."""
    return [sys.executable, str(TESTS / "kill_runner.py"), str(shard), str(scenes), "--", *runner]


def legacy(run: Path) -> dict:
    data = legacy_pickle.load_legacy_output(run / "output_dict.pickle")
    return {s: {r: {"wrld2cam_pose": np.asarray(v["wrld2cam_pose"]).round(9).tolist(),
                    "objects": [(o["name"], o["mask_index"], np.asarray(o["T_cam_obj"]).round(9).tolist())
                                for o in v["objects_in_scene"]]}
                for r, v in sc.items()} for s, sc in data.items()}


def assert_recorded_as_written(out: Path) -> None:
    """OUT's manifest.json records every file of the run as a one-process run does (datapipe/io/
    manifest.py): path, size and sha256 of its bytes; run.json, the logs, the sheets and the COCO
    files by path only (their bytes hold a time or the folder's name); every folder."""
    m = json.loads((out / "manifest.json").read_text())
    assert m["datapipe_manifest"] == 2 and m["temporaries"] == {}
    for p in sorted(out.rglob("*")):
        rel = p.relative_to(out).as_posix()
        assert not p.is_symlink(), rel
        if p.is_dir():
            assert rel in m["dirs"], rel
        elif rel not in ("manifest.json", ".datapipe.journal"):
            by_path = rel == "run.json" or rel.startswith(("logs/", "sheets/")) or rel.endswith("_coco.json")
            want = None if by_path else [[p.stat().st_size, hashlib.sha256(p.read_bytes()).hexdigest()]]
            assert m["files"][rel] == want, rel


@pytest.fixture(scope="module")
def local_ray():
    ray = pytest.importorskip("ray")
    if not ray.is_initialized():
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()
