"""Decode your own structured-light captures with datapipe.sl (docs/DECODE_YOUR_CAPTURES.md).

    python docs/examples/decode_captures.py CAPTURES_DIR CALIBRATION.json --periods 1 8 64 --steps 4 \
        [--response fit] [--out depth.npy]

CAPTURES_DIR holds the F * N fringe images (PNG or TIFF, 8 or 16 bit, grey or colour), whose file
names sort in capture order: all N steps of the first period, then all of the second, ...
CALIBRATION.json (OpenCV conventions, metres):

    {"K_cam": 3x3, "K_proj": 3x3, "R": 3x3, "t": [x, y, z], "proj_size": [width, height],
     "cam_size": [width, height], "axis": "x"}

R, t: the projector's pose relative to the camera as cv2.stereoCalibrate returns it with the camera
as the first and the projector as the second device (a point X in the camera frame is R X + t in
the projector frame). cam_size (optional, recommended): the camera image size K_cam was calibrated
at (cv2.stereoCalibrate's imageSize); images of another size are refused. Writes the depth map
(metres along the camera's z axis, NaN where invalid) as .npy and prints what the decoder kept and
why it dropped the rest.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from datapipe import sl


def load_images(folder: Path) -> np.ndarray:
    """(count, H, W) stack of the folder's images in file-name order (colour -> grey)."""
    files = sorted(p for p in Path(folder).iterdir() if p.suffix.lower() in (".png", ".tif", ".tiff"))
    if not files:
        raise SystemExit(f"{folder}: no .png / .tif images")
    frames = []
    for p in files:
        img = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise SystemExit(f"{p}: not readable as an image")
        if img.ndim == 3:
            img = cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)     # a colour camera: its luminance
        frames.append(img)
    return np.stack(frames)


def projection_matrices(calib: dict):
    """(P_cam, P_proj): the camera frame is the world frame, the projector sits at (R, t) from it."""
    K_cam = np.asarray(calib["K_cam"], np.float64)
    K_proj = np.asarray(calib["K_proj"], np.float64)
    Rt = np.hstack([np.asarray(calib["R"], np.float64), np.asarray(calib["t"], np.float64).reshape(3, 1)])
    return K_cam @ np.hstack([np.eye(3), np.zeros((3, 1))]), K_proj @ Rt


def main(argv=None) -> sl.DecodeResult:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("captures", type=Path)
    ap.add_argument("calibration", type=Path)
    ap.add_argument("--periods", type=float, nargs="+", required=True, help="fringe periods across the projector")
    ap.add_argument("--steps", type=int, required=True, help="phase steps per period")
    ap.add_argument("--response", choices=("none", "fit"), default="none",
                    help="'fit': undo the camera's tone curve (a power law fitted to the stack)")
    ap.add_argument("--out", type=Path, default=Path("depth.npy"))
    args = ap.parse_args(argv)

    images = load_images(args.captures)
    calib = json.loads(args.calibration.read_text())
    P_cam, P_proj = projection_matrices(calib)
    res = sl.decode(images, periods=tuple(args.periods), steps=args.steps, P_cam=P_cam, P_proj=P_proj,
                    proj_size=tuple(calib["proj_size"]), cam_size=calib.get("cam_size"),
                    axis=calib.get("axis", "x"),
                    response=None if args.response == "none" else args.response)
    np.save(args.out, res.depth)
    counts = {k: v for k, v in res.reason_counts().items() if v}
    print(f"{args.out}: {res.valid.mean():.1%} of the pixels with depth; reasons {counts}")
    print(f"noise model: {res.extras['noise_model']}")
    if "response" in res.extras:
        print(f"response: {res.extras['response']}")
    return res


if __name__ == "__main__":
    main()
