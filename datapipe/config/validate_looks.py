"""The rules of what a scene looks like beyond its materials: `scene.textures` (draws/textures.py)
and the environment map of `lighting` (draws/environment.py). Files are looked at (a texture folder
holds a set with a colour map; every environment map's header reads) only with check_files, and
always before any Blender work."""
from __future__ import annotations

import os
from typing import TYPE_CHECKING

from ..text_rules import path_problem
from ..errors import Problem
from .checks import _range_problems
from .limits import TEXTURE_KINDS, TEXTURE_TARGETS

if TYPE_CHECKING:
    from .checks import _Checks
    from .schema import Config


def _choices_problem(path: str, values, choices, *, allow_empty: bool) -> Problem | None:
    if not isinstance(values, list) or not all(isinstance(v, str) for v in values):
        return Problem(path, f"needs a list of names, got {values!r}", f"give a list of {', '.join(choices)}")
    unknown = [v for v in values if v not in choices]
    if unknown:
        return Problem(path, f"unknown value(s) {unknown}", f"use only {', '.join(choices)}")
    if not values and not allow_empty:
        return Problem(path, "is empty", f"give at least one of {', '.join(choices)}")
    return None


def _check_textures(ck: "_Checks", cfg: "Config", check_files: bool) -> None:
    """scene.textures: targets, kinds, ranges, and an image folder that holds texture sets."""
    t, p = cfg.scene.textures, "scene.textures"
    bad = _choices_problem(f"{p}.targets", t.targets, TEXTURE_TARGETS, allow_empty=True)
    if bad is not None:
        ck.problems.append(bad)
        return
    # the ranges even when off: every preset validate() accepts can be shown in the sidebar
    ck.problems += _range_problems(f"{p}.feature_size", t.feature_size, lo_bound=1e-4, hi_bound=10.0, unit=" m")
    ck.problems += _range_problems(f"{p}.contrast", t.contrast, lo_bound=0.0, hi_bound=1.0)
    ck.problems += _range_problems(f"{p}.albedo", t.albedo, lo_bound=0.0, hi_bound=1.0)
    ck.problems += _range_problems(f"{p}.saturation", t.saturation, lo_bound=0.0, hi_bound=1.0)
    if not t.targets:              # off: no kinds, no folder read
        return
    bad = _choices_problem(f"{p}.kinds", t.kinds, TEXTURE_KINDS, allow_empty=False)
    if bad is not None:
        ck.problems.append(bad)
    wants_images = bad is None and "image" in t.kinds
    folder = t.image_folder
    if wants_images and not folder:
        ck.add(f"{p}.image_folder", "kinds has 'image' but no image folder is given",
               "give a folder of texture images (colour/roughness/normal maps by file name), or drop 'image' "
               "from scene.textures.kinds")
    elif folder and not wants_images and bad is None:
        ck.add(f"{p}.image_folder", "is given but kinds has no 'image': its textures would never be drawn",
               "add 'image' to scene.textures.kinds, or clear image_folder")
    elif folder and check_files:
        problem = path_problem(folder)
        if problem is not None:
            ck.add(f"{p}.image_folder", *problem)
        elif not os.path.isdir(folder):
            ck.add(f"{p}.image_folder", f"{folder} is not a folder", "give the folder that holds the texture images")
        else:
            from ..draws.textures import texture_sets, unreadable_maps
            sets = texture_sets(folder)
            bad_maps = unreadable_maps(sets)
            if bad_maps:
                ck.add(f"{p}.image_folder", f"{bad_maps[0]} is named like a texture map but is not an image "
                       f"OpenCV can read ({len(bad_maps)} such file(s))",
                       "replace or remove it (PNG, JPEG, TIFF, EXR, HDR, BMP, TGA are read)")
            elif not sets:
                ck.add(f"{p}.image_folder", f"{folder} holds no texture image with a colour map in its name "
                       "(e.g. wood_Color.png, metal_basecolor.jpg, rock_albedo.png)",
                       "put colour maps there, named with color/albedo/basecolor/diffuse "
                       "(roughness and normal maps beside them are used too)")


def _check_environment(ck: "_Checks", cfg: "Config", check_files: bool) -> None:
    """lighting.environment (a readable .hdr/.exr or a folder of them), its ranges, per_render."""
    li = cfg.lighting
    if li is None:
        return
    p = "lighting"
    if not isinstance(li.per_render, bool):
        ck.add(f"{p}.per_render", f"must be true or false, got {li.per_render!r}", "give true or false")
    ck.problems += _range_problems(f"{p}.environment_strength", li.environment_strength, lo_bound=0.0,
                                   hi_bound=1e4)   # even without a map: the sidebar holds what validate takes
    ck.problems += _range_problems(f"{p}.environment_rotation_deg", li.environment_rotation_deg)
    if not li.environment or not check_files:
        return
    from ..draws.environment import find_maps, header_problem
    f = f"{p}.environment"
    problem = path_problem(li.environment)
    if problem is not None:
        ck.add(f, *problem)
        return
    if not os.path.exists(li.environment):
        ck.add(f, f"{li.environment} does not exist", "give an .hdr/.exr environment map or a folder of them")
        return
    maps = find_maps(li.environment)
    if not maps:
        ck.add(f, f"the folder {li.environment} holds no .hdr or .exr file",
               "put environment maps (.hdr/.exr) there, or give one map's path")
        return
    for m in maps:
        why = header_problem(m)
        if why is not None:
            ck.add(f, f"{why}: not a readable HDR/EXR environment map",
                   "give a Radiance .hdr or an OpenEXR .exr (or remove that file from the folder)")
            return
