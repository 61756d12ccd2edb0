"""dict -> Config: the type checks of Config.from_dict. Every problem is collected (field path +
fix) instead of raising at the first one; the semantic rules are validate.py's."""
from __future__ import annotations

import copy
import dataclasses
import os
import typing
from typing import Any

from ..errors import ConfigError, Problem
from ..text_rules import short as _short
from .checks import _join
from .limits import MAX_FREE_NESTING, SCHEMA_VERSION


def from_dict(cls, data: dict, *, base_dir: str | os.PathLike | None = None):
    """Config.from_dict: build `cls` (Config) from a dict; relative paths resolved against `base_dir`."""
    from .validate import validate
    problems: list[Problem] = []
    if not isinstance(data, dict):
        raise ConfigError(Problem("<root>", f"expected a JSON object, got {type(data).__name__}",
                                  "write the preset as {\"scene\": {...}, \"objects\": [...], ...}"))
    version = data.get("schema_version", SCHEMA_VERSION)
    if version != SCHEMA_VERSION:
        problems.append(Problem("schema_version", f"unsupported schema version {_short(version)}",
                                f"use schema_version {SCHEMA_VERSION} (re-save the preset)"))
    from .calibration import apply_calibration
    from ..devices import apply_device, is_calibration_path
    if is_calibration_path(data.get("device")):   # your own rig: a calibration file (config/calibration.py)
        data = apply_calibration(data, problems, base_dir)
    else:
        data = apply_device(data, problems)      # a device fills the sections the preset leaves out
    cfg = _build(cls, data, "", problems)
    if base_dir is not None:
        cfg.resolve_paths(base_dir)
    if problems:
        # report the semantic problems too (all at once), except at fields already flagged
        flagged = {p.path for p in problems}
        problems += [p for p in validate(cfg) if p.path not in flagged]
        raise ConfigError(problems)
    return cfg


def _type_name(tp) -> str:
    return getattr(tp, "__name__", str(tp))


def _build(tp, value, path: str, problems: list[Problem]):
    if tp is Any:                    # free-form JSON (materials): checked by validate()
        depth = _nesting(value, MAX_FREE_NESTING)
        if depth > MAX_FREE_NESTING:
            problems.append(Problem(path, f"nested more than {MAX_FREE_NESTING} levels deep (lists or objects "
                                    "inside each other)", "give a name, an object of values, or a list of those "
                                    "(a material needs 3 levels)"))
            return None
        return copy.deepcopy(value)
    origin = typing.get_origin(tp)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            problems.append(Problem(path or "<root>", f"expected an object, got {type(value).__name__}",
                                    f"give {path or 'the preset'} as a JSON object"))
            return tp()
        hints = typing.get_type_hints(tp)
        names = {f.name for f in dataclasses.fields(tp)}
        for key in value:
            if key not in names:
                problems.append(Problem(_join(path, key), "unknown key",
                                        f"remove it; known keys here: {', '.join(sorted(names))}"))
        kwargs = {}
        for f in dataclasses.fields(tp):
            if f.name in value:
                kwargs[f.name] = _build(hints[f.name], value[f.name], _join(path, f.name), problems)
        return tp(**kwargs)
    if origin is list:
        (item_tp,) = typing.get_args(tp)
        if isinstance(value, tuple):
            value = list(value)
        if not isinstance(value, list):
            problems.append(Problem(path, f"expected a list, got {type(value).__name__}",
                                    f"give {path} as a JSON array"))
            return []
        return [_build(item_tp, v, f"{path}[{i}]", problems) for i, v in enumerate(value)]
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        args = typing.get_args(tp)
        if value is None and type(None) in args:
            return None
        non_none = [a for a in args if a is not type(None)]
        for a in non_none:       # a value of one member type stays that type (exposure: 0.5 or "auto")
            if a in (str, bool) and isinstance(value, a) or \
                    a in (int, float) and isinstance(value, (int, float)) and not isinstance(value, bool):
                return _build(a, value, path, problems)
        return _build(non_none[0], value, path, problems)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            problems.append(Problem(path, f"expected a number, got {_short(value)}", "give a number"))
            return 0.0
        try:
            return float(value)
        except OverflowError:                  # an integer with hundreds of digits
            problems.append(Problem(path, "number too large", "give a number below 1e308"))
            return 0.0
    if tp is int:
        if isinstance(value, float) and value.is_integer():
            value = int(value)
        if isinstance(value, bool) or not isinstance(value, int):
            problems.append(Problem(path, f"expected an integer, got {_short(value)}", "give a whole number"))
            return 0
        if not -2**63 <= value < 2**63:        # beyond every limit below; keeps messages printable
            problems.append(Problem(path, "integer too large", "give a number of a sensible size"))
            return 0
        return value
    if tp is bool:
        if not isinstance(value, bool):
            problems.append(Problem(path, f"expected true/false, got {_short(value)}", "give true or false"))
            return False
        return value
    if tp is str:
        if not isinstance(value, str):
            problems.append(Problem(path, f"expected a string, got {_short(value)}", "give a string"))
            return ""
        return value
    raise TypeError(f"unsupported config type {_type_name(tp)} at {path}")


def _nesting(value, limit: int) -> int:
    """How deep lists/dicts nest in `value` (a scalar: 0), counted without recursion and only up
    to limit + 1 (a preset nested 950 deep must not reach Python's recursion limit)."""
    deepest, stack = 0, [(value, 0)]
    while stack:
        v, d = stack.pop()
        if isinstance(v, (list, tuple, dict)):
            if d + 1 > limit:
                return d + 1
            deepest = max(deepest, d + 1)
            stack.extend((x, d + 1) for x in (v.values() if isinstance(v, dict) else v))
    return deepest
