"""How many parts fill a bin: `scene.fill` = [min, max], a share of the bin's inner volume that the
parts' convex hulls take, drawn per scene. No bpy.

A scene draws its share f uniformly from [min, max], starts every object entry at its
min_instances and adds one part at a time, of an entry drawn uniformly among those still below
their max_instances, until the hulls reach f x the bin's inner volume (footprint x wall height of
the bin drawn for the scene) or every entry is at its max. So the mix stays even in counts, the
counts stay inside each entry's range, a scene holds at most its min_instances' hulls or the share
plus one part (what the input check bounds: part_fit.fill_problems), and a scene reports the share
it reached (scene.json simulation.fill).

Why hull volume: it is what the parts displace in a pile whatever their orientation, and what
the input check measures. A random pile of convex parts is at most ~0.6-0.74 solid (the rest is
the voids between parts), so a hull share f makes a heap about f / 0.55 of the bin's height:
MAX_FILL = 0.5 keeps the heap below the walls' top (above it, parts roll over the walls).
"""
from __future__ import annotations

import numpy as np

MAX_FILL = 0.5


def hull_volume(points: np.ndarray) -> float:
    """Convex hull volume (m^3) of (V, 3) points; 0 for a flat or degenerate set."""
    from scipy.spatial import ConvexHull, QhullError
    try:
        return float(ConvexHull(np.asarray(points, dtype=np.float64)).volume)
    except (QhullError, ValueError):
        return 0.0


def fill_counts(rng: np.random.Generator, share: float, bin_volume: float, volumes, mins, maxs
                ) -> tuple[list[int], float]:
    """Instance counts per entry whose hull volumes reach `share` x `bin_volume` (module doc), and
    the share they reach. `volumes`: one part's hull volume per entry (m^3)."""
    v = np.asarray(volumes, dtype=np.float64)
    counts = [int(m) for m in mins]
    target = float(share) * float(bin_volume)
    total = float(np.dot(counts, v))
    while total < target:
        open_ = [j for j in range(len(counts)) if counts[j] < int(maxs[j]) and v[j] > 0]
        if not open_:
            break
        j = open_[int(rng.integers(len(open_)))]
        counts[j] += 1
        total += float(v[j])
    return counts, (total / bin_volume if bin_volume > 0 else 0.0)


def draw_share(rng: np.random.Generator, fill) -> float:
    lo, hi = float(fill[0]), float(fill[1])
    return lo if hi <= lo else float(rng.uniform(lo, hi))
