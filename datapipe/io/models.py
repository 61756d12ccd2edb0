"""Part models: PLY meshes in millimetres and models_info.json (bop_toolkit's layout). No bpy.

Written at the start of every run into OUT/models/ (show and the BOP export read them) and copied
into the BOP dataset. Model coordinates are the mesh file's times the entry's scale, in mm here.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np

from ..errors import DataPipeError
from . import layout
from .files import atomic_path, copy_atomic, make_dirs, own_file, read_json, write_bytes_atomic, write_json_lines_atomic
from .input_files import MAX_MESH_BYTES, read_regular

def write_ply(path: str | os.PathLike, verts: np.ndarray, faces: np.ndarray,
              normals: np.ndarray | None = None, *, binary: bool = True) -> None:
    """PLY with `x y z [nx ny nz]` (float32) and triangle faces (uchar count, int indices)."""
    path = Path(path)
    verts = np.asarray(verts, dtype=np.float32).reshape(-1, 3)
    faces = np.asarray(faces, dtype=np.int32).reshape(-1, 3)
    if normals is not None:
        normals = np.asarray(normals, dtype=np.float32).reshape(-1, 3)
        if len(normals) != len(verts):
            raise ValueError(f"{len(normals)} normals for {len(verts)} vertices")
    if len(faces) and (faces.min() < 0 or faces.max() >= len(verts)):
        raise ValueError("face index out of range")
    props = ["x", "y", "z"] + (["nx", "ny", "nz"] if normals is not None else [])
    header = ["ply", f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
              "comment DataPipe model, units: mm", f"element vertex {len(verts)}"]
    header += [f"property float {p}" for p in props]
    header += [f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    data = verts if normals is None else np.hstack([verts, normals])
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        if binary:
            f.write(np.ascontiguousarray(data, dtype="<f4").tobytes())
            rec = np.zeros(len(faces), dtype=[("n", "u1"), ("i", "<i4", (3,))])
            rec["n"] = 3
            rec["i"] = faces
            f.write(rec.tobytes())
        else:
            np.savetxt(f, data, fmt="%.6f")
            np.savetxt(f, np.hstack([np.full((len(faces), 1), 3), faces]), fmt="%d")


_PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
              "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
              "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}


def read_ply(path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Vertices (V,3) float64 and triangle faces (F,3) of a PLY (ascii or binary, either byte order).

    Polygons with more than 3 corners are fanned into triangles."""
    raw = read_regular(path, MAX_MESH_BYTES)         # never a FIFO or device (io/input_files.py)
    fmt, elements, body_start = _ply_header(raw, path)
    if fmt == "ascii":
        verts, polys = _ply_ascii_body(raw[body_start:].split(), elements)
        tri = np.zeros((0, 3), dtype=np.int64)
    else:
        verts, polys, tri = _ply_binary_body(raw, body_start, elements, ">" if fmt == "binary_big_endian" else "<")
    if polys:
        tri = np.array([[p[0], p[k], p[k + 1]] for p in polys for k in range(1, len(p) - 1)], dtype=np.int64)
    return verts, tri.reshape(-1, 3)


def _ply_header(raw: bytes, path) -> tuple[str, list[dict], int]:
    """(format, elements [{name, count, props}], offset of the body). A property is (name, type) or,
    for a list, (name, "list", count type, index type)."""
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise DataPipeError(f"{path}: not a PLY file")
    body_start = raw.index(b"\n", end) + 1
    fmt = None
    elements: list[dict] = []
    for line in raw[:end].decode("ascii", "replace").splitlines():
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "format":
            fmt = tok[1]
        elif tok[0] == "element":
            elements.append({"name": tok[1], "count": int(tok[2]), "props": []})
        elif tok[0] == "property":
            if tok[1] == "list":
                elements[-1]["props"].append((tok[4], "list", _PLY_TYPES[tok[2]], _PLY_TYPES[tok[3]]))
            else:
                elements[-1]["props"].append((tok[2], _PLY_TYPES[tok[1]]))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise DataPipeError(f"{path}: PLY format {fmt!r} not supported (use ascii or binary_little_endian)")
    return fmt, elements, body_start


def _is_face_list(el: dict, prop: tuple) -> bool:
    return el["name"] == "face" and prop[0] in ("vertex_indices", "vertex_index")


def _ply_ascii_body(tokens: list[bytes], elements: list[dict]) -> tuple[np.ndarray, list[list[int]]]:
    """(vertices (V,3), face polygons) of an ascii body's tokens."""
    verts = np.zeros((0, 3))
    polys: list[list[int]] = []
    pos = 0
    for el in elements:
        if el["name"] == "vertex" and all(len(p) == 2 for p in el["props"]):
            n, k = el["count"], len(el["props"])
            arr = np.array(tokens[pos:pos + n * k], dtype=np.float64).reshape(n, k)
            pos += n * k
            names = [p[0] for p in el["props"]]
            verts = arr[:, [names.index("x"), names.index("y"), names.index("z")]]
            continue
        for _ in range(el["count"]):
            for p in el["props"]:
                if len(p) == 4:
                    cnt = int(tokens[pos]); pos += 1
                    vals = [int(t) for t in tokens[pos:pos + cnt]]; pos += cnt
                    if _is_face_list(el, p):
                        polys.append(vals)
                else:
                    pos += 1
    return verts, polys


def _ply_binary_body(raw: bytes, pos: int, elements: list[dict],
                     order: str) -> tuple[np.ndarray, list[list[int]], np.ndarray]:
    """(vertices (V,3), face polygons, triangles (F,3) read in one piece) of a binary body from `pos`."""
    verts = np.zeros((0, 3))
    polys: list[list[int]] = []
    tri = np.zeros((0, 3), dtype=np.int64)
    for el in elements:
        if all(len(p) == 2 for p in el["props"]):
            dt = np.dtype([(p[0], order + p[1]) for p in el["props"]])
            arr = np.frombuffer(raw, dtype=dt, count=el["count"], offset=pos)
            pos += dt.itemsize * el["count"]
            if el["name"] == "vertex":
                verts = np.stack([arr["x"], arr["y"], arr["z"]], axis=1).astype(np.float64)
            continue
        # fast path: faces that are all triangles with one list property
        if (el["name"] == "face" and len(el["props"]) == 1 and len(el["props"][0]) == 4):
            _, _, ct, it = el["props"][0]
            dt = np.dtype([("n", order + ct), ("i", order + it, (3,))])
            if pos + dt.itemsize * el["count"] <= len(raw):
                arr = np.frombuffer(raw, dtype=dt, count=el["count"], offset=pos)
                if np.all(arr["n"] == 3):
                    tri = arr["i"].astype(np.int64)
                    pos += dt.itemsize * el["count"]
                    continue
        for _ in range(el["count"]):
            for p in el["props"]:
                if len(p) == 4:
                    cdt, idt = np.dtype(order + p[2]), np.dtype(order + p[3])
                    cnt = int(np.frombuffer(raw, cdt, 1, pos)[0]); pos += cdt.itemsize
                    vals = np.frombuffer(raw, idt, cnt, pos).tolist(); pos += idt.itemsize * cnt
                    if _is_face_list(el, p):
                        polys.append(vals)
                else:
                    pos += np.dtype(p[1]).itemsize
    return verts, polys, tri


def diameter(points: np.ndarray) -> float:
    """Largest distance between any two points, exact: convex-hull vertices, then all pairs."""
    pts = np.unique(np.asarray(points, dtype=np.float64).reshape(-1, 3), axis=0)
    if len(pts) < 2:
        return 0.0
    if len(pts) > 4:
        try:
            from scipy.spatial import ConvexHull
            pts = pts[ConvexHull(pts).vertices]
        except Exception:   # flat or degenerate point sets: fall back to all points (still exact)
            pass
    best = 0.0
    step = max(1, 4_000_000 // len(pts))
    for i in range(0, len(pts), step):
        d = ((pts[i:i + step, None, :] - pts[None, :, :]) ** 2).sum(-1)
        best = max(best, float(d.max()))
    return float(np.sqrt(best))


def model_info(verts_mm: np.ndarray) -> dict:
    v = np.asarray(verts_mm, dtype=np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    return {"diameter": diameter(v),
            "min_x": float(lo[0]), "min_y": float(lo[1]), "min_z": float(lo[2]),
            "size_x": float(hi[0] - lo[0]), "size_y": float(hi[1] - lo[1]), "size_z": float(hi[2] - lo[2])}


def model_filename(obj_id: int) -> str:
    return f"obj_{int(obj_id):06d}.ply"


def write_models(models_dir: str | os.PathLike, meshes: Mapping[int, tuple], *, binary: bool = True,
                 symmetries: Mapping[int, dict] | None = None) -> dict:
    """Write `obj_XXXXXX.ply` (mm) and `models_info.json` for {obj_id: (verts_m, faces, normals)}.

    verts_m: (V,3) model coordinates in metres (scale baked, the frame of T_cam_obj); faces (F,3)
    triangles; normals (V,3) unit vertex normals or None. `symmetries`: {obj_id: {"symmetries_discrete":
    [...], "symmetries_continuous": [...]}} (mm, io/symmetry.py) added to the object's entry.
    Returns the models_info dict."""
    models_dir = Path(models_dir)
    make_dirs(models_dir)              # in a run's output folder: never through a link, and recorded
    info = {}
    for obj_id in sorted(meshes, key=int):
        verts_m, faces, normals = (tuple(meshes[obj_id]) + (None, None))[:3]
        if int(obj_id) < 1:
            raise DataPipeError(f"object id {obj_id}: BOP object ids start at 1")
        verts_mm = np.asarray(verts_m, dtype=np.float64).reshape(-1, 3) * 1000.0
        if len(verts_mm) == 0:
            raise DataPipeError(f"object {obj_id}: the mesh has no vertices")
        write_ply(models_dir / model_filename(obj_id), verts_mm, faces, normals, binary=binary)
        info[str(int(obj_id))] = {**model_info(verts_mm), **((symmetries or {}).get(obj_id) or {})}
    write_json_lines_atomic(models_dir / layout.MODELS_INFO, info)
    return info


@dataclass
class Model:
    verts_mm: np.ndarray    # (V,3) float64
    faces: np.ndarray       # (F,3) int64


def load_models(models_dir: str | os.PathLike) -> dict[int, Model]:
    models_dir = Path(models_dir)
    out = {}
    for p in sorted(models_dir.glob("obj_*.ply")):
        try:
            obj_id = int(p.stem.split("_")[1])
        except (IndexError, ValueError):
            continue
        v, f = read_ply(p)
        out[obj_id] = Model(v, f)
    return out


def load_listed_models(models_dir: str | os.PathLike) -> dict[int, Model]:
    """The models the folder's models_info.json lists (as load_models reads them; an obj_*.ply beside
    them that it does not list, e.g. a file of the user's, is not read), each file read through
    `own_file`: in a run's output folder never through a link and only the file the run wrote. A
    folder without models_info.json (outside a run): every obj_*.ply, as load_models."""
    models_dir = Path(models_dir)
    with own_file(models_dir / layout.MODELS_INFO) as p:
        if not p.is_file():
            return load_models(models_dir)
        info = read_json(p)
    out = {}
    for obj_id in sorted(int(k) for k in info if str(k).isdigit()) if isinstance(info, dict) else []:
        with own_file(models_dir / model_filename(obj_id)) as p:
            if p.is_file():                  # outside a run a missing one is left out, as load_models does
                out[obj_id] = Model(*read_ply(p))
    return out


def copy_models(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    """Copy a models folder the run wrote (OUT/models/, into the BOP export's): only the models its
    models_info.json lists (another .ply of yours in models/ is not the run's), models_info.json last
    (the BOP writer takes its presence for "the models are copied"). Read through `own_file`: in the
    run's output folder never through a link, and only the files the run wrote, so a models/ (or a
    model) replaced during the run is refused, never copied as the run's."""
    src, dst = Path(src), Path(dst)
    with own_file(src / layout.MODELS_INFO) as p:
        if not p.is_file():
            raise DataPipeError(f"{src}: no {layout.MODELS_INFO} (the run's models/ folder is written at the "
                                "start of a run by datapipe.io.models.write_models)")
        info_bytes = p.read_bytes()
    if src.resolve() == dst.resolve():
        return
    make_dirs(dst)
    info = json.loads(info_bytes)
    for obj_id in sorted(int(k) for k in info if str(k).isdigit()) if isinstance(info, dict) else []:
        with own_file(src / model_filename(obj_id)) as p:
            if p.is_file():                  # outside a run a missing one is left out, as before
                copy_atomic(p, dst / model_filename(obj_id))
    write_bytes_atomic(dst / layout.MODELS_INFO, info_bytes)    # the bytes checked above, not read again
