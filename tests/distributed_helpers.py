"""Helpers shared by the Ray tests with the stand-in runner (tests/test_distributed.py) and with the
real Blender runner (tests/blender/test_distributed_real.py). No bpy."""
from __future__ import annotations

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


@pytest.fixture(scope="module")
def local_ray():
    ray = pytest.importorskip("ray")
    if not ray.is_initialized():
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield ray
    ray.shutdown()
