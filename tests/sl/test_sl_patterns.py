"""Pattern formula, stack order and argument checks."""
import numpy as np
import pytest

from datapipe.errors import DataPipeError
from datapipe.sl import fringe_patterns, phase_shifts


def test_formula_and_frequency_major_order():
    W, H = 40, 3
    p = fringe_patterns(W, H, (1, 5), 3, a=0.25, b=0.5, dtype=np.float64)
    assert p.shape == (6, H, W)
    x = np.arange(W)
    for i, k in enumerate((1, 5)):
        for n in range(3):
            want = 0.25 + 0.5 * np.cos(2 * np.pi * k * x / W + 2 * np.pi * n / 3)
            np.testing.assert_allclose(p[i * 3 + n], np.broadcast_to(want, (H, W)), atol=1e-15)
    # pixel centres at integers: column 0 is exactly the phase origin of every step-0 pattern
    assert p[0, 0, 0] == pytest.approx(0.75) and p[3, 0, 0] == pytest.approx(0.75)


def test_axis_y_uses_rows_and_height():
    p = fringe_patterns(7, 30, (2,), 4, axis="y", dtype=np.float64)
    y = np.arange(30)
    np.testing.assert_allclose(p[1][:, 3], 0.5 + 0.5 * np.cos(2 * np.pi * 2 * y / 30 + np.pi / 2), atol=1e-15)
    assert np.all(p[1] == p[1][:, :1])           # constant along x


def test_integer_dtype_scales_to_full_range():
    p = fringe_patterns(16, 2, (1,), 4, dtype=np.uint8)
    assert p.dtype == np.uint8 and p.max() == 255 and p.min() == 0
    p16 = fringe_patterns(16, 2, (1,), 4, dtype=np.uint16)
    assert p16.max() == 65535


def test_shifts_uniform():
    np.testing.assert_allclose(phase_shifts(4), [0, np.pi / 2, np.pi, 3 * np.pi / 2])


@pytest.mark.parametrize("kw, exc, msg", [
    (dict(steps=2), ValueError, "steps"),
    (dict(periods=()), ValueError, "periods"),
    (dict(periods=(1, 1)), ValueError, "duplicates"),
    (dict(periods=(0, 8)), ValueError, "> 0"),
    (dict(axis="z"), ValueError, "axis"),
    (dict(steps=4.0), TypeError, "steps"),
])
def test_bad_arguments(kw, exc, msg):
    args = dict(width=32, height=4, periods=(1, 8), steps=4)
    args.update(kw)
    with pytest.raises(exc, match=msg) as ei:
        fringe_patterns(**args)
    assert isinstance(ei.value, DataPipeError) and "fix:" in str(ei.value)


def test_projector_gamma_in_patterns():
    p1 = fringe_patterns(32, 2, (2,), 4, dtype=np.float64)
    pg = fringe_patterns(32, 2, (2,), 4, dtype=np.float64, gamma=2.2)
    np.testing.assert_allclose(pg, p1 ** 2.2, rtol=1e-12)
    with pytest.raises(ValueError, match="gamma"):
        fringe_patterns(32, 2, (2,), 4, gamma=0)
