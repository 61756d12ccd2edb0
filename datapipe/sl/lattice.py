"""Number-theoretic temporal unwrapping for any set of integer frequencies with gcd 1.

With phases in cycles ``c_i = K_i u - n_i + e_i`` (``u`` = projector coordinate / width, ``n_i``
integer orders, ``e_i`` noise), every integer vector ``v`` with ``v . K = 0`` gives
``v . c = -v . n + v . e``: an integer plus noise. The F-1 vectors of a basis ``V`` of that null
lattice turn the measured phases into coordinates ``m = V c`` of a point near the lattice point
``z = -V n``. Maximum likelihood (equal noise on all frequencies) is the closest lattice point in
the metric of the phases themselves, i.e. of the lattice ``L`` = the projection of ``Z^F``
orthogonal to ``K`` (Gram matrix ``G`` in the coordinates ``m``). The basis is LLL-reduced and the
closest point searched among the ``3^(F-1)`` neighbours of ``rint(m)``; ``n = -R z`` with an integer
right inverse ``R`` of ``V``; a gcd of 1 makes ``n`` unique up to ``n + t K``, which only shifts
``u`` by the integer ``t`` (folded into the projector's range). Two frequencies reduce to the
classic ``round(K2 c1 - K1 c2)`` look-up (Chinese remainder theorem).

Noise tolerance: the decision is wrong when the noise, projected on the direction to another
lattice point, exceeds half the distance ``d_min`` between lattice points (in cycles): per pixel
``P(wrong) ~ n_min * Q(d_min / (2 sigma_c))`` for a phase noise of ``sigma_c`` cycles per frequency
(``n_min`` nearest neighbours, 2 for two frequencies). The noise gain ``1 / d_min`` plays the role
of a hierarchical stage's ``sqrt(r^2 + 1)``: ``sqrt(K1^2 + K2^2)`` for two frequencies (14.8 for
(13, 7)), 7.1 for (9, 10, 11). :func:`lattice_code` refuses sets whose gain exceeds 300.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

__all__ = ["LatticeCode", "lattice_code"]

MAX_GAIN = 300.0      # beyond this an order needs a phase noise < 1/600 cycle: useless in practice


def _ext_gcd(a: int, b: int):
    """(g, s, t) with s*a + t*b = g = gcd(a, b) >= 0."""
    s0, s1, t0, t1 = 1, 0, 0, 1
    while b:
        q = a // b
        a, b = b, a - q * b
        s0, s1 = s1, s0 - q * s1
        t0, t1 = t1, t0 - q * t1
    if a < 0:
        a, s0, t0 = -a, -s0, -t0
    return a, s0, t0


def _unimodular_for(k: list[int]):
    """Integer unimodular W with ``k @ W = (g, 0, ..., 0)`` (column operations of extended gcds)."""
    f = len(k)
    W = [[int(i == j) for j in range(f)] for i in range(f)]
    k = list(k)
    for i in range(1, f):
        a, b = k[0], k[i]
        g, s, t = _ext_gcd(a, b)
        if g == 0:
            continue
        for row in W:
            c0, ci = row[0], row[i]
            row[0], row[i] = s * c0 + t * ci, (-b // g) * c0 + (a // g) * ci
        k[0], k[i] = g, 0
    return np.array(W, dtype=np.int64), k[0]


def _lll(B: np.ndarray, delta: float = 0.75):
    """LLL reduction of the columns of B (float); returns (B T, T) with T unimodular integer."""
    B = B.astype(np.float64).copy()
    n = B.shape[1]
    T = np.eye(n, dtype=np.int64)
    k = 1
    while k < n:
        for j in range(k - 1, -1, -1):
            Q, _ = np.linalg.qr(B[:, :k + 1])
            mu = (B[:, k] @ Q[:, j]) / (B[:, j] @ Q[:, j])
            q = int(round(mu))
            if q:
                B[:, k] -= q * B[:, j]
                T[:, k] -= q * T[:, j]
        Q, _ = np.linalg.qr(B[:, :k + 1])
        bk = (B[:, k] @ Q[:, k]) ** 2
        bk1 = (B[:, k - 1] @ Q[:, k - 1]) ** 2
        mu = (B[:, k] @ Q[:, k - 1]) / (B[:, k - 1] @ Q[:, k - 1])
        if bk >= (delta - mu * mu) * bk1:
            k += 1
        else:
            B[:, [k - 1, k]] = B[:, [k, k - 1]]
            T[:, [k - 1, k]] = T[:, [k, k - 1]]
            k = max(k - 1, 1)
    return B, T


@dataclass(frozen=True)
class LatticeCode:
    periods: tuple        # integer frequencies K (stack order)
    V: np.ndarray         # (F-1, F) int: reduced basis of the integer vectors orthogonal to K
    R: np.ndarray         # (F, F-1) int: V @ R = I
    gram: np.ndarray      # (F-1, F-1) float: metric of the coordinates m = V c (cycles^2)
    offsets: np.ndarray   # (3^(F-1), F-1) int: candidate neighbours of rint(m)
    d_min: float          # smallest distance between lattice points (cycles)

    @property
    def gain(self) -> float:
        """Noise gain ``1 / d_min`` (see the module doc)."""
        return 1.0 / self.d_min

    def decode(self, cyc):
        """Phases in cycles (F arrays) -> (orders n (F arrays, float), margin, d1^2): ``margin`` is
        ``d2^2 - d1^2`` (cycles^2), the squared distance to the second-closest lattice point minus
        that to the closest; with phase noise sigma_c (cycles) the log-odds that the chosen point is
        right are ``margin / (2 sigma_c^2)``."""
        dt = cyc[0].dtype
        T = dt.type
        F = len(self.periods)
        m = []
        for row in self.V:
            acc = np.zeros(cyc[0].shape, dt)
            for j, v in enumerate(row):
                if v:
                    acc += T(v) * cyc[j]
            m.append(acc)
        z0 = [np.rint(mj) for mj in m]
        delta0 = [mj - zj for mj, zj in zip(m, z0)]
        g = self.gram
        best = second = None
        best_o = np.zeros(cyc[0].shape, np.int16)
        for oi, off in enumerate(self.offsets):
            d = [d0 - T(o) for d0, o in zip(delta0, off)]
            q = np.zeros(cyc[0].shape, dt)
            for a in range(F - 1):
                for b in range(a, F - 1):
                    w = g[a, b] * (1.0 if a == b else 2.0)
                    q += T(w) * d[a] * d[b]
            if best is None:
                best, second = q, np.full(q.shape, np.inf, dt)
                continue
            better = q < best
            np.copyto(second, np.where(better, best, np.minimum(second, q)))
            np.copyto(best, q, where=better)
            best_o[better] = oi
        offs = self.offsets.astype(np.float64)
        z = [z0[a] + offs[best_o, a].astype(dt) for a in range(F - 1)]
        orders = []
        for i in range(F):
            acc = np.zeros(cyc[0].shape, dt)
            for a in range(F - 1):
                if self.R[i, a]:
                    acc -= T(self.R[i, a]) * z[a]
            orders.append(acc)
        return orders, second - best, best


@lru_cache(maxsize=64)
def lattice_code(periods: tuple) -> LatticeCode:
    """The code of integer ``periods`` (ValueError text via :class:`ValueError` for a gcd > 1, a
    non-integer entry or a noise gain over MAX_GAIN; callers add the fix)."""
    ks = [int(round(k)) for k in periods]
    if any(abs(k - p) > 1e-9 for k, p in zip(ks, periods)):
        raise ValueError("number-theoretic unwrapping needs integer periods")
    if len(ks) < 2:
        raise ValueError("needs at least two frequencies")
    g = 0
    for k in ks:
        g = math.gcd(g, k)
    if g != 1:
        raise ValueError(f"the periods share the factor {g}, so every pattern repeats {g} times across the "
                         "projector and the order is ambiguous")
    F = len(ks)
    W, _ = _unimodular_for(ks)
    Y = np.rint(np.linalg.inv(W.astype(np.float64))).astype(np.int64)
    V = W[:, 1:].T.copy()                 # rows: basis of the null lattice
    R = Y[1:, :].T.copy()                 # V @ R = I
    Kv = np.asarray(ks, np.float64)
    P = np.eye(F) - np.outer(Kv, Kv) / (Kv @ Kv)
    B = P @ R.astype(np.float64)          # basis of the projected lattice, coordinates m = V c
    _, Tm = _lll(B)
    Tinv = np.rint(np.linalg.inv(Tm.astype(np.float64))).astype(np.int64)
    V = Tinv @ V
    R = R @ Tm
    Kint = np.asarray(ks, np.int64)
    for a in range(F - 1):       # R + K s^T is a right inverse too: keep its entries small
        R[:, a] -= int(round(float(R[:, a] @ Kv) / float(Kv @ Kv))) * Kint
    B = P @ R.astype(np.float64)
    gram = B.T @ B
    if not np.array_equal(V @ R, np.eye(F - 1, dtype=np.int64)):
        # the float inverse of W lost integers: periods of a million (no projector has the
        # pixels for them, 3 px per fringe) leave int64/float64 exactness behind
        raise ValueError(f"the periods {tuple(ks)} are too large for an exact integer basis; a projector "
                         "needs >= 3 px per fringe, so no real set comes near")
    offsets = np.array(list(itertools.product((-1, 0, 1), repeat=F - 1)), np.int64)
    # shortest vector: a reduced basis has it among small combinations
    small = np.array([o for o in itertools.product(range(-2, 3), repeat=F - 1) if any(o)], np.float64)
    d_min = float(np.sqrt(np.min(np.einsum("ij,jk,ik->i", small, gram, small))))
    if 1.0 / d_min > MAX_GAIN:
        raise ValueError(f"its noise gain 1/d_min = {1 / d_min:.0f} exceeds {MAX_GAIN:.0f}: an order would "
                         "need a phase noise below 1/600 cycle")
    return LatticeCode(tuple(ks), V, R, gram, offsets, d_min)
