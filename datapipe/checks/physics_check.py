"""An independent check of a settled scene from the final poses and the model meshes. No bpy.

The rigid-body engine's own contact data cannot judge the engine, so this measures the result the
way a user of the dataset sees it: the model meshes (triangles, model frame) placed at their final
world poses.

- interpenetration of two parts: sample points on A's surface (vertices, points along every edge,
  triangle centroids) that lie inside B (generalised winding number > 1/2: robust for closed
  meshes) and their distance to B's surface; a pair's depth is the larger of the two directions.
  The deepest point of two overlapping polyhedra is a vertex or an edge point of one of them, so
  the sampling misses at most about half the edge spacing of depth;
- below the floor: a part's lowest vertex under `floor_z`;
- floating: the gap from a part to everything else (other parts, the floor, the bin's walls) is
  more than `float_tol`; gaps are measured from A's samples to B's triangles and back.

Meshes need to be closed (watertight) for the inside test; the parts DataPipe drops are.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

PENETRATION_TOL = 0.0005    # m: a pair deeper than this counts as interpenetrating
FLOAT_TOL = 0.002           # m: a part further than this from everything else is floating
_CHUNK = 400_000            # points x triangles per vectorised block (memory ~ 100 MB at most)


@dataclass
class Part:
    """One placed part: model mesh (V,3)/(F,3) and its world pose T_world_model (4x4)."""
    name: str
    verts: np.ndarray
    tris: np.ndarray
    pose: np.ndarray

    def world(self) -> np.ndarray:
        T = np.asarray(self.pose, dtype=np.float64)
        return np.asarray(self.verts, dtype=np.float64) @ T[:3, :3].T + T[:3, 3]


@dataclass
class SceneCheck:
    pairs: list[tuple[str, str, float]] = field(default_factory=list)   # (a, b, depth m), depth > tol
    max_depth: float = 0.0                       # deepest interpenetration of any pair (m)
    below_floor: list[tuple[str, float]] = field(default_factory=list)  # (name, depth under floor m)
    floating: list[tuple[str, float]] = field(default_factory=list)     # (name, gap to nearest m)
    max_floor_depth: float = 0.0


def edge_samples(verts: np.ndarray, tris: np.ndarray, spacing: float) -> np.ndarray:
    """Vertices, points along each edge no further than `spacing` apart, triangle centroids."""
    v = np.asarray(verts, dtype=np.float64)
    t = np.asarray(tris, dtype=np.int64)
    e = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    e = np.unique(np.sort(e, axis=1), axis=0)
    a, b = v[e[:, 0]], v[e[:, 1]]
    n = np.maximum(1, np.ceil(np.linalg.norm(b - a, axis=1) / spacing).astype(int))
    pts = [v, v[t].mean(axis=1)]
    for k in np.unique(n):
        if k < 2:
            continue
        sel = n == k
        s = (np.arange(1, k) / k)[None, :, None]
        pts.append((a[sel][:, None] + s * (b[sel] - a[sel])[:, None]).reshape(-1, 3))
    return np.concatenate(pts)


def _blocks(n_points: int, n_tris: int):
    step = max(1, _CHUNK // max(1, n_tris))
    for i in range(0, n_points, step):
        yield slice(i, min(n_points, i + step))


def winding_number(points: np.ndarray, tri_pts: np.ndarray) -> np.ndarray:
    """Generalised winding number of a closed triangle mesh (tri_pts (F,3,3)) at each point:
    ~1 inside, ~0 outside (Van Oosterom & Strackee solid angles)."""
    out = np.empty(len(points))
    for sl in _blocks(len(points), len(tri_pts)):
        d = tri_pts[None, :, :, :] - points[sl, None, None, :]          # (P,F,3,3)
        a, b, c = d[..., 0, :], d[..., 1, :], d[..., 2, :]
        la, lb, lc = (np.sqrt(np.einsum("pfi,pfi->pf", x, x)) for x in (a, b, c))
        num = np.einsum("pfi,pfi->pf", a, np.cross(b, c))
        den = (la * lb * lc + np.einsum("pfi,pfi->pf", a, b) * lc
               + np.einsum("pfi,pfi->pf", b, c) * la + np.einsum("pfi,pfi->pf", c, a) * lb)
        out[sl] = (2.0 * np.arctan2(num, den)).sum(axis=1) / (4.0 * np.pi)
    return out


def point_triangle_distance(points: np.ndarray, tri_pts: np.ndarray) -> np.ndarray:
    """Distance of each point to the nearest of the triangles (F,3,3) (Ericson's closest point)."""
    out = np.full(len(points), np.inf)
    A, B, C = tri_pts[:, 0], tri_pts[:, 1], tri_pts[:, 2]
    AB, AC = B - A, C - A
    for sl in _blocks(len(points), len(tri_pts)):
        P = points[sl, None, :]                                          # (p,1,3)
        AP, BP, CP = P - A, P - B, P - C
        d1, d2 = (AB * AP).sum(-1), (AC * AP).sum(-1)
        d3, d4 = (AB * BP).sum(-1), (AC * BP).sum(-1)
        d5, d6 = (AB * CP).sum(-1), (AC * CP).sum(-1)
        va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
        with np.errstate(divide="ignore", invalid="ignore"):
            denom = va + vb + vc
            v = np.where(denom != 0, vb / denom, 0.0)
            w = np.where(denom != 0, vc / denom, 0.0)
            closest = A + v[..., None] * AB + w[..., None] * AC          # inside the face
            # edge regions
            t_ab = np.clip(d1 / np.where(d1 - d3 != 0, d1 - d3, 1), 0, 1)
            t_ac = np.clip(d2 / np.where(d2 - d6 != 0, d2 - d6, 1), 0, 1)
            t_bc = np.clip((d4 - d3) / np.where((d4 - d3) + (d5 - d6) != 0, (d4 - d3) + (d5 - d6), 1), 0, 1)
        on_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        on_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        on_bc = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        closest = np.where(on_bc[..., None], B + t_bc[..., None] * (C - B), closest)
        closest = np.where(on_ac[..., None], A + t_ac[..., None] * AC, closest)
        closest = np.where(on_ab[..., None], A + t_ab[..., None] * AB, closest)
        closest = np.where(((d6 >= 0) & (d5 <= d6))[..., None], C, closest)
        closest = np.where(((d3 >= 0) & (d4 <= d3))[..., None], B, closest)
        closest = np.where(((d1 <= 0) & (d2 <= 0))[..., None], A, closest)
        D = P - closest
        out[sl] = np.sqrt(np.einsum("pfi,pfi->pf", D, D).min(axis=1))
    return out


def _near_box(points: np.ndarray, part: Part, box, tol: float) -> np.ndarray:
    """The points within `tol` of the part's model-frame bounding box (tighter than a world box
    for rotated parts)."""
    T = np.asarray(part.pose, dtype=np.float64)
    local = (points - T[:3, 3]) @ T[:3, :3]
    return points[np.all((local >= box[0] - tol) & (local <= box[1] + tol), axis=1)]


def penetration_depth(samples_a: np.ndarray, tri_pts_b: np.ndarray) -> float:
    """Deepest of A's sample points inside B (0 if none)."""
    if len(samples_a) == 0:
        return 0.0
    inside = winding_number(samples_a, tri_pts_b) > 0.5
    if not inside.any():
        return 0.0
    return float(point_triangle_distance(samples_a[inside], tri_pts_b).max())


def check_scene(parts: list[Part], floor_z: float, walls: tuple[np.ndarray, np.ndarray] | None = None, *,
                pen_tol: float = PENETRATION_TOL, float_tol: float = FLOAT_TOL,
                spacing: float = 0.0005) -> SceneCheck:
    """Interpenetrating pairs, parts under the floor and floating parts. `walls`: (centre, half
    extents) of the bin's inner footprint, or None when there are no walls."""
    res = SceneCheck()
    world = [p.world() for p in parts]
    tri_pts = [w[np.asarray(p.tris, dtype=np.int64)] for w, p in zip(world, parts)]
    samples = []
    for w, p in zip(world, parts):
        size = float(np.ptp(w, axis=0).max())
        samples.append(edge_samples(w, p.tris, max(spacing, size / 200)))
    lo = np.array([w.min(axis=0) for w in world]) if parts else np.zeros((0, 3))
    hi = np.array([w.max(axis=0) for w in world]) if parts else np.zeros((0, 3))
    boxes = [(np.min(p.verts, axis=0), np.max(p.verts, axis=0)) for p in parts]   # model-frame boxes
    gap = np.full(len(parts), np.inf)
    for i, w in enumerate(world):
        zmin = float(w[:, 2].min())
        gap[i] = zmin - floor_z
        if zmin < floor_z - pen_tol:
            res.below_floor.append((parts[i].name, floor_z - zmin))
        res.max_floor_depth = max(res.max_floor_depth, floor_z - zmin)
        if walls is not None:
            c, h = (np.asarray(x, dtype=np.float64) for x in walls)
            d_wall = (h[:2] - np.abs(w[:, :2] - c[:2])).min()
            gap[i] = min(gap[i], float(d_wall))
    for i in range(len(parts)):
        for j in range(i + 1, len(parts)):
            if np.any(lo[i] > hi[j] + float_tol) or np.any(lo[j] > hi[i] + float_tol):
                continue
            # only samples near the other part's box can be inside it or within float_tol of it
            near_i = _near_box(samples[i], parts[j], boxes[j], float_tol)
            near_j = _near_box(samples[j], parts[i], boxes[i], float_tol)
            # only samples in the other part's box can be inside it (a closed mesh lies in its box)
            depth = max(penetration_depth(_near_box(near_i, parts[j], boxes[j], 0.0), tri_pts[j]),
                        penetration_depth(_near_box(near_j, parts[i], boxes[i], 0.0), tri_pts[i]))
            res.max_depth = max(res.max_depth, depth)
            if depth > pen_tol:
                res.pairs.append((parts[i].name, parts[j].name, depth))
            if depth > 0:
                gap[i] = gap[j] = min(gap[i], gap[j], 0.0)
                continue
            if gap[i] <= float_tol and gap[j] <= float_tol:
                continue                        # both already touch something: skip the distance
            d = min([float(point_triangle_distance(p, t).min()) for p, t in ((near_i, tri_pts[j]),
                                                                             (near_j, tri_pts[i])) if len(p)]
                    or [np.inf])
            gap[i], gap[j] = min(gap[i], d), min(gap[j], d)
    res.floating = [(p.name, float(g)) for p, g in zip(parts, gap) if g > float_tol]
    return res


def physics_line(sim: dict) -> str:
    """Progress-line text of one scene's `simulation` record (scene.json), e.g. '9 parts, 3 removed
    (left the bin), 1 unsettled, 64 frames x 13 substeps'. Older records (frames/settled/removed
    only) read as well."""
    removed = sim.get("removed", [])
    bits = [f"{sim['parts']} parts" if "parts" in sim else None]
    if removed:
        why = sorted({r["reason"] for r in removed})
        bits.append(f"{len(removed)} removed ({', '.join(why)})")
    if not sim.get("settled", True):
        bits.append(f"{len(sim.get('unsettled', []))} unsettled")
    pairs = sim.get("interpenetrating_pairs", [])
    if pairs:
        bits.append(f"{len(pairs)} interpenetrating (max {sim.get('max_interpenetration_mm', 0):.1f} mm)")
    for key, word in (("below_floor", "below the floor"), ("floating", "floating")):
        if sim.get(key):
            bits.append(f"{len(sim[key])} {word}")
    sub = sim.get("substeps")
    bits.append(f"{sim.get('frames', 0)} frames" + (f" x {sub} substeps" if sub else ""))
    if sim.get("attempts", 1) > 1:
        bits.append(f"drop {sim['attempts']}")
    return ", ".join(b for b in bits if b)


def add_to_totals(totals: dict, sim: dict) -> dict:
    """Accumulate a scene's `simulation` record into the run's physics totals (run.json stats)."""
    for key in ("parts", "scenes"):
        totals.setdefault(key, 0)
    totals["scenes"] += 1
    totals["parts"] += int(sim.get("parts", 0))
    for key in ("removed", "unsettled", "interpenetrating_pairs", "below_floor", "floating"):
        totals[key] = totals.get(key, 0) + len(sim.get(key, []))
    totals["unsettled_scenes"] = totals.get("unsettled_scenes", 0) + int(not sim.get("settled", True))
    totals["redrawn_scenes"] = totals.get("redrawn_scenes", 0) + int(sim.get("attempts", 1) > 1)
    totals["max_interpenetration_mm"] = max(totals.get("max_interpenetration_mm", 0.0),
                                            float(sim.get("max_interpenetration_mm", 0.0)))
    totals["max_substeps"] = max(totals.get("max_substeps", 0), int(sim.get("substeps") or 0))
    return totals


def totals_line(t: dict) -> str:
    """The run summary's physics part, e.g. 'physics: 24 parts in 3 scenes, 0 removed, 0 unsettled,
    0 interpenetrating pairs (max 0.0 mm), 0 floating'."""
    if not t:
        return "physics: no scene simulated"
    return (f"physics: {t.get('parts', 0)} parts in {t.get('scenes', 0)} scenes, {t.get('removed', 0)} removed, "
            f"{t.get('unsettled', 0)} unsettled, {t.get('interpenetrating_pairs', 0)} interpenetrating pairs "
            f"(max {t.get('max_interpenetration_mm', 0.0):.1f} mm), {t.get('below_floor', 0)} below the floor, "
            f"{t.get('floating', 0)} floating, {t.get('redrawn_scenes', 0)} scenes redrawn")
