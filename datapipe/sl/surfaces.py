"""The surfaces of the pooled order decision (:mod:`.orders`, its steps 1 and 2): links between
4-neighbour candidates whose finest phases fit the local fringe gradient, the components of that
link graph and every pixel's finest order relative to its component's first pixel; links that
close a loop whose order steps do not sum to zero lose both ends, and the graph is built again.

Why the rounds after the first are local. A loop that does not close is rare (one link in the
1080p bin scene of benchmarks/results/sl_speed.md), and cutting its two ends changes only what lies
near them: a link's gradient is a window sum of the pair phasors within ``GRAD // 2`` of its two
ends, so only links within ``CUT_REACH`` of a cut pixel can change; and only the components that
hold a cut pixel or a changed link change. A consistent component's relative orders do not depend
on the tree they are read along (every loop closes) and its root is its first pixel either way, so
the untouched components keep theirs. The later rounds therefore recompute the links in a box
around the cut pixels and the components of the touched ones only: the same links, components and
orders as a full rebuild (tests/sl/test_sl_orders.py compares the two), at a fraction of its cost.
"""
from __future__ import annotations

import numpy as np
from scipy import sparse
from scipy.sparse import csgraph

__all__ = ["surfaces", "links", "GRAD", "LINK_MAX", "LOOP_ROUNDS"]

LINK_MAX = 0.25         # cycles: largest misfit of a link's finest-phase difference to the local gradient
GRAD = 5                # pixels: window of the finest-phase gradient estimate
LOOP_ROUNDS = 3         # rounds of cutting loops that do not close
# a cut pixel p removes the phasors anchored at p, p - 1 and p - W; a link (a, b), b = a + 1 or a + W,
# reads the phasors anchored within GRAD // 2 of a or of b, i.e. within GRAD // 2 + 1 of a: it can
# change when a lies within GRAD // 2 + 2 of p (Chebyshev distance)
CUT_REACH = GRAD // 2 + 2


def _pairs(ok, W, idx=None):
    """Flat indices (a, b) of the horizontal and the vertical neighbour pairs of ``ok`` pixels (flat
    bool of an image W wide; ``idx``: their flat indices, ascending, when the caller has them), per
    direction."""
    idx = np.flatnonzero(ok) if idx is None else idx
    right = idx[idx < ok.size - 1]
    right = right[ok[right + 1]]
    right = right[right % W != W - 1]            # the row's last pixel has no right neighbour
    down = idx[idx + W < ok.size]
    down = down[ok[down + W]]
    return (right, right + 1), (down, down + W)


def links(ok, cf, shape, idx=None):
    """4-neighbour links among ``ok`` pixels whose finest-phase difference fits the local gradient
    within ``LINK_MAX`` cycles: (a, b, step), flat indices and ``step = N_b - N_a`` (finest orders).

    The gradient (cycles per pixel, per axis) at a pixel is the angle of the summed phasors of the
    wrapped differences of the pairs in its ``GRAD`` x ``GRAD`` window (a surface's fringe gradient
    varies slowly; one pair is too noisy). Work is done at the pairs only, not over the image.
    ``idx``: the flat indices of the ``ok`` pixels, ascending, where the caller has them."""
    import cv2

    H, W = shape
    k = dict(ksize=(GRAD, GRAD), normalize=False, borderType=cv2.BORDER_CONSTANT)
    pa, pb, ps = [], [], []
    # the filters run over the pixels' bounding box plus the window's reach: the same sums, on less
    # image (OpenCV sums float32 box filters in float64 running sums, so a box gives the image's sums)
    rows, cols = np.flatnonzero(ok.reshape(H, W).any(1)), np.flatnonzero(ok.reshape(H, W).any(0))
    if rows.size == 0:
        e = np.zeros(0, np.int64)
        return e, e, e
    r0, c0 = max(rows[0] - GRAD // 2, 0), max(cols[0] - GRAD // 2, 0)
    h, w = min(rows[-1] + GRAD // 2 + 1, H) - r0, min(cols[-1] + GRAD // 2 + 1, W) - c0
    z = np.zeros((h * w, 2), np.float32)         # phasors, real and imaginary part as two channels
    for a, b in _pairs(ok, W, idx):
        d = cf[b] - cf[a]
        ang = np.float32(2 * np.pi) * d
        ra, ca = np.divmod(a, W)
        la = (ra - r0) * w + (ca - c0)           # a and b in the box
        lb = la + (b - a) // W * w + (b - a) % W
        z[:] = 0
        z[la, 0] = np.cos(ang)
        z[la, 1] = np.sin(ang)
        sz = cv2.boxFilter(z.reshape(h, w, 2), -1, **k).reshape(h * w, 2)   # one pass for both parts
        # the pair's gradient: the mean of its two ends' (windows centred on a and on b)
        g = (np.arctan2(sz[la, 1] + sz[lb, 1], sz[la, 0] + sz[lb, 0]) * np.float32(1 / (2 * np.pi))).astype(np.float32)
        t = g - d                                    # = N_b - N_a + noise on one smooth surface
        n = np.rint(t)
        keep = np.abs(t - n) <= LINK_MAX
        pa.append(a[keep])
        pb.append(b[keep])
        ps.append(n[keep].astype(np.int64))
    return np.concatenate(pa), np.concatenate(pb), np.concatenate(ps)


def _links_near(ok, cf, shape, cut):
    """The links (as :func:`links`) whose first end lies within ``CUT_REACH`` of a ``cut`` pixel (flat
    indices), computed in a box around the cut pixels: the pairs whose phasors such a link reads lie
    within ``CUT_REACH + GRAD // 2 + 2`` of them (the box reaches further). Also returns the flat
    mask of those first ends' region."""
    H, W = shape
    r, c = np.divmod(cut, W)
    grow = 2 * CUT_REACH + 2
    r0, c0 = max(int(r.min()) - grow, 0), max(int(c.min()) - grow, 0)
    r1, c1 = min(int(r.max()) + grow + 1, H), min(int(c.max()) + grow + 1, W)
    h, w = r1 - r0, c1 - c0
    near = np.zeros((h, w), np.uint8)
    near[r - r0, c - c0] = 1
    near = _dilate(near, CUT_REACH).ravel().astype(bool)
    box_ok = ok.reshape(H, W)[r0:r1, c0:c1].ravel()
    box_cf = cf.reshape(H, W)[r0:r1, c0:c1].ravel()
    a, b, step = links(box_ok, box_cf, (h, w))
    mine = near[a]
    a, b, step = a[mine], b[mine], step[mine]
    to_image = lambda q: (q // w + r0) * W + q % w + c0
    region = np.zeros(H * W, bool)
    region.reshape(H, W)[r0:r1, c0:c1] = near.reshape(h, w)
    return to_image(a), to_image(b), step, region


def _dilate(mask, reach):
    import cv2

    return cv2.dilate(mask, np.ones((2 * reach + 1, 2 * reach + 1), np.uint8), borderType=cv2.BORDER_CONSTANT,
                      borderValue=0)


def _tree_steps(pred, child, a, b, step, flat, W):
    """Finest-order step of each tree edge ``pred -> child`` (local node numbers) from the links
    (a, b, step): a link joins 4-neighbours, so its end ``b`` lies at ``a + 1`` or ``a + W`` in the
    image; the edge's direction there picks the link, without a lookup table over all pairs. One
    (n, 2) table of each node's steps to its right and lower neighbour, read once per edge at its
    upper / left end (negated where that end is the child)."""
    steps = np.zeros((flat.size, 2), np.int64)
    steps[a, (flat[b] - flat[a] != 1).astype(np.intp)] = step
    diff = flat[child] - flat[pred]
    fwd = diff > 0
    val = steps[np.where(fwd, pred, child), (np.abs(diff) != 1).astype(np.intp)]
    return np.where(fwd, val, -val)


def relative_orders(n, a, b, step, flat, W):
    """Components and relative finest orders of n nodes linked by (a, b) (local node numbers; ``flat``
    their pixels' flat indices in an image ``W`` wide): (comp, ncomp, rel, bad links)."""
    ncomp, comp = csgraph.connected_components(
        sparse.coo_matrix((np.ones(a.size), (a, b)), shape=(n, n)), directed=False)
    # a virtual root joined to the first node of every component: one breadth-first tree for all
    first = np.full(ncomp, -1, np.int64)
    first[comp[::-1]] = np.arange(n)[::-1]
    root = n
    rows = np.concatenate([a, b, np.full(ncomp, root)])
    cols = np.concatenate([b, a, first])
    g = sparse.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n + 1, n + 1))
    _, pred = csgraph.breadth_first_order(g, root, directed=True, return_predecessors=True)
    pred = pred.astype(np.int64)
    pred[root] = root
    acc = np.zeros(n + 1, np.int64)
    child = np.flatnonzero(pred[:n] != root)
    if child.size:
        acc[child] = _tree_steps(pred[child], child, a, b, step, flat, W)
    ptr = pred.copy()
    while np.any(ptr[:n] != root):
        acc = acc + acc[ptr]
        ptr = ptr[ptr]
    rel = acc[:n]
    return comp, ncomp, rel, (rel[b] - rel[a]) != step


def _rebuild_touched(graph, ga, gb, step, touched_nodes, cand, local, W):
    """The components and relative orders after a local change of the links: the components that
    hold a ``touched_nodes`` node are rebuilt from the new links (ga, gb, step: flat indices;
    ``local`` maps a flat index to its candidate number), the others keep theirs (module doc).
    ``graph`` is the previous (comp, ncomp, rel)."""
    comp, ncomp, rel = graph
    n = cand.size
    touched = np.zeros(max(ncomp, 1), bool)
    touched[comp[touched_nodes]] = True
    sub = np.flatnonzero(touched[comp])          # ascending: the nodes keep their order
    num = np.full(n, -1, np.int64)
    num[sub] = np.arange(sub.size)
    a, b = local[ga], local[gb]
    inner = num[a] >= 0                          # a link of a touched component lies wholly in it
    sc, sn, sr, sbad = relative_orders(sub.size, num[a[inner]], num[b[inner]], step[inner], cand[sub], W)
    comp, rel = comp.copy(), rel.copy()
    comp[sub] = sc + ncomp
    rel[sub] = sr
    bad = np.zeros(a.size, bool)
    bad[inner] = sbad
    return (comp, ncomp + sn, rel), a, b, bad


def surfaces(cand, cf, shape):
    """Components of linked candidates and their relative finest orders; links that close a loop
    whose order steps do not sum to zero (a slip of the finest phase, or a step) lose both ends,
    ``LOOP_ROUNDS`` times; a component still inconsistent then is dropped (-1). Returns (comp,
    ncomp, rel, a, b) over the candidates (a, b: the last round's links, candidate numbers), or None
    without links. The first round builds the graph, the later ones rebuild what the cuts touch."""
    H, W = shape
    n = cand.size
    cf_full = np.zeros(H * W, np.float32)
    cf_full[cand] = cf
    local = np.zeros(H * W, np.int64)            # flat index -> candidate number (no binary searches)
    local[cand] = np.arange(n)
    ok = np.zeros(H * W, bool)
    ok[cand] = True
    alive = np.ones(n, bool)
    ga, gb, step = links(ok, cf_full, (H, W), cand)
    if ga.size == 0:
        return None
    a, b = local[ga], local[gb]
    comp, ncomp, rel, bad = relative_orders(n, a, b, step, cand, W)
    for _ in range(LOOP_ROUNDS - 1):
        if not bad.any():
            break
        cut = np.unique(np.concatenate([a[bad], b[bad]]))
        alive[cut] = False
        ok[cand[cut]] = False
        na, nb, nstep, region = _links_near(ok, cf_full, (H, W), cand[cut])
        kept = ~region[ga]                        # the links no cut can have changed
        old_touched = a[~kept]
        ga, gb, step = np.concatenate([ga[kept], na]), np.concatenate([gb[kept], nb]), np.concatenate([step[kept], nstep])
        if ga.size == 0:
            return None
        touched = np.concatenate([cut, old_touched, local[na], local[nb]])
        (comp, ncomp, rel), a, b, bad = _rebuild_touched((comp, ncomp, rel), ga, gb, step, touched, cand, local, W)
    if bad.any():
        comp = comp.copy()
        comp[np.isin(comp, np.unique(comp[a[bad]]))] = -1
        alive[a[bad]] = False
        alive[b[bad]] = False
    comp[~alive] = -1
    return comp, ncomp, rel, a, b
