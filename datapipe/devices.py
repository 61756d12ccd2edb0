"""Real-device sensor presets: structured-light scanners used in bin picking, as data. No bpy.

Each scanner is one JSON file in `datapipe/presets/devices/` (`<name>.json`): the vendor's published
figures with their sources, what had to be assumed (and why), the Config sections it fills
(`config`: camera, projector, structured_light at full resolution), the binning it offers and its
noise model (`sensor`: datapipe.sl.sensor.SensorModel fields, the full well calibrated so that the
simulated plane precision matches the data sheet, see `calibrate_full_well`).

A preset names a device at the top level and may bin the camera:

    {"device": "zivid2plus_m60", "binning": 2, "objects": [...], "camera": {"poses": [...]}}

`apply_device` fills the camera, projector and structured_light sections from the device before the
Config is built; every field the preset itself gives wins over the device's (a saved Config spells
every field out, so save -> load gives the same Config). `python -m datapipe sensors` lists the
devices, `validate` warns when the bin lies outside a device's working distance or field of view.
"""
from __future__ import annotations

import copy
import functools
import json
import math
from pathlib import Path

import numpy as np

from .errors import ConfigError, Problem

DEVICES_DIR = Path(__file__).resolve().parent / "presets" / "devices"
BINNING_MODES = ("subsample", "average")   # subsample: every k-th pixel (per-pixel noise unchanged);
                                           # average: k x k pixels summed (k^2 the signal, k x the read noise)
METRICS = {   # the vendors' own precision definitions (how tests/sl/test_sl_devices.py measures them)
    "point_precision": "1 sigma of the XYZ position of a point between consecutive captures (Zivid)",
    "temporal_noise": "1 sigma of Z over time on an 80%-albedo diffuse surface (Photoneo)",
    "z_repeatability": "1 sigma of a single pixel's Z over repeated captures of a ceramic plate (Mech-Mind)",
}


@functools.lru_cache(maxsize=1)
def _all() -> dict[str, dict]:
    return {p.stem: json.loads(p.read_text()) for p in sorted(DEVICES_DIR.glob("*.json"))}


def names() -> list[str]:
    return list(_all())


def device(name: str) -> dict:
    """The device preset `name` (a copy); ConfigError naming the known devices otherwise."""
    try:
        return copy.deepcopy(_all()[name])
    except (KeyError, TypeError):
        raise ConfigError(_unknown(name)) from None


def _unknown(name) -> Problem:
    return Problem("device", f"unknown device {name!r}", f"use one of {', '.join(names())} "
                   "(`python -m datapipe sensors` lists them)")


# ------------------------------------------------------------------------------------------------
# binning and the sensor model

def binning_factors(dev: dict) -> list[int]:
    return [int(k) for k in dev["binning"]["factors"]]


def sensor_name(name: str, binning: int = 1) -> str:
    """The datapipe.sl.sensor preset of `name` at `binning`: averaging binning changes the noise
    (`<name>_bin<k>`), subsampling does not (the full-resolution sensor)."""
    dev = _all()[name]
    if binning == 1 or dev["binning"]["mode"] == "subsample":
        return name
    return f"{name}_bin{binning}"


def sensor_fields(dev: dict, binning: int = 1) -> dict:
    """SensorModel keyword arguments of `dev` at `binning` (averaging: k^2 the electrons, k x the
    read noise of one pixel)."""
    s = {k: v for k, v in dev["sensor"].items() if not k.startswith("_")}
    if binning > 1 and dev["binning"]["mode"] == "average":
        k2 = binning * binning
        s = dict(s, full_well=s["full_well"] * k2, electrons_per_unit=s["electrons_per_unit"] * k2,
                 read_noise=s["read_noise"] * binning)
    return s


def sensor_presets() -> dict[str, dict]:
    """Every device's sensor at every binning it offers: {sensor preset name: SensorModel fields}."""
    out = {}
    for name, dev in _all().items():
        for k in binning_factors(dev):
            out.setdefault(sensor_name(name, k), sensor_fields(dev, k))
    return out


# ------------------------------------------------------------------------------------------------
# device -> Config sections

def config_sections(name: str, binning: int = 1) -> dict:
    """The camera, projector and structured_light sections `name` fills (camera binned by `binning`:
    resolution / k, same lens and sensor, so each pixel sees k x the angle)."""
    dev = device(name)
    out = dev["config"]
    w, h = out["camera"]["resolution"]
    out["camera"]["resolution"] = [w // binning, h // binning]
    out["structured_light"]["sensor"] = sensor_name(name, binning)
    return out


def _merge(base: dict, over: dict) -> dict:
    """`over` on top of `base`: nested dicts merged key by key, anything else replaced."""
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(base[k], v) if isinstance(v, dict) and isinstance(base.get(k), dict) else v
    return out


def apply_device(data: dict, problems: list[Problem]) -> dict:
    """A preset dict with its `device` filled in (the preset's own fields win); problems for an
    unknown device or a binning the device does not offer are appended, and `data` is returned
    without the fill."""
    name, binning = data.get("device"), data.get("binning", 1)
    if name is None:
        if binning not in (1, None):
            problems.append(Problem("binning", f"binning {binning!r} without a device",
                                    "give \"device\" (`python -m datapipe sensors`) or remove \"binning\""))
        return data
    problem = device_problem(name, binning)
    if problem is not None:
        problems.append(problem)
        return data
    return _merge(config_sections(name, int(binning)), data)


def device_problem(name, binning) -> Problem | None:
    """The problem with `device`/`binning` values, None when both are fine (None: no device)."""
    if name is None:
        return None if binning == 1 else Problem("binning", f"binning {binning!r} without a device",
                                                 "give \"device\" or set binning to 1")
    if not isinstance(name, str) or name not in _all():
        return _unknown(name)
    factors = binning_factors(_all()[name])
    if isinstance(binning, bool) or binning not in factors:
        return Problem("binning", f"{name} offers binning {factors}, got {binning!r}",
                       f"use one of {factors}")
    return None


# ------------------------------------------------------------------------------------------------
# geometry: field of view, working distance, the predicted plane precision

def _build_cfg(sections: dict):
    """A Config with only the device's sections (no objects: not a runnable preset)."""
    from .config import CameraConfig, Config, ProjectorConfig, StructuredLightConfig
    cfg = Config()
    cfg.camera = CameraConfig(**{k: v for k, v in sections["camera"].items()})
    cfg.projector = ProjectorConfig(**sections["projector"])
    cfg.structured_light = StructuredLightConfig(**sections["structured_light"])
    return cfg


def camera_K(cfg) -> np.ndarray:
    from .geometry import intrinsics_from_blender
    c = cfg.camera
    return intrinsics_from_blender(c.focal_length, c.sensor_width, int(c.resolution[0]), int(c.resolution[1]),
                                   c.sensor_fit)


def field_of_view_deg(cfg) -> tuple[float, float]:
    """The camera's full horizontal and vertical field of view (degrees)."""
    K = camera_K(cfg)
    w, h = cfg.camera.resolution
    return (2 * math.degrees(math.atan(w / 2 / K[0, 0])), 2 * math.degrees(math.atan(h / 2 / K[1, 1])))


def depth_slope(cfg, Z: float) -> float:
    """|dZ/dx| (m per projector pixel) on the camera's optical axis at depth Z, from the projector's
    pose and intrinsics (central differences of the exact projection)."""
    from .geometry import T_cam_proj, projector_intrinsics
    P = projector_intrinsics(cfg) @ np.linalg.inv(T_cam_proj(cfg))[:3]

    def col(z):
        x = P @ np.array([0.0, 0.0, z, 1.0])
        return x[0] / x[2]
    dz = 1e-4 * Z
    return abs(2 * dz / (col(Z + dz) - col(Z - dz)))


def predicted_precision(cfg, Z: float, full_well: float | None = None, read_noise: float | None = None,
                        adc_bits: int | None = None) -> float:
    """Depth sigma (m) of the centre pixel of a fronto-parallel Lambertian plane at depth Z, the
    noise propagation of docs/STRUCTURED_LIGHT.md ("Device presets: calibration"):

    auto exposure puts the fringe peaks A + B at AUTO_TARGET of the full well, the patterns are
    0.5 + 0.5 cos, so A = B = AUTO_TARGET * FW / 2 electrons; sigma_I^2 = A + read^2 + gain^2/12;
    sigma_phi = sqrt(2/N) sigma_I / B per frequency; the decoder's K^2 weights give
    sigma_x = W_p / (2 pi sqrt(sum K^2)) * sigma_phi projector pixels; sigma_Z = |dZ/dx| sigma_x.
    Sensor values default to the config's sensor preset."""
    from .sl.exposure import AUTO_TARGET
    from .sl.sensor import SensorModel
    sl = cfg.structured_light
    s = SensorModel.preset(sl.sensor)
    fw = s.full_well if full_well is None else full_well
    r = s.read_noise if read_noise is None else read_noise
    bits = s.adc_bits if adc_bits is None else adc_bits
    A = AUTO_TARGET * fw / 2
    gain = fw / (2 ** bits - 1)
    sigma_phi = math.sqrt(2.0 / sl.steps) * math.sqrt(A + r * r + gain * gain / 12) / A
    k = np.asarray(sl.periods, dtype=np.float64)
    sigma_x = cfg.projector.resolution[0] / (2 * math.pi * math.sqrt(float(np.sum(k * k)))) * sigma_phi
    return depth_slope(cfg, Z) * sigma_x


def calibrate_full_well(name: str) -> float:
    """The full well (e-) at which `predicted_precision` at the data sheet's distance equals the
    data sheet's figure, with the device's read noise and ADC (full resolution). What DataPipe does
    not model (the vendor's pattern engine, projector contrast and defocus, demosaicking) is folded
    into this one number: it is an *effective* full well, not the imager's."""
    from scipy.optimize import brentq
    dev = device(name)
    cfg, p = _build_cfg(config_sections(name)), dev["precision"]
    s = dev["sensor"]
    f = lambda fw: math.log(predicted_precision(cfg, p["distance"], fw, s["read_noise"], s["adc_bits"]) / p["value"])
    return float(brentq(f, 10.0, 1e8, rtol=1e-10))


def _bin_depths(cfg) -> list[tuple[str, float, float]]:
    """(which pose, depth of the bin's floor centre, depth of the drop zone's top centre) along the
    camera's optical axis, per camera pose (pool) or at the sampler's distance range (bin_view)."""
    from .geometry import camera_pose_from_config
    s, c = cfg.scene, cfg.camera
    (x, y, z), hz = s.drop_zone_loc, s.drop_zone_scale[2]
    if c.sampler.kind == "bin_view":
        lo, hi = min(c.sampler.distance), max(c.sampler.distance)
        return [("camera.sampler.distance", hi, lo - 2 * hz)]
    out = []
    for i, pose in enumerate(c.poses):
        T = np.linalg.inv(camera_pose_from_config(pose.location, pose.rotation))
        floor = T[:3, :3] @ [x, y, z - hz] + T[:3, 3]
        top = T[:3, :3] @ [x, y, z + hz] + T[:3, 3]
        out.append((f"camera.poses[{i}]", float(floor[2]), float(top[2])))
    return out


def _corners(cfg) -> np.ndarray:
    (x, y, z), (hx, hy, hz) = cfg.scene.drop_zone_loc, cfg.scene.drop_zone_scale
    return np.array([[x + sx * hx, y + sy * hy, z + sz * hz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])


def _outside(K, T_dev_world, size, pts) -> int:
    """How many world points fall outside a device's image (or behind it)."""
    pc = pts @ T_dev_world[:3, :3].T + T_dev_world[:3, 3]
    uv = pc @ K.T
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = uv[:, 0] / uv[:, 2], uv[:, 1] / uv[:, 2]
    w, h = size
    inside = (pc[:, 2] > 0) & (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5)
    return int(np.sum(~inside))


def device_warnings(cfg) -> list[str]:
    """Lines for `validate`: the bin outside the device's working distance, or drop-zone corners
    outside the camera's or the projector's image (pool poses; bin_view at its nearest distance,
    looking straight down), one line per kind naming every pose it concerns. Empty without a device."""
    if cfg.device is None or cfg.device not in _all():
        return []
    dev = _all()[cfg.device]
    lo, hi = dev["working_distance"]["range"]
    label = dev["label"]
    depths = _bin_depths(cfg)
    far = [(w, f) for w, f, _ in depths if f > hi]
    near = [(w, t) for w, _, t in depths if t < lo]
    out = []
    if far:
        out.append(f"{_poses(far)}: the bin floor is up to {max(f for _, f in far):.3f} m from the camera, beyond the "
                   f"{label}'s working distance ({lo:g}-{hi:g} m), where the real scanner is outside its "
                   "specification (DataPipe does not model its defocus) (fix: move the camera closer)")
    if near:
        out.append(f"{_poses(near)}: the top of the drop zone is {min(t for _, t in near):.3f} m from the camera, "
                   f"nearer than the {label}'s working distance ({lo:g}-{hi:g} m) (fix: move the camera away)")
    outside = _outside_view(cfg)
    if outside:
        n, what = max(v[0] for _, v in outside), " and ".join(sorted({w for _, v in outside for w in v[1]}))
        out.append(f"{_poses(outside)}: up to {n} of the drop zone's 8 corners lie outside {what} (the {label}'s "
                   "field of view): parts there get no structured-light depth (fix: move the camera away or "
                   "shrink scene.drop_zone_scale)")
    return out


def _poses(items) -> str:
    """'camera.poses[0, 2]' (or the sampler's field) for [(where, value)] items."""
    idx = [w[len("camera.poses["):-1] for w, _ in items if w.startswith("camera.poses[")]
    return f"camera.poses[{', '.join(idx)}]" if idx else items[0][0]


def _outside_view(cfg) -> list[tuple[str, tuple[int, list[str]]]]:
    """[(pose, (corners outside, which images))] for the poses that lose a drop-zone corner."""
    from .camera_sampler import look_at_pose
    from .geometry import T_cam_proj, camera_pose_from_config, projector_intrinsics
    c = cfg.camera
    if c.sampler.kind == "bin_view":
        floor = np.asarray(cfg.scene.drop_zone_loc, float) - [0, 0, cfg.scene.drop_zone_scale[2]]
        poses = [("camera.sampler.distance", look_at_pose(floor, float(min(c.sampler.distance)), 0.0, 0.0, 0.0))]
    else:
        poses = [(f"camera.poses[{i}]", camera_pose_from_config(p.location, p.rotation)) for i, p in enumerate(c.poses)]
    corners = _corners(cfg)
    K, Kp, Tcp = camera_K(cfg), projector_intrinsics(cfg), T_cam_proj(cfg)
    out = []
    for where, T_world_cam in poses:
        n_cam = _outside(K, np.linalg.inv(T_world_cam), c.resolution, corners)
        n_proj = _outside(Kp, np.linalg.inv(T_world_cam @ Tcp), cfg.projector.resolution, corners)
        if n_cam or n_proj:
            which = [w for w, n in (("the camera's image", n_cam), ("the projector's image", n_proj)) if n]
            out.append((where, (max(n_cam, n_proj), which)))
    return out


# ------------------------------------------------------------------------------------------------
# the listing of `python -m datapipe sensors`

def table() -> str:
    """One line per device: name, label, resolution (binned), field of view (degrees, and mm at the
    optimal distance), working distance, the data sheet precision and where it comes from."""
    rows = [("name", "device", "resolution (binned)", "FOV deg (mm @ optimal)", "working distance m",
             "precision (data sheet)", "source")]
    for name, dev in _all().items():
        cfg = _build_cfg(config_sections(name))
        w, h = cfg.camera.resolution
        bins = ", ".join(f"{w // k}x{h // k}" for k in binning_factors(dev) if k > 1)
        fh, fv = field_of_view_deg(cfg)
        wd, p = dev["working_distance"], dev["precision"]
        mm = [2e3 * wd["optimal"] * math.tan(math.radians(a / 2)) for a in (fh, fv)]
        rows.append((name, dev["label"], f"{w}x{h} ({bins})", f"{fh:.1f} x {fv:.1f} ({mm[0]:.0f} x {mm[1]:.0f})",
                     f"{wd['range'][0]:g}-{wd['range'][1]:g} (optimal {wd['optimal']:g})",
                     f"{p['value'] * 1e6:.0f} um {p['metric']} @ {p['distance']:g} m",
                     f"{p['source']}; {dev['sources'][0]['url']}"))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]) - 1)]
    return "\n".join("  ".join(c.ljust(wd) for c, wd in zip(r, widths)) + "  " + r[-1] for r in rows)
