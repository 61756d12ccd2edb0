"""Your own rig: `"device": "path/to/calibration.yml"` -> the camera and projector sections. No bpy.

A calibration file holds the camera's and the projector's intrinsics (K, image size, OpenCV
distortion k1 k2 p1 p2 k3) and the projector's pose relative to the camera, as OpenCV's
`stereoCalibrate` returns it with the camera as camera 1 and the projector as camera 2:
`X_proj = R @ X_cam + T`. Two layouts are read (docs/CALIBRATION.md gives both, key by key):

- OpenCV FileStorage (YAML, JSON or XML, as `cv2.FileStorage` writes them): K1 D1 K2 D2 R T,
  image_size1 image_size2 ([width, height]) and unit ("m" or "mm": the length unit of T, i.e. of the
  checkerboard square size the calibration was given);
- DataPipe's plain JSON: {"unit", "camera": {"K", "image_size", "distortion"}, "projector": {...},
  "R", "T"}.

`apply_calibration` fills `camera` (resolution, intrinsics, distortion; focal_length consistent with
fx for the estimates that read it) and `projector` (resolution, intrinsics, location, rotation in the
camera object's Blender axes, datapipe.geometry's convention) before the Config is built; the
preset's own fields win, as with a named device. Every problem with the file is a Problem at
`device` naming the key and the fix, before any work.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .. import geometry, lens
from ..devices import is_calibration_path
from ..errors import ConfigError, Problem
from .plan import camera_distances

UNITS = {"m": 1.0, "mm": 1e-3, "cm": 1e-2}
OPENCV_KEYS = {          # DataPipe's name -> the FileStorage names accepted, first = the documented one
    "K_cam": ("K1", "cameraMatrix1", "M1"), "D_cam": ("D1", "distCoeffs1"),
    "K_proj": ("K2", "cameraMatrix2", "M2"), "D_proj": ("D2", "distCoeffs2"),
    "R": ("R",), "T": ("T",), "size_cam": ("image_size1", "imageSize1"),
    "size_proj": ("image_size2", "imageSize2"), "unit": ("unit",),
}
FOCUS_SEARCH = (0.05, 10.0)    # m: the camera's central ray is sought in the projector's image over this range
MAX_FILE_BYTES = 1 << 20       # a calibration is a few kB: anything above 1 MiB is another file
ROTATION_TOL = 1e-3            # |R^T R - I| accepted (rounded files), then made exact
SENSOR_WIDTH_MM = 11.3         # the camera's nominal sensor width (only focal_length's mm depend on it)


def apply_calibration(data: dict, problems: list[Problem], base_dir=None) -> dict:
    """`data` with its calibration file's camera and projector filled in (the preset's own fields
    win) and `device` made absolute; problems appended (data unfilled) when the file is wrong."""
    name = data["device"]
    path = Path(name).expanduser()
    if not path.is_absolute() and base_dir is not None:
        path = Path(base_dir) / path
    data = dict(data, device=str(path.resolve()) if path.exists() else str(path))
    if data.get("binning", 1) != 1:
        problems.append(Problem("binning", f"binning {data.get('binning')!r} with a calibration file",
                                "calibrate the binned camera and give that file, or set binning to 1"))
    try:
        sections = load(path)
    except ConfigError as e:
        problems.extend(e.problems)
        return data
    for sec, filled in sections.items():       # the preset's fields win; a null (a saved default) is "not given"
        given = data.get(sec)
        if given is None or isinstance(given, dict):
            data[sec] = {**filled, **{k: v for k, v in (given or {}).items() if not (v is None and k in filled)}}
    return data


def load(path) -> dict:
    """The camera and projector Config sections of calibration file `path` (ConfigError otherwise)."""
    cal = read(path)
    return sections(cal, path)


# ------------------------------------------------------------------------------------------------
# reading

def _problem(path, message, fix) -> ConfigError:
    return ConfigError(Problem("device", f"calibration file {path}: {message}", fix))


def read(path) -> dict:
    """{"K_cam", "D_cam", "size_cam", "K_proj", "D_proj", "size_proj", "R", "T" (m)} from a file."""
    path = Path(path)
    if not path.is_file():
        raise _problem(path, "does not exist" if not path.exists() else "is not a file",
                       "give the path of the file cv2.FileStorage wrote after stereoCalibrate (relative "
                       "paths are relative to the preset's folder), or a device name (`python -m datapipe sensors`)")
    try:
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(4096)
    except OSError as e:
        raise _problem(path, f"cannot be read ({e.strerror})", "check the file's permissions") from None
    if size > MAX_FILE_BYTES:
        raise _problem(path, f"is {size / 2**20:.1f} MiB, not a calibration (a few kB)",
                       "give the file cv2.FileStorage wrote after stereoCalibrate")
    text_head = head.decode("utf-8", "replace").lstrip()
    if text_head.startswith(("%YAML", "<?xml")) or path.suffix.lower() in (".yml", ".yaml", ".xml"):
        return _read_opencv(path)
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise _problem(path, f"is not valid JSON ({e})", "write it with cv2.FileStorage or as the plain JSON of "
                       "docs/CALIBRATION.md") from None
    if isinstance(doc, dict) and isinstance(doc.get("camera"), dict) and "K" in doc["camera"]:
        return _read_plain(path, doc)
    if isinstance(doc, dict) and any(k in doc for keys in OPENCV_KEYS.values() for k in keys):
        return _read_opencv(path)
    raise _layout(path, sorted(doc) if isinstance(doc, dict) else type(doc).__name__)


def _layout(path, found) -> ConfigError:
    return _problem(path, f"is of another layout (top-level keys {found})",
                    "use OpenCV's stereoCalibrate keys K1 D1 K2 D2 R T image_size1 image_size2 unit, or "
                    "DataPipe's plain JSON {unit, camera: {K, image_size, distortion}, projector: {...}, R, T} "
                    "(docs/CALIBRATION.md)")


def _read_opencv(path) -> dict:
    import cv2
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        opened = fs.isOpened()
    except (cv2.error, SystemError) as e:        # cv2's parser errors arrive as either
        raise _problem(path, f"cannot be parsed by cv2.FileStorage ({str(e).strip().splitlines()[-1][:200]})",
                       "write it with cv2.FileStorage (YAML/JSON/XML) or use the plain JSON of "
                       "docs/CALIBRATION.md") from None
    if not opened:
        raise _problem(path, "cannot be opened by cv2.FileStorage", "check that it is a FileStorage file")
    try:
        root = fs.root()
        present = set(root.keys())
        out = {}
        for key, names in OPENCV_KEYS.items():
            name = next((n for n in names if n in present), None)
            if name is None:
                if key == "unit":
                    raise _problem(path, "has no `unit` (the length unit of T)",
                                   "add it: fs.write('unit', 'mm') (or 'm'): the unit of the checkerboard "
                                   "square size given to stereoCalibrate")
                if key.startswith("size"):
                    raise _problem(path, f"has no `{names[0]}` (the image size [width, height])",
                                   f"add it: fs.write('{names[0]}', np.array([width, height]))")
                if key in ("K_cam", "K_proj", "R", "T") and not (present & {n for v in OPENCV_KEYS.values() for n in v}
                                                                 - {"unit"}):
                    raise _layout(path, sorted(present))
                if key.startswith("D"):
                    out[key] = None
                    continue
                raise _problem(path, f"has no `{names[0]}`", "write every output of stereoCalibrate: "
                               "fs.write('K1', K1), ... (docs/CALIBRATION.md)")
            node = fs.getNode(name)
            out[key] = node.string() if key == "unit" else _node_value(node, name, path)
    finally:
        fs.release()
    return _checked(path, out)


def _node_value(node, name, path):
    m = node.mat()
    if m is not None:
        return np.asarray(m, dtype=np.float64)
    if node.isSeq():
        return np.array([node.at(i).real() for i in range(node.size())], dtype=np.float64)
    if node.isReal() or node.isInt():
        return np.array([node.real()])
    raise _problem(path, f"`{name}` is not a number, list or matrix", f"write {name} with fs.write")


def _read_plain(path, doc: dict) -> dict:
    try:
        cam, proj = doc["camera"], doc["projector"]
        out = {"K_cam": cam["K"], "D_cam": cam.get("distortion"), "size_cam": cam["image_size"],
               "K_proj": proj["K"], "D_proj": proj.get("distortion"), "size_proj": proj["image_size"],
               "R": doc["R"], "T": doc["T"], "unit": doc.get("unit")}
    except (KeyError, TypeError) as e:
        raise _problem(path, f"lacks {e}", "give camera.{K, image_size}, projector.{K, image_size}, R, T and "
                       "unit (docs/CALIBRATION.md)") from None
    if out["unit"] is None:
        raise _problem(path, "has no `unit` (the length unit of T)", "add \"unit\": \"mm\" (or \"m\")")
    try:
        out = {k: (v if k == "unit" or v is None else np.asarray(v, dtype=np.float64)) for k, v in out.items()}
    except (TypeError, ValueError):
        raise _problem(path, "has a non-numeric K, distortion, image_size, R or T",
                       "give numbers (lists of lists for K and R)") from None
    return _checked(path, out)


def _checked(path, raw: dict) -> dict:
    """Shapes, finiteness, focal lengths, unit, rotation: every key checked, T converted to metres."""
    unit = raw["unit"]
    if not isinstance(unit, str) or unit.strip().lower() not in UNITS:
        raise _problem(path, f"unit {unit!r} is not one of {sorted(UNITS)}", "give the unit of T: 'm' or 'mm'")
    out = {}
    for key, shape in (("K_cam", (3, 3)), ("K_proj", (3, 3)), ("R", (3, 3))):
        a = np.asarray(raw[key], dtype=np.float64)
        if a.size != 9:
            raise _problem(path, f"{_name(key)} has {a.size} numbers, not 3 x 3", f"give {_name(key)} as a 3x3 matrix")
        out[key] = a.reshape(shape)
    for key in ("T", "size_cam", "size_proj"):
        a = np.asarray(raw[key], dtype=np.float64).reshape(-1)
        want = 3 if key == "T" else 2
        if a.size != want:
            raise _problem(path, f"{_name(key)} has {a.size} numbers, not {want}",
                           "give T as 3 numbers" if key == "T" else f"give {_name(key)} as [width, height]")
        out[key] = a
    for key in ("D_cam", "D_proj"):
        out[key] = _distortion(path, key, raw[key])
    for key, a in out.items():
        if a is not None and not np.all(np.isfinite(a)):
            raise _problem(path, f"{_name(key)} has NaN or infinity", "recalibrate: the solver diverged")
    for key in ("K_cam", "K_proj"):
        K = out[key]
        if K[0, 0] <= 0 or K[1, 1] <= 0:
            raise _problem(path, f"{_name(key)} has a focal length <= 0 (fx {K[0, 0]:g}, fy {K[1, 1]:g})",
                           "give K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0 in pixels")
        if not np.allclose(K[2], [0, 0, 1]) or K[1, 0] != 0:
            raise _problem(path, f"{_name(key)}'s last row is {K[2].tolist()} (K[1][0] = {K[1, 0]:g})",
                           "give K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]")
        if abs(K[0, 1]) > 1e-9 * K[0, 0]:
            raise _problem(path, f"{_name(key)} has a skew of {K[0, 1]:g}", "calibrate without skew (OpenCV's "
                           "default): Blender cameras have none")
    for key in ("size_cam", "size_proj"):
        w, h = out[key]
        if w != int(w) or h != int(h) or w < 1 or h < 1:
            raise _problem(path, f"{_name(key)} is {out[key].tolist()}", "give [width, height] in whole pixels")
        out[key] = (int(w), int(h))
    R = out["R"]
    if not np.allclose(R.T @ R, np.eye(3), atol=ROTATION_TOL) or np.linalg.det(R) <= 0:
        raise _problem(path, "R is not a rotation (R^T R != I or det(R) <= 0)",
                       "give R as stereoCalibrate returns it (a 3x3 rotation; cv2.Rodrigues turns a vector into one)")
    u, _, vt = np.linalg.svd(R)          # the nearest rotation: a file typed with 4 decimals is off by ~1e-4
    out["R"] = u @ vt
    out["T"] = out["T"] * UNITS[unit.strip().lower()]
    return out


def _name(key) -> str:
    return {"K_cam": "K1 (camera)", "K_proj": "K2 (projector)", "D_cam": "D1 (camera)", "D_proj": "D2 (projector)",
            "size_cam": "image_size1 (camera)", "size_proj": "image_size2 (projector)"}.get(key, key)


def _distortion(path, key, d):
    """OpenCV's 4, 5, 8, 12 or 14 coefficients -> (k1, k2, p1, p2, k3); the rational and thin-prism terms
    beyond the fifth must be zero (DataPipe models k1 k2 p1 p2 k3)."""
    if d is None:
        return None
    a = np.asarray(d, dtype=np.float64).reshape(-1)
    if a.size not in (4, 5, 8, 12, 14):
        raise _problem(path, f"{_name(key)} has {a.size} coefficients", "give OpenCV's k1 k2 p1 p2 k3 (4 or 5 numbers)")
    if a.size > 5 and np.any(a[5:]):
        raise _problem(path, f"{_name(key)} uses OpenCV's rational/thin-prism terms {a[5:].tolist()}",
                       "recalibrate with OpenCV's default 5-coefficient model (no CALIB_RATIONAL_MODEL / "
                       "CALIB_THIN_PRISM_MODEL): DataPipe simulates k1 k2 p1 p2 k3")
    return np.concatenate([a[:5], np.zeros(5 - min(5, a.size))])


# ------------------------------------------------------------------------------------------------
# -> Config sections

def sections(cal: dict, path="calibration file") -> dict:
    """{"camera": {...}, "projector": {...}} of a read calibration; the rig checked (distortion that
    folds the frame, projector distortion, a projector that cannot see the camera's view)."""
    Kc, Kp = cal["K_cam"], cal["K_proj"]
    wc, hc = cal["size_cam"]
    problem = lens.fold_problem(Kc, cal["D_cam"], (wc, hc), path="device")
    if problem is not None:
        raise _problem(path, f"D1 (camera): {problem.message}", problem.fix)
    if lens.coefficients(cal["D_proj"]) is not None:
        raise _problem(path, f"D2 (projector) is {cal['D_proj'].tolist()}: DataPipe does not simulate projector "
                       "lens distortion (the light's pattern lookup and the decoder's column-plane "
                       "triangulation assume a pinhole projector)",
                       "set D2 to zeros (after undistorting your projector's images, or for a projector "
                       "whose distortion is below the decoder's noise)")
    T_proj_cam = geometry.pose_matrix(cal["T"], cal["R"])           # X_proj = R X_cam + T
    T_cam_proj = np.linalg.inv(T_proj_cam)
    _check_projector_sees(path, Kc, (wc, hc), Kp, cal["size_proj"], T_cam_proj)
    T_bl = geometry.BLENDER_TO_OPENCV @ T_cam_proj @ geometry.BLENDER_TO_OPENCV   # Blender light in camera object
    size = max(wc, hc)
    camera = {"resolution": [wc, hc], "sensor_fit": "AUTO", "sensor_width": SENSOR_WIDTH_MM,
              "focal_length": float(Kc[0, 0] * SENSOR_WIDTH_MM / size),
              "intrinsics": [float(Kc[0, 0]), float(Kc[1, 1]), float(Kc[0, 2]), float(Kc[1, 2])],
              "distortion": None if lens.coefficients(cal["D_cam"]) is None else [float(v) for v in cal["D_cam"]]}
    wp, hp = cal["size_proj"]
    projector = {"resolution": [wp, hp], "sensor_width": SENSOR_WIDTH_MM,
                 "focal_length": float(Kp[0, 0] * SENSOR_WIDTH_MM / max(wp, hp)),
                 "intrinsics": [float(Kp[0, 0]), float(Kp[1, 1]), float(Kp[0, 2]), float(Kp[1, 2])],
                 "location": [float(v) for v in T_bl[:3, 3]],
                 "rotation": [float(v) for v in geometry.matrix_to_quat(T_bl[:3, :3])]}
    return {"camera": camera, "projector": projector}


def lit_depths(Kc, size_c, Kp, size_p, T_cam_proj, z) -> np.ndarray:
    """Which depths `z` (m) of the camera's central ray the projector's image lights (bool array)."""
    wc, hc = size_c
    wp, hp = size_p
    ray = np.linalg.solve(Kc, [(wc - 1) / 2.0, (hc - 1) / 2.0, 1.0])
    X = ray[None, :] * np.asarray(z, dtype=np.float64)[:, None]
    T_proj_cam = np.linalg.inv(T_cam_proj)
    Xp = X @ T_proj_cam[:3, :3].T + T_proj_cam[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = Xp @ np.asarray(Kp).T
        u, v = uv[:, 0] / uv[:, 2], uv[:, 1] / uv[:, 2]
    return (Xp[:, 2] > 0) & (u >= -0.5) & (u <= wp - 0.5) & (v >= -0.5) & (v <= hp - 0.5)


def _check_projector_sees(path, Kc, size_c, Kp, size_p, T_cam_proj) -> None:
    """The camera's central ray must cross the projector's image (in front of it) somewhere between
    FOCUS_SEARCH[0] and [1] m: otherwise no camera pixel is ever lit (R and T inverted, the wrong
    unit, or two unrelated calibrations). Whether it is lit at the run's working distance is
    `config_problems`' (it knows the camera poses)."""
    seen = lit_depths(Kc, size_c, Kp, size_p, T_cam_proj, np.geomspace(*FOCUS_SEARCH, 400))
    if not seen.any():
        raise _problem(path, f"the projector cannot see the camera's view: the centre of the camera image is lit "
                       f"by no projector pixel between {FOCUS_SEARCH[0]:g} and {FOCUS_SEARCH[1]:g} m (the projector "
                       f"sits at {np.round(T_cam_proj[:3, 3], 4).tolist()} m in the camera frame)",
                       "check R and T: stereoCalibrate's map camera-1 (the camera) points into camera-2 (the "
                       "projector) frame, X_proj = R X_cam + T (swap or invert them if you calibrated the other "
                       "way), and check `unit`")



# ------------------------------------------------------------------------------------------------
# the config fields a calibration fills (also usable without a file): validate()'s step

def config_problems(cfg) -> list[Problem]:
    """camera.intrinsics, camera.distortion, projector.intrinsics: shapes, focal lengths > 0, a
    distortion that folds the frame or needs too large a render."""
    out: list[Problem] = []
    c = cfg.camera
    K = None
    res_ok = len(c.resolution) == 2 and all(isinstance(v, int) and v >= 1 for v in c.resolution)
    for path, vals, sec in (("camera.intrinsics", c.intrinsics, c),
                            ("projector.intrinsics", cfg.projector.intrinsics, cfg.projector)):
        if vals is None:
            continue
        if len(vals) != 4 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in vals):
            out.append(Problem(path, f"needs 4 finite numbers [fx, fy, cx, cy], got {vals!r}",
                               "give [fx, fy, cx, cy] in pixels, or null for the focal length's centred pinhole"))
        elif vals[0] <= 0 or vals[1] <= 0:
            out.append(Problem(path, f"focal length <= 0 (fx {vals[0]:g}, fy {vals[1]:g})",
                               "give fx, fy > 0 in pixels (K[0][0], K[1][1] of your calibration)"))
        elif path == "camera.intrinsics":
            K = geometry.intrinsics_matrix(vals)
    if c.distortion is None:
        return out
    d = c.distortion
    if len(d) != 5 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in d):
        out.append(Problem("camera.distortion", f"needs 5 finite numbers (OpenCV k1 k2 p1 p2 k3), got {d!r}",
                           "give [k1, k2, p1, p2, k3] (zeros for the terms you do not have), or null"))
        return out
    if not res_ok or (c.intrinsics is not None and K is None):
        return out
    if K is None:
        if not (c.focal_length > 0 and c.sensor_width > 0 and c.sensor_fit in ("AUTO", "HORIZONTAL", "VERTICAL")):
            return out
        K = geometry.camera_intrinsics(c)
    problem = lens.fold_problem(K, d, tuple(c.resolution))
    if problem is None:
        problem = lens.render_area_problem(lens.render_grid(K, d, tuple(c.resolution)))
    if problem is not None:
        out.append(problem)
    return out


def working_distance_problems(cfg) -> list[Problem]:
    """A calibrated rig whose projector does not light the centre of the camera's image at the
    distances the run renders from (camera to drop zone): its structured-light depth would be empty
    there. Only for `device` = a calibration file with structured light on."""
    if not (is_calibration_path(cfg.device) and cfg.structured_light.enabled):
        return []
    try:
        Kc, Kp, T = geometry.camera_intrinsics(cfg.camera), geometry.projector_intrinsics(cfg), geometry.T_cam_proj(cfg)
        dists = camera_distances(cfg)
    except (ValueError, TypeError, ArithmeticError, np.linalg.LinAlgError):
        return []                                      # a broken field: its own rule names it
    lit = lit_depths(Kc, tuple(cfg.camera.resolution), Kp, tuple(cfg.projector.resolution), T, dists)
    if lit.all():
        return []
    z = np.geomspace(*FOCUS_SEARCH, 400)
    band = z[lit_depths(Kc, tuple(cfg.camera.resolution), Kp, tuple(cfg.projector.resolution), T, z)]
    where = f"between {band.min():.3g} and {band.max():.3g} m" if band.size else "at no distance"
    dark = sorted({round(float(d), 3) for d, ok in zip(dists, lit) if not ok})
    return [Problem("device", f"the projector of {cfg.device} does not light the centre of the camera's image "
                    f"at {dark} m from the bin (it lights it {where})",
                    "move the camera (camera.poses or camera.sampler.distance) into that range, or check the "
                    "file's R and T (X_proj = R X_cam + T)")]
