"""N-step least-squares phase: exactness, dtypes, noise law, saturation, tone curves."""
import numpy as np
import pytest

from datapipe.sl import phase_shift, phase_shifts
from datapipe.sl.metrics import theoretical_phase_sigma

X = np.linspace(0, 2 * np.pi, 2001)[:-1]          # true phases, one per "pixel"


def wrap(d):
    return (d + np.pi) % (2 * np.pi) - np.pi


def stack(phases, shifts, a=0.5, b=0.5, f=lambda v: v):
    return np.stack([f(a + b * np.cos(phases + d)) for d in shifts])[:, None, :]


@pytest.mark.parametrize("n", [3, 4, 5, 6, 8])
def test_exact_uniform(n):
    r = phase_shift(stack(X, phase_shifts(n), a=3.0, b=2.0))
    # float64 in -> float64 arithmetic: only rounding (1e-15 rad) remains
    assert np.abs(wrap(r.phase[0] - X)).max() < 1e-12
    np.testing.assert_allclose(r.offset, 3.0, atol=1e-12)
    np.testing.assert_allclose(r.modulation, 2.0, atol=1e-12)
    assert r.phase.min() >= 0 and r.phase.max() < 2 * np.pi


def test_exact_nonuniform_shifts():
    shifts = np.array([0.0, 0.7, 2.1, 2.2, 4.0])
    r = phase_shift(stack(X, shifts, a=1.0, b=0.3), shifts)
    assert np.abs(wrap(r.phase[0] - X)).max() < 1e-12
    np.testing.assert_allclose(r.modulation, 0.3, atol=1e-12)


@pytest.mark.parametrize("dtype, scale", [(np.uint8, 255), (np.uint16, 65535), (np.float16, 1), (np.float32, 1)])
def test_dtypes_lose_no_precision(dtype, scale):
    """Every dtype is computed in float32 (exact for uint8/uint16/float16 values): the phase
    matches a float64 computation on the very same sample values to float32 rounding (~1e-6 rad
    for B of a few hundred DN; 3e-6 bound), so nothing beyond the input's own quantisation is lost."""
    img = stack(X, phase_shifts(4), a=0.5, b=0.45) * scale
    q = np.rint(img).astype(dtype) if np.dtype(dtype).kind == "u" else img.astype(dtype)
    r = phase_shift(q)
    ref = phase_shift(q.astype(np.float64))
    assert r.phase.dtype == np.float32
    assert np.abs(wrap(r.phase.astype(np.float64) - ref.phase)).max() < 3e-6
    np.testing.assert_allclose(r.modulation, ref.modulation, rtol=1e-5)


@pytest.mark.parametrize("n", [3, 4, 7])
def test_phase_noise_law(n):
    """sigma_phi = sqrt(2/N) sigma_I / B (docs/STRUCTURED_LIGHT.md). 100k samples give the std to 0.3% (1 sigma);
    the linearisation error is O(sigma_phi^2) = 1e-3: 3% tolerance is > 5 standard errors."""
    rng = np.random.default_rng(n)
    phases = rng.uniform(0, 2 * np.pi, 100_000)
    sigma, b = 0.02, 0.5
    img = stack(phases, phase_shifts(n), b=b) + rng.normal(0, sigma, (n, 1, phases.size))
    r = phase_shift(img)
    measured = np.std(wrap(r.phase[0] - phases))
    assert measured == pytest.approx(theoretical_phase_sigma(sigma, b, n), rel=0.03)


def test_phase_noise_law_8bit():
    """With 8-bit rounding the intensity variance is sigma^2 + 1/12 DN^2 (docs/STRUCTURED_LIGHT.md)."""
    rng = np.random.default_rng(8)
    phases = rng.uniform(0, 2 * np.pi, 100_000)
    sigma, b = 0.7, 60.0
    img = stack(phases, phase_shifts(4), a=120.0, b=b) + rng.normal(0, sigma, (4, 1, phases.size))
    r = phase_shift(np.rint(img).astype(np.uint8))
    measured = np.std(wrap(r.phase[0] - phases))
    assert measured == pytest.approx(theoretical_phase_sigma(np.sqrt(sigma ** 2 + 1 / 12), b, 4), rel=0.03)


@pytest.mark.parametrize("n, amp", [(3, 0.53), (4, 0.65)])
def test_saturation(n, amp):
    """Samples clipped at 1.0 (6% / 30% overexposure). Unhandled, they bias the phase (docs/STRUCTURED_LIGHT.md:
    ~0.04 rad at N = 3; > 0.01 rad asserted so the test sees the effect); excluding them and
    solving least squares on >= 3 remaining samples is exact (noise-free: 1e-12), fewer are
    flagged (at N = 3 every pixel with a clipped sample)."""
    img = np.minimum(stack(X, phase_shifts(n), a=amp, b=amp), 1.0)
    biased = phase_shift(img, saturation=np.inf)
    assert np.abs(wrap(biased.phase[0] - X)).max() > 0.01
    r = phase_shift(img, saturation=1.0)
    nsat = np.sum(img[:, 0] >= 1.0, axis=0)
    flagged = r.saturated[0]
    np.testing.assert_array_equal(flagged, nsat > n - 3)
    ok = ~flagged
    assert ok.sum() > 0.2 * X.size
    assert np.abs(wrap(r.phase[0][ok] - X[ok])).max() < 1e-12
    np.testing.assert_allclose(r.modulation[0][ok], amp, atol=1e-12)
    if n == 4:
        assert np.any((nsat == 1) & ok)          # pixels actually recovered from 3 of 4 samples


def test_integer_saturation_default_is_type_max():
    img = np.minimum(np.rint(stack(X, phase_shifts(3), a=200, b=100)), 255).astype(np.uint8)
    r = phase_shift(img)
    assert r.saturated[0].any() and not r.saturated[0][np.all(img[:, 0] < 255, axis=0)].any()


@pytest.mark.parametrize("n, lo, hi", [(3, 0.18, 0.23), (4, 0.0, 0.0085), (6, 0.0, 2.5e-4)])
def test_gamma_tone_curve(n, lo, hi):
    """A gamma 2.2 tone curve adds harmonics; N-step aliasing of harmonic N-1 gives the RMS phase
    errors of docs/STRUCTURED_LIGHT.md: ~0.2 rad at N = 3, 0.0075 at N = 4, <= 0.0002 at N >= 6. Bounds: the
    notes' values with 10-25% margin (and at N = 3 a lower bound, so the test sees the effect)."""
    r = phase_shift(stack(X, phase_shifts(n), f=lambda v: v ** 2.2))
    rms = np.sqrt(np.mean(wrap(r.phase[0] - X) ** 2))
    assert lo <= rms <= hi


def test_nonfinite_samples_are_flagged():
    img = stack(X, phase_shifts(4)).astype(np.float32)
    img[1, 0, 10] = np.nan
    img[2, 0, 20] = np.inf
    img[3, 0, 30] = -np.inf
    r = phase_shift(img)
    assert set(np.flatnonzero(r.invalid[0])) == {10, 20, 30}


@pytest.mark.parametrize("args, exc, msg", [
    (dict(images=np.zeros((2, 4, 4))), ValueError, "at least 3"),
    (dict(images=np.zeros((4, 4, 4)), shifts=[0, 1, 2]), ValueError, "one shift per image"),
    (dict(images=np.zeros((3, 4, 4)), shifts=[0, 0, np.pi * 2]), ValueError, "distinct"),
    (dict(images=np.zeros((3, 4, 4), complex)), TypeError, "dtype"),
])
def test_errors(args, exc, msg):
    with pytest.raises(exc, match=msg):
        phase_shift(**args)


def test_modulation_does_not_depend_on_where_the_output_lies():
    """One stack, one result: OpenCV's magnitude (with its IPP kernel: OpenCV 4.11, IPP 2021.12) rounds
    2-3 of 65 536 values 1 ulp differently when its output starts 20 or 40 bytes past a 64-byte
    boundary, so the decoder's modulation (and the confidences computed from it) changed with the
    memory a run was handed. The kernel now computes on an aligned buffer: the same modulation into
    outputs at every offset (on a build without that kernel this holds before the change too)."""
    from datapipe.sl.phase import PhaseKernel

    rng = np.random.default_rng(2)
    frames = [rng.integers(0, 256, (32, 2048)).astype(np.uint8) for _ in range(4)]
    kern = PhaseKernel(phase_shifts(4))
    buf = np.empty(32 * 2048 + 64, np.float32)
    got = []
    for off in range(16):
        out = buf[off:off + 32 * 2048].reshape(32, 2048)
        kern.compute(frames, np.float32, out_mod=out)
        got.append(out.copy())
    for g in got[1:]:
        np.testing.assert_array_equal(g, got[0])
