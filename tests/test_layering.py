"""The house rules of the package layout (docs/ARCHITECTURE.md), checked on the source itself.

- every module outside core/ and ui/ (found by walking the package) and core.world (bpy only inside
  BlenderWorld's methods, so the run loop imports without Blender) import with bpy absent (a subprocess
  whose import system refuses `bpy` and `mathutils`, so an installed bpy wheel cannot hide a slip);
- every module of core/ needs Blender: it imports bpy, or works on Blender's objects (listed);
- no module outside core/ and ui/ imports from core/ (except the command line and the run loop, which
  drive it, and the gate of checks, which runs the Blender preflight);
- no core module imports `show` (the run engine does not depend on the reporting module);
- the native layout's file names are spelled in datapipe/io/layout.py only;
- no function is longer than MAX_FUNCTION_LINES, except the ones listed (owned and being split
  elsewhere); none in benchmarks/ longer than MAX_BENCHMARK_FUNCTION_LINES;
- no module of the package is longer than MAX_MODULE_LINES (issue #22: small modules named for what
  they hold);
- the top-level parts (folders and top-level modules) stand on FLOORS: no import circle among them,
  each imports only parts on floors below its own, lazy imports included (issue #32; at most MAX_UP
  listed exceptions); the modules of config/ likewise on CONFIG_FLOORS.
"""
import ast
import json
import subprocess
import sys
from pathlib import Path


ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "datapipe"
MAX_FUNCTION_LINES = 80          # issue #32: a function a newcomer reads on one screen
MAX_MODULE_LINES = 600
# qualified name -> why it may be longer for now
LONG_FUNCTION_EXCEPTIONS: dict[str, str] = {
}

# Blender's side is core/ (bpy at import) and ui/ (the add-on's panels); every other module of the
# package - found by walking it, so a new module is covered the day it lands - must import with bpy
# absent. __main__ is left out: importing it runs the CLI.
BPY_SIDE = ("core", "ui")
# core/ holds the modules that need Blender. Two of them import without it, because the run loop
# (engine/pipeline.py, tested with a fake world) imports them: BlenderWorld (bpy inside its methods)
# and SceneVariety (applies the pure draws to Blender's scene and camera objects it is given).
BPY_FREE_IN_CORE = ["datapipe.core.world"]
BLENDER_OBJECT_MODULES = {"datapipe.core.world", "datapipe.core.variety", "datapipe.core"}


def _bpy_free_modules() -> list[str]:
    names = []
    for p in sorted(PKG.rglob("*.py")):
        parts = p.relative_to(ROOT).with_suffix("").parts
        if parts[1] in BPY_SIDE or parts[-1] == "__main__":
            continue
        names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return names + BPY_FREE_IN_CORE


BPY_FREE = _bpy_free_modules()
# Modules outside BPY_SIDE that may import core/: the run loop (it builds the BlenderWorld) drives
# it; the gate of checks runs the Blender mesh preflight (core/preflight.py), imported inside the
# step that needs it. (The command line reaches Blender only through engine/session.py's run.)
CORE_IMPORTERS = {"datapipe.engine.pipeline", "datapipe.engine.gate"}

_BLOCKER = """
import importlib.abc, json, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in ('bpy', 'mathutils', 'bmesh'):
            raise ImportError('bpy is absent here: ' + name)
        return None
sys.meta_path.insert(0, Block())
bad = {}
for m in json.loads(sys.argv[1]):
    try:
        __import__(m)
    except Exception as e:
        bad[m] = f'{type(e).__name__}: {e}'
print(json.dumps(bad))
"""


def test_bpy_free_modules_import_without_bpy():
    r = subprocess.run([sys.executable, "-c", _BLOCKER, json.dumps(BPY_FREE)], cwd=ROOT, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout.strip().splitlines()[-1]) == {}


def test_the_walk_finds_the_pure_modules():
    """The list is derived, not typed: modules the issue named as missing are in it, Blender's are not."""
    for m in ("datapipe.checks.part_fit", "datapipe.checks.physics_check", "datapipe.config", "datapipe.sl.scanner",
              "datapipe.io.models", "datapipe.collision"):
        assert m in BPY_FREE
    assert not any(m.startswith(("datapipe.core.renderer", "datapipe.ui")) for m in BPY_FREE)


def test_the_blocker_can_fail():
    """The check above is real: a module that needs bpy is reported."""
    r = subprocess.run([sys.executable, "-c", _BLOCKER, json.dumps(["datapipe.core.renderer"])], cwd=ROOT,
                       capture_output=True, text=True, timeout=120)
    assert "datapipe.core.renderer" in json.loads(r.stdout.strip().splitlines()[-1])


def _sources(sub: str = ""):
    return sorted((PKG / sub).rglob("*.py"))


def _imported_modules(path: Path) -> set[str]:
    """Absolute names of every module a file imports (relative imports resolved), lazy ones included;
    not those under `if TYPE_CHECKING:` (annotations only: they never run)."""
    tree = ast.parse(path.read_text())
    pkg = ".".join(path.relative_to(ROOT).with_suffix("").parts[:-1])
    names = set()
    typing_only = {id(n) for i in ast.walk(tree) if isinstance(i, ast.If) and isinstance(i.test, ast.Name)
                   and i.test.id == "TYPE_CHECKING" for b in i.body for n in ast.walk(b)}
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = pkg.split(".")
                parts = parts[:len(parts) - node.level + 1]
                base = ".".join(parts + ([node.module] if node.module else []))
            names.add(base)
            names.update(f"{base}.{a.name}" for a in node.names)
    return names


def _module_graph() -> dict[str, set[str]]:
    """{module: the datapipe modules it imports (lazily or not)}; `from pkg import mod` counts as mod."""
    paths = {}
    for p in _sources():
        parts = p.relative_to(ROOT).with_suffix("").parts
        paths[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    graph = {}
    for name, p in paths.items():
        deps = set()
        imported = _imported_modules(p)       # parsed once per file (was once per imported name: 20 s)
        for m in imported:
            if m not in paths and not any(m.startswith(k + ".") for k in paths):
                continue
            while m not in paths:             # pkg.mod.attr -> pkg.mod
                m = m.rpartition(".")[0]
            if m != name and not any(d.startswith(m + ".") for d in imported if d in paths):
                deps.add(m)
        graph[name] = deps
    return graph


# cycles left to their owners: none (the ui cycle went with #13, fringe_fast <-> structured_light
# with core/fringe_call.py)
KNOWN_CYCLES = []


def test_no_import_cycles():
    graph = _module_graph()
    cycles = _circles(graph)
    assert [c for c in cycles if c not in KNOWN_CYCLES] == []
    assert [c for c in KNOWN_CYCLES if c not in cycles] == []      # a broken known cycle leaves the list
    assert "datapipe.ui.props" in graph["datapipe.ui"]          # the graph is real: a known edge is there


def test_bpy_free_list_is_real():
    """The list found on disk holds the pure modules (the config package among them), not just a few."""
    assert {"datapipe.config", "datapipe.config.schema", "datapipe.config.validate", "datapipe.config.files",
            "datapipe.materials_spec", "datapipe.sl.decode", "datapipe.io.native"} <= set(BPY_FREE)
    assert not [m for m in BPY_FREE if m.startswith("datapipe.ui")]


def test_no_import_runs_up_the_house():
    """Nothing outside core/ and ui/ imports from core/ (lazily or not), except the command line: the
    rules a config or a check needs live below the Blender side (e.g. datapipe/materials_spec.py)."""
    offenders = {}
    for p in _sources():
        rel = p.relative_to(PKG).parts
        if rel[0] in BPY_SIDE:
            continue
        name = ".".join(("datapipe",) + p.relative_to(PKG).with_suffix("").parts)
        up = sorted(m for m in _imported_modules(p) if m == "datapipe.core" or m.startswith("datapipe.core."))
        if up and name not in CORE_IMPORTERS:
            offenders[name] = up
    assert offenders == {}
    assert any(m.startswith("datapipe.core.") for m in _imported_modules(PKG / "engine" / "pipeline.py"))  # it sees imports


def test_core_does_not_import_show():
    offenders = [str(p.relative_to(ROOT)) for p in _sources("core") if "datapipe.show" in _imported_modules(p)]
    assert offenders == []


def test_geometry_and_sl_depend_one_way():
    assert not any(m.startswith("datapipe.sl") for m in _imported_modules(PKG / "geometry.py"))


NATIVE_NAMES = {"scene.json", "run.json", "output_dict.pickle", "models_info.json", "rgb.png", "depth.exr",
                "normals.exr", "mask.exr", "sl_depth.exr", "sl_valid.png", "sl_debug.exr"}


def test_native_file_names_spelled_in_one_module():
    """As string constants in code; docstrings, messages and f-strings may mention them."""
    spelled: dict[str, set[str]] = {}
    for p in _sources():
        tree = ast.parse(p.read_text())
        docs = {id(n.body[0].value) for n in ast.walk(tree)
                if isinstance(n, (ast.Module, ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef))
                and n.body and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
        in_fstrings = {id(v) for n in ast.walk(tree) if isinstance(n, ast.JoinedStr) for v in n.values}
        for n in ast.walk(tree):
            if (isinstance(n, ast.Constant) and n.value in NATIVE_NAMES and id(n) not in docs
                    and id(n) not in in_fstrings):
                spelled.setdefault(n.value, set()).add(str(p.relative_to(ROOT)))
    assert spelled == {name: {"datapipe/io/layout.py"} for name in NATIVE_NAMES}


def _long_functions(paths=None, limit=MAX_FUNCTION_LINES):
    found = {}
    for p in _sources() if paths is None else paths:
        tree = ast.parse(p.read_text())
        for n in ast.walk(tree):
            if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
                length = n.end_lineno - n.lineno + 1
                if length > limit:
                    found[f"{p.relative_to(ROOT)}:{n.name}"] = length
    return found


def test_no_function_over_the_limit():
    long = _long_functions()
    assert {k: v for k, v in long.items() if k not in LONG_FUNCTION_EXCEPTIONS} == {}


def test_long_function_exceptions_are_still_needed():
    """An exception whose function got short (or moved) is removed from the list."""
    assert set(LONG_FUNCTION_EXCEPTIONS) <= set(_long_functions())


# benchmarks/ (issue #32): its scripts are read and changed like the package, so the same rule, at 80
MAX_BENCHMARK_FUNCTION_LINES = 80
# path:function -> why it may be longer for now
LONG_BENCHMARK_EXCEPTIONS: dict[str, str] = {
}


def test_no_benchmark_function_over_the_limit():
    long = _long_functions(sorted((ROOT / "benchmarks").glob("*.py")), MAX_BENCHMARK_FUNCTION_LINES)
    assert {k: v for k, v in long.items() if k not in LONG_BENCHMARK_EXCEPTIONS} == {}
    assert set(LONG_BENCHMARK_EXCEPTIONS) <= set(long)          # an exception that got short is removed


def test_core_holds_only_what_needs_blender():
    """core/ is the Blender side: each module imports bpy (or mathutils/bmesh; lazily counts: it runs
    Blender), imports a core module that does, or is listed as working on Blender's objects; a pure
    module that lands there fails here (it belongs outside)."""
    mods = {}
    for p in _sources("core"):
        name = ".".join(("datapipe",) + p.relative_to(PKG).with_suffix("").parts).removesuffix(".__init__")
        mods[name] = _imported_modules(p)
    blender = {m for m, deps in mods.items() if any(d.split(".")[0] in ("bpy", "mathutils", "bmesh") for d in deps)}
    while True:                                 # through imports of other core modules
        more = {m for m, deps in mods.items() if m not in blender and deps & blender}
        if not more:
            break
        blender |= more
    assert "datapipe.core.renderer" in blender and "datapipe.core.fringe_fast" in blender   # the walk is real
    assert sorted(set(mods) - blender - BLENDER_OBJECT_MODULES) == []


def _module_lengths() -> dict[str, int]:
    return {str(p.relative_to(ROOT)): len(p.read_text().splitlines()) for p in _sources()}


def test_no_module_over_the_limit():
    """Every module of the package (tests/ and benchmarks/ are not the package) stays short enough to
    read whole; a longer one is split by what it holds."""
    lengths = _module_lengths()
    assert {k: v for k, v in lengths.items() if v > MAX_MODULE_LINES} == {}
    assert len(lengths) > 50 and max(lengths.values()) > MAX_MODULE_LINES // 2   # the walk sees the package


# -- floors (issue #32): the top-level parts of the package, each on one floor --------------------
# A part is a folder of datapipe/ or a top-level module. Top to bottom; a part imports only parts on
# floors below its own (lazy imports inside functions count: they run), never one beside it. The
# package root (datapipe/__init__.py: the version, the API's names on first use) is no part: Python
# runs it before any module of the package.
FLOORS = [
    ("the entry point", {"__main__"}),
    ("the front doors: the command line, the add-on, the Python API", {"cli", "ui", "api"}),
    ("the run: the gate of checks, the run loop, sessions, step progress, Ray shards", {"engine"}),
    ("Blender's side: the world a run renders", {"core"}),
    ("checks of a preset and of results, the run read back, its contact sheets", {"checks", "reader", "show"}),
    ("the Config and its rules; measures of a part's mesh and of a render", {"config", "collision", "visibility"}),
    ("the draws, every file a run reads or writes, the structured-light decoder", {"draws", "io", "sl"}),
    ("data and math: devices, frames and intrinsics, lens distortion, materials", {"devices", "geometry", "lens",
                                                                                  "materials_spec"}),
    ("leaves: errors, the procedural shapes, text rules, the world protocol, the sheets' drawing, the version",
     {"errors", "shapes", "text_rules", "world", "sheet_draw", "version"}),
]
# (importer part, imported part) -> why it may run up; at most MAX_UP, each one a known debt
ALLOWED_UP: dict[tuple[str, str], str] = {}
MAX_UP = 2
# config/ inside: the same rule for its modules (the package's __init__ re-exports them all). The
# Config class's from_dict / problems / validate call down into parse.py and validate.py, which are
# handed the class (from_dict(cls, ...)) or the Config they check and never import schema.py at run
# time (their `if TYPE_CHECKING:` imports are annotations: they never run).
CONFIG_FLOORS = [
    ("the package's names", {"__init__"}),
    ("files: JSON presets and the original pickle", {"files"}),
    ("the original add-on's dict", {"legacy"}),
    ("the dataclasses", {"schema"}),
    ("dict -> Config", {"parse"}),
    ("the field rules", {"validate"}),
    ("the rules of a section", {"validate_sl", "validate_looks"}),
    ("a calibration file of the user's rig", {"calibration"}),
    ("what a config does at run time; the rules' helpers; a pickle's depth", {"plan", "checks", "pickle_depth"}),
    ("choices and limits", {"limits"}),
]


def _module_paths() -> dict[str, Path]:
    out = {}
    for p in _sources():
        parts = p.relative_to(ROOT).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = p
    return out


def _imports_at(path: Path) -> list[tuple[str, int]]:
    """(absolute name, line) of every import of a file, relative ones resolved, lazy ones included,
    `if TYPE_CHECKING:` ones left out; `from pkg import a` gives pkg and pkg.a."""
    tree = ast.parse(path.read_text())
    parts = path.relative_to(ROOT).with_suffix("").parts
    pkg = parts[:-1]
    typing_only = {id(n) for i in ast.walk(tree) if isinstance(i, ast.If) and isinstance(i.test, ast.Name)
                   and i.test.id == "TYPE_CHECKING" for b in i.body for n in ast.walk(b)}
    out = []
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                base = ".".join(pkg[:len(pkg) - node.level + 1] + ((node.module,) if node.module else ()))
            out.append((base, node.lineno))
            out += [(f"{base}.{a.name}", node.lineno) for a in node.names]
    return out


def _node_graph(node_of) -> dict[str, dict[str, set[str]]]:
    """{node: {imported node: {"file:line", ...}}} over the package's modules; `node_of(module)` maps a
    module of datapipe to its node (None: not in this graph). A name is the longest module it starts with."""
    paths = _module_paths()
    graph: dict[str, dict[str, set[str]]] = {}
    for name, p in paths.items():
        src = node_of(name)
        if src is None:
            continue
        graph.setdefault(src, {})
        for m, line in _imports_at(p):
            if m != "datapipe" and not m.startswith("datapipe."):
                continue
            while m not in paths:                       # pkg.mod.attr -> pkg.mod
                m = m.rpartition(".")[0]
            dst = node_of(m)
            if dst is not None and dst != src:
                graph[src].setdefault(dst, set()).add(f"{p.relative_to(ROOT)}:{line}")
    return graph


def _part_of(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None          # datapipe itself: the package root, no part


def _config_module_of(module: str) -> str | None:
    parts = module.split(".")
    if parts[:2] != ["datapipe", "config"]:
        return None
    return parts[2] if len(parts) > 2 else "__init__"


def _circles(graph: dict[str, dict]) -> list[list[str]]:
    """The strongly connected components of more than one node (Tarjan)."""
    index, low, stack, on, out = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, {}):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in list(graph):
        if v not in index:
            visit(v)
    return out


def _runs_up(graph: dict[str, dict[str, set[str]]], floors) -> dict[tuple[str, str], list[str]]:
    """Every import from a node to one on its own floor or above: {(importer, imported): where}."""
    floor = {n: k for k, (_, names) in enumerate(floors) for n in names}
    return {(a, b): sorted(where) for a, deps in graph.items() for b, where in deps.items()
            if floor[b] <= floor[a]}


def _check_floors(graph, floors, allowed=None) -> dict:
    """What breaks the floors: nodes missing from them or listed but absent, circles, imports that run
    up and are not allowed (empty dict: none)."""
    allowed = allowed or {}
    listed = [n for _, names in floors for n in names]
    bad = {}
    if sorted(listed) != sorted(set(graph)):
        bad["not on a floor"] = sorted(set(graph) - set(listed))
        bad["on a floor, not in the package"] = sorted(set(listed) - set(graph))
        return bad
    if _circles(graph):
        bad["circles"] = _circles(graph)
    up = {k: v for k, v in _runs_up(graph, floors).items() if k not in allowed}
    if up:
        bad["runs up"] = up
    return bad


def test_parts_stand_on_their_floors():
    """The import graph of the top-level parts has no circle, and every import runs down the floors
    (FLOORS), except at most MAX_UP listed in ALLOWED_UP."""
    graph = _node_graph(_part_of)
    assert _check_floors(graph, FLOORS, ALLOWED_UP) == {}
    assert len(ALLOWED_UP) <= MAX_UP
    assert set(ALLOWED_UP) <= set(_runs_up(graph, FLOORS))     # an allowance no longer needed leaves the list
    # the walk is real: known arrows are there, a lazy one (inside a function) among them
    assert "core" in graph["engine"] and "config" in graph["core"] and "world" in graph["core"]
    assert any(w.startswith("datapipe/engine/gate.py") for w in graph["engine"]["core"])   # gate: lazy preflight


def test_config_modules_stand_on_their_floors():
    """No circle inside config/ (Config -> parse -> validate -> ... never back to schema at run time)."""
    graph = _node_graph(_config_module_of)
    assert _check_floors(graph, CONFIG_FLOORS) == {}
    assert {"parse", "validate"} <= set(graph["schema"])        # the Config's methods call down, lazily


def test_the_floor_check_can_fail():
    """A planted import that runs up (io -> engine, as if a writer reported into the run loop), one
    beside its floor (draws -> io) and a part on no floor are each reported."""
    graph = _node_graph(_part_of)
    up = {k: {m: set(w) for m, w in v.items()} for k, v in graph.items()}
    up["io"]["engine"] = {"planted"}
    bad = _check_floors(up, FLOORS)
    assert ("io", "engine") in bad["runs up"] and bad["circles"]
    beside = {k: dict(v) for k, v in graph.items()}
    beside["draws"] = {**beside["draws"], "io": {"planted"}}
    assert list(_check_floors(beside, FLOORS)["runs up"]) == [("draws", "io")]
    assert _check_floors({**graph, "newpart": {}}, FLOORS)["not on a floor"] == ["newpart"]
