"""Per-scene texture draws (`scene.textures`) and the user's texture sets. No bpy (core/textures.py
builds the node set-ups from a draw).

A draw, per target (the bin's walls, the floor, each part instance), is a dict:
- ``kind``: a procedural Blender texture ("noise", "voronoi", "wave", "brick", "checker") or "image";
- ``colors``: two linear RGB colours, the bright one of HSV value `albedo` and saturation
  `saturation` at a uniform hue, the dark one the same times (1 - `contrast`): the contrast is the
  ratio of the two albedos, which is what the fringe modulation sees (B scales with albedo);
- ``feature_size`` (m): the texture's scale is 1 / feature_size in metres of world (bin, floor) or
  object (parts) space, so a texture keeps its size whatever the part's size;
- ``param``: one kind-specific shape parameter in 0..1 (noise detail, Voronoi randomness, wave
  distortion, brick mortar share), and for "image" the set drawn (``set``: {map: path}).

The draws come from `texture_rng(base, scene)` (draws/seeds.py), a stream of their own: turning
textures on changes no pose, light or camera draw. Draw order is fixed: bin then floor on one
stream (before the drop), the part instances in the order the simulation kept them on another.

Texture sets (`image_folder`): image files are grouped by folder and by the name before their map
word; a map word (case-insensitive, separated by '_', '-', '.' or a space) says which map a file is
(the words CC0 PBR sets commonly put in their file names, e.g. Wood051_1K_Color.jpg or
metal_plate_diff_1k.png: an assumption from such names, there is no standard): colour ``color``,
``colour``, ``albedo``, ``basecolor``, ``diffuse``, ``diff``, ``col``; roughness ``roughness``,
``rough``; normal ``normal``, ``nor``, ``nrm``, with ``normalgl``/``nor_gl`` preferred over the
DirectX ``normaldx``/``nor_dx`` (Blender's Normal Map node expects OpenGL's green-up convention; a
DirectX map's green would be inverted). A set needs a colour map; the other maps are optional.
"""
from __future__ import annotations

import colorsys
import os
import re
import stat
from pathlib import Path

import numpy as np

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".exr", ".hdr", ".bmp", ".tga")
MAX_SET_FILES = 10_000           # files looked at in an image folder (a texture library, not a disk)
_MAP_WORDS = {
    "color": ("basecolor", "base_color", "albedo", "diffuse", "colour", "color", "diff", "col"),
    "roughness": ("roughness", "rough"),
    "normal_dx": ("normaldx", "normal_dx", "nor_dx", "nrm_dx"),
    "normal": ("normalgl", "normal_gl", "nor_gl", "nrm_gl", "normal", "nor", "nrm"),
}


def _map_of(stem: str) -> tuple[str, str] | None:
    """(map, set name) of an image file's stem, or None when no map word ends a part of it."""
    low = stem.lower()
    for kind, words in _MAP_WORDS.items():
        for w in words:
            found = list(re.finditer(rf"(?:^|[_\-. ]){re.escape(w)}(?=[_\-. ]|$)", low))
            if found:                  # the last one: "rough_concrete_rough_1k" is set "rough_concrete"
                return kind, stem[:found[-1].start()] or stem
    return None


def _files(folder):
    """(folder, name) of the files under `folder`, sorted, at most MAX_SET_FILES of them."""
    seen = 0
    for root, dirs, files in os.walk(folder):
        dirs.sort()
        for f in sorted(files):
            seen += 1
            if seen > MAX_SET_FILES:
                return
            yield root, f


def texture_sets(folder: str | os.PathLike) -> list[dict]:
    """The texture sets under `folder` (searched to any depth, sorted by path so that the draws
    do not depend on the file system's order): [{"name", "color", "roughness"?, "normal"?}, ...]."""
    groups: dict[tuple[str, str], dict] = {}
    for root, f in _files(folder):
        p = Path(root) / f
        if p.suffix.lower() not in IMAGE_SUFFIXES:
            continue
        found = _map_of(p.stem)
        if found is None:
            continue
        kind, name = found
        g = groups.setdefault((root, name.lower()), {"name": f"{Path(root).name}/{name}"})
        g.setdefault(kind, str(p))
    sets = []
    for key in sorted(groups):
        g = groups[key]
        if "normal" not in g and "normal_dx" in g:
            g["normal"] = g["normal_dx"]
            g["normal_dx_green"] = True            # green flipped when built
        g.pop("normal_dx", None)
        if "color" in g:
            sets.append(g)
    return sets


def _uniform(rng: np.random.Generator, lo_hi) -> float:
    lo, hi = (float(v) for v in lo_hi)
    return lo if hi <= lo else float(rng.uniform(lo, hi))


def draw_one(tex, rng: np.random.Generator, sets: list[dict]) -> dict:
    """One target's texture from `tex` (a `config.TexturesConfig`). Fixed draw order: kind, hue,
    saturation, albedo, contrast, feature size, parameter, set."""
    kinds = list(tex.kinds)
    kind = kinds[int(rng.integers(0, len(kinds)))]
    hue = float(rng.uniform())
    sat = _uniform(rng, tex.saturation)
    value = _uniform(rng, tex.albedo)
    contrast = _uniform(rng, tex.contrast)
    bright = list(colorsys.hsv_to_rgb(hue, sat, value))
    dark = [c * (1.0 - contrast) for c in bright]
    d = {"kind": kind, "colors": [bright, dark], "contrast": contrast,
         "feature_size": _uniform(rng, tex.feature_size), "param": float(rng.uniform())}
    if kind == "image":
        s = sets[int(rng.integers(0, len(sets)))]
        d["set"] = {k: v for k, v in s.items()}
    return d


def draw_static(tex, rng: np.random.Generator, sets: list[dict] | None = None) -> dict:
    """One scene's bin (walls) and floor textures, for those in `tex.targets`: {"bin": draw,
    "floor": draw}; {} when neither is a target. Drawn before the drop (`texture_rng(.., STATIC)`)."""
    return {t: draw_one(tex, rng, sets or []) for t in ("bin", "floor") if t in tex.targets}


def draw_parts(tex, rng: np.random.Generator, n_parts: int, sets: list[dict] | None = None) -> list[dict]:
    """One texture per part instance (in the order the simulation kept them) when "parts" is a
    target, else []. Drawn after the drop (`texture_rng(.., PARTS)`), its number known."""
    if "parts" not in tex.targets:
        return []
    return [draw_one(tex, rng, sets or []) for _ in range(int(n_parts))]


def unreadable_maps(sets: list[dict]) -> list[str]:
    """The maps of `sets` whose first bytes no image decoder of OpenCV recognises (cv2.haveImageReader
    reads the signature only): a file named like a map that is not an image."""
    import cv2

    def readable(path: str) -> bool:           # regular files only: a FIFO would block the read
        try:
            return stat.S_ISREG(os.stat(path).st_mode) and bool(cv2.haveImageReader(path))
        except OSError:
            return False
    return [s[k] for s in sets for k in ("color", "roughness", "normal") if k in s and not readable(s[k])]


def record(draw: dict) -> dict:
    """What scene.json records of a draw: the kind, colours, contrast, size, parameter and the set's name."""
    rec = {k: v for k, v in draw.items() if k != "set"}
    if "set" in draw:
        rec["set"] = draw["set"]["name"]
    return rec
