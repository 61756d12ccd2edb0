"""Camera noise model: statistics, determinism, clipping."""
import numpy as np
import pytest

from datapipe.errors import DataPipeError
from datapipe.sl import PRESETS, SensorModel


@pytest.mark.parametrize("radiance", [0.0, 0.01, 0.1, 0.5, 1.0])
def test_mean_and_variance_match_theory(radiance):
    """Industrial preset: e = Poisson(8000 r), + N(0, 5 e-), DN = e / g with g = 10000/4095 e-/DN,
    rounded. Mean = 8000 r / g (rounding is unbiased on average); variance = S/g + (5/g)^2 + 1/12.
    200k samples: the variance is known to sqrt(2/n) = 0.3%, the mean to sigma/sqrt(n); tolerances
    3% and 6 standard errors (+ the 1/12 DN quantisation term's own approximation at S = 0)."""
    m = SensorModel.preset("industrial")
    img = np.full((200, 1000), radiance)
    dn, sat = m.apply(img, 1)
    assert dn.dtype == np.uint16 and sat < 4095
    g = m.gain
    s = 8000 * radiance / g
    var = s / g + (5 / g) ** 2 + 1 / 12
    x = dn.astype(np.float64)
    if radiance == 0:            # clipped at 0 DN: half the read noise is cut off
        assert x.mean() == pytest.approx(np.sqrt(var) * 0.4, rel=0.2)
        return
    assert x.mean() == pytest.approx(s, abs=6 * np.sqrt(var / x.size) + 1e-3)
    assert x.var() == pytest.approx(var, rel=0.03)
    assert m.noise_sigma(s) == pytest.approx(np.sqrt(var), rel=1e-9)


def test_same_seed_same_bytes():
    rng = np.random.default_rng(0)
    img = rng.uniform(0, 1, (3, 64, 80))
    m = SensorModel.preset("industrial")
    a, _ = m.apply(img, 42)
    b, _ = m.apply(img, 42)
    c, _ = m.apply(img, 43)
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes()
    d, _ = m.apply(img, np.random.default_rng(42))
    assert d.tobytes() == a.tobytes()


def test_saturation_clipping():
    """Radiance past the full well clips at the full well (pixel) and the ADC maximum; every such
    sample reads at or above the returned saturation level (full well - 4 read-noise sigmas)."""
    m = SensorModel.preset("industrial")
    img = np.linspace(0, 3, 100_000).reshape(100, 1000)
    dn, sat = m.apply(img, 5)
    assert dn.max() == 4095
    over = img * 8000 > 10000 + 5 * np.sqrt(10000)          # surely clipped at the full well
    assert np.all(dn[over] >= sat)
    assert sat == np.floor(4095 - 4 * 5 / m.gain)
    under = img * 8000 < 10000 - 6 * np.sqrt(10000) - 1000
    assert np.all(dn[under] < sat)


def test_ideal_is_exact_float():
    m = SensorModel.preset("ideal")
    img = np.random.default_rng(1).uniform(0, 2, (10, 10))
    dn, sat = m.apply(img, 0)
    assert dn.dtype == np.float32 and sat == np.inf
    np.testing.assert_allclose(dn, img * 1000, rtol=1e-6)
    assert float(m.noise_sigma(500.0)) == 0.0


def test_presets_and_8bit_output():
    assert {"ideal", "industrial", "industrial_8bit", "small_pixel"} <= set(PRESETS)
    dn, sat = SensorModel.preset("industrial_8bit").apply(np.full((10, 10), 2.0), 0)
    assert dn.dtype == np.uint8 and dn.max() == 255 and sat <= 255


@pytest.mark.parametrize("bad, exc", [
    (dict(images=np.full((2, 2), -1.0)), ValueError),
    (dict(images=np.full((2, 2), np.nan)), ValueError),
    (dict(rng_or_seed="seed"), TypeError),
])
def test_errors(bad, exc):
    args = dict(images=np.ones((2, 2)), rng_or_seed=0)
    args.update(bad)
    with pytest.raises(exc) as ei:
        SensorModel.preset("industrial").apply(**args)
    assert isinstance(ei.value, DataPipeError)
    with pytest.raises(ValueError, match="unknown sensor preset"):
        SensorModel.preset("webcam")
