"""The pooled fringe-order decision (issue #31, datapipe/sl/orders.py): a dark surface whose pixels
cannot tell their order one by one decides it together, and never across a depth step.

Ground truth: tests/sl/synth.py's ray caster; noise: read + shot (``synth.sensor_stack``). The
320x240 camera / 1280x800 projector rig at 1 m gives the finest fringe (1, 8, 64): 20 projector
pixels) about 5 camera pixels per period, as a real scanner samples it.
"""
import numpy as np
import pytest

import synth
from datapipe import sl
from sl_helpers import decode_kw

PERIODS = (1, 8, 64)
WP = 1280


def _rig(baseline):
    return synth.make_rig(cam_size=(320, 240), proj_size=(WP, 800), distance=1.0, baseline=baseline)


def _judge(res, gt, periods=PERIODS):
    """(coverage of the lit pixels, wrong count, wrong mask). Pixels whose true coordinate lies within
    2 px of the projector's left or right edge are left out: there the coordinate folds across the
    edge (the unwrapper's documented ambiguity, datapipe/sl/unwrap.py), whatever decides the orders."""
    right = np.abs(res.proj_x - gt.proj_x) < WP / max(periods) / 2        # NaN truth or depth: not right
    edge = (gt.proj_x < 1.5) | (gt.proj_x > WP - 2.5)
    wrong = res.valid & ~right & ~edge
    lit = gt.lit & ~edge
    return float(np.mean((res.valid & right)[lit])), int(wrong.sum()), wrong


@pytest.mark.parametrize("periods,floor", [((1, 8, 64), 0.95), ((16, 15), 0.9)])
def test_dark_plane_is_decoded_together(periods, floor):
    """A tilted plane of albedo 0.04 (B = 5 DN at read noise 2 DN: one pixel's (1, 8, 64) orders are
    wrong with probability ~0.2, its (16, 15) orders ~0.3): each pixel alone keeps few of them
    (main: 0-40%); the plane's pixels together keep >= 95% with (1, 8, 64) and >= 90% with (16, 15)
    (measured 0.99 / 0.93: the border ring of the local windows and the blocks that (16, 15)'s
    weaker coarse evidence leaves unsure are the rest), every order right, marked NEIGHBOUR_ORDER
    with confidence <= 1 - NEIGHBOUR_RISK."""
    cam, proj = _rig(0.15)
    gt = synth.render(synth.tilted_plane_scene(10.0, albedo=0.04), cam, proj, periods, 4)
    res = sl.decode(synth.sensor_stack(gt, read=2.0, seed=1), **decode_kw(cam, proj, periods))
    own = sl.decode(synth.sensor_stack(gt, read=2.0, seed=1), **decode_kw(cam, proj, periods), spatial=False)
    cov, n_wrong, _ = _judge(res, gt, periods)
    cov_own, _, _ = _judge(own, gt, periods)
    assert cov_own < 0.6
    assert cov >= floor, cov
    assert n_wrong == 0
    pooled = res.reason == sl.Reason.NEIGHBOUR_ORDER
    assert pooled.sum() > 0.5 * gt.lit.sum()
    assert res.confidence[pooled].max() <= np.float32(1 - sl.NEIGHBOUR_RISK)


@pytest.mark.parametrize("read", [1.0, 2.0, 3.0, 4.0])
def test_dark_patch_beside_a_step(read):
    """Issue #19's adversarial stack on the 5 cm baseline (the 0.25 m step moves the coordinate by
    about one finest period, invisible to the finest phase): at 1-4 DN of read noise no more than
    0.01% of the decoded pixels are a period off, nothing valid in the projector shadow, and at
    1-2 DN >= 97% of the lit pixels are decoded right (main: 96.5% at 1 DN, 85% at 2 DN)."""
    cam, proj = _rig(0.05)
    gt = synth.render(synth.dark_step_scene(), cam, proj, PERIODS, 4)
    res = sl.decode(synth.sensor_stack(gt, read=read, seed=2), **decode_kw(cam, proj, PERIODS))
    cov, n_wrong, wrong = _judge(res, gt)
    assert n_wrong <= 1e-4 * res.valid.sum(), n_wrong
    assert res.valid[gt.shadow].mean() <= 1e-3
    if read <= 2.0:
        assert cov >= 0.97, cov


def test_pure_noise_stays_dark():
    """A stack of pure noise (no projector light anywhere, 2 DN) gives no valid pixel: links between
    random finest phases do not make a surface, and the 3x3 joint modulation test refuses them."""
    cam, proj = _rig(0.15)
    rng = np.random.default_rng(3)
    images = (10.0 + 2.0 * rng.standard_normal((12, 240, 320))).astype(np.float32)
    res = sl.decode(images, **decode_kw(cam, proj, PERIODS), noise_sigma=2.0)
    assert res.valid.sum() == 0


def test_confidence_of_pooled_pixels_is_calibrated():
    """Among the pooled pixels of the dark-step stacks at 1-4 DN (both baselines), the share with a
    wrong order stays below one minus their smallest confidence (NEIGHBOUR_RISK = 1e-3)."""
    n_pooled = n_wrong = 0
    low = 1.0
    for baseline in (0.05, 0.15):
        cam, proj = _rig(baseline)
        gt = synth.render(synth.dark_step_scene(), cam, proj, PERIODS, 4)
        for read in (1.0, 2.0, 3.0, 4.0):
            res = sl.decode(synth.sensor_stack(gt, read=read, seed=4), **decode_kw(cam, proj, PERIODS))
            pooled = res.reason == sl.Reason.NEIGHBOUR_ORDER
            _, _, wrong = _judge(res, gt)
            n_pooled += int(pooled.sum())
            n_wrong += int((wrong & pooled).sum())
            if pooled.any():
                low = min(low, float(res.confidence[pooled].min()))
    assert n_pooled > 20000
    assert n_wrong <= (1 - low) * n_pooled, (n_wrong, n_pooled, low)


def test_block_medians_are_numpy_medians():
    """The blocks' medians (placing each block in the projector's range) by one sort equal
    ``np.median`` per block: odd and even sizes, ties, one-pixel blocks."""
    from datapipe.sl.orders import _block_medians

    rng = np.random.default_rng(3)
    size = np.array([1, 2, 5, 8, 33, 64])
    binv = np.repeat(np.arange(size.size), size)
    x = np.round(rng.normal(600, 300, binv.size), 1)          # rounded: ties inside blocks
    perm = rng.permutation(binv.size)
    starts = np.r_[0, np.cumsum(size)[:-1]]
    got = _block_medians(x[perm], binv[perm], starts, size)
    want = [np.median(x[binv == k]) for k in range(size.size)]
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)


def _full_rebuild_surfaces(cand, cf, shape):
    """The loop cutting as it was before the local rebuild (git 6927a1b): every round builds the
    links and the components of all the living candidates again."""
    from datapipe.sl import surfaces as su

    H, W = shape
    n = cand.size
    cf_full = np.zeros(H * W, np.float32)
    cf_full[cand] = cf
    local = np.zeros(H * W, np.int64)
    local[cand] = np.arange(n)
    alive = np.ones(n, bool)
    rounds = 0
    for _ in range(su.LOOP_ROUNDS):
        rounds += 1
        ok = np.zeros(H * W, bool)
        ok[cand[alive]] = True
        ga, gb, step = su.links(ok, cf_full, (H, W))
        a, b = local[ga], local[gb]
        comp, ncomp, rel, bad = su.relative_orders(n, a, b, step, cand, W)
        if not bad.any():
            break
        alive[a[bad]] = False
        alive[b[bad]] = False
    else:
        comp = comp.copy()
        comp[np.isin(comp, np.unique(comp[a[bad]]))] = -1
    comp[~alive] = -1
    return (comp, ncomp, rel, a, b), rounds


def _canonical(comp):
    """Component labels renamed to their first member's number (-1 stays): equal partitions compare equal."""
    out = np.full(comp.size, -1, np.int64)
    ok = comp >= 0
    first = {}
    for i in np.flatnonzero(ok):
        first.setdefault(int(comp[i]), i)
    out[ok] = [first[int(c)] for c in comp[ok]]
    return out


@pytest.mark.parametrize("vortices", [((30, 40),), ((12, 15), (50, 70)), ((10, 10), (11, 60), (48, 20), (50, 75))])
def test_local_loop_cutting_equals_a_full_rebuild(vortices):
    """The rounds after the first rebuild only what the cut pixels touch (datapipe/sl/surfaces.py):
    the components, relative orders and links equal those of rebuilding everything every round, on
    finest phases with phase vortices (loops whose steps do not sum to zero: the cutting runs) beside
    a smooth ramp, a second patch and scattered pixels."""
    from datapipe.sl.surfaces import surfaces

    rng = np.random.default_rng(len(vortices))
    H, W = 64, 96
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    phase = 0.19 * x + 0.04 * y + rng.normal(0, 0.02, (H, W))
    for vy, vx in vortices:
        phase += np.arctan2(y - vy - 0.5, x - vx - 0.5) / (2 * np.pi)
    ok = rng.random((H, W)) < 0.97
    ok[:, 88:90] = False                       # a gap: the right strip is another patch
    cand = np.flatnonzero(ok)
    cf = (phase.ravel()[cand] % 1.0).astype(np.float32)
    want, rounds = _full_rebuild_surfaces(cand, cf, (H, W))
    assert rounds >= 2                         # the loops were cut: the local rebuild ran
    got = surfaces(cand, cf, (H, W))
    np.testing.assert_array_equal(_canonical(got[0]), _canonical(want[0]))
    live = want[0] >= 0
    np.testing.assert_array_equal(got[2][live], want[2][live])
    assert sorted(zip(got[3].tolist(), got[4].tolist())) == sorted(zip(want[3].tolist(), want[4].tolist()))


def test_local_support_is_the_window_sums():
    """The local support (datapipe/sl/orders.py, ``_local_support``: both halves of an axis from one
    filter) equals brute-force float64 sums over each pixel's LOCAL x LOCAL window and the four halves
    of its HALF x HALF window (a half counted only with HALF_MIN pooled pixels in it), the least over
    the offsets tried; sparse pixels, capped costs, pixels at the box's edges."""
    from datapipe.sl import orders

    rng = np.random.default_rng(5)
    H, W = 40, 50
    flat = np.flatnonzero(rng.random(H * W) < 0.6)
    capped = np.minimum(rng.exponential(8.0, (64, flat.size)), orders.ROBUST_CAP).astype(np.float32)
    mq = rng.integers(0, 64, flat.size)
    shifts = [1, 7, 63]
    full, half = orders._local_support(flat, lambda m: capped[m, np.arange(flat.size)], mq, 64, (H, W), shifts)
    r, c = np.divmod(flat, W)
    L, k = orders.LOCAL // 2, orders.HALF // 2
    cnt = np.zeros((H, W))
    cnt[r, c] = 1
    want_full = np.full(flat.size, np.inf)
    want_half = np.full(flat.size, np.inf)
    for d in shifts:
        img = np.zeros((H, W))
        img[r, c] = capped[(mq + d) % 64, np.arange(flat.size)].astype(np.float64) - capped[mq, np.arange(flat.size)]
        for j, (y, x) in enumerate(zip(r, c)):
            win = lambda a, y0, y1, x0, x1: a[max(y0, 0):y1 + 1, max(x0, 0):x1 + 1].sum()
            want_full[j] = min(want_full[j], win(img, y - L, y + L, x - L, x + L))
            for y0, y1, x0, x1 in ((y - k, y, x - k, x + k), (y, y + k, x - k, x + k),
                                   (y - k, y + k, x - k, x), (y - k, y + k, x, x + k)):
                if win(cnt, y0, y1, x0, x1) >= orders.HALF_MIN:
                    want_half[j] = min(want_half[j], win(img, y0, y1, x0, x1))
    np.testing.assert_allclose(full, want_full, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(half, want_half, rtol=1e-5, atol=1e-4)


def test_block_folds_are_the_medians_folds():
    """How far each block is folded back into the projector's range (``_block_folds``: from the
    block's extremes, the median only where they disagree) equals ``floor((np.median + 0.5) /
    length)`` per block: blocks inside the range, past either edge, and straddling an edge with
    their median on either side of it."""
    from datapipe.sl.orders import _block_folds

    rng = np.random.default_rng(4)
    length = 1280.0
    centres = [600, -300, 1500, -0.5, 1279.5, 1279.4, 1279.6, 2559.5, 40]
    size = np.array([33, 40, 64, 35, 36, 50, 51, 32, 1])
    x = np.concatenate([rng.normal(c, 3.0 if c % 1 else 200.0, n) for c, n in zip(centres, size)])
    binv = np.repeat(np.arange(size.size), size)
    starts = np.r_[0, np.cumsum(size)[:-1]]
    got = _block_folds(x, binv, starts, size, length)
    want = [np.floor((np.median(x[binv == k]) + 0.5) / length) for k in range(size.size)]
    np.testing.assert_array_equal(got, want)
    assert len(set(want)) >= 3


def test_local_loop_cutting_on_random_fields():
    """The same on 60 random fields (size, ramp, noise, 0-7 vortices of either sign, some near or past
    the border, 50-100% of the pixels candidates): every case equal to a full rebuild, among them
    cases that cut loops in two rounds."""
    from datapipe.sl.surfaces import surfaces

    rounds_seen = set()
    for seed in range(60):
        rng = np.random.default_rng(seed)
        H, W = rng.integers(20, 80), rng.integers(20, 120)
        y, x = np.mgrid[0:H, 0:W].astype(np.float64)
        phase = rng.uniform(0.05, 0.3) * x + rng.uniform(-0.1, 0.1) * y + rng.normal(0, rng.uniform(0.01, 0.12), (H, W))
        for _ in range(rng.integers(0, 8)):
            vy, vx = rng.uniform(-2, H + 2), rng.uniform(-2, W + 2)
            phase += rng.choice([-1, 1]) * np.arctan2(y - vy, x - vx) / (2 * np.pi)
        cand = np.flatnonzero(rng.random((H, W)) < rng.uniform(0.5, 1.0))
        cf = (phase.ravel()[cand] % 1.0).astype(np.float32)
        want, rounds = _full_rebuild_surfaces(cand, cf, (H, W))
        rounds_seen.add(rounds)
        got = surfaces(cand, cf, (H, W))
        if want[3].size == 0:
            assert got is None
            continue
        np.testing.assert_array_equal(_canonical(got[0]), _canonical(want[0]), err_msg=f"seed {seed}")
        live = want[0] >= 0
        np.testing.assert_array_equal(got[2][live], want[2][live], err_msg=f"seed {seed}")
        assert sorted(zip(got[3].tolist(), got[4].tolist())) == sorted(zip(want[3].tolist(), want[4].tolist()))
    assert {2, 3} <= rounds_seen


def test_offset_costs_block_sums_and_single_offsets():
    """The offset costs (datapipe/sl/orders.py, ``_OffsetCosts``) without the (K_f, n) array: the
    block sums, computed a few whole blocks at a time (here a chunk of 50 pixels, blocks of 1-120
    pixels, so chunks of several blocks and blocks wider than a chunk), and one offset per pixel,
    equal the formula evaluated in float64 and summed per block (float32 rounding: rtol 1e-4)."""
    from datapipe.sl.orders import ROBUST_CAP, _OffsetCosts

    rng = np.random.default_rng(7)
    per = np.array([1.0, 8.0, 64.0])
    sizes = rng.integers(1, 121, 40)
    sizes[5] = 120
    n = int(sizes.sum())
    fine = rng.uniform(0, 1, n) + rng.integers(0, 3, n)
    cyc = [rng.uniform(-0.5, 0.5, n).astype(np.float32) for _ in per]
    var_c = [rng.uniform(1e-4, 5e-3, n).astype(np.float32) for _ in per]
    m = np.arange(64)[:, None]
    want = np.zeros((64, n))
    for i in (0, 1):
        t = per[i] / 64 * (fine + m) - cyc[i].astype(np.float64)
        want += (t - np.rint(t)) ** 2 / (var_c[i].astype(np.float64) + (per[i] / 64) ** 2 * var_c[2])
    starts = np.r_[0, np.cumsum(sizes)[:-1]]
    costs = _OffsetCosts(fine, cyc, var_c, per)
    got = costs.block_sums(starts, ROBUST_CAP, chunk=50)
    np.testing.assert_allclose(got, np.add.reduceat(np.minimum(want, ROBUST_CAP), starts, axis=1), rtol=1e-4, atol=1e-4)
    mq = rng.integers(0, 64, n)
    np.testing.assert_allclose(costs.at(mq), want[mq, np.arange(n)], rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(costs.at(mq, ROBUST_CAP), np.minimum(want[mq, np.arange(n)], ROBUST_CAP),
                               rtol=1e-4, atol=1e-6)
