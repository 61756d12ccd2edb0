"""JSON presets: built-in ones ship read-only in `datapipe/presets/`; user ones live in the extension's
user folder (`bpy.utils.extension_path_user(<package>, path="presets")`), or, when DataPipe runs as a
plain package (`import datapipe`, the bpy module), in `<Blender user config>/datapipe/presets`.
`DATAPIPE_USER_PRESETS` (environment) overrides the user folder (tests, shared studio presets).

A preset file is exactly what the headless runner reads (`python -m datapipe run PRESET.json`).
"""
from __future__ import annotations

import os
import re
from pathlib import Path

import bpy

from .. import config as C
from ..errors import DataPipeError

ADDON_PACKAGE = __package__.rpartition(".")[0]      # "datapipe" or "bl_ext.<repo>.datapipe"
_NAME_RE = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_. -]*$")


def builtin_dir() -> Path:
    return C.presets_dir()


def user_dir(create: bool = True) -> Path:
    env = os.environ.get("DATAPIPE_USER_PRESETS")
    if env:
        path = Path(env)
    else:
        try:
            path = Path(bpy.utils.extension_path_user(ADDON_PACKAGE, path="presets", create=create))
        except (ValueError, KeyError, RuntimeError, AttributeError):   # not installed as an extension
            path = Path(bpy.utils.user_resource("CONFIG", path="datapipe")) / "presets"
    if create:
        path.mkdir(parents=True, exist_ok=True)
    return path


def builtin_presets() -> dict[str, Path]:
    return {p.stem: p for p in sorted(builtin_dir().glob("*.json"))}


def user_presets() -> dict[str, Path]:
    d = user_dir(create=False)
    return {p.stem: p for p in sorted(d.glob("*.json"))} if d.is_dir() else {}


def is_builtin(path: str | os.PathLike) -> bool:
    """True for files inside the package's presets folder (read-only: never overwritten)."""
    try:
        return Path(path).resolve().parent == builtin_dir().resolve()
    except OSError:
        return False


# The enum items must stay referenced while Blender shows them (a known bpy pitfall with
# dynamic EnumProperty items), so they live in a module-level list.
_ENUM_CACHE: list[tuple[str, str, str]] = []


def enum_items() -> list[tuple[str, str, str]]:
    items = [(f"builtin:{name}", name, f"Built-in preset (read-only): {path}")
             for name, path in builtin_presets().items()]
    try:
        items += [(f"user:{name}", f"{name} (user)", f"User preset: {path}") for name, path in user_presets().items()]
    except OSError:
        pass
    if not items:
        items = [("NONE", "No presets", "No presets found")]
    _ENUM_CACHE[:] = items
    return _ENUM_CACHE


def resolve(identifier: str) -> Path:
    """'builtin:default' / 'user:mine' / a plain name (user first, then built-in) -> file path."""
    kind, _, name = identifier.rpartition(":")
    table = {"builtin": builtin_presets(), "user": user_presets()}
    if kind in table and name in table[kind]:
        return table[kind][name]
    if not kind:
        for t in (user_presets(), builtin_presets()):
            if name in t:
                return t[name]
    known = ", ".join(list(builtin_presets()) + list(user_presets()))
    raise DataPipeError(f"preset: no preset named {identifier!r} (fix: choose one of {known})")


def save_path_for(name: str = "", filepath: str = "") -> Path:
    """Where a save goes: `filepath` if given, else `<user presets>/<name>.json`. Built-ins are refused."""
    if filepath:
        path = Path(bpy.path.abspath(filepath))
        if path.suffix.lower() != ".json":
            path = path.with_suffix(".json")
    else:
        name = name.strip()
        if name.lower().endswith(".json"):
            name = name[:-5]
        if not _NAME_RE.match(name or ""):
            raise DataPipeError(f"preset name: {name!r} is not a usable file name (fix: use letters, digits, "
                                "'_', '-', '.' or spaces)")
        if name in builtin_presets():
            raise DataPipeError(f"preset name: {name!r} is a built-in preset, which is read-only (fix: save "
                                "under another name)")
        path = user_dir() / f"{name}.json"
    if is_builtin(path):
        raise DataPipeError(f"preset: {path} is a built-in preset, which is read-only (fix: save under another "
                            "name or folder)")
    return path


def save(cfg: C.Config, path: Path) -> Path:
    C.save(cfg, path)
    return path


def load(path: str | os.PathLike) -> C.Config:
    return C.load(path)
