"""Drawing primitives of the contact sheets and the run overview (datapipe/show.py): the sheets'
colours, text, per-instance colours, colour maps and colour bars, histogram panels. cv2 and numpy
only; nothing here reads a run."""
from __future__ import annotations

import math

import cv2
import numpy as np

LEGEND = 36                      # height of a colour bar under a panel (px)
BG = (38, 38, 38)
FG = (235, 235, 235)
FONT = cv2.FONT_HERSHEY_SIMPLEX


def put_text(img, text, org, scale=0.45, color=FG, thickness=1):
    cv2.putText(img, str(text), (int(org[0]), int(org[1])), FONT, scale, color, thickness, cv2.LINE_AA)


def text_width(text, scale=0.45, thickness=1) -> int:
    return cv2.getTextSize(str(text), FONT, scale, thickness)[0][0]


def instance_color(index: int) -> tuple[int, int, int]:
    """A bright, stable BGR colour per instance index (never black)."""
    h = int((index * 0.61803398875 % 1.0) * 180)
    hsv = np.uint8([[[h, 200, 255]]])
    b, g, r = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0]
    return int(b), int(g), int(r)


def _diverging_lut() -> np.ndarray:
    """256 x 3 BGR: blue (negative) -> white (0) -> red (positive)."""
    t = np.linspace(-1, 1, 256)
    r = np.where(t < 0, 1 + t, 1.0)
    b = np.where(t > 0, 1 - t, 1.0)
    g = 1 - np.abs(t)
    rgb = np.stack([b, g, r], 1)
    rgb = np.where(t[:, None] < 0, rgb * [1, 1, 1], rgb)
    # keep the ends saturated but not black
    rgb = 0.15 + 0.85 * rgb
    return (rgb * 255).astype(np.uint8)


DIVERGING = _diverging_lut()


def colorize(values: np.ndarray, lo: float, hi: float, *, diverging: bool = False) -> np.ndarray:
    """float (H,W) -> BGR; NaN -> black. TURBO for depth, blue-white-red for signed errors."""
    v = np.asarray(values, dtype=np.float64)
    valid = np.isfinite(v)
    t = np.zeros(v.shape)
    if hi > lo:
        t[valid] = np.clip((v[valid] - lo) / (hi - lo), 0, 1)
    idx = (t * 255).astype(np.uint8)
    if diverging:
        img = DIVERGING[idx]
    else:
        img = cv2.applyColorMap(idx, cv2.COLORMAP_TURBO)
    img[~valid] = 0
    return img


def colorbar(width: int, lo: float, hi: float, unit: str, *, diverging=False, ticks=3) -> np.ndarray:
    bar = np.full((LEGEND, width, 3), BG, np.uint8)
    x0, x1 = 6, width - 6
    grad = np.linspace(lo, hi, x1 - x0)[None, :].repeat(10, 0)
    bar[4:14, x0:x1] = colorize(grad, lo, hi, diverging=diverging)
    for k in range(ticks):
        f = k / (ticks - 1)
        val = lo + f * (hi - lo)
        x = int(x0 + f * (x1 - x0 - 1))
        cv2.line(bar, (x, 14), (x, 18), FG, 1)
        label = f"{val:+.1f}" if diverging else f"{val:.0f}"
        if k == ticks - 1:
            label += f" {unit}"
        w = text_width(label, 0.4)
        put_text(bar, label, (min(max(x - w // 2, 0), width - w), 31), 0.4)
    return bar


def fit_tile(img: np.ndarray, tw: int, th: int, *, nearest=False) -> np.ndarray:
    if img.shape[1] == tw and img.shape[0] == th:
        return img
    return cv2.resize(img, (tw, th), interpolation=cv2.INTER_NEAREST if nearest else cv2.INTER_AREA)


def message_tile(tw, th, lines) -> np.ndarray:
    tile = np.full((th, tw, 3), 70, np.uint8)
    for k, line in enumerate(lines):
        w = text_width(line, 0.55)
        put_text(tile, line, ((tw - w) // 2, th // 2 - 10 * (len(lines) - 1) + 22 * k), 0.55, (200, 200, 200))
    return tile


def hist_panel(values, bins: np.ndarray, title: str, xlabel: str, *, w=440, h=300, color=(90, 170, 250),
                note: str | None = None, fmt="{:g}", integer=False) -> np.ndarray:
    """A histogram drawn with cv2: bars, count axis, x ticks (integer=True: one label per bar)."""
    img = np.full((h, w, 3), BG, np.uint8)
    put_text(img, title, (8, 18), 0.5)
    if note:
        put_text(img, note, (8, 38), 0.38, (220, 220, 160))
    x0, x1, y0, y1 = 46, w - 12, 50, h - 44          # plot area (y0 top, y1 bottom)
    cv2.rectangle(img, (x0, y0), (x1, y1), (90, 90, 90), 1)
    values = np.asarray(values, dtype=np.float64)
    if values.size == 0:
        return img
    counts, edges = np.histogram(values, bins=bins)
    top = max(1, int(counts.max()))
    n = len(counts)
    for k, c in enumerate(counts):
        bx0 = x0 + 1 + int(k * (x1 - x0 - 1) / n)
        bx1 = x0 + 1 + int((k + 1) * (x1 - x0 - 1) / n) - (2 if integer else 1)
        by = y1 - int(round(c / top * (y1 - y0 - 4)))
        if c > 0:
            cv2.rectangle(img, (bx0, by), (max(bx0, bx1), y1 - 1), color, -1)
    if integer:
        every = max(1, int(math.ceil(n / 15)))
        ticks = [((k + 0.5) / n, f"{(edges[k] + edges[k + 1]) / 2:.0f}") for k in range(0, n, every)]
    else:
        ticks = [(f, fmt.format(edges[0] + f * (edges[-1] - edges[0]))) for f in (0.0, 0.25, 0.5, 0.75, 1.0)]
    for f, s in ticks:
        x = int(x0 + f * (x1 - x0))
        cv2.line(img, (x, y1), (x, y1 + 4), FG, 1)
        tw_ = text_width(s, 0.4)
        put_text(img, s, (min(max(x - tw_ // 2, 0), w - tw_), y1 + 18), 0.4)
    put_text(img, str(top), (max(2, x0 - 6 - text_width(str(top), 0.4)), y0 + 10), 0.4)
    put_text(img, "0", (x0 - 14, y1), 0.4)
    put_text(img, xlabel, (x0, h - 8), 0.42)
    return img
