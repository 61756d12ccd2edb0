"""sl.regions: regions of agreeing pixels, against a plain breadth-first search over the pixels."""
from collections import deque

import numpy as np

from datapipe.sl.regions import LINKS, region_labels


def _bfs_sizes(keep, agree):
    """Region size of every kept pixel by breadth-first search along agreeing 8-neighbour pairs
    (a pair (p, q = p + (dy, dx)) is joined when agree[(dy, dx)][p]), plus the one documented
    merge: where both diagonals of a 2 x 2 block are joined, their four pixels are one region."""
    H, W = keep.shape
    nbrs = {(y, x): [] for y in range(H) for x in range(W) if keep[y, x]}

    def join(p, q):
        nbrs[p].append(q)
        nbrs[q].append(p)

    for (dy, dx) in LINKS:
        for (y, x) in nbrs:
            q = (y + dy, x + dx)
            if q in nbrs and agree[(dy, dx)][y, x]:
                join((y, x), q)
    for y in range(H - 1):
        for x in range(W - 1):
            if ((y, x) in nbrs and (y + 1, x + 1) in nbrs and agree[(1, 1)][y, x]
                    and (y, x + 1) in nbrs and (y + 1, x) in nbrs and agree[(1, -1)][y, x + 1]):
                join((y, x), (y, x + 1))
    size = np.zeros((H, W), int)
    seen = set()
    for p in nbrs:
        if p in seen:
            continue
        comp, todo = [p], deque([p])
        seen.add(p)
        while todo:
            for q in nbrs[todo.popleft()]:
                if q not in seen:
                    seen.add(q)
                    comp.append(q)
                    todo.append(q)
        for q in comp:
            size[q] = len(comp)
    return size


def test_region_sizes_match_a_breadth_first_search():
    rng = np.random.default_rng(5)
    for _ in range(150):
        H, W = (int(v) for v in rng.integers(1, 10, 2))
        keep = rng.random((H, W)) < rng.uniform(0.3, 1.0)
        agree = {k: rng.random((H, W)) < rng.uniform(0.2, 0.9) for k in LINKS}
        labels, sizes = region_labels(keep, agree)
        assert np.array_equal(sizes, _bfs_sizes(keep, agree))
        assert (labels[~keep] == 0).all() and (labels[keep] > 0).all()
        for lab in np.unique(labels[keep]):            # a label is one region: all its pixels have its size
            assert (sizes[labels == lab] == (labels == lab).sum()).all()


def test_links_that_only_touch_at_a_corner_stay_apart():
    """An anti-diagonal pair beside a lone pixel: the lone pixel (0, 0) touches the pair's link
    only at a corner of the grid's cells; it is its own region. Where both diagonals of the block
    agree, the four pixels join (the documented merge)."""
    keep = np.ones((2, 2), bool)
    none = {k: np.zeros((2, 2), bool) for k in LINKS}
    anti = dict(none)
    anti[(1, -1)] = np.array([[False, True], [False, False]])     # (0, 1) - (1, 0)
    _, sizes = region_labels(keep, anti)
    assert sizes.tolist() == [[1, 2], [2, 1]]
    both = dict(anti)
    both[(1, 1)] = np.array([[True, False], [False, False]])      # (0, 0) - (1, 1)
    assert region_labels(keep, both)[1].tolist() == [[4, 4], [4, 4]]
    assert region_labels(np.zeros((3, 4), bool), {k: np.ones((3, 4), bool) for k in LINKS})[1].sum() == 0
