"""What compiled code would give the decoder (issue #31 item 3): a numba kernel of step 1
(`datapipe.sl.decode_slab`) against today's numpy slabs, alone and inside a whole decode, on the
1080p (1, 8, 64) x 4 uint8 stack of bench_sl_speed.py. An experiment, not a part of the decoder:
numba is not a dependency of DataPipe.

Run as a script (not a test) in an environment that has numba; in the project's environment
(no numba) it says so and exits 0:

    python3.11 -m venv /tmp/nbvenv && /tmp/nbvenv/bin/pip install numba numpy==1.26.4 \
        opencv-contrib-python-headless scipy
    PYTHONPATH=$PWD /tmp/nbvenv/bin/python benchmarks/bench_sl_numba.py [--repeat 7] [--llvm-checks=N]

The kernel does per pixel, row by row, what the numpy slabs do in ~190 passes over 64k-pixel
slabs: the least-squares offset, cosine and sine rows of each frequency (the same integer sums),
its modulation and wrapped phase; the noise variance from the fitted noise table at the first
frequency's offset; the joint Gamma floor and the contrast test (NO_LIGHT); the hierarchical
unwrap (1 -> 8 -> 64, its rounding stages and the K^2 combination); the stages' wrong-order
probability and the INCONSISTENT test; the closed-form triangulation (depth, ILL_CONDITIONED,
OUTSIDE_PROJECTOR); the reasons; the neighbour pass's candidates and dim pixels as index lists.
Every operation in float32 in the numpy code's order (no fastmath), except ``atan2``: numba calls
the scalar libm function (~24 ns a value here, numpy's SIMD float32 ufunc under 1 ns), so the
kernel has its own polynomial one (Cephes' atanf), within a few float32 ulp like numpy's (both
measured against float64 below). The row loops are written branch-free so that LLVM vectorises
them; the second reads and writes ~25 arrays, more than LLVM's default limit of run-time alias
checks lets it vectorise, so the script raises that limit (`llvmlite.binding.set_option`, before
anything is compiled; ``--llvm-checks=0`` keeps LLVM's defaults and shows the scalar cost).
It covers the decode the benchmark runs (multi-frequency (1, 8, 64) x 4, uint8, fitted noise
table, no gamma / response / legacy rules; asserted); saturated pixels (a sample of 255) are
listed for the numpy reduced fit (none in this stack; not wired).

Also timed: ``atan2`` alone (numpy's float32 ufunc against the scalar libm call numba makes), and
a union-find of a 1080p 4-neighbour grid graph against scipy's connected components (the link
graph of `datapipe.sl.surfaces` uses scipy's). CPU = ``time.process_time`` (one thread), median
(best) of ``--repeat`` runs in turns; compile time reported separately. Prints Markdown rows
(the findings of benchmarks/results/sl_speed.md quote them).
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from datapipe import sl  # noqa: E402
from datapipe.sl import decode_slab as slab_mod  # noqa: E402
from datapipe.sl.confidence import INV_2PI_SQ  # noqa: E402
from datapipe.sl.decode import _assemble  # noqa: E402
from datapipe.sl.decode_neighbours import neighbour_pass  # noqa: E402
from datapipe.sl.decode_setup import DecodeOptions, prepare_decode  # noqa: E402

# LLVM's limits on a loop's run-time alias checks (8 pointer pairs by default): raised before
# anything is compiled, unless --llvm-checks=0
CHECKS = next((int(a.split("=")[1]) for a in sys.argv if a.startswith("--llvm-checks=")), 2000)
try:
    import numba
    from numba import njit
    if CHECKS:
        import llvmlite.binding as _llvm
        _llvm.set_option("", f"-runtime-memory-check-threshold={CHECKS}")
        _llvm.set_option("", f"-vectorize-memory-check-threshold={CHECKS}")
except ImportError:                      # the project's environment: importable, main() says so
    numba = None

    def njit(*a, **k):
        return (lambda f: f) if not (len(a) == 1 and callable(a[0])) else a[0]

f32 = np.float32
# the kernel's constants, one float64 vector (cast to float32 where numpy casts them)
(K_ASCALE_F, K_MSC, K_CK, K_TK, K_JQ2, K_FL1, K_LI1, K_FINE, K_MW, K_L, K_LO, K_HI, K_PP0, K_PP1,
 K_PP2, K_KX1, K_KX2, K_C00, K_C01, K_C11, K_C12, K_WMID, K_PH, K_B0, K_B1, K_B2, K_HP, K_N) = range(28)
_PI_4, _PI_2, _PI, _TAN_PI_8 = f32(np.pi / 4), f32(np.pi / 2), f32(np.pi), f32(0.41421356237)
_TWO_PI, _INV_2PI, _INV_2PI_SQ = f32(2 * np.pi), f32(1 / (2 * np.pi)), f32(INV_2PI_SQ)


@njit(inline="always")
def _atan2f(y, x):
    """float32 atan2 without a libm call (so that LLVM vectorises the loop around it): Cephes'
    atanf polynomial on [0, tan(pi/8)] after the reductions to the first octant (selects)."""
    ax, ay = abs(x), abs(y)
    mx, mn = max(ax, ay), min(ax, ay)
    t = mn / mx if mx > f32(0) else f32(0)
    big = t > _TAN_PI_8
    u = (t - f32(1)) / (t + f32(1)) if big else t
    z = u * u
    r = (((f32(8.05374449538e-2) * z - f32(1.38776856032e-1)) * z + f32(1.99777106478e-1)) * z
         - f32(3.33329491539e-1)) * z * u + u
    r = r + _PI_4 if big else r
    r = _PI_2 - r if ay > ax else r
    r = _PI - r if x < f32(0) else r
    return -r if y < f32(0) else r


@njit(nogil=True, error_model="numpy")
def _phase_row(stack, r, w, k, wrapped, modulation, asum, a0, nol, satr):   # maps indexed [i, r, col]: unit stride
    """Row r: per frequency the rows A', C', S' (4 steps: exact integer sums), modulation, wrapped
    phase in [0, 2 pi); the offset sum, the first frequency's A', the contrast and saturation flags."""
    msc, ck = f32(k[K_MSC]), f32(k[K_CK])
    for i in range(wrapped.shape[0]):
        for col in range(wrapped.shape[2]):
            a = c = s = f32(0)
            mxv = 0
            for n in range(4):          # N = 4 as a constant: unrolled, the loop over col vectorised
                v = stack[i * 4 + n, r, col]
                mxv = max(mxv, v)
                fv = f32(v)
                a += w[0, n] * fv
                c += w[1, n] * fv
                s += w[2, n] * fv
            b = f32(math.sqrt(c * c + s * s)) * msc
            phi = _atan2f(s, c) + _PI
            wrapped[i, r, col] = f32(0) if phi >= _TWO_PI else phi
            modulation[i, r, col] = b
            bad = b * ck < a
            if i == 0:
                asum[col], a0[col], nol[col], satr[col] = a, a, bad, mxv >= 255
            else:
                asum[col] += a
                nol[col] |= bad
                satr[col] |= mxv >= 255


@njit(nogil=True, error_model="numpy")
def _noise_row(a0, table, tk, s2):
    """The noise table's gather (its own loop: a gather keeps LLVM from vectorising the next)."""
    n = table.shape[0]
    for col in range(a0.shape[0]):
        s2[col] = table[min(max(int(f32(math.sqrt(a0[col])) * tk), 0), n - 1)]


@njit(nogil=True, error_model="numpy")
def _pixel_row(r, k, wr, md, s2row, asum, nol, satr, xinf, lin, linc, fo, reason, inconsistent, lod, flag):
    """Row loop 2 (selects only): noise -> phase variances and the joint floor, the unwrap stages,
    their log-odds (the exp waits for `_rare_row`), triangulation, reasons. fo: offset, order error,
    proj_x, phase, depth, p_wrong rows."""
    jq2, fl1, li1, fine = f32(k[K_JQ2]), f32(k[K_FL1]), f32(k[K_LI1]), f32(k[K_FINE])
    Lf, lo, hi, wmid, ph = f32(k[K_L]), f32(k[K_LO]), f32(k[K_HI]), f32(k[K_WMID]), f32(k[K_PH])
    pp0, pp1, pp2, kx1, kx2 = f32(k[K_PP0]), f32(k[K_PP1]), f32(k[K_PP2]), f32(k[K_KX1]), f32(k[K_KX2])
    c00, c01, c11, c12 = f32(k[K_C00]), f32(k[K_C01]), f32(k[K_C11]), f32(k[K_C12])
    b0, b1, b2, hp5, asf = f32(k[K_B0]), f32(k[K_B1]), f32(k[K_B2]), f32(k[K_HP]) - f32(0.5), f32(k[K_ASCALE_F])
    for col in range(wr.shape[2]):
        fo[0, r, col] = asum[col] * asf
        s2 = s2row[col]
        m0, m1, m2 = md[0, r, col], md[1, r, col], md[2, r, col]
        q0, q1, q2 = m0 * m0 / s2, m1 * m1 / s2, m2 * m2 / s2
        floor = (q0 + q1) + q2 <= jq2
        vc0 = f32(1) / max(q0 - f32(2), f32(0.25)) * _INV_2PI_SQ
        vc1 = f32(1) / max(q1 - f32(2), f32(0.25)) * _INV_2PI_SQ
        vc2 = f32(1) / max(q2 - f32(2), f32(0.25)) * _INV_2PI_SQ
        x = wr[0, r, col] * _INV_2PI * pp0
        x = x - Lf if x >= hi else x
        x = x + Lf if x < lo else x
        c1 = wr[1, r, col] * _INV_2PI
        t = x * kx1 - c1
        kk = f32(np.rint(t))
        d1 = abs(t - kk)
        x1 = kk * pp1 + c1 * pp1
        c2 = wr[2, r, col] * _INV_2PI
        t = x1 * kx2 - c2
        kk = f32(np.rint(t))
        d2 = abs(t - kk)
        x2 = kk * pp2 + c2 * pp2
        m1, m2 = f32(1) - d1 * f32(2), f32(1) - d2 * f32(2)
        v1, v2 = vc0 * c00 + vc1 * c01, vc1 * c11 + vc2 * c12
        e1, e2 = (f32(1) - m1) * f32(0.5), (f32(1) - m2) * f32(0.5)
        e1, e2 = e1 * e1, e2 * e2
        inc = ((e1 > fl1) & (e1 > v1 * li1)) | ((e2 > fl1) & (e2 > v2 * li1))
        lod[0, col], lod[1, col] = m1 / (v1 * f32(2)), m2 / (v2 * f32(2))
        fo[1, r, col] = max(d1, d2)
        xc = x2 + (x1 - x2) * wmid
        xc = xc - Lf if xc >= hi else xc
        xc = xc + Lf if xc < lo else xc
        fo[2, r, col], fo[3, r, col] = xc, xc * ph
        num = (xc * (-b2) + b0) / (xc - xinf[r, col])
        a2 = lin[0, col] + linc[0, r]
        z = num / a2
        zp = a2 * z + b2
        fo[4, r, col] = z
        ok = (zp * zp <= abs(lin[1, col] + linc[1, r]) * z) & (z > 0) & (abs(z) < np.inf)
        y = ((lin[2, col] + linc[2, r]) * z + b1) / zp
        outside = (~(zp > 0)) | (~((y >= f32(-0.5)) & (y <= hp5)))
        sat, nl = satr[col], nol[col] | floor
        reason[r, col] = np.uint8(2) if sat else (np.uint8(1) if nl else (
            np.uint8(5) if not ok else (np.uint8(4) if outside else np.uint8(0))))
        basic = sat | nl
        fo[5, r, col] = f32(np.nan) if basic else f32(0)
        inconsistent[r, col] = inc & (~basic)
        flag[col] = np.uint8(0 if basic else (1 if (vc2 <= fine) & (~inc) else 2)) | \
            np.uint8(4 if (~sat) & floor & (~nol[col]) else 0) | np.uint8(8 if sat else 0)


@njit(nogil=True, error_model="numpy")
def _rare_row(r, mw, lod, flag, fo, lists, counts):
    """Row loop 3 (scalar, rarely taken branches): the exp of the stages that are not certain, the
    candidates (uncertain, consistent, precise finest phase), dim and saturated pixels' indices."""
    W = flag.shape[0]
    for col in range(W):
        fcol = flag[col]
        if fcol & 3:
            p = f32(0)
            if lod[0, col] < f32(40):
                p += f32(1) / (f32(1) + f32(math.exp(lod[0, col])))
            if lod[1, col] < f32(40):
                p += f32(1) / (f32(1) + f32(math.exp(lod[1, col])))
            p = min(p, f32(1))
            fo[5, r, col] = p
            if fcol & 1 and p > mw:
                lists[0, counts[0]] = r * W + col
                counts[0] += 1
        elif fcol & 12:
            j = 1 if fcol & 4 else 2
            lists[j, counts[j]] = r * W + col
            counts[j] += 1


@njit(nogil=True, error_model="numpy")
def _kernel(stack, w, k, table, xinf, lin, linc, wrapped, modulation, fo, reason, inconsistent, lists):
    """All rows; returns the lengths of the candidates', dim and saturated pixels' lists."""
    W = stack.shape[2]
    asum, a0, s2 = np.empty(W, np.float32), np.empty(W, np.float32), np.empty(W, np.float32)
    nol, satr = np.empty(W, np.bool_), np.empty(W, np.bool_)
    lod, flag = np.empty((2, W), np.float32), np.empty(W, np.uint8)
    counts = np.zeros(3, np.int64)
    tk, mw = f32(k[K_TK]), f32(k[K_MW])
    for r in range(stack.shape[1]):
        _phase_row(stack, r, w, k, wrapped, modulation, asum, a0, nol, satr)
        _noise_row(a0, table, tk, s2)
        _pixel_row(r, k, wrapped, modulation, s2, asum, nol, satr, xinf, lin, linc, fo, reason, inconsistent,
                   lod, flag)
        _rare_row(r, mw, lod, flag, fo, lists, counts)
    return counts


class NumbaSlabs:
    """The kernel's inputs from today's setup (what `decode_slab` reads from it), and its maps."""

    def __init__(self, st, stack):
        plan, kern, tri = st.plan, st.kernel, st.tri
        assert plan.method == "multi-frequency" and tuple(plan.periods) == (1, 8, 64) and st.steps == 4
        assert list(plan.order) == [0, 1, 2] and st.frames[0].dtype == np.uint8 and st.min_contrast
        assert st.gamma_lut is None and not st.order_factor and st.max_order_error is None
        assert st.max_depth_slope is None and st.check_other_axis and st.min_modulation is None
        self.stack, self.st = stack, st          # the caller's (12, H, W) array, no copy
        self.w = np.zeros((3, 4), np.float32)
        for j, row in enumerate((kern.row_a, kern.row_c, kern.row_s)):
            for n, wn in row.plan:
                self.w[j, n] = wn
        table, tk = st.sigma_fn._table
        self.table = (table * f32(st.row_sigma ** 2)).astype(np.float32)
        L, per = float(st.wcoded), plan.periods
        co = plan.stage_coefs()
        assert co[0][2] == 0 and co[1][0] == 0          # stages 1 -> 8 and 8 -> 64
        lim1, _, floor1, _ = st.consistency_limits
        k = np.zeros(K_N)
        k[[K_ASCALE_F, K_MSC, K_CK, K_TK, K_JQ2, K_FL1, K_LI1, K_FINE, K_MW]] = (
            kern.a_scale / 3, kern.mod_scale, 1.0 / (st.min_contrast * kern.a_scale), f32(tk * np.sqrt(kern.a_scale)),
            st.joint_q2, floor1, lim1, slab_mod.MAX_FINE_NOISE ** 2, st.max_wrong)
        k[[K_L, K_LO, K_HI, K_PP0, K_PP1, K_PP2, K_KX1, K_KX2]] = (
            L, L / 2 - 0.5 - 0.5 * L, L / 2 - 0.5 + 0.5 * L, L / per[0], L / per[1], L / per[2], per[1] / L, per[2] / L)
        k[[K_C00, K_C01, K_C11, K_C12]] = co[0][0] ** 2, co[0][1] ** 2, co[1][1] ** 2, co[1][2] ** 2
        k[[K_WMID, K_PH, K_HP]] = per[1] ** 2 / (per[1] ** 2 + per[2] ** 2), 2 * np.pi * per[2] / L, tri.proj_size[1]
        k[[K_B0, K_B1, K_B2]] = tri._beta
        self.k = k
        lin = tri.coefficients["lin"]
        assert all(lin[n][1] is not None for n in ("a2", "q", "a1"))   # a pinhole camera: row + column terms
        self.lin = np.stack([lin[n][0].ravel() for n in ("a2", "q", "a1")])
        self.linc = np.stack([lin[n][1].ravel() for n in ("a2", "q", "a1")])     # (3, H): per row
        self.xinf = tri.coefficients["xinf"]

    def allocate(self):
        """Maps like `DecodeMaps.allocate`'s, as views of a few stacked arrays (the kernel's rows)."""
        H, W = self.st.shape
        out = slab_mod.DecodeMaps.allocate(H, W, 3)
        self.wrapped, self.fo = np.empty((3, H, W), np.float32), np.empty((6, H, W), np.float32)
        self.u8 = np.zeros((2, H, W), np.uint8)
        out.wrapped = list(self.wrapped)
        out.offset, out.order_error, out.proj_x, out.phase, out.depth, out.p_wrong = self.fo
        out.reason, out.inconsistent = self.u8[0], self.u8[1].view(bool)
        return out

    def run(self, out):
        """Step 1 into ``out`` (from `allocate`); returns the candidates', dim and saturated lists."""
        H, W = self.st.shape
        lists = np.empty((3, H * W), np.int64)
        n = _kernel(self.stack, self.w, self.k, self.table, self.xinf, self.lin, self.linc, self.wrapped,
                    out.modulation, self.fo, out.reason, out.inconsistent, lists)
        return tuple(lists[j, :n[j]] for j in range(3))


def decode_numba_step1(images, kw, spatial=True):
    """`datapipe.sl.decode` with step 1 (the numpy slabs) replaced by the kernel; the setup (input
    checks, noise fit), step 2 (neighbour pass) and the assembly are today's."""
    st = prepare_decode(images, DecodeOptions(**kw, spatial=spatial))
    st.tri.coefficients
    nb = NumbaSlabs(st, images)
    out = nb.allocate()
    with np.errstate(all="ignore"):
        cand, dim, sat = nb.run(out)
        assert sat.size == 0, "saturated pixels: the reduced fit is not wired into this experiment"
        if spatial:
            out.candidates, out.dim = ([cand] if cand.size else []), ([dim] if dim.size else [])
            neighbour_pass(st, out)
    return _assemble(st, out)


def numpy_slabs(st):
    """Today's step 1 (the loop of `decode`), into fresh maps."""
    H, W = st.shape
    out = slab_mod.DecodeMaps.allocate(H, W, len(st.plan.periods))
    coefs = st.plan.stage_coefs()
    rows = max(1, (1 << 16) // W)
    with np.errstate(all="ignore"):
        for r0 in range(0, H, rows):
            slab_mod.decode_slab(st, out, r0, min(H, r0 + rows), coefs)
    return out


@njit(nogil=True, error_model="numpy")
def _atan2_libm(s, c, out):
    for i in range(s.size):
        out[i] = math.atan2(s[i], c[i])


@njit(nogil=True, error_model="numpy")
def _atan2_poly(y, x, out):
    for i in range(y.size):
        out[i] = _atan2f(y[i], x[i])


@njit(nogil=True)
def _find(parent, i):
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@njit(nogil=True)
def _union_find(right, down, label):
    """Components of the grid graph whose edges to the right / lower neighbour are marked."""
    H, W = right.shape
    parent = np.arange(H * W)
    for r in range(H):
        for c in range(W):
            i = r * W + c
            for ok, j in ((c + 1 < W and right[r, c], i + 1), (r + 1 < H and down[r, c], i + W)):
                if ok:
                    a, b = _find(parent, i), _find(parent, j)
                    if a != b:
                        parent[max(a, b)] = min(a, b)
    for i in range(H * W):
        label[i] = _find(parent, i)


def scipy_components(right, down):
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    H, W = right.shape
    idx = np.arange(H * W).reshape(H, W)
    i = np.concatenate([idx[:, :-1][right[:, :-1]], idx[:-1][down[:-1]]])
    j = np.concatenate([idx[:, 1:][right[:, :-1]], idx[1:][down[:-1]]])
    g = coo_matrix((np.ones(i.size, np.int8), (i, j)), shape=(H * W, H * W)).tocsr()
    return connected_components(g, directed=False)[1]


def timed(fns, repeat):
    for f in fns.values():
        f()
    t = {k: [] for k in fns}
    for _ in range(repeat):
        for k, f in fns.items():
            c0 = time.process_time()
            f()
            t[k].append((time.process_time() - c0) * 1e3)
    return {k: (float(np.median(v)), min(v)) for k, v in t.items()}


def step1_differences(a, b, lists):
    """How the kernel's step-1 maps (b, its lists) differ from today's slabs' (a)."""
    fin = np.isfinite(a.depth) & np.isfinite(b.depth)
    return {
        "reason codes differing": int(np.sum(a.reason != b.reason)),
        "INCONSISTENT differing": int(np.sum(a.inconsistent != b.inconsistent)),
        "candidate and dim lists equal": bool(np.array_equal(np.concatenate(a.candidates), lists[0])
                                              and np.array_equal(np.concatenate(a.dim), lists[1])),
        "offset values differing": int(np.sum(a.offset != b.offset)),
        "max wrapped phase difference rad": float(max(np.max(np.abs(x - y)) for x, y in zip(a.wrapped, b.wrapped))),
        "max modulation difference, relative": float(np.max(np.abs(a.modulation - b.modulation)
                                                            / np.maximum(a.modulation, 1e-6))),
        "max proj_x difference px": float(np.nanmax(np.abs(a.proj_x - b.proj_x))),
        "max depth difference, relative": float(np.max(np.abs(a.depth - b.depth)[fin] / np.abs(a.depth[fin]))),
        "max p_wrong difference": float(np.nanmax(np.abs(a.p_wrong - b.p_wrong))),
        "p_wrong NaN differing": int(np.sum(np.isnan(a.p_wrong) != np.isnan(b.p_wrong))),
    }


def whole_differences(a, b):
    """How a whole decode with the kernel (b) differs from today's (a)."""
    both = a.valid & b.valid
    return {"reason codes differing": int(np.sum(a.reason != b.reason)),
            "valid differing": int(np.sum(a.valid != b.valid)), "valid pixels": int(a.valid.sum()),
            "max depth difference m": float(np.max(np.abs(a.depth - b.depth)[both])),
            "max confidence difference": float(np.max(np.abs(a.confidence - b.confidence)))}


def atan2_ulps(rng):
    """Largest error in float32 ulp of the polynomial and of numpy's float32 atan2 (against float64)."""
    y, x = rng.normal(size=(2, 1 << 20)).astype(np.float32)
    ref = np.arctan2(y.astype(np.float64), x.astype(np.float64))
    ulp = np.spacing(np.abs(ref).astype(np.float32)).astype(np.float64)
    got = np.empty_like(y)
    _atan2_poly(y, x, got)
    return float(np.max(np.abs(got - ref) / ulp)), float(np.max(np.abs(np.arctan2(y, x) - ref) / ulp))


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--repeat", type=int, default=7)
    ap.add_argument("--llvm-checks", type=int, default=2000,
                    help="LLVM's run-time alias check limits, as --llvm-checks=N (0: LLVM's defaults)")
    args = ap.parse_args()
    if numba is None:
        print("bench_sl_numba: numba is not installed here; skipped (the module doc says how to run it)")
        return 0
    import bench_sl_speed as bs
    u8, gt, cam, proj = bs.stack_1080p()
    kw = dict(periods=bs.PERIODS, steps=bs.STEPS, P_cam=cam.P, P_proj=proj.P, proj_size=proj.size)
    st = prepare_decode(u8, DecodeOptions(**kw))
    st.tri.coefficients
    nb = NumbaSlabs(st, u8)
    out = nb.allocate()
    c0 = time.process_time()
    lists = nb.run(out)
    compile_ms = (time.process_time() - c0) * 1e3
    step1 = step1_differences(numpy_slabs(st), out, lists)
    whole = {sp: whole_differences(sl.decode(u8, **kw, spatial=sp), decode_numba_step1(u8, kw, sp))
             for sp in (True, False)}
    rng = np.random.default_rng(0)
    s, c = rng.normal(size=(2, 3 * u8[0].size)).astype(np.float32)
    o = np.empty_like(s)
    _atan2_libm(s[:8], c[:8], o[:8])
    _atan2_poly(s[:8], c[:8], o[:8])
    px = out.proj_x                     # a grid graph: 4-neighbours whose coordinates agree within 2 px
    right, down = np.zeros(px.shape, bool), np.zeros(px.shape, bool)
    right[:, :-1], down[:-1] = np.abs(np.diff(px, axis=1)) < 2, np.abs(np.diff(px, axis=0)) < 2
    lab = np.empty(px.size, np.int64)
    _union_find(right[:4, :4].copy(), down[:4, :4].copy(), lab[:16])
    t = timed({
        "today's decode": lambda: sl.decode(u8, **kw),
        "decode with the numba step 1": lambda: decode_numba_step1(u8, kw),
        "today's decode, no neighbour pass": lambda: sl.decode(u8, **kw, spatial=False),
        "decode with the numba step 1, no neighbour pass": lambda: decode_numba_step1(u8, kw, False),
        "step 1: today's numpy slabs": lambda: numpy_slabs(st),
        "step 1: numba kernel": lambda: nb.run(out),
        "atan2 3 x 1080p: numpy float32 ufunc": lambda: np.arctan2(s, c, out=o),
        "atan2 3 x 1080p: numba, libm atan2 per value": lambda: _atan2_libm(s, c, o),
        "atan2 3 x 1080p: numba, polynomial": lambda: _atan2_poly(s, c, o),
        "components of a 1080p grid graph: scipy": lambda: scipy_components(right, down),
        "components of a 1080p grid graph: numba union-find": lambda: _union_find(right, down, lab),
    }, args.repeat)
    lab_sp = scipy_components(right, down)
    _union_find(right, down, lab)
    n = (np.unique(lab_sp).size, np.unique(lab).size, np.unique(np.stack([lab_sp, lab]), axis=1).shape[1])
    report(t, step1, whole, compile_ms, atan2_ulps(rng), n, args.repeat)
    return 0


def report(t, step1, whole, compile_ms, ulps, n, repeat):
    print(f"numba {numba.__version__}, numpy {np.__version__}, LLVM alias check limits "
          f"{CHECKS or 'LLVM defaults'}; kernel compile {compile_ms:.0f} ms CPU; median (best) of {repeat}")
    print("\n| what | CPU ms |\n|---|---|")
    print("\n".join(f"| {k} | {m:.1f} ({b:.1f}) |" for k, (m, b) in t.items()))
    print("\n| step 1 maps: numba kernel against today's slabs | |\n|---|---|")
    print("\n".join(f"| {k} | {v} |" for k, v in step1.items()))
    print("\n| whole decode: numba step 1 against today's | neighbour pass | no neighbour pass |\n|---|---|---|")
    print("\n".join(f"| {k} | {whole[True][k]} | {whole[False][k]} |" for k in whole[True]))
    print(f"\natan2 largest error, float32 ulp: polynomial {ulps[0]:.2f}, numpy float32 {ulps[1]:.2f}; "
          f"grid graph components: scipy {n[0]}, union-find {n[1]}, pairs of the two labels {n[2]} "
          "(equal counts: the same partition)")


if __name__ == "__main__":
    sys.exit(main())
