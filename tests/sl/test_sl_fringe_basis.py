"""The quadrature basis (sl.fringe_basis): every phase step mixed from white, cos and sin images.

Light transport is linear in the emitted image: the radiance of every camera pixel is T @ image for
some non-negative transport matrix T (direct light, mirror images, diffuse bounces alike). A random
T with sharp (one-column, mirror-like) and broad (diffuse) rows stands in for a scene here, so
the test does not depend on any renderer: mixing T @ basis must give T @ pattern for every step."""
import numpy as np
import pytest

from datapipe import sl
from datapipe.sl import frames_from_basis, quadrature_basis

WP, HP = 96, 40


def transport(rng, n_pix, n_src):
    """(n_pix, n_src) non-negative transport: a direct/mirror part (one source texel per pixel,
    random: a mirror maps pixels anywhere) plus a weak broad diffuse part."""
    T = np.zeros((n_pix, n_src))
    T[np.arange(n_pix), rng.integers(0, n_src, n_pix)] = rng.uniform(0.2, 1.0, n_pix)
    return T + rng.uniform(0.0, 0.02, (n_pix, n_src))


@pytest.mark.parametrize("steps", [3, 4, 5, 8])
def test_mixed_steps_equal_the_patterns_through_any_linear_transport(steps):
    rng = np.random.default_rng(steps)
    periods, rows = (1, 8, 24), (4,)
    basis = quadrature_basis(WP, HP, periods, row_periods=rows)
    assert basis.shape == (sl.basis_size(len(periods), rows=True), HP, WP) == (9, HP, WP)
    assert basis.min() >= 0.0 and basis.max() <= 1.0                 # a light can emit all of them
    patterns = np.concatenate([sl.fringe_patterns(WP, HP, periods, steps),
                               sl.fringe_patterns(WP, HP, rows, steps, axis="y")])
    # the images themselves: white at a = 0.5 plus the quadrature pair is every step
    assert np.abs(frames_from_basis(basis, steps) - patterns).max() < 1e-6
    T = transport(rng, 300, WP * HP)
    seen = (basis.reshape(len(basis), -1) @ T.T).reshape(len(basis), 300, 1)
    want = (patterns.reshape(len(patterns), -1) @ T.T).reshape(len(patterns), 300, 1)
    got = frames_from_basis(seen, steps)
    assert got.shape == want.shape == (len(periods) * steps + len(rows) * steps, 300, 1)
    assert np.abs(got - want).max() < 1e-5 * want.max()


def test_a_projector_gamma_is_not_a_mix_of_cos_and_sin():
    """Why quadrature mode refuses projector_gamma != 1: p ** gamma has harmonics of every order."""
    basis = quadrature_basis(WP, 1, (8,))
    gamma = sl.fringe_patterns(WP, 1, (8,), 4, gamma=2.2)
    assert np.abs(frames_from_basis(basis, 4) - gamma).max() > 0.05


def test_frames_from_basis_refuses_an_incomplete_basis():
    with pytest.raises(ValueError, match="rendered"):
        frames_from_basis(np.ones((4, 3, 3), np.float32), 4)      # white + a pair + one more
    with pytest.raises(ValueError, match="steps"):
        frames_from_basis(np.ones((3, 3, 3), np.float32), 2)
