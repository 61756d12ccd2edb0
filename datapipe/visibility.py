"""Visible fraction per instance (BOP's visib_fract): visible pixels / full silhouette pixels, and its
distribution over a run. No bpy.

The visible pixels are the instance's pixels in the render's mask; the full silhouette is the
part's model rasterised with the render's K and T_cam_obj (io/silhouette.py, as the BOP writer
and the overview sheet do), on a canvas one image size beyond each side, plus any visible pixel
the rasteriser missed, so the fraction stays <= 1. Dense piles are the point: occlusion is what
makes bin picking hard, and a run says how much it has (run.json stats "visib_fract", the overview
sheet).
"""
from __future__ import annotations

import numpy as np

from .io.silhouette import rasterize_silhouette

HIST_BINS = 1000          # run.json keeps a histogram: constant size, median to 0.001


def visible_fractions(objects: list[dict], mask: np.ndarray | None, K, models: dict, width: int, height: int,
                      dist=None) -> list[float]:
    """Per render-record object (obj_id, mask_index, T_cam_obj in m) with a model in `models`
    ({obj_id: (verts_mm, faces)}): its visible fraction. Objects without a model are skipped.
    Each fraction is also written into its object record as "visib_fract" (rounded to 1e-4, BOP's
    name), so scene.json carries it and a resumed run counts the scenes made before."""
    out = []
    for o in objects:
        mdl = models.get(int(o["obj_id"]))
        if mdl is None:
            continue
        visible = (mask == int(o["mask_index"])) if mask is not None else None
        n_vis = int(np.count_nonzero(visible)) if visible is not None else int(o.get("px_count_visib") or 0)
        T = np.asarray(o["T_cam_obj"], dtype=np.float64)
        sil, count, _ = rasterize_silhouette(mdl[0], mdl[1], K, T[:3, :3], T[:3, 3] * 1000.0, width, height,
                                             dist=dist)
        if visible is not None:
            count += int(np.count_nonzero(visible & ~sil))
        out.append(n_vis / count if count else 0.0)
        o["visib_fract"] = round(out[-1], 4)
    return out


class VisibStats:
    """The run's visible fractions as a histogram (run.json stats["visib_fract"])."""

    def __init__(self):
        self.counts = np.zeros(HIST_BINS, dtype=np.int64)

    @classmethod
    def of_scenes(cls, scenes) -> "VisibStats":
        """The histogram of the fractions the scene records (scene.json) carry."""
        stats = cls()
        for scene in scenes:
            stats.add([o["visib_fract"] for rd in scene.get("renders", []) for o in rd.get("objects", [])
                       if isinstance(o.get("visib_fract"), (int, float))])
        return stats

    def add(self, fractions) -> None:
        f = np.clip(np.asarray(fractions, dtype=np.float64), 0.0, 1.0)
        idx = np.minimum((f * HIST_BINS).astype(int), HIST_BINS - 1)
        np.add.at(self.counts, idx, 1)

    def quantile(self, q: float) -> float | None:
        """The smallest fraction with at least q of the instances at or below it (the inverted CDF:
        with an even count the median is the lower middle value), to the bin's centre (+-0.0005)."""
        n = int(self.counts.sum())
        if n == 0:
            return None
        k = int(np.searchsorted(np.cumsum(self.counts), q * n, side="left"))
        return round((min(k, HIST_BINS - 1) + 0.5) / HIST_BINS, 4)     # the bin's centre

    def summary(self) -> dict:
        n = int(self.counts.sum())
        deciles = self.counts.reshape(10, -1).sum(axis=1)
        return {"instances": n, "median": self.quantile(0.5), "p10": self.quantile(0.1),
                "p90": self.quantile(0.9),
                "below_0.1": round(float(deciles[0]) / n, 4) if n else None,
                "deciles": [int(c) for c in deciles]}     # counts in [0, 0.1), [0.1, 0.2), ... [0.9, 1]
