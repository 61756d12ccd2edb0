"""The small checks every validation step uses: `_Checks` (the problem list with typed checks),
number predicates, field paths, message splitting, [min, max] ranges and the field-of-view limit."""
from __future__ import annotations

import math
import re

from ..errors import Problem
from ..text_rules import path_problem, short as _short
from .limits import MAX_FIELD_OF_VIEW_DEG, MAX_RESOLUTION, MIN_POSITIVE


class _Checks:
    """The problem list and the small checks every validation step uses."""

    def __init__(self):
        self.problems: list[Problem] = []

    def add(self, path: str, msg: str, fix: str) -> None:
        self.problems.append(Problem(path, msg, fix))

    def positive(self, path, v, fix="give a value > 0") -> bool:
        if not (_is_number(v) and math.isfinite(v) and v > 0):
            self.add(path, f"must be > 0, got {_short(v)}", fix)
            return False
        return self.not_below(path, v)

    def not_below(self, path, v) -> bool:
        """The field's smallest value (limits.MIN_POSITIVE: what the sidebar can hold), if it has one."""
        lo = MIN_POSITIVE.get(re.sub(r"\[\d+\]", "", path))
        if lo is not None and _is_number(v) and v < lo:
            self.add(path, f"{v:g} is below {lo:g}, the smallest value DataPipe (and its sidebar) takes",
                     f"give at least {lo:g}")
            return False
        return True

    def at_most(self, path, v, hi, why: str) -> bool:
        if _is_number(v) and v > hi:
            self.add(path, f"{v} is more than {hi} ({why})", f"give at most {hi}")
            return False
        return True

    def int_range(self, path, v, lo, hi, what: str) -> bool:
        if v < lo:
            self.add(path, f"must be >= {lo}, got {v}", f"give at least {lo} {what}")
            return False
        return self.at_most(path, v, hi, f"more {what} than any useful run needs")

    def vector(self, path, v, n, *, pos=False) -> bool:
        if len(v) != n:
            self.add(path, f"needs {n} numbers, got {len(v)}", f"give {n} numbers")
            return False
        if not all(_finite(x) for x in v):
            self.add(path, "contains NaN or infinity", "give finite numbers")
            return False
        if pos and not all(x > 0 for x in v):
            self.add(path, f"all values must be > 0, got {v}", "give positive sizes")
            return False
        return not pos or self.not_below(path, min(v))

    def min_max(self, path, lo_name, hi_name, lo, hi, lo_bound=0) -> bool:
        ok = True
        if lo < lo_bound:
            self.add(f"{path}.{lo_name}", f"must be >= {lo_bound}, got {lo}", f"set it to {lo_bound} or more")
            ok = False
        if hi < lo_bound:
            self.add(f"{path}.{hi_name}", f"must be >= {lo_bound}, got {hi}", f"set it to {lo_bound} or more")
            ok = False
        if lo > hi:
            self.add(f"{path}.{lo_name}", f"{lo_name} ({lo}) > {hi_name} ({hi})", f"make {lo_name} <= {hi_name}")
            ok = False
        return ok

    def resolution(self, path, res) -> bool:
        if len(res) != 2:
            self.add(path, f"needs [width, height], got {res}", "give two integers [width, height]")
            return False
        ok = True
        for name, v in zip(("width", "height"), res):
            if not 1 <= v <= MAX_RESOLUTION:
                self.add(path, f"{name} {v} outside 1..{MAX_RESOLUTION}",
                         f"give a {name} between 1 and {MAX_RESOLUTION}")
                ok = False
        return ok

    def path(self, path, v: str) -> bool:
        """A path string the OS can take (no NUL, no lone surrogate: text_rules)."""
        problem = path_problem(v)
        if problem is not None:
            self.add(path, *problem)
        return problem is None

    def choice(self, path, v, options) -> bool:
        if v not in options:
            self.add(path, f"unknown value {_short(v)}", f"use one of {', '.join(map(str, options))}")
            return False
        return True

    def has(self, prefix: str) -> bool:
        """Is there already a problem at `prefix` or below it?"""
        return any(p.path == prefix or p.path.startswith((prefix + ".", prefix + "[")) for p in self.problems)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _finite(v) -> bool:
    try:
        return _is_number(v) and math.isfinite(v)
    except OverflowError:            # an int too large for a float
        return False


def _split_fix(text: str) -> tuple[str, str | None]:
    """'what (fix: how)' -> ('what', 'how'), so a wrapped message does not say "(fix:" twice."""
    head, sep, tail = text.partition(" (fix: ")
    return (head, tail[:-1] if tail.endswith(")") else tail) if sep else (text, None)


def _split_field(message: str) -> tuple[str, str, str]:
    """'field: what (fix: how)' -> (field, what, how)."""
    field, _, rest = message.partition(": ")
    what, fix = _split_fix(rest)
    return field, what, fix or "see docs/DATASETS.md"


def _range_problems(path: str, v, *, lo_bound: float | None = None, hi_bound: float | None = None,
                    unit: str = "") -> list[Problem]:
    """A [min, max] range: two finite numbers, min <= max, within [lo_bound, hi_bound]."""
    if len(v) != 2 or not all(math.isfinite(x) for x in v):
        return [Problem(path, f"needs [min, max] as two finite numbers, got {v}", "give two numbers [min, max]")]
    out = []
    if v[0] > v[1]:
        out.append(Problem(path, f"min {v[0]:g} > max {v[1]:g}", "give [min, max] with min <= max"))
    if lo_bound is not None and min(v) < lo_bound:
        out.append(Problem(path, f"values must be >= {lo_bound:g}{unit}, got {v}", f"keep the range at or above {lo_bound:g}{unit}"))
    if hi_bound is not None and max(v) > hi_bound:
        out.append(Problem(path, f"values must be <= {hi_bound:g}{unit}, got {v}", f"keep the range at or below {hi_bound:g}{unit}"))
    return out


def _check_field_of_view(ck: "_Checks", device: str, focal: float, sensor: float, verb: str, why: str,
                         fix: str) -> None:
    """A lens wider than MAX_FIELD_OF_VIEW_DEG (once focal length and sensor width are valid)."""
    if ck.has(f"{device}.focal_length") or ck.has(f"{device}.sensor_width"):
        return
    fov = 2 * math.degrees(math.atan(sensor / (2 * focal)))
    if fov > MAX_FIELD_OF_VIEW_DEG:
        ck.add(f"{device}.focal_length", f"{focal} mm on a {sensor} mm {verb} {fov:.1f} deg across "
               f"(more than {MAX_FIELD_OF_VIEW_DEG:g}{why})", fix)


def _join(path: str, key) -> str:
    if not (isinstance(key, str) and key.isidentifier()):     # '', 'a b', 3: quoted, so the path is never empty
        return f"{path}[{_short(key)}]"
    return f"{path}.{key}" if path else key
