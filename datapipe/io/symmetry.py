"""Symmetries of a part mesh in BOP's models_info.json form, detected or checked. No bpy.

BOP lists a model's symmetries as `symmetries_discrete`: every non-identity rigid transform that maps
the model onto itself, each a 4x4 matrix as 16 row-major numbers (translation in mm), and
`symmetries_continuous`: axes of revolution as {"axis": unit vector, "offset": a point on the axis
in mm}. Pose errors that respect symmetry (MSSD, MSPD) and symmetry-aware training losses read them.

Detection (`detect_symmetries`): a rotation R about an axis through the surface's centroid (every
symmetry fixes it) is a symmetry when every point of a uniform surface sample, rotated by R (and by
R^-1), lies on the surface within `tolerance` x the model's diameter (a Hausdorff test, one-sided
for R and R^-1: R is area preserving, so R(S) inside S means R(S) = S). The distance of a rotated
point to the surface is exact: to the triangles under the rotated point's nearest samples of a dense second sample.

Candidate axes: the normals of the largest faces (side faces of a prism give its flip axes), and
the principal axes of the surface's inertia. Per axis, a continuous symmetry is tested first (three
unrelated angles), then the orders n = 2 .. MAX_ORDER of rotations by 2 pi / n (the largest whose
multiples all pass). The discrete symmetries written are the group those rotations generate, less the identity
and, for a body of revolution, less the rotations about its own axis (BOP lists only the flip).
"""
from __future__ import annotations

import numpy as np

TOLERANCE = 0.01          # fraction of the diameter (default): 1% of a 40 mm part is 0.4 mm
MAX_ORDER = 24            # largest n of a discrete rotation by 2 pi / n that is tested
MAX_GROUP = 96            # a larger closure means the tolerance is too loose for discrete symmetries
_CONTINUOUS_ANGLES = (0.4137, 1.1, 2.0 * np.pi / 7.3)   # unrelated to any 2 pi / n, n <= MAX_ORDER
_N_CHECK = 1500           # rotated sample points per test
_N_REF = 40000            # dense reference sample of the surface
_K = 8                    # nearest reference samples considered per point


def sample_surface(verts: np.ndarray, faces: np.ndarray, n: int, rng: np.random.Generator, *,
                   with_faces: bool = False):
    """`n` points uniformly distributed on the surface (area-weighted) and their unit face normals
    (or, with_faces, the index of their triangle)."""
    tri = np.asarray(verts, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(cross, axis=1)
    if area.sum() <= 0:
        raise ValueError("the mesh has no surface area")
    f = rng.choice(len(tri), size=n, p=area / area.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    t = tri[f]
    pts = t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0])
    if with_faces:
        return pts, f
    return pts, cross[f] / np.maximum(np.linalg.norm(cross[f], axis=1, keepdims=True), 1e-300)


def rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)


def _segment_distance(p, a, b):
    ab = b - a
    t = np.clip(np.einsum("...c,...c->...", p - a, ab) / np.maximum(np.einsum("...c,...c->...", ab, ab), 1e-300),
                0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1)


def point_triangle_distance(p: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Exact distance of points p (..., 3) to triangles tri (..., 3, 3)."""
    a, b, c = tri[..., 0, :], tri[..., 1, :], tri[..., 2, :]
    n = np.cross(b - a, c - a)
    nn = np.maximum(np.einsum("...c,...c->...", n, n), 1e-300)
    w = p - a
    # barycentric coordinates of p's projection onto the triangle's plane
    s = np.einsum("...c,...c->...", np.cross(w, c - a), n) / nn
    t = np.einsum("...c,...c->...", np.cross(b - a, w), n) / nn
    inside = (s >= 0) & (t >= 0) & (s + t <= 1)
    plane = np.abs(np.einsum("...c,...c->...", w, n)) / np.sqrt(nn)
    edges = np.minimum(np.minimum(_segment_distance(p, a, b), _segment_distance(p, b, c)), _segment_distance(p, c, a))
    return np.where(inside, plane, edges)


class _Surface:
    """Distance of points to a mesh surface: exact to the triangles under the nearest samples of a
    dense surface sample (every triangle has its centroid in it). Missing the closest triangle can
    only over-estimate a distance, so a symmetry may be missed but never made up."""

    def __init__(self, verts, faces, rng):
        from scipy.spatial import cKDTree
        self.tri = np.asarray(verts, dtype=np.float64)[np.asarray(faces, dtype=np.int64)]
        pts, face = sample_surface(verts, faces, _N_REF, rng, with_faces=True)
        self.ref = np.vstack([pts, self.tri.mean(axis=1)])
        self.face = np.concatenate([face, np.arange(len(self.tri))])
        self.tree = cKDTree(self.ref)

    def distance(self, pts: np.ndarray) -> np.ndarray:
        _, idx = self.tree.query(pts, k=_K)
        d = point_triangle_distance(pts[:, None, :], self.tri[self.face[idx]])
        return d.min(axis=1)


def _maps_onto_itself(surface: _Surface, pts: np.ndarray, centre: np.ndarray, R: np.ndarray, tol: float) -> bool:
    for M in (R, R.T):
        q = (pts - centre) @ M.T + centre
        # a cheap look at a few points first: most candidates fail there
        if surface.distance(q[:150]).max() > tol or surface.distance(q[150:]).max() > tol:
            return False
    return True


def _candidate_axes(verts: np.ndarray, faces: np.ndarray, tolerance: float) -> list[np.ndarray]:
    """Normals of the largest faces (exact for CAD meshes), then the principal axes of the surface's
    inertia (for curved parts); one per direction: axes closer than 2 x tolerance radians turn no
    point further apart than the tolerance (the diameter's fraction), so they are one axis."""
    tri = verts[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = np.linalg.norm(cross, axis=1)
    axes = [cross[f] / area[f] for f in np.argsort(-area)[:64] if area[f] > 0]
    centroid = (area[:, None] * tri.mean(axis=1)).sum(axis=0) / area.sum()
    inertia = np.zeros((3, 3))
    for k in range(3):       # second moment of the vertices of each triangle, area weighted
        d = tri[:, k] - centroid
        inertia += (area[:, None, None] * d[:, :, None] * d[:, None, :]).sum(axis=0)
    vals, vecs = np.linalg.eigh(inertia)
    for k in range(3):       # an axis of a degenerate pair is arbitrary (any in-plane direction)
        if all(abs(vals[k] - vals[j]) > 0.01 * abs(vals).max() for j in range(3) if j != k):
            axes.append(vecs[:, k])
    out: list[np.ndarray] = []
    for a in axes:
        a = a / np.linalg.norm(a)
        a = a if a[np.argmax(np.abs(a))] > 0 else -a              # one sign per direction
        if all(abs(float(a @ b)) < np.cos(max(2.0 * tolerance, 1e-3)) for b in out):
            out.append(a)
    return out


def _closure(gens: list[np.ndarray], same: float) -> list[np.ndarray] | None:
    """Every product of the generators (3x3 rotations), identity included; None past MAX_GROUP.

    Two products closer than `same` (largest element difference) are one: measured axes are off by
    rounding, so the products of the measured generators never close exactly."""
    group = [np.eye(3)]
    frontier = [np.eye(3)]
    while frontier:
        new = []
        for g in frontier:
            for h in gens:
                m = h @ g
                if not any(np.abs(m - e).max() < same for e in group):
                    group.append(m)
                    new.append(m)
                    if len(group) > MAX_GROUP:
                        return None
        frontier = new
    return group


def _transform(R: np.ndarray, centre: np.ndarray) -> list[float]:
    """The 4x4 rotation by R about `centre`, row-major."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = centre - R @ centre
    T[np.abs(T) < 1e-12] = 0.0
    return [float(x) for x in T.reshape(-1)]


def detect_symmetries(verts_mm: np.ndarray, faces: np.ndarray, *, tolerance: float = TOLERANCE,
                      diameter_mm: float | None = None, seed: int = 0) -> dict:
    """{"symmetries_discrete": [...], "symmetries_continuous": [...]} of a mesh (BOP's form, mm);
    empty lists for none. `tolerance` is a fraction of the diameter."""
    from .models import diameter
    verts = np.asarray(verts_mm, dtype=np.float64).reshape(-1, 3)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    rng = np.random.default_rng(seed)
    surface = _Surface(verts, faces, rng)
    pts, _ = sample_surface(verts, faces, _N_CHECK, rng)
    # the area centroid, computed exactly from the triangles (every symmetry fixes it)
    tri = verts[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    centre = (area[:, None] * tri.mean(axis=1)).sum(axis=0) / area.sum()
    dia = diameter(verts) if diameter_mm is None else float(diameter_mm)
    tol = float(tolerance) * dia
    continuous: list[np.ndarray] = []
    gens: list[np.ndarray] = []
    for axis in _candidate_axes(verts, faces, float(tolerance)):
        if all(_maps_onto_itself(surface, pts, centre, rotation(axis, a), tol) for a in _CONTINUOUS_ANGLES):
            continuous.append(axis)
            continue
        for n in range(MAX_ORDER, 1, -1):
            # every multiple of the turn too: at a loose tolerance a hexagon passes 2 pi / 7, not 3 x it
            if all(_maps_onto_itself(surface, pts, centre, rotation(axis, 2 * np.pi * k / n), tol)
                   for k in range(1, n // 2 + 1)):
                gens.append(rotation(axis, 2 * np.pi / n))
                break
    if continuous:
        if len(continuous) > 1:           # revolution about two axes: a sphere; BOP has no form for it
            continuous = continuous[:1]
        axis = continuous[0]
        # the flip: a half turn about any axis perpendicular to the axis of revolution
        perp = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
        perp /= np.linalg.norm(perp)
        flip = rotation(perp, np.pi)
        discrete = [flip] if _maps_onto_itself(surface, pts, centre, flip, tol) else []
    else:
        # rotations that move no point by more than half the tolerance are the same symmetry
        group = _closure(gens, 0.5 * float(tolerance)) if gens else [np.eye(3)]
        if group is None:
            raise ValueError(f"more than {MAX_GROUP} discrete symmetries at tolerance {tolerance:g} x the "
                             "diameter (give a smaller tolerance)")
        discrete = group[1:]
    return {"symmetries_discrete": [_transform(R, centre) for R in discrete],
            "symmetries_continuous": [{"axis": [float(x) + 0.0 for x in a], "offset": [float(x) + 0.0 for x in centre]}
                                      for a in continuous]}


def check_symmetries(sym: object, where: str) -> dict:
    """A symmetries entry given by hand or read from a BOP models_info.json, checked: returns
    {"symmetries_discrete": [...], "symmetries_continuous": [...]} with only the keys it has."""
    from ..errors import DataPipeError
    if not isinstance(sym, dict):
        raise DataPipeError(f"{where}: expected a dict with 'symmetries_discrete' and/or "
                            "'symmetries_continuous', got " + type(sym).__name__)
    out = {}
    unknown = set(sym) - {"symmetries_discrete", "symmetries_continuous"}
    if unknown:
        raise DataPipeError(f"{where}: unknown keys {sorted(unknown)} (fix: use 'symmetries_discrete' "
                            "(4x4 row-major lists, mm) and 'symmetries_continuous' ({axis, offset}))")
    for key in ("symmetries_discrete", "symmetries_continuous"):
        if not isinstance(sym.get(key, []), list):
            raise DataPipeError(f"{where}.{key}: expected a list, got {type(sym[key]).__name__} (fix: "
                                + ("a list of 4x4 row-major matrices, translation in mm)" if key.endswith("discrete")
                                   else "a list of {\"axis\": [x, y, z], \"offset\": [x, y, z]})"))
    for k, T in enumerate(sym.get("symmetries_discrete", [])):
        M = _finite_array(T, 16)
        if M is None:
            raise DataPipeError(f"{where}.symmetries_discrete[{k}]: expected 16 numbers, all finite (fix: a 4x4 "
                                "row-major matrix, translation in mm)")
        M = M.reshape(4, 4)
        R = M[:3, :3]
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-4 or np.linalg.det(R) < 0 or np.abs(M[3] - [0, 0, 0, 1]).max() > 1e-6:
            raise DataPipeError(f"{where}.symmetries_discrete[{k}]: not a rigid transform (fix: a rotation "
                                "matrix with det +1 and last row 0 0 0 1)")
    if "symmetries_discrete" in sym:
        out["symmetries_discrete"] = [[float(x) for x in T] for T in sym["symmetries_discrete"]]
    for k, c in enumerate(sym.get("symmetries_continuous", [])):
        ok = isinstance(c, dict) and set(c) == {"axis", "offset"}
        axis, offset = (_finite_array(c["axis"], 3), _finite_array(c["offset"], 3)) if ok else (None, None)
        if axis is None or offset is None or not np.linalg.norm(axis) > 0:
            raise DataPipeError(f"{where}.symmetries_continuous[{k}]: expected {{\"axis\": [x, y, z] (finite, "
                                "non-zero), \"offset\": [x, y, z] (finite, mm)}")
    if "symmetries_continuous" in sym:
        out["symmetries_continuous"] = [{"axis": [float(x) for x in c["axis"]],
                                         "offset": [float(x) for x in c["offset"]]}
                                        for c in sym["symmetries_continuous"]]
    return out


def _finite_array(values, n: int) -> np.ndarray | None:
    """`values` as n finite float64s (a flat list of numbers, not bools), or None."""
    if not (isinstance(values, list) and len(values) == n
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in values)):
        return None
    with np.errstate(over="ignore"):             # 10**400 does not fit a float64: refused below
        try:
            a = np.asarray(values, dtype=np.float64)
        except OverflowError:
            return None
    return a if np.isfinite(a).all() else None
