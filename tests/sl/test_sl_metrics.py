"""Metric helpers and the theoretical noise formulas."""
import numpy as np
import pytest

from datapipe.sl import depth_error_stats, effective_period, theoretical_depth_sigma, theoretical_phase_sigma


def test_depth_error_stats():
    gt = np.ones((10, 10))
    d = gt.copy()
    d[0, :5] += 0.01            # 5 outliers of 10 mm
    d[1, :] = np.nan            # 10 undecoded
    lit = np.ones_like(gt, bool)
    shadow = np.zeros_like(gt, bool)
    shadow[9, :] = True
    st = depth_error_stats(d, gt, lit=lit, shadow=shadow)
    assert st["count"] == 90
    assert st["median_abs"] == 0.0
    assert st["rmse"] == pytest.approx(np.sqrt(5 * 1e-4 / 90))
    assert st["outlier_fraction"] == pytest.approx(5 / 90)
    assert st["decoded_fraction"] == pytest.approx(0.9)
    assert st["false_valid_shadow"] == 1.0
    assert st["p99"] == pytest.approx(np.percentile(np.abs((d - gt)[np.isfinite(d)]), 99))
    with pytest.raises(ValueError, match="shape"):
        depth_error_stats(d, gt[:5])


def test_formulas():
    assert theoretical_phase_sigma(2.0, 100.0, 4) == pytest.approx(np.sqrt(0.5) * 0.02)
    s = theoretical_depth_sigma(1.0, 1000.0, 0.1, 16.0, 0.01)
    assert s == pytest.approx(1.0 / 100.0 * 16 / (2 * np.pi) * 0.01)
    assert effective_period(512, (64,)) == 8.0
    assert effective_period(512, (8, 7)) == pytest.approx(512 / np.sqrt(113))
