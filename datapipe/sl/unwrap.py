"""Temporal phase unwrapping (several fringe frequencies of the same projector coordinate).

Notation: frequency ``K`` (periods across the projector width W), wrapped phase
``phi_K = 2*pi*K*u mod 2*pi`` with ``u = x / W`` the projector coordinate as a fraction of the
width (pixel centres at ``x = 0..W-1``, so the lit range is ``u in [-0.5/W, 1 - 0.5/W)``).

Methods
-------
``'multi-frequency'`` (hierarchical): the coarsest frequency has ``K <= 1`` (one period or less
    across the projector), so its phase is absolute; each finer frequency is unwrapped from the
    estimate of the previous one: ``k = round((K_i * u_prev - phi_i/2pi))``. Ratios need not be
    integers. An order error needs ``|r*noise| > 1/2`` with ``r = K_i/K_{i-1}`` (docs/STRUCTURED_LIGHT.md).
``'heterodyne'``: two frequencies with ``|K1 - K2| <= 1`` (the original DataPipe's method): the
    beat ``phi_1 - phi_2`` has ``K1 - K2`` periods and is absolute. With 3+ frequencies the beats
    of neighbouring frequencies are beaten again (``(K1-K2) - (K2-K3)`` ...) until one beat of at
    most one period remains; then every level is unwrapped top-down from the level above.
``'number-theoretic'``: any integer frequencies with gcd 1, e.g. (13, 7) or (9, 10, 11): the
    closest point of the lattice of consistent order vectors (:mod:`.lattice`; maximum likelihood
    for equal phase noise). Noise gain ``1/d_min``: ``sqrt(K1^2 + K2^2)`` for two frequencies
    (identical to heterodyne for ``|K1 - K2| = 1``), 7.1 for (9, 10, 11), 11.8 for (70, 64, 59)
    where the heterodyne chain's worst stage has 15.8.
``'auto'``: hierarchical when the coarsest frequency is ``<= 1`` period, else number-theoretic for
    integer sets with gcd 1, else heterodyne when the (chained) beat reaches one period, else
    ``ValueError`` with a valid suggestion.

Result: the projector coordinate combines all original frequencies weighted by ``K^2`` (inverse
variance for equal phase noise), which lowers the noise below that of the finest frequency alone
by ``K_max / sqrt(sum K^2)``. ``order_error`` is, per pixel, the largest distance of any rounded
order estimate from its integer (0 = certain, 0.5 = a coin toss). ``margins`` holds, per rounding
stage, the evidence for its decision: ``1 - 2|r - round(r)|`` (a lattice stage: the squared
distance to the second-closest point minus that to the closest), in the units of the stage's
noise coefficients ``UnwrapPlan.stage_coefs()``; :mod:`.confidence` turns them into the
probability that the orders are right.

Edges: the coarse estimate is wrapped into the projector's lit range centred on the projector
(``[-0.5, W-0.5)`` in pixels, when ``proj_width`` is given) and, for integer frequencies, the final
coordinate is wrapped into the same range: a coarse estimate that noise pushed across the left or
right edge is consistent with every finer frequency shifted by exactly one width, so the fine
phase brings it back. Only pixels within the fine-phase noise of ``x = -0.5`` stay ambiguous.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ._errors import bad_value
from .lattice import lattice_code
from .patterns import _check_periods

__all__ = ["UnwrapResult", "UnwrapPlan", "unwrap_phase", "unwrap_cycles", "plan_unwrap", "as_plan"]

TWO_PI = 2.0 * np.pi
_TOL = 1e-9
METHODS = ("auto", "heterodyne", "multi-frequency", "number-theoretic")


@dataclass
class UnwrapResult:
    """``phase``: absolute phase of the finest frequency ``2*pi*K_max*x/W`` (combined estimate);
    ``x``: projector coordinate (pixels with ``proj_width``, else the fraction ``x/W``);
    ``order_error``: see the module doc."""
    phase: np.ndarray
    x: np.ndarray
    order_error: np.ndarray
    method: str
    periods: tuple
    margins: list = None       # per rounding stage, see the module doc
    residuals: list = None     # per stage: squared distance to the chosen order (None: ((1-margin)/2)^2)


def _is_int(k: float) -> bool:
    return abs(k - round(k)) < 1e-9


def _suggest(per: Sequence[float]) -> str:
    kmax = max(per)
    hier = (1,) + tuple(sorted(int(k) if _is_int(k) else k for k in per if k > 1))
    k = int(round(kmax)) if kmax >= 2 else 8
    return (f"add a one-period pattern for hierarchical unwrapping, e.g. periods={hier}, "
            f"or use a heterodyne pair such as periods=({k}, {k - 1}) or integers without a common factor "
            "such as (13, 7) or (9, 10, 11); (1, 8, 64) is a robust default")


def _chain(per_desc: list[float]):
    """Heterodyne levels: list of levels, each a list of (K, coeff-vector over originals)."""
    m = len(per_desc)
    level = [(k, np.eye(m, dtype=np.int64)[i]) for i, k in enumerate(per_desc)]
    levels = [level]
    while len(level) > 1:
        nxt = []
        for j in range(len(level) - 1):
            k = level[j][0] - level[j + 1][0]
            c = level[j][1] - level[j + 1][1]
            if k < 0:
                k, c = -k, -c
            nxt.append((k, c))
        level = nxt
        levels.append(level)
    return levels


@dataclass(frozen=True)
class UnwrapPlan:
    method: str                 # 'heterodyne', 'multi-frequency' or 'number-theoretic'
    periods: tuple              # as given (stack order)
    order: tuple                # indices into periods: coarse -> fine (hierarchical) / desc (heterodyne)
    levels: tuple = ()          # heterodyne chain (see _chain), top level last
    integer: bool = True

    @property
    def finest(self) -> int:
        return int(np.argmax(self.periods))

    @property
    def lattice(self):
        return lattice_code(tuple(self.periods)) if self.method == "number-theoretic" else None

    def noise_gain(self) -> float:
        """Largest noise gain of a rounding stage (see :meth:`stage_gains`)."""
        g = self.stage_gains()
        return max(g) if g else 0.0

    def stage_gains(self) -> list:
        """Noise gain of every rounding stage, in units of one frequency's phase noise.

        A stage rounds ``r = (k/k_above) * c_above - c``; with independent phase noise sigma_phi
        per frequency its noise is ``gain * sigma_phi`` (radians of the rounded phase), gain being
        the norm of the stage's coefficient vector over the original phases (so a beat shared by
        both terms counts once): ``sqrt(r^2 + 1)`` for a hierarchical stage of ratio r,
        ``sqrt(K1^2 + K2^2)`` for a heterodyne pair with K1 - K2 = 1 (docs/STRUCTURED_LIGHT.md: 27.6 for 20/19).
        The order is then wrong with probability ``erfc(pi / (sqrt(2) * gain * sigma_phi))``.
        (For chains the estimate from the level above is taken as its best node: conservative.)
        A number-theoretic plan has one stage of gain ``1/d_min`` (:mod:`.lattice`).
        """
        if self.method == "number-theoretic":
            return [self.lattice.gain]
        return [float(np.linalg.norm(c)) for c in self.stage_coefs()]

    def stage_coefs(self) -> list:
        """Per rounding stage, its coefficients over the original phases (stack order): the stage's
        noise variance is ``sum(coef_j^2 sigma_j^2)`` (sigma_j: phase noise of frequency j, in
        cycles) in the units of its margin (module doc). None for a lattice stage of 3+ frequencies,
        whose margin is in cycles^2 of the largest sigma_j."""
        F = len(self.periods)
        out = []
        if self.method == "multi-frequency":
            for a, b in zip(self.order[:-1], self.order[1:]):
                c = np.zeros(F)
                c[a], c[b] = self.periods[b] / self.periods[a], -1.0
                out.append(c)
            return out
        if self.method == "number-theoretic":
            lat = self.lattice
            return [lat.V[0].astype(float)] if F == 2 else [None]
        above_k, above_c = self.levels[-1][0][0], np.asarray(self.levels[-1][0][1], float)
        for li in range(len(self.levels) - 2, -1, -1):
            best = None
            for k, c in self.levels[li]:
                c = np.asarray(c, float)
                coef = (k / above_k) * above_c - c
                full = np.zeros(F)
                full[list(self.order)] = coef
                out.append(full)
                w = k * k / float(np.sum(c * c))
                if best is None or w > best[0]:
                    best = (w, k, c)
            above_k, above_c = best[1], best[2]
        return out


def _lattice_or_none(per):
    try:
        return lattice_code(tuple(per))
    except ValueError as e:
        return str(e)


def plan_unwrap(periods, method: str = "auto") -> UnwrapPlan:
    """Validate ``periods`` for ``method`` and choose the scheme; ValueError says why and what works."""
    per = _check_periods(periods)
    if method not in METHODS:
        raise bad_value("unwrap", f"unknown method {method!r}", f"use one of {METHODS}")
    integer = all(_is_int(k) for k in per)
    kmin = min(per)
    asc = tuple(int(i) for i in np.argsort(per))
    if method in ("auto", "multi-frequency") and kmin <= 1 + _TOL:
        return UnwrapPlan("multi-frequency", per, asc, (), integer)
    if method == "multi-frequency":
        raise bad_value("periods", f"{per} has no coarse pattern: hierarchical unwrapping needs the "
                        f"coarsest frequency to have at most 1 period across the projector (it has {kmin:g}), "
                        "otherwise its phase repeats and the fringe order is ambiguous", _suggest(per))
    if len(per) == 1:
        raise bad_value("periods", f"a single frequency of {per[0]:g} periods repeats {per[0]:g} times "
                        "across the projector, so the fringe order cannot be found", _suggest(per))
    if method in ("auto", "number-theoretic"):
        lat = _lattice_or_none(per)
        if not isinstance(lat, str):
            return UnwrapPlan("number-theoretic", per, asc, (), True)
        if method == "number-theoretic":
            raise bad_value("periods", f"{per} cannot be unwrapped number-theoretically: {lat}",
                            "use integer periods without a common factor, e.g. (13, 7) or (9, 10, 11)")
    desc = tuple(int(i) for i in np.argsort(per)[::-1])
    levels = _chain([per[i] for i in desc])
    top_k = levels[-1][0][0]
    bad_level = any(k <= _TOL for lvl in levels[1:] for k, _ in lvl)
    if bad_level or top_k > 1 + _TOL:
        why = ("two beat frequencies coincide" if bad_level else
               f"their (chained) beat has {top_k:g} periods across the projector, not <= 1, so it repeats")
        if len(per) == 2:
            why = (f"the heterodyne beat of {per[0]:g} and {per[1]:g} has {abs(per[0] - per[1]):g} periods "
                   "across the projector; it must be <= 1 (|K1-K2| <= 1) to be unambiguous")
        if method == "auto" and integer:
            why += f"; number-theoretic unwrapping does not apply either: {lat}"
        raise bad_value("periods", f"{per} cannot be unwrapped unambiguously: {why}", _suggest(per))
    return UnwrapPlan("heterodyne", per, desc, tuple(tuple(l) for l in levels), integer)


def as_plan(periods, unwrap) -> UnwrapPlan:
    """``unwrap`` as the plan of ``periods``: a method name is planned (:func:`plan_unwrap`); a plan
    made once beforehand (the Scanner's, a run's FringePlan's) is taken as it is, after checking it
    is of these periods, so a decode per render does not plan again. ValueError otherwise."""
    if not isinstance(unwrap, UnwrapPlan):
        return plan_unwrap(periods, unwrap)
    if [float(k) for k in np.ravel(periods)] != [float(k) for k in unwrap.periods]:
        raise bad_value("unwrap", f"is the plan of periods {unwrap.periods}, not of {list(np.ravel(periods))}",
                        "pass plan_unwrap(periods) of the periods decoded, or a method name")
    return unwrap


def unwrap_phase(wrapped_list, periods, method: str = "auto", *, proj_width=None,
                 plan: UnwrapPlan | None = None) -> UnwrapResult:
    """Unwrap the wrapped phases (radians; one array per entry of ``periods``, same order).

    Works on arrays of any (common) shape; float32 in -> float32 out. With ``proj_width``
    (pixels; recommended) the result ``x`` is the projector coordinate in pixels and the
    unambiguous range is centred on the projector's pixel-centre range ``[-0.5, W-0.5)``;
    without it ``x`` is the fraction ``u = x/W`` in ``[0, 1)``.
    Raises ``ValueError`` for a set of periods that cannot be unwrapped unambiguously.

    Precision: each frequency's coordinate is formed as ``k*T + c*T`` (order k, fractional phase
    c in cycles, period T in pixels) and the K^2-weighted mean as the finest estimate plus the
    weighted (small) differences, so float32 loses no more than about one ulp of x. Frequencies
    whose K^2 weight is below 1% of the total are left out of the mean (their effect on the
    noise is below 0.5%).
    """
    if plan is None:
        plan = plan_unwrap(periods, method)
    if len(wrapped_list) != len(plan.periods):
        raise bad_value("wrapped_list", f"has {len(wrapped_list)} phase maps for {len(plan.periods)} periods",
                        "pass one wrapped phase map per fringe frequency, in the order of periods")
    if proj_width is not None and not (np.isfinite(proj_width) and proj_width > 0):
        raise bad_value("proj_width", f"must be a positive number of pixels, got {proj_width!r}",
                        "pass the projector width (or height for axis='y')")
    phis = [np.asarray(p) for p in wrapped_list]
    dt = np.result_type(*[p.dtype for p in phis], np.float32)
    cyc = []
    for p in phis:
        c = np.multiply(p, dt.type(1.0 / TWO_PI), dtype=dt)
        c -= np.floor(c)                     # any representative -> [0, 1]
        cyc.append(c)
    return unwrap_cycles(cyc, plan, proj_width)


class _Stages:
    """The rounding stages of one unwrap, on arrays of one shape and dtype: the order error (largest
    distance of a rounded value from its integer), the margins and residuals per stage (module doc),
    and two scratch arrays reused by every stage."""

    def __init__(self, shape, dt, L, centre):
        self.T = dt.type
        self.L, self.centre = L, centre
        self.tmp = np.empty(shape, dt)
        self.kk = np.empty(shape, dt)
        self.err = None
        self.margins, self.residuals = [], []

    def stage(self, x_prev, k, c, out):
        """Round the order of phase ``c`` (cycles, k periods) from estimate x_prev -> out (pixels)."""
        T, tmp, kk = self.T, self.tmp, self.kk
        per_px = self.L / k
        np.multiply(x_prev, T(k / self.L), out=tmp)
        np.subtract(tmp, c, out=tmp)
        np.rint(tmp, out=kk)
        np.subtract(tmp, kk, out=tmp)
        np.abs(tmp, out=tmp)
        if self.err is None:
            self.err = tmp.copy()
        else:
            np.maximum(self.err, tmp, out=self.err)
        self.margins.append(np.subtract(T(1), np.multiply(tmp, T(2))))
        self.residuals.append(None)
        np.multiply(kk, T(per_px), out=out)
        np.multiply(c, T(per_px), out=tmp)
        np.add(out, tmp, out=out)
        return out

    def fold(self, x, length):
        """Bring x (within one length of it) into [centre - length/2, centre + length/2)."""
        T = self.T
        lo, hi = T(self.centre - 0.5 * length), T(self.centre + 0.5 * length)
        np.subtract(x, T(length), out=x, where=np.greater_equal(x, hi))
        np.add(x, T(length), out=x, where=np.less(x, lo))
        return x

    def wrap_into(self, x, length):
        """Bring any x into the range (floor based)."""
        T, tmp = self.T, self.tmp
        np.subtract(x, T(self.centre - 0.5 * length), out=tmp)
        np.multiply(tmp, T(1.0 / length), out=tmp)
        np.floor(tmp, out=tmp)
        np.multiply(tmp, T(length), out=tmp)
        np.subtract(x, tmp, out=x)
        return x


def unwrap_cycles(cyc, plan: UnwrapPlan, proj_width=None) -> UnwrapResult:
    """:func:`unwrap_phase` on phases given in cycles (``phi / 2pi``) in ``[0, 1]``."""
    per = plan.periods
    L = float(proj_width) if proj_width is not None else 1.0
    centre = (L / 2.0 - 0.5) if proj_width is not None else 0.5
    dt = cyc[0].dtype
    T = dt.type
    shape = cyc[0].shape
    st = _Stages(shape, dt, L, centre)
    xs: dict[int, np.ndarray] = {}
    if plan.method == "multi-frequency":
        i0 = plan.order[0]
        k0 = per[i0]
        x = np.multiply(cyc[i0], T(L / k0))
        st.fold(x, L / k0)          # cycles are in [0, 1], so one fold suffices
        xs[i0] = x
        prev = x
        for i in plan.order[1:]:
            prev = st.stage(prev, per[i], cyc[i], np.empty(shape, dt))
            xs[i] = prev
    elif plan.method == "number-theoretic":
        st.err = _lattice_stage(cyc, plan, L, centre, xs, st.margins, st.residuals)
    else:
        _heterodyne(cyc, plan, st, xs)
    err = st.err if st.err is not None else np.zeros(shape, dt)
    # K^2-weighted combination of the original frequencies
    coord = _combine([(k * k, xs[i]) for i, k in enumerate(per)], st.tmp, min_fraction=0.01)
    if plan.integer:
        st.fold(coord, L)
    phase = np.multiply(coord, T(TWO_PI * max(per) / L))
    return UnwrapResult(phase=phase, x=coord, order_error=err, method=plan.method, periods=per,
                        margins=st.margins, residuals=st.residuals)


def _heterodyne(cyc, plan, st: _Stages, xs):
    """The heterodyne chain (:func:`_chain`) from its top level down; the original frequencies'
    coordinates go into ``xs``."""
    levels, T, L = plan.levels, st.T, st.L
    shape, dt = cyc[0].shape, cyc[0].dtype

    def node_cycles(coeff):
        out = np.zeros(shape, dt)
        for j, cj in enumerate(coeff):
            if cj:
                out += T(cj) * cyc[plan.order[j]]
        return out

    ktop, ctop = levels[-1][0]
    est = node_cycles(ctop) * T(L / ktop)
    st.wrap_into(est, L / ktop)
    for li in range(len(levels) - 2, -1, -1):
        ests = []
        for j, (k, coeff) in enumerate(levels[li]):
            c = cyc[plan.order[j]] if li == 0 else node_cycles(coeff)
            xj = st.stage(est, k, c, np.empty(shape, dt))
            if li == 0:
                xs[plan.order[j]] = xj
            ests.append((k * k / float(np.sum(np.asarray(coeff) ** 2)), xj))
        est = _combine(ests, st.tmp)


def _lattice_stage(cyc, plan, L, centre, xs, margins, residuals):
    """Number-theoretic orders (:mod:`.lattice`) -> per-frequency coordinates in ``xs``; returns the
    order error (two frequencies: ``|m - round(m)|``; more: 0.5 * (1 - margin / largest margin))."""
    lat = plan.lattice
    per = plan.periods
    dt = cyc[0].dtype
    T = dt.type
    if len(per) == 2:
        v = lat.V[0]
        m = T(v[0]) * cyc[0] + T(v[1]) * cyc[1]
        z = np.rint(m)
        err = np.abs(m - z)
        margins.append(T(1) - T(2) * err)
        residuals.append(None)
        orders = [-T(lat.R[i, 0]) * z for i in range(2)]
    else:
        orders, gap, d1 = lat.decode(cyc)
        margins.append(gap)
        residuals.append(d1)
        err = (T(0.5) * np.clip(T(1) - gap / T(lat.d_min ** 2), 0, 1)).astype(dt)
    # n + t K is equally consistent: pick t that puts the finest coordinate into the lit range
    f = int(np.argmax(per))
    lo = (centre - 0.5 * L) / L
    t = np.floor((orders[f] + cyc[f]) * T(1.0 / per[f]) - T(lo))
    for i, k in enumerate(per):
        n = orders[i] - t * T(k)
        xs[i] = (n + cyc[i]) * T(L / k)
    return err


def _combine(weighted, tmp, min_fraction=0.0):
    """Weighted mean as the best (highest weight) estimate plus weighted differences (precise)."""
    wsum = float(sum(w for w, _ in weighted))
    weighted = [(w, x) for w, x in weighted if w >= min_fraction * wsum]
    wsum = float(sum(w for w, _ in weighted))
    best = max(range(len(weighted)), key=lambda j: weighted[j][0])
    base = weighted[best][1]
    out = base.copy()
    for j, (w, xj) in enumerate(weighted):
        if j == best:
            continue
        np.subtract(xj, base, out=tmp)
        tmp *= tmp.dtype.type(w / wsum)
        out += tmp
    return out
