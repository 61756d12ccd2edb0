#!/usr/bin/env python3
"""Build DataPipe's Blender extension zip(s) without a Blender binary.

The manifest lives at the repository root, the extension's source is the `datapipe/` package. This
script
  1. downloads the wheels the manifest lists (for the platforms asked for) into ./wheels with
     `pip download --no-deps --only-binary=:all: --python-version 3.11 --platform <the wheel's tags>`
     (skipped for wheels already there),
  2. stages build/extension/ = the datapipe package + blender_manifest.toml (its `platforms` and
     `wheels` narrowed to the platforms asked for) + wheels/,
  3. runs the bpy wheel's `blender_ext.py validate` and `build --split-platforms` into dist/.

Usage: python make/build_extension.py [--platforms linux-x64,windows-x64] [--out dist] [--no-download]
       python make/build_extension.py --stage-only       (stage + validate, no wheels needed)
Prints the built zip paths, one per line, last.
"""
from __future__ import annotations

import argparse
import importlib.util
import re
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MANIFEST = ROOT / "blender_manifest.toml"
PACKAGE = ROOT / "datapipe"
WHEELS = ROOT / "wheels"
STAGE = ROOT / "build" / "extension"
PY_VERSION = "3.11"

_WHEEL_RE = re.compile(r"^(?P<name>[^-]+)-(?P<version>[^-]+)-(?P<py>[^-]+)-(?P<abi>[^-]+)-(?P<plat>[^-]+)\.whl$")


def fail(msg: str) -> None:
    print(f"build_extension: {msg}", file=sys.stderr)
    raise SystemExit(2)


def wheel_platforms(filename: str) -> set[str]:
    """Blender platform names a wheel serves (same mapping as blender_ext.py)."""
    m = _WHEEL_RE.match(filename)
    if not m:
        fail(f"not a wheel file name: {filename}")
    out = set()
    for tag in m["plat"].split("."):
        if tag == "any":
            return {"any"}
        if tag.startswith(("manylinux", "musllinux", "linux")):
            osname = "linux"
        elif tag.startswith("win"):
            osname = "windows"
        elif tag.startswith("macosx"):
            osname = "macos"
        else:
            continue
        if tag.endswith(("x86_64", "amd64")):
            out.add(f"{osname}-x64")
        elif tag.endswith(("arm64", "aarch64")):
            out.add(f"{osname}-arm64")
        elif tag.endswith("universal2"):
            out |= {f"{osname}-x64", f"{osname}-arm64"}
    return out


def read_manifest() -> tuple[str, list[str], list[str]]:
    text = MANIFEST.read_text()
    try:
        import tomllib
    except ImportError:  # pragma: no cover - Python < 3.11
        fail("needs Python 3.11+ (tomllib)")
    data = tomllib.loads(text)
    return text, list(data.get("platforms", [])), list(data.get("wheels", []))


def blender_ext() -> Path:
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        fail("the bpy module is not installed in this Python (pip install bpy==5.0.1, or `make venv`)")
    base = Path(list(spec.submodule_search_locations)[0])
    found = sorted(base.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not found:
        fail(f"blender_ext.py not found under {base}")
    return found[-1]


def download(wheels: list[str]) -> None:
    WHEELS.mkdir(exist_ok=True)
    for rel in wheels:
        name = Path(rel).name
        if (WHEELS / name).is_file():
            continue
        m = _WHEEL_RE.match(name)
        plats = m["plat"].split(".")
        cmd = [sys.executable, "-m", "pip", "download", "--quiet", "--no-deps", "--only-binary=:all:",
               "--python-version", PY_VERSION, "--dest", str(WHEELS)]
        for p in plats:
            cmd += ["--platform", p]
        if m["abi"] != "abi3" and m["abi"] != "none":
            cmd += ["--implementation", "cp", "--abi", m["abi"]]
        cmd.append(f"{m['name']}=={m['version']}")
        print("build_extension: downloading", name, flush=True)
        r = subprocess.run(cmd)
        if r.returncode != 0 or not (WHEELS / name).is_file():
            fail(f"could not download {name} (pip exit {r.returncode}); check the network or put the file "
                 f"into {WHEELS}")


def narrowed_manifest(text: str, platforms: list[str], wheels: list[str]) -> str:
    """The manifest text with `platforms` and `wheels` replaced (everything else byte-identical)."""
    plat_line = "platforms = [" + ", ".join(f'"{p}"' for p in platforms) + "]"
    text, n = re.subn(r"(?m)^platforms\s*=\s*\[[^\]]*\]", plat_line, text)
    if n != 1:
        fail("blender_manifest.toml: expected one `platforms = [...]` line")
    wheel_block = "wheels = [\n" + "".join(f'  "{w}",\n' for w in wheels) + "]"
    text, n = re.subn(r"(?ms)^wheels\s*=\s*\[.*?\]", wheel_block, text)
    if n != 1:
        fail("blender_manifest.toml: expected one `wheels = [...]` list")
    return text


def stage(text: str, wheels: list[str], *, copy_wheels: bool) -> None:
    if STAGE.exists():
        shutil.rmtree(STAGE)
    shutil.copytree(PACKAGE, STAGE, ignore=shutil.ignore_patterns("__pycache__", "*.pyc", "*.tmp"))
    (STAGE / "blender_manifest.toml").write_text(text)
    if copy_wheels:
        (STAGE / "wheels").mkdir()
        for rel in wheels:
            name = Path(rel).name
            try:
                (STAGE / "wheels" / name).hardlink_to(WHEELS / name)
            except OSError:
                shutil.copy2(WHEELS / name, STAGE / "wheels" / name)


def check_package() -> None:
    init = (PACKAGE / "__init__.py").read_text()
    if not re.search(r"(?m)^def register\(", init) or not re.search(r"(?m)^def unregister\(", init):
        fail("datapipe/__init__.py defines no register()/unregister(): Blender could not enable the add-on "
             "(add: def register(): from .ui import register as r; r()  and the same for unregister)")
    m = re.search(r'(?m)^__version__\s*=\s*"([^"]+)"', (PACKAGE / "version.py").read_text())
    ver = re.search(r'(?m)^version\s*=\s*"([^"]+)"', MANIFEST.read_text())
    if not m:
        fail('datapipe/version.py holds no __version__ = "X.Y.Z" line: write the version there')
    if ver and m.group(1) != ver.group(1):
        fail(f"version mismatch: datapipe.__version__ {m.group(1)} vs blender_manifest.toml {ver.group(1)}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--platforms", default="", help="comma-separated Blender platforms (default: all in the manifest)")
    ap.add_argument("--out", default=str(ROOT / "dist"), help="output folder for the zips")
    ap.add_argument("--no-download", action="store_true", help="fail instead of downloading missing wheels")
    ap.add_argument("--stage-only", action="store_true", help="stage and validate without wheels; build nothing")
    args = ap.parse_args(argv)

    text, all_platforms, all_wheels = read_manifest()
    platforms = [p for p in args.platforms.split(",") if p] or all_platforms
    unknown = [p for p in platforms if p not in all_platforms]
    if unknown:
        fail(f"platform(s) {unknown} not in the manifest's platforms {all_platforms}")
    wheels = [w for w in all_wheels if wheel_platforms(Path(w).name) & ({"any"} | set(platforms))]
    for p in platforms:
        if not any(p in wheel_platforms(Path(w).name) or "any" in wheel_platforms(Path(w).name) for w in wheels):
            fail(f"no wheels listed for platform {p}")
    check_package()
    ext = blender_ext()

    if args.stage_only:
        stage(narrowed_manifest(text, platforms, []), [], copy_wheels=False)
    else:
        missing = [w for w in wheels if not (WHEELS / Path(w).name).is_file()]
        if missing and args.no_download:
            fail("missing wheels (run without --no-download): " + ", ".join(Path(w).name for w in missing))
        download(missing)
        stage(narrowed_manifest(text, platforms, wheels), wheels, copy_wheels=True)

    r = subprocess.run([sys.executable, str(ext), "validate", str(STAGE)])
    if r.returncode != 0:
        fail("blender_ext.py validate rejected the staged extension")
    if args.stage_only:
        print(STAGE)
        return 0

    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    before = set(out.glob("*.zip"))
    version = re.search(r'(?m)^version\s*=\s*"([^"]+)"', text).group(1)
    for old in out.glob(f"datapipe-{version}*.zip"):
        old.unlink()
    r = subprocess.run([sys.executable, str(ext), "build", "--source-dir", str(STAGE), "--output-dir", str(out),
                        "--split-platforms"])
    if r.returncode != 0:
        fail("blender_ext.py build failed")
    built = sorted(out.glob(f"datapipe-{version}*.zip"))
    if not built:
        fail(f"no zip appeared in {out}")
    del before
    for z in built:
        print(z)
    return 0


if __name__ == "__main__":
    sys.exit(main())
