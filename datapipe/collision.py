"""Collision geometry of a part, from its model mesh: how concave it is, how thin it is, and its
convex decomposition. No bpy (numpy, scipy, coacd), so it is tested without Blender.

Concave parts
    Blender's triangle-mesh shape for moving bodies (MESH) lets concave parts catch on each other
    and throws them out of the bin; a convex hull fills their hollows. DataPipe simulates concave
    parts as a compound of convex pieces from CoACD (approximate convex decomposition, collision-
    aware; `coacd` on PyPI). A decomposition takes seconds (0.6 s for the demo bracket, 3.5 s for
    the nut), so it is cached on disk, keyed by the mesh data itself (vertex and triangle bytes,
    i.e. file + scale) and the decomposition settings: a run decomposes each mesh at most once,
    later runs never.

    "Clearly concave": the mesh fills less than CONCAVE_FILL of its convex hull's volume (an
    L-bracket 0.48, a U-channel ~0.5; a hex nut 0.79 and a peg 1.0 stay convex hulls, which only
    fills a nut's hole).

Thinness
    `min_width`: the smallest width of a convex shape, over the directions of its hull's face
    normals (exact for polytopes up to edge-edge directions). For a decomposed part, the smallest
    over its pieces: that is what another part could pass through in one physics substep.
"""
from __future__ import annotations

import hashlib
import os
import tempfile
from pathlib import Path

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from .errors import Problem

CONCAVE_FILL = 0.7                 # mesh volume / hull volume below this: decompose
COACD_SETTINGS = {"threshold": 0.05, "max_convex_hull": 16, "preprocess_mode": "auto", "seed": 0}
CACHE_ENV = "DATAPIPE_CACHE"       # folder of the on-disk cache (default ~/.cache/datapipe)

Hull = tuple[np.ndarray, np.ndarray]    # (V,3) float64 vertices, (F,3) int64 triangles


def cache_dir() -> Path:
    env = os.environ.get(CACHE_ENV)
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "datapipe"


def mesh_volume(verts: np.ndarray, tris: np.ndarray) -> float:
    """Enclosed volume of a closed triangle mesh (signed tetrahedra, absolute value)."""
    v = np.asarray(verts, dtype=np.float64)
    t = np.asarray(tris, dtype=np.int64)
    if len(t) == 0:
        return 0.0
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    return abs(float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum()) / 6.0)


def _hull(verts: np.ndarray) -> ConvexHull | None:
    try:
        return ConvexHull(np.asarray(verts, dtype=np.float64))
    except (QhullError, ValueError):       # flat or degenerate: no volume
        return None


def fill_ratio(verts: np.ndarray, tris: np.ndarray) -> float:
    """Mesh volume over its convex hull's volume (1.0 for a convex or a degenerate mesh)."""
    h = _hull(verts)
    if h is None or h.volume <= 0:
        return 1.0
    return min(1.0, mesh_volume(verts, tris) / h.volume)


def is_clearly_concave(verts: np.ndarray, tris: np.ndarray) -> bool:
    return fill_ratio(verts, tris) < CONCAVE_FILL


def min_width(verts: np.ndarray) -> float:
    """Smallest width of the convex hull of `verts` over its face-normal directions (m)."""
    v = np.asarray(verts, dtype=np.float64)
    h = _hull(v)
    if h is None:
        return float(np.ptp(v, axis=0).min()) if len(v) else 0.0
    n = h.equations[:, :3]
    proj = v @ n.T
    return float((proj.max(axis=0) - proj.min(axis=0)).min())


def coacd_available() -> bool:
    """Whether this Python can import coacd (PyPI has no wheel for some platforms, e.g. Intel macOS)."""
    try:
        import coacd  # noqa: F401
    except ImportError:
        return False
    return True


def missing_coacd(field: str) -> Problem:
    """The refusal of a part that needs convex pieces where coacd cannot be imported."""
    return Problem(field, "the part is simulated as convex pieces (a concave part with AUTO, or DECOMPOSED/MESH), "
                   "which needs the coacd package, and this Python cannot import it",
                   "install coacd into the Python that runs DataPipe (pip install coacd; the Blender extension "
                   "bundles it for linux-x64, windows-x64 and macos-arm64, PyPI has no wheel of coacd >= 1.0.14 "
                   "for macos-x64), or set this collision_shape to CONVEX_HULL (the part's hollows are then "
                   "filled in the simulation)")


def _key(verts: np.ndarray, tris: np.ndarray) -> str:
    import coacd
    h = hashlib.sha256()
    h.update(np.ascontiguousarray(verts, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(tris, dtype=np.int64).tobytes())
    h.update(repr(sorted(COACD_SETTINGS.items())).encode())
    h.update(getattr(coacd, "__version__", "").encode())
    return h.hexdigest()[:32]


def decompose(verts: np.ndarray, tris: np.ndarray, cache: Path | None = None) -> tuple[list[Hull], bool]:
    """Convex pieces of a closed mesh (model coordinates) and whether they came from the cache."""
    cache = cache_dir() if cache is None else Path(cache)
    path = cache / "convex" / f"{_key(verts, tris)}.npz"
    if path.is_file():
        try:
            with np.load(path) as z:
                return _unpack(z["verts"], z["tris"], z["vcount"], z["tcount"]), True
        except (OSError, KeyError, ValueError):
            pass                           # unreadable entry: decompose again and overwrite it
    import coacd
    coacd.set_log_level("error")
    mesh = coacd.Mesh(np.asarray(verts, dtype=np.float64), np.asarray(tris, dtype=np.int64))
    pieces = [(np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64))
              for v, f in coacd.run_coacd(mesh, **COACD_SETTINGS)]
    pieces = [p for p in pieces if len(p[0]) >= 4 and len(p[1]) >= 4]
    if not pieces:
        pieces = [(np.asarray(verts, dtype=np.float64), np.asarray(tris, dtype=np.int64))]
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".npz.tmp")
    os.close(fd)
    from .io.files import atomic_path
    # atomic: parallel workers never read half a file; a failed write leaves no temporary
    with atomic_path(path, tmp) as t, open(t, "wb") as fh:
        np.savez(fh, verts=np.concatenate([p[0] for p in pieces]), tris=np.concatenate([p[1] for p in pieces]),
                 vcount=[len(p[0]) for p in pieces], tcount=[len(p[1]) for p in pieces])
    return pieces, False


def _unpack(verts, tris, vcount, tcount) -> list[Hull]:
    out = []
    vo = to = 0
    for nv, nt in zip(vcount, tcount):
        out.append((np.asarray(verts[vo:vo + nv], dtype=np.float64), np.asarray(tris[to:to + nt], dtype=np.int64)))
        vo, to = vo + int(nv), to + int(nt)
    return out
