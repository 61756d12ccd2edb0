"""What the benchmark reports share (no bpy): the generated Markdown with its hand-written notes, the
raw rows as CSV, and the frame of a scatter plot over log-scaled CPU seconds (OpenCV: no plotting
library in the environment)."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np


def write_with_notes(path: Path, lines: list[str]) -> None:
    """Write a generated report with the hand-written findings of `<stem>_notes.md` appended."""
    path = Path(path)
    notes = path.with_name(f"{path.stem}_notes.md")
    if notes.is_file():
        lines = [*lines, notes.read_text()]
    path.write_text("\n".join(lines) + "\n")


def write_rows_csv(path: Path, rows: list[dict]) -> None:
    """Rows of one benchmark (dicts with the same keys) as CSV."""
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)


def log_x_frame(size: tuple[int, int], margin: int, x_range, y_range, x_ticks):
    """A white canvas with the plot area framed and vertical grid lines at `x_ticks` (values, drawn
    on a log10 axis); returns (image, px) where px(log10 x, y) is the pixel of a data point."""
    import cv2

    W, H = size
    m = margin
    (x0, x1), (y0, y1) = x_range, y_range
    img = np.full((H, W, 3), 255, np.uint8)

    def px(x, y):
        return int(m + (x - x0) / (x1 - x0) * (W - 2 * m)), int(H - m - (y - y0) / (y1 - y0) * (H - 2 * m))

    cv2.rectangle(img, (m, m), (W - m, H - m), (0, 0, 0), 1)
    for v in x_ticks:
        if x0 <= np.log10(v) <= x1:
            p = px(np.log10(v), y0)
            cv2.line(img, (p[0], m), (p[0], H - m), (225, 225, 225), 1)
            cv2.putText(img, f"{v:g}", (p[0] - 8, H - m + 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)
    return img, px
