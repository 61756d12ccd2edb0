"""The ONE place that maps `Scene.datapipe` (the sidebar's PropertyGroup tree) to and from a `Config`.

Fields map by name, section by section; the few that differ in shape are listed in `_SPECIAL`
(periods and HDR factors as text, exposure as an auto switch + a number, output/format sets, the
optional blend file, scene.picks as a switch + flat fields, the projector's Euler/quaternion rotation); `camera.sampler` is a sub-group
(`_NESTED`); the optional `lighting` section is the group `lighting` with its `enabled` switch
(off = no section); the top-level `device` and `binning` are the root's `device` (NONE = no device)
and `binning`, and choosing a device fills the camera, projector and structured-light groups
(`fill_device`). Floats come back from Blender as float32; they are written as the shortest
decimal that round-trips in float32 (0.06, not 0.05999999865889549), so a preset saved from the
sidebar reads exactly like one written by hand, and save -> load -> save is a fixed point.
"""
from __future__ import annotations

import dataclasses
import json
import math
import os
import typing

import bpy
import numpy as np

from .. import config as C
from ..errors import ConfigError, Problem

INT_MAX = 2**31 - 1          # Blender's IntProperty is a signed 32-bit integer

SECTIONS = ("scene", "camera", "projector", "structured_light", "render", "simulation", "output")
_COLLECTIONS = {("camera", "poses")}          # handled with the object list
_NESTED = {("camera", "sampler"): C.CameraSamplerConfig,    # a sub-group: fields map by name again
           ("scene", "textures"): C.TexturesConfig}


def parse_periods(text: str) -> list[int]:
    """'8, 7' -> [8, 7]. Raises ValueError for anything but a non-empty list of integers >= 1."""
    tokens = [t for t in text.replace(",", " ").replace(";", " ").replace("[", " ").replace("]", " ").split()]
    if not tokens:
        raise ValueError("no periods given")
    values = [int(t) for t in tokens]
    if any(v < 1 for v in values):
        raise ValueError("periods must be >= 1")
    return values


def format_periods(values) -> str:
    return ", ".join(str(int(v)) for v in values)


def parse_factors(text: str) -> list[float] | str:
    """'1, 4, 16' -> [1.0, 4.0, 16.0]; '' -> [] (one exposure); 'auto' -> 'auto'. ValueError unless
    numbers > 0."""
    if text.strip().lower() == "auto":
        return "auto"
    tokens = [t for t in text.replace(",", " ").replace(";", " ").replace("[", " ").replace("]", " ").split()]
    values = [float(t) for t in tokens]
    if any(not (math.isfinite(v) and v > 0) for v in values):
        raise ValueError("factors must be numbers > 0")
    return values


def format_factors(values) -> str:
    if values == "auto":
        return "auto"
    return ", ".join(f"{float(v):g}" for v in values)


def f32(value: float) -> float:
    """A float as Blender stores it (float32), spelled as the shortest decimal that round-trips."""
    return float(str(np.float32(value)))


def _abspath(path: str) -> str:
    """Blender-relative '//' paths become absolute (the headless runner has no .blend to resolve them)."""
    if path.startswith("//") and bpy.data.filepath:
        return os.path.normpath(bpy.path.abspath(path))
    return path


# ------------------------------------------------------------------------------------------------
# fields whose property differs in shape: (props -> config value, config value -> [(prop, value)])

def _rot_get(grp):
    if grp.rotation_mode == "QUATERNION":
        return [f32(v) for v in grp.rotation_quaternion]
    return [f32(v) for v in grp.rotation_euler]


def _rot_set(value):
    if len(value) == 4:
        return [("rotation_mode", "QUATERNION"), ("rotation_quaternion", tuple(value))]
    if len(value) == 3:
        return [("rotation_mode", "XYZ"), ("rotation_euler", tuple(value))]
    raise ValueError(f"needs 3 (XYZ Euler) or 4 (quaternion wxyz) numbers, got {len(value)}")


def _ordered(options):
    return lambda grp, name: [k for k in options if k in getattr(grp, name)]


_SPECIAL = {
    ("scene", "blend_file"): (lambda grp, name: _abspath(grp.blend_file) or None,
                              lambda value: [("blend_file", value or "")]),
    ("scene", "fill"): (lambda grp, name: [f32(v) for v in grp.fill] if grp.use_fill else None,
                        lambda value: [("use_fill", False)] if value is None
                        else [("use_fill", True), ("fill", tuple(value))]),
    ("scene", "picks"): (lambda grp, name: _picks_get(grp), lambda value: _picks_set(value)),
    ("projector", "rotation"): (lambda grp, name: _rot_get(grp), _rot_set),
    # a calibration's fields (docs/CALIBRATION.md): null <-> the use_ switch off
    ("camera", "intrinsics"): (lambda grp, name: _optional_get(grp, name),
                               lambda value: _optional_set("intrinsics", value)),
    ("camera", "distortion"): (lambda grp, name: _optional_get(grp, name),
                               lambda value: _optional_set("distortion", value)),
    ("projector", "intrinsics"): (lambda grp, name: _optional_get(grp, name),
                                  lambda value: _optional_set("intrinsics", value)),
    ("structured_light", "periods"): (lambda grp, name: parse_periods(grp.periods),
                                      lambda value: [("periods", format_periods(value))]),
    ("structured_light", "exposure"): (lambda grp, name: "auto" if grp.auto_exposure else f32(grp.exposure),
                                       lambda value: [("auto_exposure", True)] if value == "auto"
                                       else [("auto_exposure", False), ("exposure", value)]),
    ("structured_light", "hdr"): (lambda grp, name: parse_factors(grp.hdr),
                                  lambda value: [("hdr", format_factors(value))]),
    ("scene", "bin_material"): (lambda grp, name: _material_get(grp, name),
                                lambda value: [("bin_material", _material_set(value))]),
    ("objects", "material"): (lambda grp, name: _material_get(grp, name),
                              lambda value: [("material", _material_set(value))]),
    # the sidebar's Source choice: a mesh file or a BOP models folder (io/bop_models.py)
    ("objects", "filepath"): (lambda grp, name: _abspath(grp.filepath) if grp.source == "FILE" else "",
                              lambda value: [("filepath", value)]),
    ("objects", "bop_models"): (lambda grp, name: _abspath(grp.bop_models) if grp.source == "BOP" else "",
                                lambda value: [("bop_models", value), ("source", "BOP" if value else "FILE")]),
    ("objects", "bop_obj_ids"): (lambda grp, name: _ids_get(grp) if grp.source == "BOP" else [],
                                 lambda value: [("bop_obj_ids", ", ".join(str(int(i)) for i in value))]),
    ("objects", "shape"): (lambda grp, name: _json_or_text(grp.shape) if grp.source == "SHAPE" else None,
                           lambda value: [] if value is None else [("shape", value if isinstance(value, str)
                                                                    else json.dumps(value)), ("source", "SHAPE")]),
    ("objects", "symmetries"): (lambda grp, name: _json_or_text(grp.symmetries),
                                lambda value: [("symmetries", value if isinstance(value, str)
                                                else json.dumps(value))]),
    ("render", "outputs"): (_ordered(C.OUTPUT_KINDS), lambda value: [("outputs", set(value))]),
    ("output", "formats"): (_ordered(C.FORMATS), lambda value: [("formats", set(value))]),
    ("textures", "targets"): (_ordered(C.TEXTURE_TARGETS), lambda value: [("targets", set(value))]),
    ("textures", "kinds"): (_ordered(C.TEXTURE_KINDS), lambda value: [("kinds", set(value))]),
    ("textures", "image_folder"): (lambda grp, name: _abspath(grp.image_folder),
                                   lambda value: [("image_folder", value)]),
    ("lighting", "environment"): (lambda grp, name: _abspath(grp.environment),
                                  lambda value: [("environment", value)]),
    ("output", "path"): (lambda grp, name: _abspath(grp.path), lambda value: [("path", value)]),
    ("output", "bop_sensor"): (lambda grp, name: grp.bop_sensor or None, lambda value: [("bop_sensor", value or "")]),
}


def _picks_get(grp):
    """scene.picks <-> the use_picks switch and the picks_* fields (off: None)."""
    if not grp.use_picks:
        return None
    return C.PicksConfig(per_step=int(grp.picks_per_step), order=grp.picks_order, until=int(grp.picks_until))


def _picks_set(value):
    if value is None:
        return [("use_picks", False)]
    return [("use_picks", True), ("picks_per_step", value.per_step), ("picks_order", value.order),
            ("picks_until", value.until)]


def _optional_get(grp, name):
    return [f32(v) for v in getattr(grp, name)] if getattr(grp, f"use_{name}") else None


def _optional_set(name, value):
    return [(f"use_{name}", False)] if value is None else [(f"use_{name}", True), (name, tuple(value))]


def _ids_get(grp):
    """'7, 12 30' -> [7, 12, 30]; anything else stays text, so that Config.validate() names the field."""
    tokens = grp.bop_obj_ids.replace(",", " ").split()
    return [int(t) for t in tokens] if all(t.isdigit() for t in tokens) else grp.bop_obj_ids


def _json_or_text(text: str):
    """A JSON object's text -> dict; a word ("auto", "none" ...) or malformed JSON stays text."""
    if text.strip().startswith("{"):
        try:
            return json.loads(text)
        except ValueError:
            pass
    return text.strip()


def _material_get(grp, name):
    """A material field's text -> name / list / dict (malformed JSON is kept as text so that
    Config.validate() names the field)."""
    from ..materials_spec import parse_text
    try:
        return parse_text(getattr(grp, name))
    except ValueError:
        return getattr(grp, name)


def _material_set(value) -> str:
    from ..materials_spec import format_text
    return format_text(value)


def _read(grp, name: str, hint):
    value = getattr(grp, name)
    origin = typing.get_origin(hint)
    if origin is list:
        (item,) = typing.get_args(hint)
        return [f32(v) if item is float else int(v) for v in value]
    if hint is float:
        return f32(value)
    if hint is int:
        return int(value)
    if hint is bool:
        return bool(value)
    if hint is str:
        return _abspath(value) if name == "filepath" else str(value)
    raise TypeError(f"no property mapping for {name} ({hint})")


def _read_group(grp, dc_type, section: str) -> dict:
    hints = typing.get_type_hints(dc_type)
    return {f.name: _SPECIAL[(section, f.name)][0](grp, f.name) if (section, f.name) in _SPECIAL
            else _read(grp, f.name, hints[f.name]) for f in dataclasses.fields(dc_type)}


# ------------------------------------------------------------------------------------------------
# props -> Config

def props_to_config(props) -> C.Config:
    """Build a `Config` from `Scene.datapipe`. Not validated: call `cfg.validate()`."""
    cfg = C.Config()
    for section in SECTIONS:
        dc = getattr(cfg, section)
        grp = getattr(props, section)
        hints = typing.get_type_hints(type(dc))
        for f in dataclasses.fields(dc):
            key = (section, f.name)
            if key in _COLLECTIONS:
                continue
            if key in _NESTED:
                value = _NESTED[key](**_read_group(getattr(grp, f.name), _NESTED[key], f.name))
            elif key in _SPECIAL:
                value = _SPECIAL[key][0](grp, f.name)
            else:
                value = _read(grp, f.name, hints[f.name])
            setattr(dc, f.name, value)
    cfg.camera.poses = [C.CameraPose(**_read_group(p, C.CameraPose, "poses")) for p in props.camera.poses]
    if props.lighting.enabled:        # off: no lighting section, the fixed key light
        cfg.lighting = C.LightingConfig(**_read_group(props.lighting, C.LightingConfig, "lighting"))
    cfg.objects = [C.ObjectEntry(**_read_group(o, C.ObjectEntry, "objects")) for o in props.objects]
    cfg.device = None if props.device == "NONE" else props.device
    cfg.binning = int(props.binning)
    return cfg


# ------------------------------------------------------------------------------------------------
# Config -> props (checked first: nothing changes when a value cannot be shown)

def _check(rna, name: str, value, path: str, problems: list[Problem]) -> None:
    """Would `value` survive assignment to property `name` unchanged (limits, enum items)?"""
    prop = rna.properties[name]
    values = value if isinstance(value, (list, tuple)) else [value]
    if prop.type in ("INT", "FLOAT"):
        lo, hi = prop.hard_min, prop.hard_max
        if prop.type == "INT":
            lo, hi = max(lo, -INT_MAX - 1), min(hi, INT_MAX)
        for v in values:
            if isinstance(v, float) and not math.isfinite(v):
                problems.append(Problem(path, f"{v} is not a finite number", "give a finite number"))
            elif not lo <= v <= hi:
                problems.append(Problem(path, f"{v} is outside the range the sidebar allows ({lo:g}..{hi:g})",
                                        f"give a value between {lo:g} and {hi:g}"))
        if getattr(prop, "is_array", False) and prop.array_length != len(values):
            problems.append(Problem(path, f"needs {prop.array_length} numbers, got {len(values)}",
                                    f"give {prop.array_length} numbers"))
    elif prop.type == "ENUM":
        known = {item.identifier for item in prop.enum_items}
        chosen = value if isinstance(value, set) else {value}
        for v in sorted(chosen):
            if v not in known:
                problems.append(Problem(path, f"unknown value {v!r}", f"use one of {', '.join(sorted(known))}"))


def _plan_group(obj, rna, dc_type, section: str, path: str, problems) -> list[tuple[str, object]]:
    """[(property, value)] that set a group from dataclass instance `obj`, after checking each."""
    hints = typing.get_type_hints(dc_type)
    plan = []
    for f in dataclasses.fields(dc_type):
        key = (section, f.name)
        if key in _COLLECTIONS or key in _NESTED:
            continue
        value = getattr(obj, f.name)
        fpath = f"{path}.{f.name}"
        if key in _SPECIAL:
            try:
                pairs = _SPECIAL[key][1](value)
            except ValueError as e:
                problems.append(Problem(fpath, str(e), "fix the value in the preset"))
                continue
        else:
            if typing.get_origin(hints[f.name]) is list:
                value = tuple(value)
            pairs = [(f.name, value)]
        for name, v in pairs:
            if name == "periods":
                try:
                    parse_periods(v)
                except ValueError as e:
                    problems.append(Problem(fpath, str(e), "give integers >= 1, e.g. [1, 8, 64]"))
                    continue
            else:
                _check(rna, name, v, fpath, problems)
            plan.append((name, v))
    return plan


def config_to_props(cfg: C.Config, props) -> None:
    """Fill `Scene.datapipe` from `cfg` (the panels then show the preset).

    Raises ConfigError, changing nothing, when a value cannot be held by the sidebar (outside a
    property's limits, an unknown choice). Paired limits are set low-then-high so the update
    callbacks that keep min <= max never alter a valid config."""
    problems: list[Problem] = []
    plans = []
    for section in SECTIONS:
        rna = getattr(props, section).bl_rna
        plans.append((getattr(props, section),
                      _plan_group(getattr(cfg, section), rna, type(getattr(cfg, section)), section, section,
                                  problems)))
    object_rna = props.bl_rna.properties["objects"].fixed_type         # the item types, without importing props
    pose_rna = props.camera.bl_rna.properties["poses"].fixed_type
    objects = [_plan_group(o, object_rna, C.ObjectEntry, "objects", f"objects[{i}]", problems)
               for i, o in enumerate(cfg.objects)]
    poses = [_plan_group(p, pose_rna, C.CameraPose, "poses", f"camera.poses[{i}]", problems)
             for i, p in enumerate(cfg.camera.poses)]
    for (section, name), dc in _NESTED.items():
        grp = getattr(getattr(props, section), name)
        plans.append((grp, _plan_group(getattr(getattr(cfg, section), name), grp.bl_rna, dc, name,
                                       f"{section}.{name}", problems)))
    lighting = [("enabled", cfg.lighting is not None)]
    if cfg.lighting is not None:
        lighting += _plan_group(cfg.lighting, props.lighting.bl_rna, C.LightingConfig, "lighting", "lighting",
                                problems)
    plans.append((props.lighting, lighting))
    known = {item.identifier for item in props.bl_rna.properties["device"].enum_items}
    from ..devices import is_calibration_path
    if is_calibration_path(cfg.device):       # the file's rig is spelled out in the camera/projector fields
        cfg = dataclasses.replace(cfg, device=None)
    if cfg.device is not None and cfg.device not in known:
        problems.append(Problem("device", f"unknown device {cfg.device!r}", f"use one of {', '.join(sorted(known))}"))
    if problems:
        raise ConfigError(problems)

    global FILLING
    FILLING = True                    # the preset's own fields win: showing its device fills nothing
    try:
        props.device = cfg.device or "NONE"
        props.binning = cfg.binning
    finally:
        FILLING = False
    for grp, plan in plans:
        _apply(grp, plan)
    props.objects.clear()
    for plan in objects:
        _apply(props.objects.add(), plan)
    props.objects_index = 0
    props.camera.poses.clear()
    for plan in poses:
        _apply(props.camera.poses.add(), plan)
    props.camera.poses_index = 0


FILLING = False      # True while config_to_props shows a preset: its device must not refill the fields


def fill_device(props) -> None:
    """Fill the camera, projector and structured-light fields from `props.device` at `props.binning`
    (every other field stays). A binning the device does not offer falls back to 1, said on the console."""
    from ..devices import binning_factors, config_sections, device
    factors = binning_factors(device(props.device))
    if props.binning not in factors:
        print(f"DataPipe: binning {props.binning} is not offered by {props.device} (it offers {factors}); using 1")
        props.binning = 1                      # its update fills
        return
    d = props_to_config(props).to_dict()
    for section, fields in config_sections(props.device, props.binning).items():
        d[section].update(fields)
    config_to_props(C.Config.from_dict(d), props)


def _apply(grp, plan) -> None:
    # in field order: min before max, clip start before end, rotation mode before the rotation
    for name, value in plan:
        setattr(grp, name, value)
