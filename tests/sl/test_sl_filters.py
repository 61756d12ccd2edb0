"""The edge/speckle and multipath filters the pipeline applies after decoding (no bpy)."""
import numpy as np
import pytest
import synth
from sl_helpers import PERIODS, STEPS, decode_kw

from datapipe import sl
from datapipe.sl import edge_speckle_filter
from datapipe.sl import exposure as X


def test_edge_filter_removes_flying_pixels_and_speckles_keeps_slopes():
    H, W = 40, 60
    f = 450.0                                          # px, the preset camera at 320 px
    u = np.arange(W)[None, :].repeat(H, 0).astype(np.float64)
    z = np.full((H, W), 0.8)
    z[:, 30:] = 0.72                                   # a step (box top 8 cm above the floor)
    z[:, 29] = 0.76                                    # a column of flying pixels between the two
    z[10, 10] = 0.70                                   # an isolated speckle (wrong fringe order)
    slope = 0.8 + (u - 45) * 0.8 / f * np.tan(np.radians(70))   # a 70 deg slanted strip, kept
    z[20:, 40:] = slope[20:, 40:]
    valid = np.ones((H, W), bool)
    sigma = np.full((H, W), 1e-4)
    bad = edge_speckle_filter(z, valid, sigma, 1.0 / f)
    assert bad[:, 29].all() and bad[10, 10]
    keep = np.ones((H, W), bool)
    keep[:, 29] = False
    keep[10, 10] = False
    assert not bad[keep].any()                         # floor, box top, borders and the 70 deg slope stay
    # the same with a slope steeper than the filter admits (85 deg): its pixels lose their support
    z2 = z.copy()
    z2[20:, 40:] = (0.8 + (u - 45) * 0.8 / f * np.tan(np.radians(85)))[20:, 40:]
    assert edge_speckle_filter(z2, valid, sigma, 1.0 / f)[21:-1, 41:-1].all()



def test_edge_filter_removes_the_remnant_of_an_island_of_wrong_orders():
    """Demo render 1 in render mode (320 x 240, benchmarks/results/sl_truth.md): the decoder's
    depth (mm, NaN = no data) and depth sigma (um) at rows 146-152, columns 33-39, before the edge
    filter. Columns 33-35: the bin floor (z-buffer 617-618 mm); 36-39: the bin wall at grazing
    incidence, where light bounced off the floor pulls the 1-period phase by 0.107 periods and
    the 8-period order goes one too far: 456-459 mm for 620-624 mm (953 mm: one order the other
    way). The support test removed the island's rim (too few agreeing neighbours each) and kept
    its middle pixel (row 149, column 36: its rim agreed with it) -- alone, 164 mm off, among 3
    kept floor pixels that do not agree with it. It must go; the floor stays."""
    n = np.nan
    z = np.array([[617.24, 617.03, 618.16, n, n, 627.82, n],
                  [617.35, 617.18, 618.19, n, 623.86, n, 631.54],
                  [617.41, 617.33, 618.40, 456.55, 458.45, n, 631.97],
                  [617.51, 617.48, 618.43, 456.56, n, 627.76, n],
                  [617.79, 617.64, 618.76, 953.33, 458.61, n, 631.83],
                  [617.92, 617.73, 618.67, n, n, n, n],
                  [617.94, 617.83, 618.22, n, 458.63, 627.88, n]]) * 1e-3
    sigma = np.array([[56, 56, 74, n, n, 179, n],
                      [55, 54, 73, n, 161, n, 165],
                      [55, 56, 73, 112, 116, n, 194],
                      [54, 55, 71, 111, n, 202, n],
                      [55, 54, 77, 475, 125, n, 167],
                      [55, 55, 71, n, n, n, n],
                      [55, 55, 70, n, 125, 176, n]]) * 1e-6
    valid = np.isfinite(z)
    bad = edge_speckle_filter(z, valid, sigma, 1.0 / 453.1)      # fx of the demo camera at 320 px
    assert bad[3, 3]                                   # the remnant (row 149, column 36)
    assert bad[2:5, 3:5][valid[2:5, 3:5]].all()        # and the rest of the island
    assert not bad[1:-1, 1:3].any()                    # the floor pixels with all 8 neighbours here stay

def test_multipath_filter_removes_inter_reflected_orders_not_ambient(rig):
    """Plane, periods (1, 8, 64). Right half: besides the direct light, light from another surface
    point 256 projector px away, 1.5x as strong, blurred by a bounce (modulation kept 98% / 21% /
    0% for 1 / 8 / 64 periods: the pipeline's INDIRECT_BLUR_PX at K/W = 1/512 etc.): the coarse
    phase follows the other point, so the decoder picks wrong fringe orders (> 5 mm errors).
    Left half: 4x the projector's mean light as unmodulated ambient (contrast B/A = 0.2).
    The filter removes the wrong orders and none of the ambient-lit pixels; the fixed contrast test
    it replaces (B/A >= 0.5) removed the whole ambient-lit half."""
    cam, proj = rig
    r = synth.render(synth.plane_scene(), cam, proj, PERIODS, STEPS)
    W = proj.size[0]
    cols = np.arange(r.lit.shape[1])[None, :]
    right, left = r.lit & (cols >= r.lit.shape[1] // 2), r.lit & (cols < r.lit.shape[1] // 2)
    img = r.images.copy()
    kept = {1: 0.98, 8: 0.21, 64: 0.0}
    x_other = np.where(right, r.proj_x + 256.0, 0.0)
    for i, K in enumerate(PERIODS):
        for n in range(STEPS):
            glob = 1.5 * (0.5 + 0.5 * kept[K] * np.cos(2 * np.pi * K * x_other / W + 2 * np.pi * n / STEPS))
            img[i * STEPS + n] += np.where(right, glob, 0.0)
    img[:, left] += 2.0
    img = img.astype(np.float32)
    ind = sl.SensorModel.preset("industrial")
    cap = X.capture(img, ind, [X.auto_exposure(img, ind)], 3)
    res = sl.decode(cap.images, noise_sigma=cap.noise_sigma, saturation=cap.saturation,
                    **decode_kw(cam, proj, min_contrast=0.05))
    wrong = res.valid & (np.abs(res.depth - r.depth) > 5e-3)
    assert wrong[right].mean() > 0.9                   # the decoder alone trusts the wrong orders
    mp = sl.multipath_filter(res.modulation, res.offset, PERIODS, STEPS, cap.noise_sigma, res.valid)
    assert (wrong & ~mp)[right].mean() < 0.005
    assert res.valid[left].mean() > 0.99 and not mp[left].any()
    fixed = sl.decode(cap.images, noise_sigma=cap.noise_sigma, saturation=cap.saturation,
                      **decode_kw(cam, proj, min_contrast=0.5))
    assert fixed.valid[left].mean() < 0.01
    # heterodyne-like sets (finest / coarsest < 4) have no coarse fringe to compare: nothing removed
    assert not sl.multipath_filter(res.modulation, res.offset, (70, 64, 59), STEPS, cap.noise_sigma,
                                   res.valid).any()


def _scanner(cam, proj, **kw):
    return sl.Scanner(PERIODS, STEPS, proj.size, proj.K, np.linalg.inv(cam.T) @ proj.T, **kw)


def test_reflection_filter_removes_mirror_ghosts_off_the_epipolar_plane(rig):
    """Box on a plane, fringes plus the row code (8 periods of row fringes over the projector
    height, synth.render axis='y'). A 20 x 25 px patch of floor pixels sees, as through a mirror,
    only the light of the pixels 10 columns and 25 rows away (box top and floor): one path, every
    frequency sharp, so the decoder and the local (multipath) filter trust it and triangulate
    ghosts > 5 mm off. Its light left the projector 72-74 rows from the row at which the projector
    sees the ghost (analytic), 22-24 rows from a whole row period (48 rows): the row code removes
    every ghost (reason REFLECTION) and no directly lit pixel (1% noise, sensor model)."""
    cam, proj = rig
    scene = synth.box_scene()
    cols = synth.render(scene, cam, proj, PERIODS, STEPS)
    rows = synth.render(scene, cam, proj, sl.scanner.ROW_PERIODS, STEPS, axis="y")
    clean = np.concatenate([cols.images, rows.images]).astype(np.float32)
    stack = clean.copy()
    patch = (slice(5, 25), slice(5, 30))
    stack[:, patch[0], patch[1]] = clean[:, 30:50, 15:40]              # the mirror image
    ghost = np.zeros(cols.depth.shape, bool)
    ghost[patch] = True
    local = _scanner(cam, proj, row_check=False).scan(stack, 3, cam.K, cam.T)
    assert local.reflection is None and local.summary()["reflection_filter"] == "local"
    wrong = local.result.valid & ghost & (np.abs(local.result.depth - cols.depth) > 5e-3)
    assert wrong.sum() > 0.9 * ghost.sum()                            # trusted ghosts
    scan = _scanner(cam, proj).scan(stack, 3, cam.K, cam.T)
    res = scan.result
    assert scan.summary()["reflection_filter"] == "global"
    assert not (res.valid & ghost).any() and (res.reason[wrong] == sl.Reason.REFLECTION).all()
    assert not scan.reflection[~ghost].any()                          # direct light always agrees
    assert (res.valid == local.result.valid)[~ghost].all()
    # the debug map says why: the ghosts' rows are 22-24 rows off, the direct pixels' within the noise
    rr = scan.maps(debug=True)["sl_debug"]["row_residual"]
    assert (np.abs(rr[wrong]) > 20).all() and np.nanmax(np.abs(rr[res.valid])) < 1.0
    # the decoded depth of the kept pixels is untouched, and without the row code nothing changes
    plain = _scanner(cam, proj).scan(stack[:len(PERIODS) * STEPS], 3, cam.K, cam.T)
    assert plain.reflection is None
    assert np.array_equal(plain.result.valid, local.result.valid)
    with pytest.raises(ValueError, match="row-coded"):                # neither stack length
        _scanner(cam, proj).scan(stack[:-1], 3, cam.K, cam.T)


def test_reflection_filter_tolerance_follows_the_row_code_noise():
    """The test itself, 8 row periods over 600 rows (75-row period): a residual beyond
    sqrt((5 sigma_y)^2 + min_px^2) is removed, below kept; sigma_y grows as the row code's
    modulation falls (a dark pixel is not removed for noise); residuals wrap at the period (the
    prediction unwraps the code: one whole period off is an alias, kept); pixels whose row code
    cannot be read are kept."""
    Hp, N, K = 600, 4, 8
    period = Hp / K
    sig, B = 2.0, np.array([[400.0, 400.0, 400.0, 4.0, 400.0, 400.0]])
    sigma_y = period / (2 * np.pi) * np.sqrt(2 / N) * sig / B
    tol = np.sqrt((sl.filters.ROW_SIGMAS * sigma_y) ** 2 + sl.filters.ROW_MIN_PX ** 2)
    pred = np.full((1, 6), 300.0)
    meas = pred + np.array([[0.9, 1.1, 0.0, 0.9, 30.0, 0.0]]) * np.array([[*tol[0, :2], 1, tol[0, 3], 1, 1]])
    meas[0, 2] = pred[0, 2] + period + 0.5 * tol[0, 2]             # one period off: an alias, kept
    meas[0, 5] = pred[0, 5] + 30.0                                 # off, but its row code is unreadable
    phase = np.mod(meas * 2 * np.pi * K / Hp, 2 * np.pi)
    valid = np.ones((1, 6), bool)
    checkable = np.array([[True, True, True, True, True, False]])
    residual = sl.filters.row_residual(sl.filters.row_from_phase(phase, Hp, K), pred, period)
    bad = sl.reflection_filter(residual, B, Hp, N, sig, valid, periods=K, checkable=checkable)
    assert bad.tolist() == [[False, True, False, False, True, False]]
    assert tol[0, 3] > 20 > 4 > tol[0, 0]                          # a dark pixel's noise widens it
    assert not sl.reflection_filter(residual, B, Hp, N, sig, ~valid, periods=K).any()


def test_global_light_filter_removes_bounce_decided_orders_and_bounce_only_light(rig):
    """Plane, periods (1, 8, 64), the pipeline's bounce model (modulation kept 98% / 21% / 0% for
    1 / 8 / 64 periods). Right half: besides the direct light, as much bounced light (g / d = 1)
    from a point 5W/16 away in projector columns: the 1-period phasor turns by ~55 deg, 8 x that is
    more than one 8-period fringe, so the decoder picks wrong orders, while the fine and coarse
    modulations still agree within the multipath filter's 0.6 (what the demo's bin wall showed).
    (The filter reads d from the 8 and 64-period modulations; an 8-period bounce phasor in phase
    with the direct one would raise B_8 by g_8 g / 2 and hide up to 21% of g.)
    A band of the left half gets the bounce alone (a projector-shadowed wall). The global-light
    filter removes the wrong orders and the bounce-only band; the directly lit rest (g = 0) stays,
    and pure noise (no light) is never removed by it."""
    cam, proj = rig
    r = synth.render(synth.plane_scene(), cam, proj, PERIODS, STEPS)
    W = proj.size[0]
    H2, W2 = r.lit.shape
    cols = np.arange(W2)[None, :].repeat(H2, 0)
    rows = np.arange(H2)[:, None].repeat(W2, 1)
    right = r.lit & (cols >= W2 // 2)
    only = r.lit & (cols < W2 // 2) & (rows < H2 // 4)
    clean = r.lit & (cols < W2 // 2) & (rows >= H2 // 4)
    img = r.images.copy()
    img[:, only] = 0.0
    kept = {1: 0.98, 8: 0.21, 64: 0.0}
    assert all(abs(sl.indirect_gain(K, 912) - g) < 0.01 for K, g in kept.items())   # the renderer's, 912 px projector
    x_other = r.proj_x + W * 5.0 / 16.0
    for i, K in enumerate(PERIODS):
        for n in range(STEPS):
            glob = 0.5 + 0.5 * kept[K] * np.cos(2 * np.pi * K * x_other / W + 2 * np.pi * n / STEPS)
            img[i * STEPS + n] += np.where(right | only, glob, 0.0)
    img = img.astype(np.float32)
    ind = sl.SensorModel.preset("industrial")
    cap = X.capture(img, ind, [X.auto_exposure(img, ind)], 3)
    res = sl.decode(cap.images, noise_sigma=cap.noise_sigma, saturation=cap.saturation, **decode_kw(cam, proj))
    wrong = res.valid & (np.abs(res.depth - r.depth) > 5e-3)
    assert wrong[right].mean() > 0.3                    # the bounce decides the orders
    mp = sl.multipath_filter(res.modulation, res.offset, PERIODS, STEPS, cap.noise_sigma, res.valid)
    assert (wrong & ~mp)[right].mean() > 0.2            # ... and the ratio test leaves most of them
    direct = sl.filters.direct_frequencies(PERIODS, W)
    assert direct.tolist() == [False, True, True]
    gl = sl.filters.global_light_filter(res.modulation, res.offset, direct, STEPS, cap.noise_sigma, res.valid)
    assert (wrong & ~gl & ~mp)[right].mean() < 0.002
    assert not (res.valid & ~gl & ~mp)[only].any()      # no depth from bounced light alone
    assert res.valid[clean].mean() > 0.99 and gl[clean].mean() < 0.001
    noise = sl.filters.global_light_filter(res.modulation * 0 + 1e-3, np.full(res.offset.shape, 5.0), direct, STEPS,
                                           30.0, np.ones_like(res.valid))
    assert not noise.any()                              # A - 1.7 B within 3 sigma of the noise: kept
    # a projector gamma changes direct light's own A / B: (1/2 + 1/2 cos)^0.25, 4 steps: up to 3.3
    c = sl.filters.direct_offset_ratio(0.25, STEPS)
    t = np.linspace(0, 2 * np.pi, STEPS, endpoint=False)[:, None, None]
    frames = 200.0 * (0.5 + 0.5 * np.cos(t + np.linspace(0, 6, 50)[None, None, :])) ** 0.25
    ph = sl.phase_shift(np.repeat(frames, 3, axis=1).reshape(STEPS, 3, 50))
    assert abs(float(np.max(ph.offset / ph.modulation)) - c) < 0.02 and c > 1.9
    mods = np.broadcast_to(ph.modulation, (3, 3, 50))
    assert sl.filters.global_light_filter(mods, ph.offset, direct, STEPS, 1.0, np.ones((3, 50), bool)).mean() > 0.8
    assert not sl.filters.global_light_filter(mods, ph.offset, direct, STEPS, 1.0, np.ones((3, 50), bool),
                                              direct_offset=c).any()
    # the scanner runs it with the local reflection filter: reason MULTIPATH, off with the filter off
    scan = _scanner(cam, proj).scan(img, 3, cam.K, cam.T)
    res = scan.result
    assert not (res.valid & only).any() and (res.valid & right & (np.abs(res.depth - r.depth) > 5e-3)).mean() < 0.002
    assert (res.reason[right & ~res.valid] == sl.Reason.MULTIPATH).mean() > 0.5 and res.valid[clean].mean() > 0.99
    off = _scanner(cam, proj, multipath_filter=False).scan(img, 3, cam.K, cam.T).result
    assert (off.valid & right & (np.abs(off.depth - r.depth) > 5e-3)).mean() > 0.3


def test_bounce_islands_of_wrong_orders_are_removed_small_regions_in_direct_light_stay(rig):
    """Plane, periods (1, 8, 64), the pipeline's bounce model (98% / 21% / 0%). A 3 x 4 px patch
    gets, besides its direct light d, bounced light g = 0.9 d from a point W/4 away in projector
    columns: the 1-period phasor turns by atan(0.98 * 0.9) = 41 deg, 8 x that is 0.92 of an
    8-period fringe, so the patch decodes one whole fringe off, consistently (the frequencies fit
    the wrong order: confidence ~1). The 8-period bounce is in phase with the direct light, so the
    filter's g / d = 0.79 g / (1 + 0.21 g) = 0.6 is under the global-light filter's 0.7, and the
    12 wrong pixels support each other in the edge filter -- an island, as the aluminium parts'
    renders left them (benchmarks/results/sl_truth.md). It must go (reason MULTIPATH). A band of
    rows with g = 0.6 d from W/32 away (1-period phasor turned by 4 deg: orders right; 8-period
    bounce in quadrature: g / d = 0.59 as well) is large and stays; a 3 x 3 patch of directly lit
    plane inside a dark ring (a small region in direct light) stays."""
    cam, proj = rig
    r = synth.render(synth.plane_scene(), cam, proj, PERIODS, STEPS)
    W = proj.size[0]
    island = np.zeros(r.lit.shape, bool)
    island[40:43, 60:64] = True
    band = np.zeros(r.lit.shape, bool)
    band[80:100, 10:150] = True
    small, ring = np.zeros(r.lit.shape, bool), np.zeros(r.lit.shape, bool)
    ring[20:27, 100:107] = True
    small[22:25, 102:105] = True
    ring &= ~small
    assert r.lit[island | band | ring].all()
    img = r.images.copy()
    kept = {1: 0.98, 8: 0.21, 64: 0.0}
    for i, K in enumerate(PERIODS):
        for n in range(STEPS):
            for where, shift, g in ((island, W / 4.0, 0.9), (band, W / 32.0, 0.6)):
                phase = 2 * np.pi * K * (r.proj_x + shift) / W + 2 * np.pi * n / STEPS
                glob = g * (0.5 + 0.5 * kept[K] * np.cos(phase))
                img[i * STEPS + n] += np.where(where, glob, 0.0)
    img[:, ring] = 0.0
    img = img.astype(np.float32)
    wrong = lambda res: res.valid & (np.abs(res.depth - r.depth) > 5e-3)   # noqa: E731
    decoded = sl.decode(img, **decode_kw(cam, proj))
    assert wrong(decoded)[island].mean() > 0.9 and decoded.confidence[wrong(decoded)].min() > 0.99
    gd = sl.filters.global_direct_ratio(decoded.modulation, decoded.offset, sl.filters.direct_frequencies(PERIODS, W))
    assert 0.55 < np.median(gd[island]) < 0.65 and 0.55 < np.median(gd[band]) < 0.65 and np.median(gd[small]) < 0.1
    scan = _scanner(cam, proj).scan(img, 3, cam.K, cam.T)
    res = scan.result
    assert not wrong(res)[island].any()
    assert (res.reason[island & wrong(decoded)] == sl.Reason.MULTIPATH).all()
    assert res.valid[band].mean() > 0.99 and res.valid[small].all()
    assert not wrong(res).any()
    # the filter alone: regions of fewer than 20 px (this 160 x 120 image; 540 at 1080p) whose mean g / d is above 0.45
    assert sl.filters.island_pixels((120, 160)) == 20 and sl.filters.island_pixels((1080, 1920)) == 540
    keep = np.zeros((3, 7), bool)
    keep[1, 1:3] = keep[1, 4:6] = True                  # two 2-pixel regions
    agree = sl.filters.neighbour_agreement(np.full((3, 7), 0.6), keep, np.full((3, 7), 1e-4), 1e-3)
    gd = np.zeros((3, 7))
    gd[1, 1:3], gd[1, 4:6] = (0.3, 0.7), (0.3, 0.55)     # means 0.5 and 0.425
    assert sl.filters.bounce_island_filter(keep, agree, gd).tolist() == (keep & (np.arange(7) < 3)).tolist()
    assert not sl.filters.bounce_island_filter(keep, agree, gd, max_pixels=2).any()   # 2 px is not below 2
    off = _scanner(cam, proj, multipath_filter=False).scan(img, 3, cam.K, cam.T).result
    assert wrong(off)[island].mean() > 0.9              # with the reflection filters off, nothing is removed
