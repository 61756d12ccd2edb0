"""The Blender extension carries every module the package imports outside Blender's own bundle.

The list is derived, not written down: every `import x` / `from x import ...` in datapipe/**/*.py
(at any depth: lazy imports inside functions count), minus the standard library, datapipe itself,
Blender's modules and what Blender's Python ships with (numpy), minus the optional extras (Ray).
Each remaining module must map to a PyPI distribution whose wheels blender_manifest.toml lists for
every platform it targets, except the gaps named here (a gap must be refused with a clear error).
No bpy: the manifest and the sources are read as text; wheel tags are mapped to Blender platforms
by make/build_extension.py, the script `make extension` runs.
"""
import ast
import importlib.util
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "datapipe"

BLENDER_MODULES = {"bpy", "mathutils", "bmesh", "bpy_extras", "addon_utils", "bl_math", "gpu", "gpu_extras",
                   "blf", "aud", "idprop", "imbuf", "freestyle", "bl_ui", "bl_operators", "rna_prop_ui"}
BLENDER_BUNDLED = {"numpy"}          # Blender 4.2+ ship numpy in their Python (bpy's wheel requires numpy<2)
OPTIONAL = {"ray": "datapipe.engine.distributed (--ray, the `ray` extra)"}     # imported lazily, refused without
MODULE_TO_DIST = {"cv2": "opencv_contrib_python_headless", "scipy": "scipy", "OpenEXR": "openexr",
                  "coacd": "coacd"}   # wheel file names: the distribution with '-' as '_', lower case
# (distribution, Blender platform) without a wheel on PyPI, and what the user gets there instead
KNOWN_GAPS = {("coacd", "macos-x64"): "collision.missing_coacd: objects[i].collision_shape refused "
                                      "with the fix (pip install coacd, or CONVEX_HULL)"}


def _build_script():
    spec = importlib.util.spec_from_file_location("build_extension", ROOT / "make" / "build_extension.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def imported_top_modules() -> dict[str, set[str]]:
    """Top-level module name -> files of the package importing it (absolute imports only)."""
    found: dict[str, set[str]] = {}
    for path in sorted(PACKAGE.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            names = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            for name in names:
                found.setdefault(name.split(".")[0], set()).add(str(path.relative_to(ROOT)))
    return found


def third_party_modules() -> dict[str, set[str]]:
    return {m: files for m, files in imported_top_modules().items()
            if m not in sys.stdlib_module_names and m != "datapipe" and m not in BLENDER_MODULES
            and m not in BLENDER_BUNDLED and m not in OPTIONAL}


def manifest_wheels() -> tuple[list[str], dict[str, set[str]]]:
    """(the manifest's platforms, distribution -> Blender platforms its listed wheels serve)."""
    data = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    build = _build_script()
    served: dict[str, set[str]] = {}
    for rel in data["wheels"]:
        name = Path(rel).name
        served.setdefault(name.split("-")[0].lower(), set()).update(build.wheel_platforms(name))
    return list(data["platforms"]), served


def test_the_import_walk_sees_what_the_package_imports():
    """The derivation itself: it finds the known imports, lazy ones inside functions included."""
    found = imported_top_modules()
    assert "datapipe/io/exr.py" in found["OpenEXR"] and "datapipe/collision.py" in found["coacd"]
    assert {"bpy", "mathutils", "numpy", "cv2", "scipy", "ray", "json"} <= set(found)


def test_every_third_party_import_has_wheels_for_every_platform():
    platforms, served = manifest_wheels()
    problems = []
    for module, files in sorted(third_party_modules().items()):
        dist = MODULE_TO_DIST.get(module)
        if dist is None:
            problems.append(f"{module} (imported by {sorted(files)}) is not mapped to a distribution: add it to "
                            "MODULE_TO_DIST here and its wheels to blender_manifest.toml (or, if Blender ships "
                            "it or it is optional, to BLENDER_BUNDLED / OPTIONAL with the reason)")
            continue
        for plat in platforms:
            if plat in served.get(dist, set()) or "any" in served.get(dist, set()):
                assert (dist, plat) not in KNOWN_GAPS, f"{dist} now has a {plat} wheel: drop the known gap"
            elif (dist, plat) not in KNOWN_GAPS:
                problems.append(f"{module}: blender_manifest.toml lists no {dist} wheel for {plat}")
    assert not problems, "\n".join(problems)


def test_every_listed_wheel_is_needed():
    """No wheel for a module the package no longer imports (it would only grow every zip)."""
    _, served = manifest_wheels()
    needed = {MODULE_TO_DIST[m] for m in third_party_modules() if m in MODULE_TO_DIST}
    assert set(served) == needed, (sorted(served), sorted(needed))


def test_optional_modules_are_imported_lazily_and_refused_clearly():
    """ray is only imported inside a function that turns ImportError into DataPipe's own error."""
    for module in OPTIONAL:
        for rel in imported_top_modules().get(module, ()):
            tree = ast.parse((ROOT / rel).read_text())
            top = [n for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))
                   and any((a.name if isinstance(n, ast.Import) else n.module or "").split(".")[0] == module
                           for a in (n.names if isinstance(n, ast.Import) else [n]))]
            assert not top, f"{rel} imports the optional {module} at module level"
            guarded = [h for n in ast.walk(tree) if isinstance(n, ast.Try) for h in n.handlers
                       if isinstance(h.type, ast.Name) and h.type.id in ("ImportError", "ModuleNotFoundError")
                       and any(isinstance(x, (ast.Import, ast.ImportFrom)) for s in n.body for x in ast.walk(s))]
            assert guarded, f"{rel}: the import of {module} is not guarded by `except ImportError`"
