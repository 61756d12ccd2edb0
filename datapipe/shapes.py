"""Procedural distractor shapes (`objects[i].shape`): the spec, its rules, the per-instance size draw
and the meshes, so a scene gets clutter without any asset download (no bpy; core/objects.py builds
the Blender objects from these arrays).

A shape entry is a distractor (`annotate: false`): every instance draws its own size, so no single
model could describe the entry in BOP's models folder. Spec (sizes in metres, times the entry's
`scale`; each `size` is one fixed list or `[[min ...], [max ...]]`, each number drawn uniformly):

    {"kind": "box",      "size": [x, y, z]}                          edges
    {"kind": "plate",    "size": [x, y, thickness]}                  a box whose thickness is at most
                                                                     PLATE_RATIO x its smaller side
    {"kind": "cylinder", "size": [diameter, length]}                 ROUND_SEGMENTS flat sides
    {"kind": "tube",     "size": [outer diameter, wall, length]}     wall < half the outer diameter

Every mesh is closed, outward-facing and centred on its centroid (the origin is the centre of mass,
so Blender's rigid body needs no re-centred copy). Collision: the convex kinds are their own convex
hull; a tube is a compound of its ROUND_SEGMENTS wall segments (each a convex hexahedron), exact
without CoACD.
"""
from __future__ import annotations

import math

import numpy as np

KINDS = {          # kind -> the names of its size numbers
    "box": ("x", "y", "z"),
    "plate": ("x", "y", "thickness"),
    "cylinder": ("diameter", "length"),
    "tube": ("outer diameter", "wall", "length"),
}
ROUND_SEGMENTS = 16          # flat sides of a cylinder or tube (a 16-gon's area is 97% of the circle's)
PLATE_RATIO = 0.25           # a plate is at most this thick relative to its smaller side (else: a box)
MIN_SIZE = 1e-3              # m; thinner than this a part is below Bullet's margins and the camera's pixel


def size_range(spec: dict) -> tuple[np.ndarray, np.ndarray]:
    """(lo, hi) float arrays of a valid spec's size (a fixed size: lo == hi)."""
    size = spec["size"]
    if size and isinstance(size[0], (list, tuple)):
        return np.asarray(size[0], dtype=np.float64), np.asarray(size[1], dtype=np.float64)
    a = np.asarray(size, dtype=np.float64)
    return a, a.copy()


def problems(spec, where: str) -> list[tuple[str, str, str]]:
    """(field, what is wrong, fix) of a shape spec; [] when it is valid."""
    if not isinstance(spec, dict):
        return [(where, f"expected an object like {{\"kind\": \"box\", \"size\": [...]}}, got {type(spec).__name__}",
                 f"give {{\"kind\": one of {', '.join(KINDS)}, \"size\": [...]}}")]
    out = []
    extra = sorted(set(spec) - {"kind", "size"})
    if extra:
        out.append((f"{where}.{extra[0]}", "unknown key", "use only \"kind\" and \"size\""))
    kind = spec.get("kind")
    if kind not in KINDS:
        return out + [(f"{where}.kind", f"unknown kind {kind!r}", f"use one of {', '.join(KINDS)}")]
    names = KINDS[kind]
    n = len(names)
    fix_form = (f"give {n} sizes in metres ({', '.join(names)}), or [[min ...], [max ...]] to draw each "
                "instance's size")
    size = spec.get("size")
    if not isinstance(size, (list, tuple)) or not size:
        return out + [(f"{where}.size", f"expected a list, got {size!r}", fix_form)]
    ranged = isinstance(size[0], (list, tuple))
    rows = list(size) if ranged else [size]
    if ranged and len(rows) != 2:
        return out + [(f"{where}.size", f"a range needs 2 lists ([min ...], [max ...]), got {len(rows)}", fix_form)]
    for r in rows:
        if not isinstance(r, (list, tuple)) or len(r) != n or not all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in r):
            return out + [(f"{where}.size", f"{kind} needs {n} finite numbers ({', '.join(names)}), got {r!r}",
                           fix_form)]
    lo, hi = size_range({"size": size})
    for k in range(n):
        if lo[k] < MIN_SIZE:
            out.append((f"{where}.size", f"{names[k]} {lo[k]:g} m is below {MIN_SIZE * 1000:g} mm",
                        f"give every size in metres, >= {MIN_SIZE:g}"))
        if lo[k] > hi[k]:
            out.append((f"{where}.size", f"{names[k]}: min {lo[k]:g} > max {hi[k]:g}",
                        "give [[min ...], [max ...]] with each min <= its max"))
    if out:
        return out
    if kind == "plate" and hi[2] > PLATE_RATIO * min(lo[0], lo[1]):
        out.append((f"{where}.size", f"a thickness up to {hi[2]:g} m is more than {PLATE_RATIO:g} x the smaller "
                    f"side ({min(lo[0], lo[1]):g} m): not a plate", "make the plate thinner, or use kind \"box\""))
    if kind == "tube" and hi[1] >= lo[0] / 2:
        out.append((f"{where}.size", f"a wall up to {hi[1]:g} m leaves no bore in an outer diameter of "
                    f"{lo[0]:g} m", "give a wall below half the smallest outer diameter, or use kind \"cylinder\""))
    return out


def draw_sizes(rng: np.random.Generator, spec: dict, scale: float, n: int) -> np.ndarray:
    """(n, k) sizes in metres, each number uniform in its range (a fixed size draws nothing)."""
    lo, hi = size_range(spec)
    if n == 0:
        return np.zeros((0, len(lo)))
    if np.array_equal(lo, hi):
        return np.tile(lo * scale, (n, 1))
    return (lo + (hi - lo) * rng.random((n, len(lo)))) * scale


def largest(spec: dict, scale: float) -> np.ndarray:
    """The largest size a spec draws (m): its bounding sphere places the instances."""
    return size_range(spec)[1] * scale


def _prism(ring: np.ndarray, length: float) -> tuple[np.ndarray, np.ndarray]:
    """A convex prism along z (centred) over the convex polygon `ring` (m, counter-clockwise seen from +z)."""
    m = len(ring)
    h = length / 2
    verts = np.vstack([np.column_stack([ring, np.full(m, -h)]), np.column_stack([ring, np.full(m, h)])])
    faces = []
    for k in range(m):
        a, b = k, (k + 1) % m
        faces += [(a, b, m + b), (a, m + b, m + a)]
    faces += [(0, k + 1, k) for k in range(1, m - 1)]                   # bottom, facing -z
    faces += [(m, m + k, m + k + 1) for k in range(1, m - 1)]           # top, facing +z
    return verts, np.asarray(faces, dtype=np.int64)


def _circle(d: float) -> np.ndarray:
    a = 2 * math.pi * np.arange(ROUND_SEGMENTS) / ROUND_SEGMENTS
    return np.column_stack([np.cos(a), np.sin(a)]) * (d / 2)


def mesh(kind: str, size) -> tuple[np.ndarray, np.ndarray]:
    """(verts (V,3) m, triangles (F,3)) of one instance: closed, outward-facing, centroid at the origin."""
    s = [float(x) for x in size]
    if kind in ("box", "plate"):
        x, y = s[0] / 2, s[1] / 2
        return _prism(np.array([[-x, -y], [x, -y], [x, y], [-x, y]]), s[2])
    if kind == "cylinder":
        return _prism(_circle(s[0]), s[1])
    if kind == "tube":
        outer, inner = _circle(s[0]), _circle(s[0] - 2 * s[1])
        m, h = ROUND_SEGMENTS, s[2] / 2
        verts = np.vstack([np.column_stack([outer, np.full(m, -h)]), np.column_stack([outer, np.full(m, h)]),
                           np.column_stack([inner, np.full(m, -h)]), np.column_stack([inner, np.full(m, h)])])
        ob, ot, ib, it = 0, m, 2 * m, 3 * m
        faces = []
        for k in range(m):
            j = (k + 1) % m
            faces += [(ob + k, ob + j, ot + j), (ob + k, ot + j, ot + k)]        # outer wall, outward
            faces += [(ib + k, it + j, ib + j), (ib + k, it + k, it + j)]        # bore, facing the axis
            faces += [(ot + k, ot + j, it + j), (ot + k, it + j, it + k)]        # top ring, +z
            faces += [(ob + k, ib + j, ob + j), (ob + k, ib + k, ib + j)]        # bottom ring, -z
        return verts, np.asarray(faces, dtype=np.int64)
    raise ValueError(f"unknown shape kind {kind!r}")


def convex_pieces(kind: str, size) -> list[tuple[np.ndarray, np.ndarray]]:
    """The convex pieces the simulation uses: the mesh itself for the convex kinds, a tube's wall
    segments (between neighbouring corners of the outer and inner polygons) for a tube."""
    if kind != "tube":
        return [mesh(kind, size)]
    s = [float(x) for x in size]
    outer, inner = _circle(s[0]), _circle(s[0] - 2 * s[1])
    pieces = []
    for k in range(ROUND_SEGMENTS):
        j = (k + 1) % ROUND_SEGMENTS
        ring = np.array([inner[k], outer[k], outer[j], inner[j]])     # counter-clockwise seen from +z
        pieces.append(_prism(ring, s[2]))
    return pieces
