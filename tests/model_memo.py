"""The models' analysis of a run (symmetry detection for models/, the resampling for models_eval/),
computed once per distinct mesh in a test session instead of once per run.

Why: every fake-world run (tests/fake_world.py, no Blender) analyses the same three box models again
at its start (Pipeline._build_world: io.bop_models.models_symmetries -> io.symmetry.detect_symmetries)
and at each BOP export (io.bop.BopWriter._write_models_eval -> resample_for_eval): measured 2.7 of
the 3.0 s of test_run_loop's small run. The tests of the run loop, the output folder, the picks and
the BOP sensor and xyz_crop exports check what a run or an export writes and when, not these two
functions (tests/test_symmetry.py, test_bop_models.py and test_bop.py check them, unmemoised: keep the
fixture out of them); both are pure functions of their arguments, so a remembered result is the one a
new call would give and every file a run writes keeps its bytes.

The first call with given arguments runs the real function; a later call with equal arguments (the
same array bytes, dtype and shape, the same other values) gets a deep copy of that result. The second
call runs the function again and asserts the same result, so the determinism the runs' byte-for-byte
comparisons (resume, shards, --force) relied on is still checked once per mesh.
"""
from __future__ import annotations

import copy
import hashlib
import pickle

import numpy as np

_RESULTS: dict[str, object] = {}          # session-wide: shared by every module that asks for it
_CHECKED: set[str] = set()                # keys whose result a second real call gave again


def _key(name: str, args, kwargs) -> str:
    h = hashlib.sha256(name.encode())

    def add(a):
        if isinstance(a, np.ndarray):
            a = np.ascontiguousarray(a)
            h.update(repr((a.dtype.str, a.shape)).encode())
            h.update(a.tobytes())
        else:
            h.update(repr(a).encode())
    for a in args:
        add(a)
    for k, v in sorted(kwargs.items()):
        h.update(k.encode())
        add(v)
    return h.hexdigest()


def _remembered(name: str, fn):
    def call(*args, **kwargs):
        k = _key(name, args, kwargs)
        if k not in _RESULTS:
            _RESULTS[k] = fn(*args, **kwargs)
        elif k not in _CHECKED:          # the second call computes again: a result that changes from
            again = fn(*args, **kwargs)  # call to call (an unseeded draw) fails here, as the runs' byte
            assert pickle.dumps(again) == pickle.dumps(_RESULTS[k]), f"{name}: another result for the same mesh"
            _CHECKED.add(k)              # comparisons would have caught it without the memo
        return copy.deepcopy(_RESULTS[k])
    return call


def remember_model_analysis(monkeypatch) -> None:
    """Route detect_symmetries (as io.bop_models imports it, at call time) and resample_for_eval (as
    io.bop holds it) through the session's memo, until `monkeypatch` undoes it."""
    from datapipe.io import bop, symmetry
    monkeypatch.setattr(symmetry, "detect_symmetries", _remembered("detect_symmetries", symmetry.detect_symmetries))
    monkeypatch.setattr(bop, "resample_for_eval", _remembered("resample_for_eval", bop.resample_for_eval))
