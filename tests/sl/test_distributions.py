"""`sl.distributions` against `scipy.stats`, and the import it saves.

Both call the same special functions, so the values agree to the special functions' own accuracy
(~1e-15 relative); rtol 1e-12 leaves room for a different evaluation order in a later scipy.
"""
import subprocess
import sys

import numpy as np
import pytest
import scipy.stats

from datapipe.sl import distributions as d

DFS = [1, 2, 3, 5, 8, 11, 24, 63]
PS = [1e-12, 1e-8, 1e-4, 0.01, 0.05, 0.5, 0.9, 0.999]


@pytest.mark.parametrize("df", DFS)
def test_chi2_matches_scipy_stats(df):
    p = np.array(PS)
    np.testing.assert_allclose(d.chi2_isf(p, df), scipy.stats.chi2.isf(p, df), rtol=1e-12)
    np.testing.assert_allclose(d.chi2_ppf(p, df), scipy.stats.chi2.ppf(p, df), rtol=1e-12)
    x = scipy.stats.chi2.ppf(p, df)
    np.testing.assert_allclose(d.chi2_cdf(x, df), scipy.stats.chi2.cdf(x, df), rtol=1e-12)
    assert d.chi2_median(df) == pytest.approx(scipy.stats.chi2.median(df), rel=1e-12)


@pytest.mark.parametrize("dfn,dfd", [(1, 10), (4, 100), (6, 2000), (9, 50000)])
def test_f_isf_matches_scipy_stats(dfn, dfd):
    for p in (1e-6, 1e-3, 0.01, 0.5):
        assert d.f_isf(p, dfn, dfd) == pytest.approx(scipy.stats.f.isf(p, dfn, dfd), rel=1e-10)


def test_the_gate_does_not_import_scipy_stats_or_optimize():
    """Every CLI call imports the gate; scipy.stats + scipy.optimize cost it ~0.8 s each time."""
    code = ("import sys, datapipe.engine.gate; "
            "print(sorted(m for m in ('scipy.stats', 'scipy.optimize') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]", out.stdout
