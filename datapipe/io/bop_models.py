"""Object entries from a BOP dataset's models folder, and the symmetries every entry exports. No bpy.

A BOP models folder (ITODD, XYZ-IBD, IPD, T-LESS ... `models/` or `models_cad/`) holds
`obj_XXXXXX.ply` in millimetres and `models_info.json` (diameter, extents, symmetries). An object
entry with `bop_models` set names such a folder and `bop_obj_ids` (empty: every object of its
models_info.json); `expand_bop_objects` replaces it by one plain entry per object before the run:
filepath the PLY, scale 0.001 (mm -> m), name `obj_XXXXXX` (or `NAME_XXXXXX` when the entry has a
name), obj_id the BOP id, symmetries copied from models_info.json; every other setting (instances,
mass, material ...) is the entry's. The export therefore writes the source's ids and symmetries, and
the same model frame (the PLY's, in mm).

Each expanded entry remembers where it came from (`source_field`, e.g. "objects[0] (obj_id 5)"), so later
checks (the mesh preflight) name the preset's field.
"""
from __future__ import annotations

import copy
import json
import os
from pathlib import Path

from ..errors import DataPipeError
from .input_files import MAX_MESH_BYTES, file_problem, read_json_file
from .layout import MODELS_INFO
SYMMETRY_KEYS = ("symmetries_discrete", "symmetries_continuous")


def ply_path(models_dir: str | os.PathLike, obj_id: int) -> Path:
    return Path(models_dir) / f"obj_{int(obj_id):06d}.ply"


def read_models_info(models_dir: str | os.PathLike, field: str) -> dict[int, dict]:
    """{obj_id: entry} of a BOP models folder's models_info.json, every entry checked (an object of
    numbers, symmetries as BOP writes them); DataPipeError naming `field`, the file and the object id."""
    d = Path(models_dir)
    if not d.is_dir():
        raise DataPipeError(f"{field}: no such folder: {d} (fix: give a BOP dataset's models folder, the one "
                            f"holding obj_000001.ply ... and {MODELS_INFO})")
    p = d / MODELS_INFO
    if not os.path.lexists(p):
        raise DataPipeError(f"{field}: {d} has no {MODELS_INFO} (fix: give a BOP models folder; BOP's "
                            "calc_model_info.py writes the file for a folder of obj_XXXXXX.ply)")
    fix = ("fix: a JSON object {\"1\": {\"diameter\": ..., \"min_x\": ...}, ...} as BOP's calc_model_info.py "
           "writes it")
    try:
        raw = read_json_file(p)
    except DataPipeError as e:
        raise DataPipeError(f"{field}: {p} is not a BOP {MODELS_INFO}: {e} ({fix})") from None
    if not isinstance(raw, dict):
        raise DataPipeError(f"{field}: {p} is not a BOP {MODELS_INFO}: a JSON {type(raw).__name__}, not an "
                            f"object keyed by object id ({fix})")
    info = {}
    for key, entry in raw.items():
        try:
            k = int(key)
        except ValueError:
            k = 0
        if k < 1:
            raise DataPipeError(f"{field}: {p}: key {key!r} is not an object id (an integer >= 1) ({fix})")
        problem = _entry_problem(entry)
        if problem is not None:
            raise DataPipeError(f"{field}: {p}, object {k}: {problem} ({fix})")
        given = {name: entry[name] for name in SYMMETRY_KEYS if name in entry}
        if given:
            from .symmetry import check_symmetries
            try:
                check_symmetries(given, f"object {k}")
            except DataPipeError as e:
                raise DataPipeError(f"{field}: {p}, {e}") from None
        info[k] = entry
    return info


def _entry_problem(entry) -> str | None:
    """Why one models_info.json entry is not BOP's (an object; diameter, extents numbers), or None."""
    import math
    if not isinstance(entry, dict):
        return f"the entry is {json.dumps(entry)[:40]}, not an object of diameter, min_x ... size_z"
    for key in ("diameter", "min_x", "min_y", "min_z", "size_x", "size_y", "size_z"):
        v = entry.get(key, 0.0)
        try:
            finite = not isinstance(v, bool) and isinstance(v, (int, float)) and math.isfinite(v)
        except OverflowError:           # an integer past float64 (10**400)
            finite = False
        if not finite:
            return f"{key} is {json.dumps(v)[:40]}, not a finite number (mm)"
    return None


def bop_ids(entry, field: str) -> list[int]:
    """The BOP object ids an entry with `bop_models` stands for, each checked to have its PLY."""
    if not (isinstance(entry.bop_obj_ids, list) and all(isinstance(i, int) for i in entry.bop_obj_ids)):
        raise DataPipeError(f"{field}.bop_obj_ids: expected a list of object ids, got {entry.bop_obj_ids!r} "
                            "(fix: e.g. [1, 5, 7], or [] for all)")
    info = read_models_info(entry.bop_models, f"{field}.bop_models")
    ids = [int(i) for i in entry.bop_obj_ids] if entry.bop_obj_ids else sorted(info)
    if not ids:
        raise DataPipeError(f"{field}.bop_models: {entry.bop_models}/{MODELS_INFO} lists no object")
    missing = [i for i in ids if i not in info]
    if missing:
        raise DataPipeError(f"{field}.bop_obj_ids: {missing} not in {entry.bop_models}/{MODELS_INFO} (it has "
                            f"{sorted(info)}) (fix: give ids it lists, or [] for all)")
    for i in ids:
        problem = file_problem(ply_path(entry.bop_models, i), MAX_MESH_BYTES)
        if problem is not None and problem.startswith("file not found"):
            raise DataPipeError(f"{field}.bop_obj_ids: object {i} has no {ply_path(entry.bop_models, i).name} in "
                                f"{entry.bop_models} (fix: drop id {i} or restore the file)")
        if problem is not None:
            raise DataPipeError(f"{field}.bop_obj_ids: object {i}: {problem} (fix: drop id {i} or restore the file)")
    if len(set(ids)) != len(ids):
        raise DataPipeError(f"{field}.bop_obj_ids: {ids} lists an id twice (fix: list each id once)")
    return ids


def planned_obj_ids(cfg) -> list[tuple[str, int]]:
    """(origin, obj_id) of every entry after expansion; BOP entries whose folder is unreadable are
    skipped (their own check reports them)."""
    out, pos = [], 0
    for i, o in enumerate(cfg.objects):
        if o.bop_models:
            try:
                ids = bop_ids(o, f"objects[{i}]")
            except DataPipeError:
                continue
            out += [(f"objects[{i}] (obj_id {k})", k) for k in ids]
            pos += len(ids)
        else:
            pos += 1
            out.append((f"objects[{i}]", int(o.obj_id) if o.obj_id else pos))
    return out


def expand_bop_objects(cfg):
    """A copy of `cfg` with every BOP-folder entry replaced by one entry per object (see above).
    Call after validation; a config without such entries comes back unchanged (a copy)."""
    cfg = copy.deepcopy(cfg)
    objects = []
    for i, o in enumerate(cfg.objects):
        if not o.bop_models:
            objects.append(o)
            continue
        field = f"objects[{i}]"
        info = read_models_info(o.bop_models, f"{field}.bop_models")
        for k in bop_ids(o, field):
            e = copy.deepcopy(o)
            e.filepath = str(ply_path(o.bop_models, k).resolve())
            e.bop_models, e.bop_obj_ids = "", []
            e.scale = 0.001 * float(o.scale)
            e.obj_id = k
            e.name = f"{o.name}_{k:06d}" if o.name else f"obj_{k:06d}"
            if o.symmetries == "auto":
                e.symmetries = {key: info[k][key] for key in SYMMETRY_KEYS if key in info[k]}
            e.source_field = f"{field} (obj_id {k})"
            objects.append(e)
    cfg.objects = objects
    return cfg


def entry_field(entry, index: int) -> str:
    """The preset field an (expanded) object entry came from."""
    return getattr(entry, "source_field", None) or f"objects[{index}]"


def model_symmetries(entry, index: int, verts_mm, faces) -> dict:
    """The symmetries an (expanded) entry's model exports: given (a dict), detected ("auto" or
    "detect" at the default tolerance, {"tolerance": t}), or none ("none"). Empty lists are left
    out (BOP's convention)."""
    from .symmetry import TOLERANCE, check_symmetries, detect_symmetries
    s = entry.symmetries
    where = f"{entry_field(entry, index)}.symmetries"
    if s == "none":
        return {}
    if isinstance(s, dict) and set(s) != {"tolerance"}:
        found = check_symmetries(s, where)
    elif isinstance(s, dict) or s in ("auto", "detect"):
        tol = float(s["tolerance"]) if isinstance(s, dict) else TOLERANCE
        try:
            found = detect_symmetries(verts_mm, faces, tolerance=tol)
        except ValueError as e:
            raise DataPipeError(f"{where}: {e}") from None
    else:
        raise DataPipeError(f"{where}: {s!r} (fix: \"auto\", \"detect\", \"none\", {{\"tolerance\": 0.01}} or a "
                            "dict of symmetries_discrete / symmetries_continuous)")
    return {k: v for k, v in found.items() if v}


def models_symmetries(cfg, meshes) -> dict[int, dict]:
    """{obj_id: symmetries} of an (expanded) config's entries, for io.models.write_models;
    `meshes` is {obj_id: (verts m, faces, ...)}."""
    import numpy as np
    out = {}
    for i, e in enumerate(cfg.objects):
        k = cfg.obj_id(i)
        if not e.annotate:          # a distractor has no model
            continue
        verts_m, faces = meshes[k][0], meshes[k][1]
        out[k] = model_symmetries(e, i, np.asarray(verts_m, dtype=np.float64) * 1000.0, faces)
    return out
