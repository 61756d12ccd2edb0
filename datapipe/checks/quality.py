"""Quality gates: after each render, say when it holds nothing a model can learn from. No bpy.

A run with a black image, no visible part or an empty structured-light depth map used to finish
with exit 0 and no word. `render_warnings` names each such defect in one short line; the pipeline
shows it in the progress line and run.json's `warnings`, and `--strict` makes it an error.
"""
from __future__ import annotations

import numpy as np

BLACK_LEVEL = 3               # sRGB 8-bit: the 99th percentile of the brightest channel below this = black
SATURATED_FRACTION = 0.5      # more than half of the pixels clipped at 255 in some channel
MIN_SL_VALID_FRACTION = 0.01  # structured-light depth on fewer than 1% of the pixels


def rgb_warnings(rgb: np.ndarray | None) -> list[str]:
    if rgb is None or rgb.size == 0:
        return []
    peak = rgb.max(axis=-1) if rgb.ndim == 3 else rgb
    if float(np.percentile(peak, 99)) < BLACK_LEVEL:
        return ["RGB is black (99% of the pixels below 3/255): check render.light_power and the scene's lights"]
    clipped = float(np.mean(peak >= 255))
    if clipped > SATURATED_FRACTION:
        return [f"RGB is saturated ({clipped:.0%} of the pixels at 255): lower render.light_power"]
    return []


def render_warnings(*, rgb: np.ndarray | None, visible_px: list[int | None], sl_valid_fraction: float | None,
                    parts_dropped: int, parts_lost: int) -> list[str]:
    """One line per defect of a render (empty: nothing to say). `visible_px`: per instance, visible
    pixels in the mask (None without a mask output); `parts_lost`: instances the simulation removed."""
    out = rgb_warnings(rgb)
    counts = [n for n in visible_px if n is not None]
    if counts and max(counts) == 0 or (not visible_px and parts_dropped > 0):
        out.append("no part is visible: check the camera poses against scene.drop_zone_loc")
    if sl_valid_fraction is not None and sl_valid_fraction < MIN_SL_VALID_FRACTION:
        out.append(f"structured-light depth on {sl_valid_fraction:.1%} of the pixels (< 1%): check "
                   "structured_light.periods, projector.power and structured_light.exposure")
    if parts_lost and parts_lost == parts_dropped:
        out.append(f"all {parts_lost} parts were lost in the simulation (left the bin)")
    elif parts_lost:
        out.append(f"{parts_lost} of {parts_dropped} parts lost in the simulation (left the bin)")
    return out
