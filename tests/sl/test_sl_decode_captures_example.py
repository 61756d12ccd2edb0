"""docs/examples/decode_captures.py on a synthetic capture: 8-bit PNGs through an sRGB tone curve
in a folder, a calibration JSON in OpenCV's stereo convention (camera = world, projector at R, t);
the depth it writes matches the ray-cast truth (tests/sl/synth.py) away from the depth edges."""
import importlib.util
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.ndimage import maximum_filter, minimum_filter

import synth

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "examples" / "decode_captures.py"
PERIODS, STEPS = (1, 8, 64), 4


def _example():
    spec = importlib.util.spec_from_file_location("decode_captures", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _capture(tmp_path, scale=1):
    """A synthetic sRGB capture as a folder of PNGs (resized by ``scale`` after the calibration) and
    its calibration JSON; returns (the truth, the folder, the JSON)."""
    cam, proj = synth.make_rig(cam_size=(200, 150), proj_size=(912, 570), baseline=0.15)
    gt = synth.render(synth.box_scene(), cam, proj, PERIODS, STEPS)
    imgs, _ = synth.tone_curve_stack(gt, synth.srgb_encode, noise_dn=1.0, seed=5)
    folder = tmp_path / "captures"
    folder.mkdir()
    for i, img in enumerate(imgs):                      # capture order = file-name order
        if scale != 1:
            img = cv2.resize(img, None, fx=scale, fy=scale, interpolation=cv2.INTER_LINEAR)
        cv2.imwrite(str(folder / f"frame_{i:03d}.png"), img)
    T_proj_cam = np.linalg.inv(proj.T) @ cam.T          # camera frame -> projector frame
    calib = {"K_cam": cam.K.tolist(), "K_proj": proj.K.tolist(), "R": T_proj_cam[:3, :3].tolist(),
             "t": T_proj_cam[:3, 3].tolist(), "proj_size": list(proj.size), "cam_size": list(cam.size), "axis": "x"}
    (tmp_path / "calib.json").write_text(json.dumps(calib))
    return gt, folder, tmp_path / "calib.json"


@pytest.mark.parametrize("response", ["none", "fit"])
def test_example_decodes_a_folder_of_pngs(tmp_path, response):
    gt, folder, calib = _capture(tmp_path)
    out = tmp_path / "depth.npy"
    res = _example().main([str(folder), str(calib), "--periods", "1", "8", "64",
                           "--steps", "4", "--response", response, "--out", str(out)])
    depth = np.load(out)
    np.testing.assert_array_equal(np.isfinite(depth), res.valid)
    z = np.where(np.isfinite(gt.depth), gt.depth, 0.0)
    step = np.maximum(np.abs(z - maximum_filter(z, 5)), np.abs(z - minimum_filter(z, 5))) > 0.005
    inner = gt.lit & ~step                              # away from the box's depth edges (+-2 px)
    ok = res.valid & inner
    assert ok.sum() >= 0.97 * inner.sum()
    # sRGB's 3rd harmonic ripples the phase: p99 1.84 mm as it is, 0.48 mm with --response fit
    err = np.abs(depth - gt.depth)[ok]
    assert np.percentile(err, 99) < {"none": 3e-3, "fit": 1e-3}[response] and err.max() < 5e-3


def test_example_refuses_captures_of_another_size(tmp_path):
    """Captures upscaled 2x after the calibration (K_cam's principal point then at 25% across, which
    the principal-point test lets pass): the calibration's cam_size makes it an error naming both
    sizes, before a depth map is written."""
    gt, folder, calib = _capture(tmp_path, scale=2)
    out = tmp_path / "depth.npy"
    with pytest.raises(ValueError, match="400x300 pixels but cam_size .* is 200x150"):
        _example().main([str(folder), str(calib), "--periods", "1", "8", "64", "--steps", "4", "--out", str(out)])
    assert not out.exists()
