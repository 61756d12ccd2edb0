"""The edge/speckle filter the pipeline applies after decoding (no bpy)."""
import numpy as np

from datapipe.sl import edge_speckle_filter


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
