"""Bad input to `decode` is an error that names what to fix, never a wrong depth map (issue #31):
a stack whose image count does not match periods x steps, an image without a finite value, images
of another size than the camera matrix was made for."""
import numpy as np
import pytest

import synth
from sl_helpers import PERIODS, STEPS, add_noise, decode_kw
from datapipe.errors import DataPipeError
from datapipe.sl import decode


def _raises(images, kw, *needles):
    with pytest.raises(ValueError) as ei:
        decode(images, **kw)
    msg = str(ei.value)
    assert isinstance(ei.value, DataPipeError) and "fix:" in msg
    for n in needles:
        assert n in msg, msg
    return msg


@pytest.mark.parametrize("count", [11, 13, 4])
def test_image_count_must_match_periods_times_steps(rig, plane_render, count):
    cam, proj = rig
    imgs = np.resize(plane_render.images.astype(np.float32), (count,) + plane_render.images.shape[1:])
    _raises(imgs, decode_kw(cam, proj), f"{count} images", "needs 12")
    _raises(list(imgs), decode_kw(cam, proj), f"{count} images")


@pytest.mark.parametrize("stack, given", [((1, 8, 64), (64, 8, 1)), ((1, 8, 64), (8, 1, 64)), ((13, 7), (7, 13))])
def test_periods_in_another_order_than_the_stack(rig, stack, given):
    """A stack rendered for ``stack`` decoded with ``given``: before this check (64, 8, 1) for a
    (1, 8, 64) plane decoded 27.5% of the pixels, 64% of those more than 5 mm off. A finer fringe's
    phase changes faster from pixel to pixel, so the error names periods and the two frequencies
    whose images say otherwise; the stack's own order decodes."""
    cam, proj = rig
    r = synth.render(synth.box_scene(), cam, proj, stack, STEPS)
    imgs = add_noise(r.images, 0.005, 1).astype(np.float32)
    _raises(imgs, decode_kw(cam, proj, periods=given), "periods", "does not match the stack", "rad per pixel")
    assert decode(imgs, **decode_kw(cam, proj, periods=stack)).valid[r.lit].mean() > 0.9
    # stack_checks=False (the pipeline's scanner, which makes stack and geometry from one config)
    # skips the check: the mismatched stack then decodes to a map instead of an error
    decode(imgs, **decode_kw(cam, proj, periods=given), stack_checks=False)


def test_an_image_without_finite_values_is_named(rig, plane_render):
    """A NaN frame (a failed conversion) is named with its period and step; a stray NaN sample
    stays a per-pixel INVALID_INPUT (tests/sl/test_sl_decode.py::test_nonfinite_inputs)."""
    cam, proj = rig
    imgs = plane_render.images.astype(np.float32)
    imgs[5] = np.nan                       # period 8, step 1 of (1, 8, 64) x 4
    _raises(imgs, decode_kw(cam, proj), "image 5", "period 8, step 1", "NaN or inf")
    imgs[5] = np.inf
    _raises(imgs, decode_kw(cam, proj), "image 5")
    imgs[5] = plane_render.images[5]
    imgs[5, 3, 3] = np.nan                 # one dead sample: decodes, that pixel INVALID_INPUT
    assert not decode(imgs, **decode_kw(cam, proj)).valid[3, 3]


@pytest.mark.parametrize("how", ["half size", "cropped"])
def test_images_of_another_size_than_the_camera_matrix(how):
    """Before this check, half-size images with the full-size P_cam decoded 37.5% of the pixels,
    97% of those more than 5 mm off (median 0.94 m: every pixel on a wrong ray); the cropped ones
    came back all invalid without a word. Now the error names P_cam and the images' size."""
    cam, proj = synth.make_rig(cam_size=(160, 120))
    r = synth.render(synth.plane_scene(), cam, proj, PERIODS, STEPS)
    imgs = {"half size": r.images[:, ::2, ::2], "cropped": r.images[:, :, 100:]}[how]
    imgs = np.ascontiguousarray(imgs, dtype=np.float32)
    _raises(imgs, decode_kw(cam, proj), "P_cam", "principal point", f"{imgs.shape[2]}x{imgs.shape[1]}")


def test_upscaled_images_with_the_calibrations_cam_size():
    """Twice the size of the camera matrix's images: its principal point sits at 25% across, inside
    the central 90%. Before these checks the decode ran: half the pixels valid, every one of them
    more than 5 mm off (median 0.72 m: each on another pixel's ray). With the calibration's cam_size
    it is an error naming both sizes, before any work; without it the decoded points say it (49%
    of them outside the projector's image, sl.decode_setup.check_geometry_fits). The right
    P_cam and cam_size decode as before."""
    cam, proj = synth.make_rig(cam_size=(160, 120))
    big, _ = synth.make_rig(cam_size=(320, 240))
    r = synth.render(synth.plane_scene(), big, proj, PERIODS, STEPS)
    imgs = r.images.astype(np.float32)
    _raises(imgs, decode_kw(cam, proj, cam_size=(160, 120)), "cam_size", "320x240", "160x120")
    _raises(imgs, decode_kw(cam, proj), "P_cam / P_proj / proj_size", "outside the projector's image")
    ok = decode(imgs, **decode_kw(big, proj, cam_size=(320, 240)))
    assert ok.valid.mean() > 0.9 and np.nanmax(np.abs(ok.depth - r.depth)[ok.valid]) < 1e-4
    with pytest.raises(TypeError, match="cam_size"):
        decode(imgs, **decode_kw(big, proj, cam_size=320))


@pytest.mark.parametrize("scale", [0.5, 2.0])
def test_a_proj_size_of_another_projector_mode(rig, plane_render, scale):
    """proj_size half or twice the one P_proj was made for: before this check a plane decoded with
    50% / 12.5% of the pixels valid, every one more than 5 mm off; now an error naming the
    geometry. (A swapped width and height cannot be told from the images: one coded axis.)"""
    cam, proj = rig
    size = (int(proj.size[0] * scale), int(proj.size[1] * scale))
    _raises(plane_render.images.astype(np.float32), decode_kw(cam, proj, proj_size=size), "proj_size",
            "outside the projector's image")


def test_the_images_own_camera_matrix_decodes():
    """The same half-size images with the camera matrix scaled to them decode to the truth."""
    cam, proj = synth.make_rig(cam_size=(160, 120))
    small, _ = synth.make_rig(cam_size=(80, 60))
    r = synth.render(synth.plane_scene(), small, proj, PERIODS, STEPS)
    res = decode(r.images, **decode_kw(small, proj))
    assert res.valid.mean() > 0.9 and np.nanmax(np.abs(res.depth - r.depth)[res.valid]) < 1e-4


def test_decode_options_defaults_are_decodes():
    """``decode``'s keyword defaults and the ``DecodeOptions`` it hands to ``prepare_decode`` are one
    set of defaults: every option of decode's signature (besides the images and ``slab_pixels``, a
    loop setting) is a field of the same default, and no field is missing from the signature."""
    import dataclasses
    import inspect

    from datapipe.sl.decode_setup import DecodeOptions

    params = {k: v.default for k, v in inspect.signature(decode).parameters.items()
              if k not in ("images", "slab_pixels")}
    fields = {f.name: f.default for f in dataclasses.fields(DecodeOptions)}
    assert set(params) == set(fields)
    for name, default in params.items():
        if default is inspect.Parameter.empty:
            assert fields[name] is dataclasses.MISSING, name
        else:
            assert fields[name] == default, name
