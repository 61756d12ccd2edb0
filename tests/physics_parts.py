"""Procedural test parts for the physics tests and benchmarks/bench_physics.py: closed, outward-wound
triangle meshes in metres, written as OBJ. No bpy. scripts/make_assets.py builds the demo parts
(datapipe/assets/) with the same two extruders, `ring_prism` and `extrude_profile`.

    plate(0.04, 0.04, 0.001)     thin plate 40 x 40 x 1 mm
    washer(0.012, 0.0065, 0.0015) flat washer (ring), 24 sides
    peg(0.0025, 0.005)           cylinder (5 mm tall peg: "tiny parts")
    hex_nut(0.005, ...)          hex prism with a hex hole
    u_channel(), l_bracket()     concave extrusions (the cases that need DECOMPOSED)
"""
from __future__ import annotations

from pathlib import Path

import numpy as np


def ring_prism(outer, height, inner=None):
    """Extrude a CCW polygon (x, y) along z; with `inner` (same vertex count) a ring with a hole."""
    outer = np.asarray(outer, float)
    n = len(outer)
    z0, z1 = -height / 2, height / 2
    verts = [(x, y, z0) for x, y in outer] + [(x, y, z1) for x, y in outer]
    faces = []
    for i in range(n):
        j = (i + 1) % n
        faces += [(i, j, n + j), (i, n + j, n + i)]
    if inner is None:
        for i in range(1, n - 1):
            faces += [(0, i + 1, i), (n, n + i, n + i + 1)]
    else:
        inner = np.asarray(inner, float)
        b = len(verts)
        verts += [(x, y, z0) for x, y in inner] + [(x, y, z1) for x, y in inner]
        for i in range(n):
            j = (i + 1) % n
            faces += [(b + i, b + n + j, b + j), (b + i, b + n + i, b + n + j)]
            faces += [(i, b + j, j), (i, b + i, b + j)]
            faces += [(n + i, n + j, b + n + j), (n + i, b + n + j, b + n + i)]
    return np.array(verts), np.array(faces)


def _ear_clip(poly):
    """Triangles (index triples, CCW) of a simple CCW polygon."""
    idx = list(range(len(poly)))
    p = np.asarray(poly, float)
    tris = []

    def cross(o, a, b):
        return (a[0] - o[0]) * (b[1] - o[1]) - (a[1] - o[1]) * (b[0] - o[0])

    while len(idx) > 3:
        for k in range(len(idx)):
            i, j, m = idx[k - 1], idx[k], idx[(k + 1) % len(idx)]
            if cross(p[i], p[j], p[m]) <= 0:
                continue                      # reflex corner
            inside = any(cross(p[i], p[j], p[q]) >= 0 and cross(p[j], p[m], p[q]) >= 0 and
                         cross(p[m], p[i], p[q]) >= 0 for q in idx if q not in (i, j, m))
            if not inside:
                tris.append((i, j, m))
                idx.pop(k)
                break
        else:
            raise ValueError("polygon is not simple")
    tris.append(tuple(idx))
    return tris


def extrude_profile(profile, depth, caps=None, centre=True):
    """Extrude a simple CCW profile in the x-z plane along y (any concave outline). `caps`: the
    profile's triangles (default: ear clipping); `centre`: move the bounding box's centre to the origin."""
    prof = np.asarray(profile, float)
    n = len(prof)
    # profile (x, z) CCW seen from -y: extrude along +y
    verts = [(x, -depth / 2, z) for x, z in prof] + [(x, depth / 2, z) for x, z in prof]
    faces = []
    for i in range(n):
        j = (i + 1) % n
        faces += [(i, n + j, j), (i, n + i, n + j)]
    for a, b, c in _ear_clip(prof) if caps is None else caps:
        faces += [(a, b, c), (n + a, n + c, n + b)]
    v, f = np.array(verts), np.array(faces)
    return (v - (v.min(axis=0) + v.max(axis=0)) / 2 if centre else v), f


def plate(w=0.04, d=0.04, t=0.001):
    return ring_prism([(-w / 2, -d / 2), (w / 2, -d / 2), (w / 2, d / 2), (-w / 2, d / 2)], t)


def washer(r_out=0.012, r_in=0.0065, t=0.0015, sides=24):
    a = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    return ring_prism(np.c_[r_out * np.cos(a), r_out * np.sin(a)], t, np.c_[r_in * np.cos(a), r_in * np.sin(a)])


def peg(r=0.0025, h=0.005, sides=16):
    a = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    return ring_prism(np.c_[r * np.cos(a), r * np.sin(a)], h)


def hex_nut(across_flats=0.01, hole=0.0028, t=0.004):
    a = np.linspace(0, 2 * np.pi, 6, endpoint=False) + np.pi / 6
    r = across_flats / 2 / np.cos(np.pi / 6)
    return ring_prism(np.c_[r * np.cos(a), r * np.sin(a)], t, np.c_[hole * np.cos(a), hole * np.sin(a)])


def u_channel(w=0.04, h=0.025, t=0.004, depth=0.03):
    prof = [(0, 0), (w, 0), (w, h), (w - t, h), (w - t, t), (t, t), (t, h), (0, h)]
    return extrude_profile(prof, depth)


def l_bracket(w=0.04, h=0.03, t=0.004, depth=0.02):
    return extrude_profile([(0, 0), (w, 0), (w, t), (t, t), (t, h), (0, h)], depth)


def volume(verts, faces) -> float:
    v = np.asarray(verts)
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    return float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6)


def write_obj(path, verts, faces) -> str:
    path = Path(path)
    lines = [f"v {x:.7f} {y:.7f} {z:.7f}" for x, y, z in verts]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces]
    path.write_text("\n".join(lines) + "\n")
    return str(path)


PARTS = {"plate": plate, "washer": washer, "peg5": peg, "nut5": hex_nut, "u_channel": u_channel,
         "l_bracket": l_bracket}


def write_all(folder) -> dict[str, str]:
    """Write every part of PARTS into `folder`; name -> path."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    return {name: write_obj(folder / f"{name}.obj", *make()) for name, make in PARTS.items()}
