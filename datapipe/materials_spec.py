"""The material spec (no bpy): surface materials of the parts (`objects[i].material`) and of the
bin (`scene.bin_material`).

A material is given as
- ``"file"`` (default): what the mesh file carries (parts) or the built-in grey bin material
  (0.5 grey, roughness 0.6); no material nodes are built;
- a preset name (PRESETS below);
- a dict of Principled BSDF values: ``base_color`` ([r, g, b] linear, 0..1), ``metallic`` (0..1),
  ``roughness`` (0..1), ``ior`` (>= 1) or ``specular`` (0..1, Blender's Specular IOR Level),
  ``anisotropic`` (0..1), ``variation`` (0..1: a noise texture varies roughness and base colour by
  up to this fraction, ~1 cm features), plus ``name`` (what the annotations call it);
- a list of preset names / dicts (parts only): each instance draws one from the scene seed, on a
  random stream of its own (poses do not change when a list is given).

The RGB and the fringe renders see the same material: they are view layers of one scene.

Preset values (linear). Metals: base colour = specular reflectance at normal incidence (F0);
dielectrics: base colour = diffuse albedo, IOR 1.5 (4% reflectance at normal incidence, the
common-dielectric value; PMMA 1.49, ABS ~1.54, natural rubber ~1.52). Albedo/F0 from Filament's
"Material Properties" reference (google.github.io/filament, notes/material_properties): iron sRGB
(192, 189, 186) -> linear (0.53, 0.51, 0.49), aluminium (244, 245, 245) -> (0.91, 0.92, 0.92),
rubber (53, 53, 53) -> 0.036; dielectric albedo range sRGB 10..240 (linear 0.003..0.87).
Roughness values are chosen within the ranges those references show for the finish (machined
and brushed metal glossy but not mirror-like, matte plastic and rubber rough), not measured.

The Blender side (building the Principled BSDF) is core/materials.py; config validation, the
per-scene draws and the add-on's text fields use this module.
"""
from __future__ import annotations

import math

import numpy as np

from .text_rules import name_problem, short

FILE = "file"
PRESETS: dict[str, dict] = {
    "matte_plastic": {"base_color": [0.5, 0.5, 0.5], "metallic": 0.0, "roughness": 0.6, "ior": 1.5},
    "dark_plastic": {"base_color": [0.04, 0.04, 0.04], "metallic": 0.0, "roughness": 0.4, "ior": 1.5},
    "painted": {"base_color": [0.35, 0.35, 0.35], "metallic": 0.0, "roughness": 0.3, "ior": 1.5},
    "steel": {"base_color": [0.53, 0.51, 0.49], "metallic": 1.0, "roughness": 0.25},
    "aluminium": {"base_color": [0.91, 0.92, 0.92], "metallic": 1.0, "roughness": 0.35, "anisotropic": 0.5},
    "rubber": {"base_color": [0.036, 0.036, 0.036], "metallic": 0.0, "roughness": 0.85, "ior": 1.52},
}
NAMES = (FILE, *PRESETS)
KEYS = {"name", "base_color", "metallic", "roughness", "ior", "specular", "anisotropic", "variation"}
MATERIAL_PREFIX = "datapipe_mat_"
STREAM = 0x6D617472              # "matr": the material draw's own random stream of the scene seed
BIN_STREAM = 0x62696E            # "bin": the bin's draw within it (object entries use 0, 1, ...)


def _number(v) -> bool:
    """A finite number (an int beyond float range, e.g. 10**400, is not: math.isfinite overflows)."""
    if not isinstance(v, (int, float)) or isinstance(v, bool):
        return False
    try:
        return math.isfinite(v)
    except OverflowError:
        return False


def _unit(v) -> bool:
    return _number(v) and 0 <= v <= 1


def _dict_problem(d: dict) -> tuple[str, str] | None:
    unknown = set(d) - KEYS
    if unknown:
        return f"unknown key(s) {sorted(unknown)}", f"use only {sorted(KEYS)}"
    if "base_color" in d:
        c = d["base_color"]
        if not (isinstance(c, (list, tuple)) and len(c) in (3, 4) and all(_unit(x) for x in c)):
            shown = "[" + ", ".join(short(x) for x in c) + "]" if isinstance(c, (list, tuple)) else short(c)
            return f"base_color must be 3 numbers in 0..1 (linear RGB), got {shown}", "e.g. [0.5, 0.5, 0.5]"
    for k in ("metallic", "roughness", "specular", "anisotropic", "variation"):
        if k in d and not _unit(d[k]):
            return f"{k} must be a number in 0..1, got {short(d[k])}", f"give {k} between 0 and 1"
    if "ior" in d:
        v = d["ior"]
        if not (_number(v) and 1 <= v <= 4):
            return f"ior must be a number in 1..4, got {short(v)}", "e.g. 1.5 for plastics"
    if "name" in d:
        if not isinstance(d["name"], str):
            return f"name must be a string, got {short(d['name'])}", "give a short name for the annotations"
        problem = name_problem(d["name"], prefix=MATERIAL_PREFIX, suffix="_00000000")   # see build()
        if problem is not None:
            return f"name {problem[0]}", problem[1]
    return None


def material_problem(value, *, allow_list: bool = True) -> tuple[str, str] | None:
    """(what is wrong, the fix) unless `value` is a valid material (see the module doc)."""
    fix = f"give one of {', '.join(NAMES)}, a dict of Principled BSDF values" + \
          (", or a list of those" if allow_list else "")
    if isinstance(value, str):
        return None if value in NAMES else (f"unknown material {short(value)}", fix)
    if isinstance(value, dict):
        return _dict_problem(value)
    if isinstance(value, list) and allow_list:
        if not value:
            return "empty list", fix
        for i, v in enumerate(value):
            p = material_problem(v, allow_list=False)
            if p is not None:
                return f"item {i}: {p[0]}", p[1]
        return None
    return f"expected a material name, dict{' or list' if allow_list else ''}, got {type(value).__name__}", fix


def label(spec) -> str:
    """What the annotations call a material: its preset name, a dict's 'name', else 'custom'."""
    if isinstance(spec, str):
        return spec
    return str(spec.get("name", "custom"))


def values(spec) -> dict:
    """The Principled BSDF values of a preset name or dict (defaults filled in)."""
    d = dict(PRESETS[spec]) if isinstance(spec, str) else dict(spec)
    d.setdefault("base_color", [0.8, 0.8, 0.8])
    d.setdefault("metallic", 0.0)
    d.setdefault("roughness", 0.5)
    d.setdefault("anisotropic", 0.0)
    d.setdefault("variation", 0.0)
    return d


def draw(value, n: int, scene_seed: int, entry_index: int = 0) -> list:
    """The material spec of each of `n` instances of one object entry: `value` itself, or for a
    list one item per instance from the scene seed's material stream (independent of the pose
    stream, so giving a list changes no pose)."""
    if not isinstance(value, list):
        return [value] * n
    rng = np.random.default_rng(np.random.SeedSequence([int(scene_seed), STREAM, int(entry_index)]))
    return [value[int(k)] for k in rng.integers(0, len(value), size=n)]


def draw_bin(value, scene_seed: int):
    """The bin's material spec for one scene: `value` itself, or for a list one item drawn from the
    scene seed on a stream of its own (apart from the parts' material and pose streams)."""
    if not isinstance(value, list):
        return value
    rng = np.random.default_rng(np.random.SeedSequence([int(scene_seed), STREAM, BIN_STREAM]))
    return value[int(rng.integers(0, len(value)))]


# ------------------------------------------------------------------------------------------------
# text form (the add-on's material fields)

def parse_text(text: str):
    """'steel' -> 'steel'; 'steel, aluminium' -> ['steel', 'aluminium']; JSON ('{...}' / '[...]')
    -> a dict / list. ValueError for malformed JSON (names are checked by Config.validate)."""
    import json

    t = text.strip()
    if t.startswith("{") or t.startswith("["):
        try:
            return json.loads(t)
        except json.JSONDecodeError as e:
            raise ValueError(f"not valid JSON: {e}") from None
    names = [n.strip() for n in t.split(",") if n.strip()]
    if not names:
        return FILE
    return names if len(names) > 1 else names[0]


def format_text(value) -> str:
    import json

    if isinstance(value, str):
        return value
    if isinstance(value, list) and all(isinstance(v, str) for v in value):
        return ", ".join(value)
    return json.dumps(value)
