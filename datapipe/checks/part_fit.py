"""Does each part fit the drop zone, and do all of them fit the bin? No bpy.

`part_fit_warnings`: a warning for `validate`, before any Blender work.

Parts are spawned as bounding spheres on a grid over the drop zone's footprint. A part whose
bounding sphere is wider than the footprint's shorter side, or taller than the zone, cannot be
placed inside it: it starts overlapping the walls and is thrown out of the bin (the benchmark's
0.3 m part in the default bin: 3 of 4 lost). The bounding box is read straight from the mesh file
(OBJ, PLY, STL; glTF is not checked here), times the entry's scale, against the configured
drop zone (a .blend's own `drop_zone` object is only known once Blender opens it).

`fill_problems`: the refusal of part counts that cannot fit the bin, from each part's convex hull
volume (the Blender preflight measures it on the imported mesh, every format). A dropped pile is a
random packing: spheres settle at 0.55-0.64 of the space they are in (random loose to random close
packing), elongated convex shapes reach up to ~0.74 at the most (ellipsoids, compressed: Donev et
al., Science 303, 990 (2004)), and shaking-free drops stay well below. So if the hull volumes of a
scene's most parts exceed RANDOM_PACKING_MAX of the smallest bin a scene can draw, they cannot all
lie in it: the surplus is thrown over the walls, scene after scene. Below that bound a full bin is
the user's choice (parts may still pile over the walls: the simulation reports those it loses).
With `scene.fill` a scene stops adding parts at its drawn share of the bin, so the bound applies
to what it can then hold: its min_instances' hulls, or the largest share plus one part.
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from ..errors import DataPipeError, Problem
from ..io.input_files import MAX_MESH_BYTES, read_regular
from ..io.models import read_ply

RANDOM_PACKING_MAX = 0.74   # densest random packing of convex parts (see the module doc), of hull volume


def mesh_extent(path: str | Path) -> np.ndarray | None:
    """(3,) bounding-box size of the vertices in a mesh file (file units), None if unread."""
    p = Path(path)
    try:
        ext = p.suffix.lower()
        if ext == ".obj":
            text = read_regular(p, MAX_MESH_BYTES).decode("utf-8", "replace")
            pts = [line.split()[1:4] for line in text.splitlines() if line.startswith("v ")]
            v = np.array(pts, dtype=np.float64)
        elif ext == ".ply":
            v = read_ply(p)[0]
        elif ext == ".stl":
            v = _stl_vertices(read_regular(p, MAX_MESH_BYTES))
        else:
            return None
    except (OSError, ValueError, KeyError, IndexError, struct.error, DataPipeError):
        return None
    if v is None or len(v) == 0:
        return None
    return np.ptp(v.reshape(-1, 3), axis=0)


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


def bin_volume(scene_cfg) -> float:
    """Inner volume (m^3) of the smallest bin a scene can draw: the drop zone's footprint times the
    wall height (the zone's height without walls), each at the low end of scene.bin_size_scale /
    bin_wall_scale (datapipe.draws.bin_shape)."""
    hx, hy, hz = (float(v) for v in scene_cfg.drop_zone_scale)
    size = min(scene_cfg.bin_size_scale)
    wall = min(scene_cfg.bin_wall_scale) if scene_cfg.make_bin else 1.0
    return (2 * hx * size) * (2 * hy * size) * (2 * hz * wall)


def fill_problems(cfg, hull_volumes: dict[int, float]) -> list[Problem]:
    """A problem at the object entry that adds the most volume when the convex hulls of a scene's
    largest part count (each entry's max_instances) cannot be packed into the bin (module doc).
    `hull_volumes`: object entry index -> one part's hull volume in m^3 (scale applied).
    With scene.fill the counts stop at the drawn share instead (_fill_share_problems)."""
    room = RANDOM_PACKING_MAX * bin_volume(cfg.scene)
    parts = {i: cfg.objects[i].max_instances * v for i, v in hull_volumes.items()}
    total = sum(parts.values())
    if total <= room or not parts:
        return []
    if cfg.scene.fill is not None:
        return _fill_share_problems(cfg, hull_volumes, room)
    worst = max(parts, key=parts.get)
    o, v = cfg.objects[worst], hull_volumes[worst]
    keep = int(max(0.0, room - (total - parts[worst])) // v) if v > 0 else o.max_instances
    fix = (f"lower objects[{worst}].max_instances to {keep} or less" if keep >= max(o.min_instances, 1) else
           "lower the max_instances of the object entries") + ", or enlarge scene.drop_zone_scale"
    return [Problem(f"objects[{worst}].max_instances",
                    f"a scene may hold {sum(cfg.objects[i].max_instances for i in parts)} parts whose convex hulls "
                    f"take {total * 1e3:.3g} litres ({o.max_instances} x {v * 1e6:.3g} cm^3 from this entry), and the bin holds {bin_volume(cfg.scene) * 1e3:.3g} litres: no random pile is "
                    f"denser than {RANDOM_PACKING_MAX:g} of that ({room * 1e3:.3g} litres), so the rest would be "
                    "thrown out of the bin", fix)]


def _fill_share_problems(cfg, hull_volumes: dict[int, float], room: float) -> list[Problem]:
    """scene.fill adds parts only until their hulls reach the drawn share of the scene's bin
    (datapipe/draws/fill.py), starting from every entry's min_instances: a scene holds at most the
    min_instances' hulls, or the largest share plus the one part that crosses it. As shares of the
    drawn bin, both are largest in the smallest bin; max_instances then only caps the counts."""
    smallest = bin_volume(cfg.scene)
    least = {i: cfg.objects[i].min_instances * v for i, v in hull_volumes.items()}
    if sum(least.values()) > room:
        worst = max(least, key=least.get)
        return [Problem(f"objects[{worst}].min_instances",
                        f"the min_instances' convex hulls take {sum(least.values()) * 1e3:.3g} litres, more than "
                        f"{RANDOM_PACKING_MAX:g} of the smallest bin ({room * 1e3:.3g} litres): the rest would be "
                        "thrown out of the bin", "lower the min_instances of the object entries, or enlarge "
                        "scene.drop_zone_scale")]
    crossing = max(hull_volumes.values())
    if float(cfg.scene.fill[1]) * smallest + crossing > room:
        return [Problem("scene.fill", f"the fill share {float(cfg.scene.fill[1]):g} of the smallest bin "
                        f"({smallest * 1e3:.3g} litres) plus one part of {crossing * 1e6:.3g} cm^3 exceeds "
                        f"{RANDOM_PACKING_MAX:g} of it: no random pile is that dense", "lower scene.fill, or "
                        "enlarge scene.drop_zone_scale")]
    return []
