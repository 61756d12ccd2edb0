"""The neighbour vote's median (datapipe/sl/spatial.py, ``_nan_median``: a sorting network over
the 12 predictions of each pixel, some of them missing) against numpy's ``nanmedian``."""
import numpy as np

from datapipe.sl.spatial import _nan_median


def test_nan_median_is_numpys():
    rng = np.random.default_rng(3)
    for rows in (12, 5):
        P = rng.normal(0, 100, (rows, 4000)).astype(np.float32)
        miss = rng.random(P.shape) < rng.uniform(0, 1, P.shape[1])     # 0 .. all of a column missing
        P[miss] = np.nan
        med, k = _nan_median(P)
        np.testing.assert_array_equal(k, np.sum(~miss, 0))
        none = k == 0
        assert none.any() and np.all(np.isnan(med[none]))
        with np.errstate(invalid="ignore"):
            want = np.nanmedian(P[:, ~none].astype(np.float64), axis=0)
        np.testing.assert_allclose(med[~none], want, rtol=1e-6, atol=1e-5)
