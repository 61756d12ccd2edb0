"""A calibration file as the device (datapipe/config/calibration.py): the file cv2.FileStorage writes after a
real cv2.stereoCalibrate, and DataPipe's plain JSON, give the camera and projector of that rig; the
refusals (missing, unreadable, another layout, focal length <= 0, a folding lens, a projector that
cannot see the camera's view, projector distortion) come before any work, naming the field and the fix.

Ground truth is OpenCV's own: the rig is solved by cv2.stereoCalibrate from synthetic checkerboard
views, and a world point's projector pixel from DataPipe's P_proj must equal cv2.projectPoints' with
the file's R, T, K2 (to 1e-6 px: both are float64 pinhole projections of the same point, with T in
the file's millimetres)."""
import json
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from datapipe import config as C
from datapipe import geometry
from datapipe.errors import ConfigError

K1 = np.array([[1210.5, 0.0, 652.25], [0.0, 1209.75, 471.5], [0.0, 0.0, 1.0]])    # 1280 x 960 camera
D1 = np.array([-0.12, 0.085, 0.0007, -0.0004, -0.02])
K2 = np.array([[1480.0, 0.0, 455.5], [0.0, 1481.0, 700.25], [0.0, 0.0, 1.0]])     # 912 x 1140 projector,
R_TRUE = cv2.Rodrigues(np.array([0.01, 0.16, 0.004]))[0]     # toed in: axes cross ~1 m; projector optics offset (cy high)
T_TRUE = np.array([-160.0, 2.5, 12.0])        # mm: X_proj = R X_cam + T (the projector on the camera's +x)
SIZE1, SIZE2 = (1280, 960), (912, 1140)


def stereo_calibrated():
    """(K1, D1, K2, D2, R, T) from cv2.stereoCalibrate on 6 synthetic views of a 9x6 board (25 mm)."""
    obj = np.zeros((54, 3), np.float32)
    obj[:, :2] = np.mgrid[0:9, 0:6].T.reshape(-1, 2) * 25.0
    obj -= obj.mean(axis=0)
    rng = np.random.default_rng(3)
    objs, p1, p2 = [], [], []
    for _ in range(6):
        rvec = rng.normal(0, 0.25, 3)
        tvec = np.array([rng.normal(0, 40), rng.normal(0, 30), rng.uniform(550, 800)])
        a, _ = cv2.projectPoints(obj, rvec, tvec, K1, D1)
        R_b = cv2.Rodrigues(rvec)[0]
        rvec2 = cv2.Rodrigues(R_TRUE @ R_b)[0]
        b, _ = cv2.projectPoints(obj, rvec2, R_TRUE @ tvec + T_TRUE, K2, np.zeros(5))
        objs.append(obj), p1.append(a.astype(np.float32)), p2.append(b.astype(np.float32))
    ret = cv2.stereoCalibrate(objs, p1, p2, K1.copy(), D1.copy(), K2.copy(), np.zeros(5), SIZE1,
                              flags=cv2.CALIB_FIX_INTRINSIC)
    _, k1, d1, k2, d2, R, T = ret[:7]
    return k1, d1, k2, d2, R, T


@pytest.fixture(scope="module")
def calibrated():
    return stereo_calibrated()


def write_opencv(path, k1, d1, k2, d2, R, T, unit="mm", sizes=(SIZE1, SIZE2)):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for name, v in (("K1", k1), ("D1", d1), ("K2", k2), ("D2", d2), ("R", R), ("T", T)):
        fs.write(name, np.asarray(v, dtype=np.float64))
    if sizes is not None:
        fs.write("image_size1", np.array(sizes[0], dtype=np.float64))
        fs.write("image_size2", np.array(sizes[1], dtype=np.float64))
    if unit is not None:
        fs.write("unit", unit)
    fs.release()
    return path


def preset(device) -> dict:
    d = C.default_config().to_dict()
    for sec in ("camera", "projector"):
        for k in ("focal_length", "sensor_width", "resolution", "location", "rotation", "sensor_fit"):
            d[sec].pop(k, None)
    d["structured_light"]["enabled"] = True
    d["device"] = str(device)
    return d


@pytest.mark.parametrize("suffix", [".yml", ".json", ".xml"])
def test_filestorage_after_stereocalibrate_gives_that_rig(tmp_path, calibrated, suffix):
    k1, d1, k2, d2, R, T = calibrated
    assert np.abs(T.ravel() - T_TRUE).max() < 1e-3              # the solver found the rig it was shown
    path = write_opencv(tmp_path / f"rig{suffix}", k1, d1, k2, np.zeros(5), R, T)
    cfg = C.Config.from_dict(preset(path))
    assert cfg.problems(check_files=False) == []
    assert cfg.device == str(path.resolve())
    assert np.array_equal(geometry.camera_intrinsics(cfg.camera), k1)      # float64 round trip, exact
    assert cfg.camera.distortion == [float(v) for v in d1.ravel()]
    assert cfg.camera.resolution == list(SIZE1) and cfg.projector.resolution == list(SIZE2)
    assert np.array_equal(geometry.projector_intrinsics(cfg), k2)
    # the independent truth: OpenCV's projection of world points into camera 2 (the projector)
    T_world_cam = geometry.camera_pose_from_config([0.3, -0.2, 1.1], [0.9, 0.1, -0.3, 0.2])
    X_cam = np.array([[0.05, -0.03, 0.62], [-0.12, 0.08, 0.9], [0.0, 0.0, 0.7]])
    X_world = X_cam @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
    P = geometry.projector_matrix(cfg, T_world_cam)
    ours = np.c_[X_world, np.ones(3)] @ P.T
    ours = ours[:, :2] / ours[:, 2:]
    cv, _ = cv2.projectPoints(X_cam * 1000.0, cv2.Rodrigues(R)[0], T, k2, None)
    assert np.abs(ours - cv.reshape(-1, 2)).max() < 1e-6


def test_plain_json_equals_filestorage(tmp_path, calibrated):
    k1, d1, k2, d2, R, T = calibrated
    plain = {"unit": "m", "camera": {"K": k1.tolist(), "image_size": list(SIZE1), "distortion": d1.ravel().tolist()},
             "projector": {"K": k2.tolist(), "image_size": list(SIZE2)},
             "R": R.tolist(), "T": (T.ravel() / 1000.0).tolist()}
    (tmp_path / "rig.json").write_text(json.dumps(plain))
    a = C.Config.from_dict(preset(tmp_path / "rig.json"))
    b = C.Config.from_dict(preset(write_opencv(tmp_path / "rig.yml", k1, d1, k2, np.zeros(5), R, T)))
    assert a.camera.intrinsics == b.camera.intrinsics and a.camera.distortion == b.camera.distortion
    assert np.allclose(geometry.T_cam_proj(a), geometry.T_cam_proj(b), atol=1e-12)
    # saved and loaded again: the same Config (the sections are spelled out)
    c = C.Config.from_dict(json.loads(json.dumps(a.to_dict())))
    assert c.to_dict() == a.to_dict()


def test_relative_path_is_relative_to_the_preset(tmp_path, calibrated):
    write_opencv(tmp_path / "rig.yml", *calibrated[:3], np.zeros(5), *calibrated[4:])
    cfg = C.Config.from_dict(preset("./rig.yml"), base_dir=tmp_path)
    assert cfg.device == str((tmp_path / "rig.yml").resolve())


def refusal(tmp_path, path) -> str:
    with pytest.raises(ConfigError) as e:
        C.Config.from_dict(preset(path))
    assert "device" in e.value.paths()
    return str(e.value)


def test_refusals_name_the_field_and_the_fix(tmp_path, calibrated):
    k1, d1, k2, d2, R, T = calibrated
    assert "does not exist" in refusal(tmp_path, tmp_path / "nowhere.yml")
    (tmp_path / "garbage.yml").write_text("%YAML:1.0\nK1: [1, 2\n  ::: {\n")
    assert "cv2.FileStorage" in refusal(tmp_path, tmp_path / "garbage.yml")
    (tmp_path / "preset.json").write_text(json.dumps(C.default_config().to_dict()))
    assert "another layout" in refusal(tmp_path, tmp_path / "preset.json")
    (tmp_path / "big.json").write_bytes(b" " * (2 << 20))
    assert "not a calibration" in refusal(tmp_path, tmp_path / "big.json")
    (tmp_path / "dir.yml").mkdir()
    assert "is not a file" in refusal(tmp_path, tmp_path / "dir.yml")
    bad = k1.copy()
    bad[1, 1] = -bad[1, 1]
    msg = refusal(tmp_path, write_opencv(tmp_path / "neg.yml", bad, d1, k2, np.zeros(5), R, T))
    assert "focal length <= 0" in msg and "fix:" in msg
    msg = refusal(tmp_path, write_opencv(tmp_path / "fold.yml", k1, [0.0, -2.0, 0, 0, 0], k2, np.zeros(5), R, T))
    assert "folds the image" in msg
    turned = cv2.Rodrigues(np.array([0.0, np.pi, 0.0]))[0] @ R        # the projector looks backwards
    msg = refusal(tmp_path, write_opencv(tmp_path / "away.yml", k1, d1, k2, np.zeros(5), turned, T))
    assert "cannot see the camera's view" in msg and "X_proj = R X_cam + T" in msg
    msg = refusal(tmp_path, write_opencv(tmp_path / "m.yml", k1, d1, k2, np.zeros(5), R, T, unit="m"))
    assert "cannot see the camera's view" in msg          # millimetres read as metres: 160 m away
    assert "no `unit`" in refusal(tmp_path, write_opencv(tmp_path / "nounit.yml", k1, d1, k2, d2, R, T, unit=None))
    assert "image_size1" in refusal(tmp_path, write_opencv(tmp_path / "nosize.yml", k1, d1, k2, d2, R, T, sizes=None))
    msg = refusal(tmp_path, write_opencv(tmp_path / "pd.yml", k1, d1, k2, [0.05, 0, 0, 0, 0], R, T))
    assert "D2 (projector)" in msg and "does not simulate projector lens distortion" in msg


def test_cli_validate_exits_2_before_any_work(tmp_path):
    p = tmp_path / "preset.json"
    p.write_text(json.dumps(preset(tmp_path / "missing.yml")))
    r = subprocess.run([sys.executable, "-m", "datapipe", "validate", str(p)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2, r.stdout + r.stderr
    assert "device" in r.stdout + r.stderr and "does not exist" in r.stdout + r.stderr


def test_camera_distortion_without_a_file_is_checked():
    cfg = C.default_config()
    cfg.camera.distortion = [-0.2, 0.05, 0.0, 0.0, 0.0]
    assert cfg.problems(check_files=False) == []
    cfg.camera.distortion = [-2.0, 0.0, 0.0, 0.0, 0.0]       # r = 0.44 at the corners: turns at r = 0.41
    assert [p.path for p in cfg.problems(check_files=False)] == ["camera.distortion"]
    cfg.camera.distortion = [0.1, 0.0, 0.0]
    assert [p.path for p in cfg.problems(check_files=False)] == ["camera.distortion"]
    cfg.camera.distortion = None
    cfg.camera.intrinsics = [0.0, 400.0, 160.0, 120.0]
    assert [p.path for p in cfg.problems(check_files=False)] == ["camera.intrinsics"]


def test_the_documented_plain_json_example_loads(tmp_path):
    """docs/CALIBRATION.md's example: it loads, and its projector sits ~111 mm to the camera's +x with
    its axis crossing the camera's near 1.3 m (the numbers it was written with)."""
    text = (Path(__file__).resolve().parents[1] / "docs" / "CALIBRATION.md").read_text()
    block = text.split("### DataPipe's plain JSON", 1)[1].split("```json", 1)[1].split("```", 1)[0]
    (tmp_path / "rig.json").write_text(block)
    cfg = C.Config.from_dict(preset(tmp_path / "rig.json"))
    T = geometry.T_cam_proj(cfg)
    assert np.allclose(T[:3, 3], [0.1112, 0.0, 0.0079], atol=5e-4)
    z = 1.3
    Xp = np.linalg.inv(T) @ np.array([0.0, 0.0, z, 1.0])            # the camera axis at 1.3 m, projector frame
    assert abs(Xp[0] / Xp[2]) < 0.01


def test_a_rig_that_does_not_light_the_working_distance_is_refused(tmp_path, calibrated):
    """The stereoCalibrate rig (axes crossing near 1 m) with the camera moved to 0.2 m from the bin:
    the projector, 0.16 m to the side and toed in, lights the image centre only farther away, so
    validate names `device` and the lit range."""
    path = write_opencv(tmp_path / "rig.yml", *calibrated[:3], np.zeros(5), *calibrated[4:])
    d = preset(path)
    assert C.Config.from_dict(d).problems(check_files=False) == []       # the demo's poses: lit
    for pose in d["camera"]["poses"]:
        pose["location"] = [pose["location"][0], pose["location"][1], pose["location"][2] - 0.5]
    msg = [str(p) for p in C.Config.from_dict(d).problems(check_files=False) if p.path == "device"]
    assert msg and "does not light the centre of the camera's image" in msg[0] and "it lights it between" in msg[0]
