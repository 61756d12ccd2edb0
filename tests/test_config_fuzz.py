"""Property-based fuzzing of the preset loaders and validate(): whatever a preset holds, the answer is
a valid Config or a ConfigError naming field paths and fixes, never another exception.

Seeded (derandomize=True), so a failure reproduces. The default profile runs 120 examples per test (~3 s);
`DATAPIPE_FUZZ=full` runs the acceptance size (2,000 generated presets per test, ~1 min in all):
    DATAPIPE_FUZZ=full python -m pytest -q tests/test_config_fuzz.py
"""
import copy
import math
import os
import pickle

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: E402

from datapipe import config as C  # noqa: E402
from datapipe.errors import ConfigError  # noqa: E402

EXAMPLES = 2000 if os.environ.get("DATAPIPE_FUZZ") == "full" else 120
FUZZ = settings(max_examples=EXAMPLES, derandomize=True, database=None, deadline=None,
                suppress_health_check=list(HealthCheck))

# Scalars a hostile or careless preset holds: edge numbers, huge ints, NaN/inf, wrong types.
scalars = st.one_of(
    st.none(), st.booleans(),
    st.integers(), st.sampled_from([0, -1, 1, 2, 3, 2**31, 2**32, 2**63, 10**9, 10**400]),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([1e-9, 1e6, 1e308, -0.0, math.nan]),
    st.text(max_size=8), st.sampled_from(["", "CYCLES", "AUTO", "rgb", "bop", "heterodyne", "peg.obj", "/", "bin_view", "pool"]),
)
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=5),
                                                       st.dictionaries(st.text(max_size=6), inner, max_size=4)),
                      max_leaves=12)


def _leaf_paths(obj, prefix=()):
    """Every position in a nested dict/list (containers included) as a key path."""
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _leaf_paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _leaf_paths(v, prefix + (i,))


def _set(obj, path, value):
    if not path:
        return value
    parent = obj
    for k in path[:-1]:
        parent = parent[k]
    parent[path[-1]] = value
    return obj


@st.composite
def mutated(draw, base: dict):
    """A valid dict with a few positions replaced, keys added or removed, lists grown or emptied."""
    d = copy.deepcopy(base)
    for _ in range(draw(st.integers(1, 6))):
        paths = list(_leaf_paths(d))
        path = draw(st.sampled_from(paths))
        action = draw(st.sampled_from(["replace", "replace", "replace", "delete", "add_key", "extend"]))
        target = d
        for k in path:
            target = target[k]
        if action == "delete" and path:
            parent = d
            for k in path[:-1]:
                parent = parent[k]
            del parent[path[-1]]
        elif action == "add_key" and isinstance(target, dict):
            target[draw(st.text(max_size=6))] = draw(values)
        elif action == "extend" and isinstance(target, list):
            target.extend(draw(st.lists(values, max_size=3)))
        else:
            d = _set(d, path, draw(values))
    return d


def _check(error: ConfigError):
    assert error.problems
    for p in error.problems:
        assert isinstance(p.path, str) and p.path, p
        assert p.message and p.fix, p
        assert str(p).count("(fix:") == 1, p


BASE = C.Config().to_dict()
BASE["objects"] = [{"filepath": "/nowhere/part.obj", "name": "part"}]
BASE_SL = copy.deepcopy(BASE)
BASE_SL["structured_light"]["enabled"] = True
BASE_SL["camera"]["sampler"]["kind"] = "bin_view"         # the sampler's range checks too
BASE_SL["lighting"] = {}                                  # and the lighting section's defaults


@FUZZ
@given(st.one_of(mutated(BASE), mutated(BASE_SL), values))
def test_from_dict_and_validate_raise_only_config_errors(data):
    try:
        cfg = C.Config.from_dict(data)
        cfg.validate(check_files=False)
    except ConfigError as e:
        _check(e)


LEGACY = C.to_legacy_dict(C.Config(objects=[C.ObjectEntry(filepath="/nowhere/part.obj")]))
LEGACY["camera"]["is_structured_light"] = True


@FUZZ
@given(st.one_of(mutated(LEGACY), values))
def test_legacy_loader_raises_only_config_errors(data):
    try:
        raw = pickle.dumps(data)
    except (RecursionError, ValueError):
        return
    try:
        cfg = C.load_legacy_pickle(raw)
        cfg.validate(check_files=False)
    except ConfigError as e:
        _check(e)


@FUZZ
@given(st.binary(max_size=200))
def test_garbage_bytes_are_config_errors(raw):
    for load in (C.load_legacy_pickle, lambda b: C.loads(b.decode("utf-8", "replace"))):
        try:
            load(raw)
        except ConfigError as e:
            _check(e)


def test_deeply_nested_json_and_pickle_are_config_errors(tmp_path):
    """Defect #8: JSON nested 100,000 deep was a RecursionError traceback."""
    (tmp_path / "deep.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ConfigError, match="nested too deeply"):
        C.load(tmp_path / "deep.json")
    bad = copy.deepcopy(LEGACY)
    inner = bad["objects"]["objects_list"][0]
    for _ in range(200):
        inner["filepath"] = {"x": inner.get("filepath")}
        inner = inner["filepath"]
    with pytest.raises(ConfigError) as ei:
        C.load_legacy_pickle(pickle.dumps(bad))
    assert "objects.objects_list[0].filepath" in ei.value.paths()


def test_legacy_wrong_value_types_name_the_key():
    """Defect #8: `focal_length: 'abc'` in a legacy pickle was a ValueError traceback."""
    bad = copy.deepcopy(LEGACY)
    bad["camera"]["focal_length"] = "abc"
    bad["projector"]["resolution"] = [480, "wide"]
    bad["scene"]["num_renders"] = 2.5
    bad["objects"]["objects_list"][0]["mass"] = None
    with pytest.raises(ConfigError) as ei:
        C.load_legacy_pickle(pickle.dumps(bad))
    assert {"camera.focal_length", "projector.resolution[1]", "scene.num_renders",
            "objects.objects_list[0].mass"} <= set(ei.value.paths())
