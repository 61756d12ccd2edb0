"""The chi-square and F quantiles the decoder's tests use, from `scipy.special`.

`scipy.stats` gives the same numbers, but importing it costs ~0.5 s in every process that imports
`datapipe.sl` (the gate does: every `validate`, `run` and `demo`). Its `chi2` and `f` distributions
call exactly these special functions (scipy 1.17.1, `scipy/stats/_continuous_distns.py`:
`chi2_gen._isf` is "return sc.chdtri(df, p)", `_ppf` "return 2*sc.gammaincinv(df/2, p)", `_cdf`
"return sc.chdtr(df, x)"; `f_gen._ppf` "return sc.fdtri(dfn, dfd, q)", and its `isf` is the generic
`ppf(1 - q)`), so the values are the same; `tests/sl/test_distributions.py` compares them.
"""
from __future__ import annotations

from scipy import special

__all__ = ["chi2_isf", "chi2_ppf", "chi2_cdf", "chi2_median", "f_isf"]


def chi2_isf(p, df):
    """x with P(chi2(df) > x) = p."""
    return special.chdtri(df, p)


def chi2_ppf(q, df):
    """x with P(chi2(df) <= x) = q."""
    return 2.0 * special.gammaincinv(df / 2.0, q)


def chi2_cdf(x, df):
    """P(chi2(df) <= x)."""
    return special.chdtr(df, x)


def chi2_median(df):
    return chi2_ppf(0.5, df)


def f_isf(p, dfn, dfd):
    """x with P(F(dfn, dfd) > x) = p (for the p of a test, not for p near machine epsilon)."""
    return special.fdtri(dfn, dfd, 1.0 - p)
