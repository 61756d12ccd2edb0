"""Does each part fit the drop zone? A warning for `validate`, before any Blender work. No bpy.

Parts are spawned as bounding spheres on a grid over the drop zone's footprint. A part whose
bounding sphere is wider than the footprint's shorter side, or taller than the zone, cannot be
placed inside it: it starts overlapping the walls and is thrown out of the bin (the benchmark's
0.3 m part in the default bin: 3 of 4 lost). The bounding box is read straight from the mesh file
(OBJ, PLY, STL; glTF is not checked here), times the entry's scale, against the configured
drop zone (a .blend's own `drop_zone` object is only known once Blender opens it).
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np


def mesh_extent(path: str | Path) -> np.ndarray | None:
    """(3,) bounding-box size of the vertices in a mesh file (file units), None if unread."""
    p = Path(path)
    try:
        ext = p.suffix.lower()
        if ext == ".obj":
            pts = [line.split()[1:4] for line in p.read_text(errors="replace").splitlines() if line.startswith("v ")]
            v = np.array(pts, dtype=np.float64)
        elif ext == ".ply":
            v = _ply_vertices(p.read_bytes())
        elif ext == ".stl":
            v = _stl_vertices(p.read_bytes())
        else:
            return None
    except (OSError, ValueError, struct.error):
        return None
    if v is None or len(v) == 0:
        return None
    return np.ptp(v.reshape(-1, 3), axis=0)


def _ply_vertices(data: bytes) -> np.ndarray | None:
    end = data.find(b"end_header")
    if end < 0:
        return None
    header = data[:end].decode("ascii", "replace").splitlines()
    fmt = next((h.split()[1] for h in header if h.startswith("format")), "ascii")
    n, props, in_vertex = 0, [], False
    for h in header:
        w = h.split()
        if w[:2] == ["element", "vertex"]:
            n, in_vertex = int(w[2]), True
        elif w and w[0] == "element":
            in_vertex = False
        elif in_vertex and w and w[0] == "property":
            props.append((w[1], w[-1]))
    names = [nm for _, nm in props]
    if not {"x", "y", "z"} <= set(names):
        return None
    body = data[end + len(b"end_header"):].lstrip(b"\r\n")
    if fmt == "ascii":
        rows = body.decode("ascii", "replace").splitlines()[:n]
        arr = np.array([r.split()[:len(props)] for r in rows], dtype=np.float64)
    else:
        sizes = {"char": "i1", "uchar": "u1", "int8": "i1", "uint8": "u1", "short": "i2", "ushort": "u2",
                 "int16": "i2", "uint16": "u2", "int": "i4", "uint": "u4", "int32": "i4", "uint32": "u4",
                 "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
        order = "<" if "little" in fmt else ">"
        dt = np.dtype([(nm, order + sizes[t]) for t, nm in props])
        rec = np.frombuffer(body, dtype=dt, count=n)
        arr = np.stack([rec[k].astype(np.float64) for k in names], axis=1)
    return arr[:, [names.index("x"), names.index("y"), names.index("z")]]


def _stl_vertices(data: bytes) -> np.ndarray:
    if len(data) >= 84:
        n = struct.unpack("<I", data[80:84])[0]
        if 84 + 50 * n == len(data):          # binary
            rec = np.frombuffer(data, dtype=np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]),
                                count=n, offset=84)
            return rec["v"].reshape(-1, 3).astype(np.float64)
    pts = [line.split()[1:4] for line in data.decode("ascii", "replace").splitlines()
           if line.strip().startswith("vertex")]
    return np.array(pts, dtype=np.float64)


def part_fit_warnings(cfg) -> list[str]:
    """One line per object entry whose part cannot be placed inside the drop zone."""
    half = np.asarray(cfg.scene.drop_zone_scale, dtype=np.float64)
    out = []
    for i, o in enumerate(cfg.objects):
        ext = mesh_extent(o.filepath)
        if ext is None:
            continue
        size = ext * float(o.scale)
        diameter = float(np.linalg.norm(size))
        room = float(min(2 * half[0], 2 * half[1], 2 * half[2]))
        if diameter > room:
            out.append(f"objects[{i}]: the part is {size[0]:.3g} x {size[1]:.3g} x {size[2]:.3g} m (bounding "
                       f"sphere {diameter:.3g} m), larger than the drop zone's smallest side {room:.3g} m: it "
                       "starts against the walls and is likely thrown out of the bin (fix: enlarge "
                       "scene.drop_zone_scale or reduce objects[i].scale)".replace("objects[i]", f"objects[{i}]"))
    return out
