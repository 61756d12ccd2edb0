"""Property-based fuzzing of the preset loaders and validate(): whatever a preset holds, the answer is
a valid Config or a ConfigError naming field paths and fixes, never another exception.

Issue 21's hostile values are in the generators: NUL bytes and lone surrogates in paths and names,
names past Blender's 63 bytes, 401-digit ints and 1e308 in materials, lists nested 1,200 deep,
periods of a million and 2**62 (`hostile` sets the fields where they bite; the mutations put them
anywhere); `test_preset_files_raise_only_config_errors` goes through the file loaders (JSON and
pickle, relative paths resolved, files checked). benchmarks/fuzz_presets.py runs thousands more,
the Blender preflight included.

Seeded (derandomize=True), so a failure reproduces. The default profile runs 120 examples per test (~6 s);
`DATAPIPE_FUZZ=full` runs the acceptance size (2,000 generated presets per test, ~2 min in all):
    DATAPIPE_FUZZ=full python -m pytest -q tests/test_config_fuzz.py
"""
import copy
import json
import math
import os
import pickle
import tempfile
from pathlib import Path

import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings, strategies as st  # noqa: E402

from datapipe import config as C  # noqa: E402
from datapipe.errors import ConfigError  # noqa: E402

EXAMPLES = 2000 if os.environ.get("DATAPIPE_FUZZ") == "full" else 120
FUZZ = settings(max_examples=EXAMPLES, derandomize=True, database=None, deadline=None,
                suppress_health_check=list(HealthCheck))

# Scalars a hostile or careless preset holds: edge numbers, huge ints, NaN/inf, wrong types, and
# the strings the OS or Blender refuse (issue 21: NUL, lone surrogates, control characters, names
# past Blender 4.x's 63 bytes).
HOSTILE_TEXT = ["\x00", "a\x00.obj", "\x00.blend", "\ud800", "\ud800.obj", "\udc80.obj", "peg\n", "\t",
                "é" * 40, "x" * 70, "bad.blend", "datapipe_template_peg", "loop"]
scalars = st.one_of(
    st.none(), st.booleans(),
    st.integers(), st.sampled_from([0, -1, 1, 2, 3, 2**31, 2**32, 2**63, 10**9, 10**400, int("9" * 401),
                                    2**62 + 1, 2**62 - 1, 1000003, 999983, 2730, 2731]),
    st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([1e-9, 1e6, 1e308, -1e308, -0.0, math.nan]),
    st.text(max_size=8), st.sampled_from(["", "CYCLES", "AUTO", "rgb", "bop", "heterodyne", "peg.obj", "/", "bin_view",
                                          "pool", "steel"] + HOSTILE_TEXT),
)


def _nest(depth: int, leaf="steel"):
    for _ in range(depth):
        leaf = [leaf] if depth % 2 else {"name": leaf}
    return leaf


values = st.one_of(
    st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=5),
                                                  st.dictionaries(st.text(max_size=6), inner, max_size=4)),
                 max_leaves=12),
    st.integers(6, 1200).map(_nest),                                      # nesting past any preset's
    st.lists(st.sampled_from([1, 7, 8, 13, 64, 304, 305, 1000003, 999983, 2**62 + 1, 2**62 - 1]),
             min_size=1, max_size=4),                                     # fringe periods, absurd ones too
)


def _leaf_paths(obj, prefix=()):
    """Every position in a nested dict/list (containers included) as a key path, down to 12 levels
    (a value nested 1,200 deep is one position, not 1,200)."""
    yield prefix
    if len(prefix) >= 12:
        return
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


# Fields where a hostile value reaches the OS, Blender or the unwrapping maths (issue 21): each
# generated preset sets one to three of them, so 120 examples reach every kind (a random position
# among the ~150 of a preset would rarely be one of these).
hostile_text = st.one_of(st.sampled_from(HOSTILE_TEXT), st.text(max_size=70))
huge = st.sampled_from([10**400, int("9" * 401), 2**62 + 1, 1e308, -1e308, math.inf, math.nan])
TARGETS = {
    ("objects", 0, "filepath"): hostile_text.map(lambda t: t + _obj_suffix(t)),
    ("objects", 0, "name"): hostile_text,
    ("scene", "blend_file"): hostile_text.map(lambda t: t + ".blend"),
    ("output", "path"): hostile_text,
    ("objects", 0, "material"): st.one_of(
        st.builds(lambda k, v: {k: v}, st.sampled_from(["roughness", "ior", "metallic", "specular", "variation"]),
                  huge),
        st.builds(lambda v: {"base_color": v}, st.lists(huge, min_size=3, max_size=3)),
        st.builds(lambda v: [{"name": v}], hostile_text), st.integers(6, 1200).map(_nest)),
    ("scene", "bin_material"): st.one_of(st.integers(6, 1200).map(_nest), st.sampled_from(HOSTILE_TEXT)),
    ("structured_light", "periods"): st.lists(st.one_of(huge, st.sampled_from([1, 8, 64, 304, 305, 1000003, 999983,
                                                                               2**62 + 1, 2**62 - 1])),
                                              min_size=1, max_size=4),
    ("objects", "objects_list", 0, "filepath"): hostile_text.map(lambda t: t + ".obj"),  # the legacy layout
    ("objects", "objects_list", 0, "scale"): huge,
}


def _obj_suffix(text: str) -> str:
    return "" if text.endswith(".obj") else ".obj"


@st.composite
def hostile(draw, base: dict):
    """`base`, maybe with a few generic mutations, then one to three of the TARGETS it still has set
    to hostile values (last: mutations deep-copy, and a value nested 1,200 deep cannot be)."""
    d = draw(mutated(base)) if draw(st.booleans()) else copy.deepcopy(base)
    present = [p for p in TARGETS if _has(d, p[:-1])]
    if not present:
        return d
    chosen = draw(st.lists(st.sampled_from(present), min_size=1, max_size=3, unique=True))
    for path in chosen:
        _set(d, path, draw(TARGETS[path]))
    if any(p[0] == "structured_light" for p in chosen):
        d["structured_light"]["enabled"] = True          # periods are checked with structured light on
    return d


def _has(d, path) -> bool:
    for k in path:
        if isinstance(d, dict) and k in d or isinstance(d, list) and isinstance(k, int) and k < len(d):
            d = d[k]
        else:
            return False
    return isinstance(d, dict)


def _check(error: ConfigError):
    assert error.problems
    for p in error.problems:
        assert isinstance(p.path, str) and p.path, p
        assert p.message and p.fix, p
        assert str(p).count("(fix:") == 1, p


BASE = C.Config().to_dict()
BASE["objects"] = [{"filepath": "/nowhere/part.obj", "name": "part",
                    "material": [{"roughness": 0.3, "ior": 1.5, "name": "m"}, "steel"]}]
BASE["scene"]["bin_material"] = {"base_color": [0.5, 0.5, 0.5], "name": "bin"}
BASE_SL = copy.deepcopy(BASE)
BASE_SL["structured_light"]["enabled"] = True
BASE_SL["camera"]["sampler"]["kind"] = "bin_view"         # the sampler's range checks too
BASE_SL["lighting"] = {}                                  # and the lighting section's defaults


def _from_dict_and_validate(data):
    try:
        cfg = C.Config.from_dict(data)
        cfg.validate(check_files=False)
    except ConfigError as e:
        _check(e)


@FUZZ
@given(st.one_of(mutated(BASE), mutated(BASE_SL), values))
def test_from_dict_and_validate_raise_only_config_errors(data):
    _from_dict_and_validate(data)


@FUZZ
@given(st.one_of(hostile(BASE), hostile(BASE_SL)))
def test_hostile_fields_raise_only_config_errors(data):
    _from_dict_and_validate(data)


LEGACY = C.to_legacy_dict(C.Config(objects=[C.ObjectEntry(filepath="/nowhere/part.obj")]))
LEGACY["camera"]["is_structured_light"] = True


@FUZZ
@given(st.one_of(mutated(LEGACY), hostile(LEGACY), values))
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


ASSETS = Path(C.assets_dir())
FILE_BASE = C.default_config().to_dict()
for _o in FILE_BASE["objects"]:
    _o["filepath"] = _o["filepath"].rsplit("/", 1)[-1]             # resolved against the preset's folder
FILE_BASE["structured_light"]["enabled"] = True


@FUZZ
@given(st.one_of(mutated(FILE_BASE), hostile(FILE_BASE), hostile(LEGACY)), st.booleans())
def test_preset_files_raise_only_config_errors(data, as_pickle):
    """Through the real loaders, paths resolved and files checked, as `validate` runs them."""
    with tempfile.TemporaryDirectory() as d:
        for a in ASSETS.iterdir():
            os.symlink(a, Path(d) / a.name)
        os.symlink("loop.obj", Path(d) / "loop.obj")              # a symlink loop (issue 21 found none;
        os.symlink("loop.blend", Path(d) / "loop.blend")          # Path.resolve raised RuntimeError)
        path = Path(d) / ("inputs.pickle" if as_pickle else "preset.json")
        try:
            path.write_bytes(pickle.dumps(data) if as_pickle else json.dumps(data).encode())
        except (RecursionError, ValueError):   # json/pickle cannot write it (4,300+ digit ints, depth)
            return
        try:
            C.load(path).validate()
        except ConfigError as e:
            _check(e)
