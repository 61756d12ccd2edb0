"""`models_eval/`: the uniformly resampled models BOP's evaluation reads (MSSD, MSPD, VSD). No bpy.

bop_toolkit makes them with a voxel remesh whose default voxel is 1 mm (its Blender script
scripts/remesh_models_for_eval_bpy.py; the older MeshLab script resamples at 0.25% of the bounding
box diagonal and decimates), so its model points lie about 1 mm apart whatever the source mesh.
The evaluation takes the maximum (MSSD, MSPD) or the mean (ADD) over these points, so they should
cover the surface evenly; VSD renders them, so they stay a mesh.

Here, without changing the surface: every triangle is subdivided until its edges are at most
`cell`, then the vertices are clustered on a grid of that cell (one vertex per occupied cell: the
one nearest the cell's centre, so every point lies on the original surface), and the triangles are
re-indexed onto the kept vertices (degenerate ones dropped). With cell = spacing / (1 + sqrt 3),
every surface point is within `spacing` of a model point (a point is within `cell` of a subdivided
vertex, which is within a cell diagonal of its cluster's vertex), i.e. the points are at most the
toolkit's sampling distance apart.
"""
from __future__ import annotations

import numpy as np

SPACING_MM = 1.0          # bop_toolkit's voxel size for models_eval (remesh_models_for_eval_bpy.py)


def _subdivide(verts: np.ndarray, faces: np.ndarray, edge: float) -> tuple[np.ndarray, np.ndarray]:
    """Every triangle split into n x n by a barycentric grid, n = ceil(longest edge / edge)."""
    tri = verts[faces]
    longest = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(axis=1)
    n_per = np.maximum(np.ceil(longest / edge).astype(np.int64), 1)
    out_v, out_f, base = [], [], 0
    for n in np.unique(n_per):
        t = tri[n_per == n]                                           # (T, 3, 3)
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        i, j = i[keep], j[keep]
        index = -np.ones((n + 1, n + 1), dtype=np.int64)
        index[i, j] = np.arange(len(i))
        pts = (t[:, None, 0] + (i / n)[None, :, None] * (t[:, None, 1] - t[:, None, 0])
               + (j / n)[None, :, None] * (t[:, None, 2] - t[:, None, 0]))
        a, b = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
        up = a + b < n
        down = a + b < n - 1
        local = np.concatenate([
            np.stack([index[a[up], b[up]], index[a[up] + 1, b[up]], index[a[up], b[up] + 1]], 1),
            np.stack([index[a[down] + 1, b[down]], index[a[down] + 1, b[down] + 1], index[a[down], b[down] + 1]], 1)])
        offsets = base + np.arange(len(t))[:, None, None] * len(i)
        out_v.append(pts.reshape(-1, 3))
        out_f.append((local[None] + offsets).reshape(-1, 3))
        base += len(t) * len(i)
    return np.concatenate(out_v), np.concatenate(out_f)


def resample_for_eval(verts_mm: np.ndarray, faces: np.ndarray, spacing_mm: float = SPACING_MM
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(verts, faces) of the evaluation model of a mesh: points every ~`spacing_mm`, none farther
    than `spacing_mm` from any surface point (see above)."""
    verts = np.asarray(verts_mm, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    cell = float(spacing_mm) / (1.0 + np.sqrt(3.0))
    sv, sf = _subdivide(verts, faces, cell)
    key = np.floor((sv - sv.min(axis=0)) / cell).astype(np.int64)
    _, cluster = np.unique(key, axis=0, return_inverse=True)
    cluster = cluster.reshape(-1)
    off = np.linalg.norm(sv - (sv.min(axis=0) + (key + 0.5) * cell), axis=1)
    order = np.lexsort((off, cluster))                   # per cluster, the vertex nearest its centre first
    first = order[np.concatenate([[True], cluster[order][1:] != cluster[order][:-1]])]
    rep = np.empty(cluster.max() + 1, dtype=np.int64)
    rep[cluster[first]] = np.arange(len(first))
    f = rep[cluster[sf]]
    f = f[(f[:, 0] != f[:, 1]) & (f[:, 1] != f[:, 2]) & (f[:, 0] != f[:, 2])]
    _, uniq = np.unique(np.sort(f, axis=1), axis=0, return_index=True)
    return sv[first], f[np.sort(uniq)]


def vertex_normals(verts: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Unit area-weighted vertex normals (0 for a vertex in no triangle)."""
    tri = verts[faces]
    fn = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n = np.zeros_like(verts)
    for k in range(3):
        np.add.at(n, faces[:, k], fn)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    return np.where(norm > 0, n / np.where(norm > 0, norm, 1.0), 0.0)
