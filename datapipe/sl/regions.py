"""Regions of a depth map: kept pixels joined by chains of agreeing 8-neighbours, labelled at
image speed (what a scanner's speckle filter measures: OpenCV's filterSpeckles "Filters off small
noise blobs (speckles)", https://docs.opencv.org/4.x/d9/d0c/group__calib3d.html).

Two kept pixels share a region when a chain of 8-neighbour pairs joins them, each pair agreeing in
depth (`agree`, the edge filter's test: sl.filters.neighbour_agreement). Labelled on a grid three
times the image in both axes: pixel (y, x) at cell (3y, 3x), each agreeing pair as the two cells
between its ends, and OpenCV's 8-connected labelling of that grid (a graph search over the pixels,
scipy.sparse.csgraph, took 0.8 s CPU at 1920x1080; this 0.085-0.1 s). With two
cells per link a link cell touches only its own ends and the links that share an end, except where
both diagonals of a 2x2 block agree: their cells cross and join all four pixels. That can only join
two regions, never split one, so a region is never measured smaller than it is.
"""
from __future__ import annotations

import numpy as np

__all__ = ["LINKS", "region_labels"]

LINKS = ((0, 1), (1, 0), (1, 1), (1, -1))      # the 4 directions that give every 8-neighbour pair once
# cells of a link (dy, dx) from pixel (y, x), as (row offset, column offset) inside the 3 x 3 block of
# the pixel the link's cells lie in: (0, 1) and (1, 0) and (1, 1) in the block of (y, x); (1, -1) in
# the block of (y, x - 1), whose cells (3y + 1, 3x - 1) and (3y + 2, 3x - 2) are (1, 2) and (2, 1) there
_CELLS = {(0, 1): ((0, 1), (0, 2)), (1, 0): ((1, 0), (2, 0)), (1, 1): ((1, 1), (2, 2)), (1, -1): ((1, 2), (2, 1))}


def region_labels(keep, agree) -> tuple[np.ndarray, np.ndarray]:
    """(labels, sizes), both (H, W) int32: each kept pixel's region (module doc) and its number of
    pixels; 0 in both where not kept.

    keep: (H, W) bool; agree: {(dy, dx): (H, W) bool} for every direction of LINKS (more are
    ignored), True where pixel (y, x) agrees with (y + dy, x + dx); ignored where either is not kept
    or lies off the image."""
    import cv2

    keep = np.asarray(keep, bool)
    H, W = keep.shape
    grid = np.zeros((3 * H, 3 * W), np.uint8)
    grid[::3, ::3] = keep
    for (dy, dx), cells in _CELLS.items():
        a = np.asarray(agree[(dy, dx)], bool) & keep
        y1, x0, x1 = H - dy, max(0, -dx), W - max(0, dx)        # pixels whose neighbour is on the image
        link = np.zeros((H, W), bool)
        link[:y1, x0:x1] = a[:y1, x0:x1] & keep[dy:, x0 + dx:x1 + dx]
        if dx < 0:                                # the cells lie in the block of (y, x - 1)
            link = np.concatenate([link[:, 1:], np.zeros((H, 1), bool)], axis=1)
        for oy, ox in cells:
            grid[oy::3, ox::3] |= link
    _, lab = cv2.connectedComponents(grid, connectivity=8, ltype=cv2.CV_32S)
    labels = np.ascontiguousarray(lab[::3, ::3])
    labels[~keep] = 0
    sizes = np.bincount(labels.ravel())
    sizes[0] = 0
    return labels, sizes[labels].astype(np.int32)
