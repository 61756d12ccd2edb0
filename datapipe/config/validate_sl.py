"""The field rules of the projector and structured_light sections (validate.py runs them). The
rules of period sets, exposure and sensor presets live with the sl/ code that uses them."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

from ..text_rules import short as _short
from .checks import _Checks, _check_field_of_view, _split_fix
from .limits import (AMBIENT_MODES, FRINGE_MODES, MAX_FRINGE_BYTES, MAX_PERIODS, MAX_RESOLUTION, MAX_SL_SAMPLES,
                     MAX_STEPS, MIN_FRINGE_CAMERA_PX, REFLECTION_FILTERS, UNWRAP_METHODS)
from .plan import fringe_memory_bytes, fringe_period_camera_px

if TYPE_CHECKING:                 # annotations only: Config's methods call the rules, not the other way
    from .schema import Config, StructuredLightConfig


def _check_projector(ck: _Checks, cfg: Config, check_files: bool) -> None:
    if not cfg.structured_light.enabled:
        return
    pr = cfg.projector
    ck.positive("projector.focal_length", pr.focal_length)
    ck.positive("projector.sensor_width", pr.sensor_width)
    ck.resolution("projector.resolution", pr.resolution)
    ck.vector("projector.location", pr.location, 3)
    if len(pr.rotation) not in (3, 4):
        ck.add("projector.rotation", f"needs 3 (XYZ Euler, rad) or 4 (quaternion wxyz) numbers, got "
               f"{len(pr.rotation)}", "give [rx, ry, rz] or [w, x, y, z]")
    elif len(pr.rotation) == 4 and math.sqrt(sum(q * q for q in pr.rotation)) < 1e-6:
        ck.add("projector.rotation", "zero quaternion", "give a unit quaternion (w, x, y, z)")
    ck.positive("projector.power", pr.power)
    _check_field_of_view(ck, "projector", pr.focal_length, pr.sensor_width, "DMD throws", "",
                         "give the focal length of a real projector lens (8-50 mm)")


def _check_structured_light(ck: _Checks, cfg: Config, check_files: bool) -> None:
    sl, pr = cfg.structured_light, cfg.projector
    if not sl.enabled:
        return
    if sl.steps < 3:
        ck.add("structured_light.steps", f"must be >= 3, got {sl.steps}",
               "use 3 or more phase steps (4 or more avoids gamma errors)")
    ck.at_most("structured_light.steps", sl.steps, MAX_STEPS, "more steps than lower the phase noise usefully")
    if len(sl.periods) > MAX_PERIODS:
        ck.add("structured_light.periods", f"{len(sl.periods)} frequencies (more than {MAX_PERIODS})",
               "three frequencies unwrap any useful range, e.g. [1, 8, 64]")
    else:
        _check_sl_periods(sl, pr, ck.add)
    ck.choice("structured_light.unwrap", sl.unwrap, UNWRAP_METHODS)
    ck.choice("structured_light.fringe_mode", sl.fringe_mode, FRINGE_MODES)
    ck.choice("structured_light.reflection_filter", sl.reflection_filter, REFLECTION_FILTERS)
    ck.choice("structured_light.ambient", sl.ambient, AMBIENT_MODES)
    if sl.reflection_filter == "global" and sl.fringe_mode == "fast":
        ck.add("structured_light.reflection_filter", "'global' checks a path-traced row code, and fast mode "
               "synthesises the patterns (no mirrored light to find)", "set structured_light.fringe_mode to "
               "'quadrature', 'render' or 'auto', or reflection_filter to 'local'")
    if sl.fringe_mode == "quadrature" and sl.projector_gamma != 1.0:
        ck.add("structured_light.fringe_mode", f"'quadrature' mixes every phase step from a cos and a sin image, "
               f"which a projector gamma ({sl.projector_gamma!r}) makes non-linear",
               "set structured_light.fringe_mode to 'render' or 'auto', or projector_gamma to 1.0")
    if not (0.2 <= sl.projector_gamma <= 5.0):
        ck.add("structured_light.projector_gamma", f"must be a number in [0.2, 5], got {sl.projector_gamma!r}",
               "use 1.0 for a linear projector, ~2.2 for a typical DLP/LCD response")
    from ..sl.sensor import PRESETS
    if sl.sensor not in PRESETS:
        ck.add("structured_light.sensor", f"unknown sensor preset {sl.sensor!r}", f"use one of {sorted(PRESETS)}")
    ck.int_range("structured_light.samples", sl.samples, 1, MAX_SL_SAMPLES, "samples")
    _check_exposure(sl, ck.add)
    _check_fringe_memory(ck, cfg)
    _check_fringe_size(ck, cfg)


def _check_sl_periods(sl, pr, add) -> None:
    """structured_light.periods: what datapipe.sl.plan_unwrap decodes (hierarchical, heterodyne,
    number-theoretic sets such as [13, 7] or [9, 10, 11]) with >= 3 projector px per fringe."""
    if not sl.periods:
        add("structured_light.periods", "empty", "give fringe periods, e.g. [1, 8, 64]")
        return
    if any(k < 1 for k in sl.periods):
        add("structured_light.periods", f"periods must be >= 1, got {sl.periods}", "give positive periods")
        return
    # >= 3 projector px per fringe: the real limit on any period (a wider projector than
    # MAX_RESOLUTION is refused anyway), checked before the unwrapping maths sees the numbers
    width = pr.resolution[0] if len(pr.resolution) == 2 and 1 <= pr.resolution[0] <= MAX_RESOLUTION \
        else MAX_RESOLUTION
    if max(sl.periods) * 3 > width:
        add("structured_light.periods", f"{_short(max(sl.periods))} periods across {width} px leave fewer than 3 "
            "px per fringe", f"give at most {width // 3} periods (the finest fringe), or raise the projector width")
        return
    if sl.unwrap in UNWRAP_METHODS:
        from ..sl import plan_unwrap      # pure numpy; the decoder owns the rules for period sets
        try:
            plan_unwrap(sl.periods, sl.unwrap)
        except ValueError as e:
            msg, fix = _split_fix(str(e))
            add("structured_light.periods", f"cannot be unwrapped: {msg}", fix or "use a set the message "
                "suggests, e.g. [1, 8, 64] (hierarchical), [70, 64, 59] or [13, 7] (number-theoretic)")


def _check_exposure(sl: "StructuredLightConfig", add) -> None:
    """structured_light.exposure (number > 0 or "auto") and .hdr (distinct factors > 0)."""
    from ..sl.exposure import exposure_problem, hdr_problem   # the rules live with the code using them
    for path, problem in (("structured_light.exposure", exposure_problem(sl.exposure)),
                          ("structured_light.hdr", hdr_problem(sl.hdr))):
        if problem is not None:
            add(path, *problem)


def _check_fringe_memory(ck: _Checks, cfg: Config) -> None:
    if ck.has("structured_light") or ck.has("projector.resolution") or ck.has("camera.resolution"):
        return
    need = fringe_memory_bytes(cfg)
    if need > MAX_FRINGE_BYTES:
        ck.add("structured_light.steps", f"{len(cfg.structured_light.periods)} frequencies x {cfg.structured_light.steps} "
               f"steps need about {need / 2**30:.1f} GiB for the fringe stack (limit "
               f"{MAX_FRINGE_BYTES / 2**30:.0f} GiB)", "use fewer steps or frequencies, or a smaller projector or "
               "camera resolution (the row code of reflection_filter 'global'/'auto' and hdr add to it)")


def _check_fringe_size(ck: _Checks, cfg: Config) -> None:
    if any(ck.has(p) for p in ("structured_light.periods", "projector", "camera", "scene.drop_zone_loc")) or \
            (cfg.camera.sampler.kind == "bin_view" and len(cfg.camera.sampler.distance) != 2):
        return
    px = fringe_period_camera_px(cfg)
    if px < MIN_FRINGE_CAMERA_PX:
        ck.add("structured_light.periods", f"the finest fringe ({max(cfg.structured_light.periods)} periods) is "
               f"about {px:.2f} camera pixels wide at the working distance (need >= {MIN_FRINGE_CAMERA_PX:g}: the "
               "camera cannot resolve it and the depth map would be empty)",
               "lower the finest period count, raise camera.resolution or camera.focal_length, or raise "
               "projector.focal_length")
