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


# -- three images per rendered layer (sl.pack_basis / unpack_basis) --------------------------------

LUM = np.array([0.2126, 0.7152, 0.0722])     # the grey value a monochrome camera takes (any weights do)


def render_rgb(T_rgb, images):
    """(n, H*W, 3): each image through the per-channel transports T_rgb (3, n_pix, n_src); images
    (n, Hp, Wp) grey or (n, Hp, Wp, 3)."""
    im = np.asarray(images, np.float64)
    if im.ndim == 3:
        im = np.repeat(im[..., None], 3, axis=-1)
    flat = im.reshape(len(im), -1, 3)
    return np.stack([flat[..., c] @ T_rgb[c].T for c in range(3)], axis=-1)


def packed_vs_alone(T_rgb, periods=(1, 8, 24), rows=(4,), n_layers=None):
    basis = quadrature_basis(WP, HP, periods, row_periods=rows)
    layout = sl.packed_layout(len(periods), len(rows))
    packed = sl.pack_basis(basis, layout)[:n_layers]
    rgb = render_rgb(T_rgb, packed)                                   # (L, n_pix, 3)
    grey_white = render_rgb(T_rgb, basis[:1])[0] @ LUM
    got = sl.unpack_basis(np.moveaxis(rgb, -1, 1)[..., None], grey_white[:, None], layout)[..., 0]
    want = render_rgb(T_rgb, basis[:len(got)]) @ LUM                   # each image alone, grey
    return got, want


def test_layout_packs_nine_images_into_four_layers_with_the_row_code_last():
    layout = sl.packed_layout(3, 1)
    assert layout == [(0, 0, 0), (1, 2, 3), (4, 5, 6), (7, 8, None)]
    assert sl.packed_layout(3, 0) == layout[:3]                       # no row code: its layer left out
    assert sl.packed_layout(2, 1) == [(0, 0, 0), (1, 2, 3), (4, None, None), (5, 6, None)]
    basis = quadrature_basis(WP, HP, (1, 8, 24), row_periods=(4,))
    packed = sl.pack_basis(basis, layout)
    assert packed.shape == (4, HP, WP, 3) and np.array_equal(packed[1, ..., 2], basis[3])
    assert np.array_equal(packed[3, ..., 2], np.zeros((HP, WP)))      # an unused channel emits nothing


def test_unpacked_images_equal_each_image_alone_where_light_has_one_colour_balance():
    """Grey, or tinted by one material (per channel a scale of one transport): exact, mirror and
    diffuse parts alike; also with the row code's layer left out."""
    rng = np.random.default_rng(0)
    T = transport(rng, 300, WP * HP)
    for tint in ((1.0, 1.0, 1.0), (0.53, 0.51, 0.49), (0.9, 0.2, 0.05)):
        got, want = packed_vs_alone(np.stack([k * T for k in tint]))
        assert got.shape == want.shape == (9, 300)
        assert np.abs(got - want).max() < 1e-5 * want.max()
    got, want = packed_vs_alone(np.stack([T] * 3), n_layers=3)
    assert got.shape == (7, 300) and np.abs(got - want).max() < 1e-5 * want.max()


def test_each_single_path_is_exact_whatever_its_colour():
    """One source texel per pixel (one path), a random colour per pixel: the ratio to the white
    image in any channel is the pattern's value where that path left the projector."""
    rng = np.random.default_rng(1)
    n = 300
    cols = rng.integers(0, WP * HP, n)
    T_rgb = np.zeros((3, n, WP * HP))
    for c in range(3):
        T_rgb[c, np.arange(n), cols] = rng.uniform(0.05, 1.0, n)
    got, want = packed_vs_alone(T_rgb)
    assert np.abs(got - want).max() < 1e-5 * want.max()


def test_light_of_two_colours_in_one_pixel_is_approximate_and_grows_with_the_colour():
    """A red part's bounce beside a grey direct path: each channel weights the two pattern values
    by its own colour, not by grey (why core/structured_light.py packs only grey materials)."""
    rng = np.random.default_rng(2)
    direct, bounce = np.zeros((2, 300, WP * HP))
    for T in (direct, bounce):                          # one texel each: two mirror-like paths
        T[np.arange(300), rng.integers(0, WP * HP, 300)] = rng.uniform(0.2, 1.0, 300)
    err = {}
    for name, tint in (("steel", (0.53, 0.51, 0.49)), ("red", (0.9, 0.2, 0.05))):
        T_rgb = np.stack([direct + k * bounce for k in tint])
        got, want = packed_vs_alone(T_rgb)
        err[name] = np.abs(got - want).max() / want.max()
    assert err["steel"] < 0.02 and err["red"] > 0.1, err      # measured 0.9% and 21% of the peak


def test_a_channel_without_light_gives_no_modulation_not_a_phase():
    """A pure red pixel has no green or blue to carry the images packed there: all its images are
    a * white, so every mixed step is the same value and the decoder finds no fringe."""
    rng = np.random.default_rng(3)
    T = transport(rng, 50, WP * HP)
    T_rgb = np.stack([T, 0 * T, 0 * T])
    basis = quadrature_basis(WP, HP, (1, 8, 24))
    layout = sl.packed_layout(3)
    rgb = render_rgb(T_rgb, sl.pack_basis(basis, layout))
    grey = render_rgb(T_rgb, basis[:1])[0] @ LUM
    got = sl.unpack_basis(np.moveaxis(rgb, -1, 1)[..., None], grey[:, None], layout)[..., 0]
    frames = frames_from_basis(got[:, :, None], 4)[..., 0]
    assert np.ptp(frames, axis=0).max() < 1e-6 * grey.max()
    with pytest.raises(ValueError, match="rgb"):
        sl.unpack_basis(np.moveaxis(rgb, -1, 1)[:, :2, :, None], grey[:, None], layout)
