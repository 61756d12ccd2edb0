"""A camera's tone curve undone before decoding (datapipe/sl/response.py, issue #31): given as a
look-up table or fitted from the stack. Truth: the ray-cast projector coordinate of each pixel
(tests/sl/synth.py) and the exponent the stack was made with."""
import numpy as np
import pytest

import synth
from datapipe.errors import DataPipeError
from datapipe.sl import decode
from datapipe.sl.response import fit_response

PERIODS, STEPS = (1, 8, 64), 4


def srgb_decode(v):
    """The inverse of synth.srgb_encode (IEC 61966-2-1)."""
    v = np.clip(v, 0.0, 1.0)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


@pytest.fixture(scope="module")
def scene():
    cam, proj = synth.make_rig(cam_size=(240, 180), proj_size=(912, 570), baseline=0.15)
    gt = synth.render(synth.dark_step_scene(), cam, proj, PERIODS, STEPS)
    kw = dict(periods=PERIODS, steps=STEPS, P_cam=cam.P, P_proj=proj.P, proj_size=proj.size)
    return gt, kw


@pytest.mark.parametrize("gamma", [1.0, 1.8, 2.2])
def test_fitted_power_law(scene, gamma):
    gt, _ = scene
    imgs, _ = synth.tone_curve_stack(gt, lambda x: np.clip(x, 0, 1) ** (1 / gamma), noise_dn=1.0, seed=2)
    assert fit_response(list(imgs), STEPS).gamma == pytest.approx(gamma, abs=0.05)


def test_linearised_phase_is_as_good_as_a_linear_camera(scene):
    """sRGB-encoded images: the 3rd harmonic bends the phase (median error 3.4x the linear
    camera's); with the inverse curve given, or a power law fitted, the error is within 1.3x of the
    linear camera's on the same scene and noise, with no less coverage and <= 0.01% wrong orders."""
    gt, kw = scene
    half = 912 / max(PERIODS) / 2

    def err(imgs, **extra):
        r = decode(imgs, **kw, **extra)
        e = np.abs(r.proj_x - gt.proj_x)[r.valid & gt.lit]
        assert np.sum(e > half) <= 1e-4 * e.size           # the decoder's wrong share (linear: 2 of 35535)
        return float(np.median(e)), float(np.mean(r.valid[gt.lit]))

    lin, lin_cov = err(synth.tone_curve_stack(gt, lambda x: np.clip(x, 0, 1), noise_dn=1.0, seed=1)[0])
    srgb, _ = synth.tone_curve_stack(gt, synth.srgb_encode, noise_dn=1.0, seed=1)
    raw, _ = err(srgb)
    lut, cov_lut = err(srgb, response=255.0 * srgb_decode(np.arange(256) / 255.0))
    fit, cov_fit = err(srgb, response="fit")
    assert raw > 2.0 * lin
    assert lut <= 1.3 * lin and fit <= 1.3 * lin, (lin, raw, lut, fit)
    assert min(cov_lut, cov_fit) >= lin_cov - 0.005
    res = decode(srgb, **kw, response="fit")
    assert res.extras["response"]["kind"] == "fit" and res.extras["response"]["gamma"] == pytest.approx(2.26, abs=0.1)


@pytest.mark.parametrize("response, steps, needle", [
    (np.arange(200.0), 4, "entries"),
    (np.arange(256.0)[::-1], 4, "non-decreasing"),
    ("gamma", 4, "unknown"),
    ("fit", 3, "4 phase steps"),
    (3.0, 4, "callable"),
])
def test_bad_response(scene, response, steps, needle):
    gt, kw = scene
    imgs = np.full((len(PERIODS) * steps,) + gt.depth.shape, 100, np.uint8)
    imgs[:, 0, 0] = 250
    with pytest.raises((ValueError, TypeError)) as ei:
        decode(imgs, **{**kw, "steps": steps}, response=response)
    assert isinstance(ei.value, DataPipeError) and needle in str(ei.value) and "fix:" in str(ei.value)
