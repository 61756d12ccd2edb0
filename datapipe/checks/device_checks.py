"""What a real-device preset (datapipe.devices) means physically. No bpy.

- `field_of_view_deg`, `depth_slope`: from the Config sections a device fills;
- `predicted_precision`: the plane precision the noise propagation of docs/STRUCTURED_LIGHT.md
  ("Device presets: calibration") predicts, and `calibrate_full_well`: the effective full well that
  makes it the published figure (stored as the `sensor.full_well` figure of each calibrated
  preset; tests/sl/test_sl_devices.py checks both against the simulated scanner);
- `device_warnings`: validate's lines when the bin lies outside a device's working distance or
  field of view;
- `table`: what `python -m datapipe sensors` prints.
"""
from __future__ import annotations

import math

import numpy as np

from ..draws.camera_sampler import look_at_pose
from ..config import CameraConfig, Config, ProjectorConfig, StructuredLightConfig
from ..devices import binning_factors, config_sections, device, names
from ..geometry import T_cam_proj, camera_pose_from_config, camera_intrinsics, projector_intrinsics
from ..sl.exposure import AUTO_TARGET
from ..sl.sensor import SensorModel


def _build_cfg(sections: dict):
    """A Config with only the device's sections (no objects: not a runnable preset)."""
    cfg = Config()
    cfg.camera = CameraConfig(**sections["camera"])
    cfg.projector = ProjectorConfig(**sections["projector"])
    cfg.structured_light = StructuredLightConfig(**sections["structured_light"])
    return cfg


def camera_K(cfg) -> np.ndarray:
    """The camera's K (geometry.camera_intrinsics: a calibration's intrinsics when given)."""
    return camera_intrinsics(cfg.camera)


def field_of_view_deg(cfg) -> tuple[float, float]:
    """The camera's full horizontal and vertical field of view (degrees)."""
    K = camera_K(cfg)
    w, h = cfg.camera.resolution
    return (2 * math.degrees(math.atan(w / 2 / K[0, 0])), 2 * math.degrees(math.atan(h / 2 / K[1, 1])))


def depth_slope(cfg, Z: float) -> float:
    """|dZ/dx| (m per projector pixel) on the camera's optical axis at depth Z, from the projector's
    pose and intrinsics (central differences of the exact projection)."""
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
    """The full well (e-) at which `predicted_precision` at the published figure's distance equals
    the published figure, with the device's read noise and ADC (full resolution). What DataPipe
    does not model (the vendor's pattern engine and number of images, projector contrast and
    defocus, demosaicking) is folded into this one number: it is an *effective* full well, not the
    imager's. Only for a device whose noise model is calibrated (`noise_model.calibrated_to`)."""
    dev = device(name)
    p = dev["precision"]
    if not p["published"] or "calibrated_to" not in dev["noise_model"]:
        raise ValueError(f"{name}: no published precision figure to calibrate against "
                         f"(its sensor is {dev['noise_model'].get('sibling')}'s)")
    cfg = _build_cfg(config_sections(name))
    s = dev["sensor"]
    f = lambda fw: math.log(predicted_precision(cfg, p["distance"], fw, s["read_noise"], s["adc_bits"]) / p["value"])
    from scipy.optimize import brentq  # here: scipy.optimize costs ~0.3 s to import, and only calibration needs it
    return float(brentq(f, 10.0, 1e8, rtol=1e-10))


def _bin_depths(cfg) -> list[tuple[str, float, float]]:
    """(which pose, depth of the bin's floor centre, depth of the drop zone's top centre) along the
    camera's optical axis, per camera pose (pool) or at the sampler's distance range (bin_view)."""
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
    if cfg.device not in names():
        return []
    dev = device(cfg.device)
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
    changed = _changed_fields(cfg)
    if changed:
        out.append(f"{', '.join(changed)}: differ from the {label}'s, so the simulated scanner is not the {label} "
                   "its data sheet describes (fix: remove these fields from the preset to use the device's)")
    outside = _outside_view(cfg)
    if outside:
        n, what = max(v[0] for _, v in outside), " and ".join(sorted({w for _, v in outside for w in v[1]}))
        out.append(f"{_poses(outside)}: up to {n} of the drop zone's 8 corners lie outside {what} (the {label}'s "
                   "field of view): parts there get no structured-light depth (fix: move the camera away or "
                   "shrink scene.drop_zone_scale)")
    return out


DEVICE_FIELDS = {"camera": ("focal_length", "sensor_width", "sensor_fit", "resolution"),
                 "projector": ("focal_length", "sensor_width", "resolution", "location", "rotation"),
                 "structured_light": ("sensor",)}    # what makes the device: its optics and noise


def _changed_fields(cfg) -> list[str]:
    """The device-defining fields (DEVICE_FIELDS) a preset set to other values than its device's."""
    fill = config_sections(cfg.device, cfg.binning)
    out = []
    for section, keys in DEVICE_FIELDS.items():
        for k in keys:
            want, got = fill[section][k], getattr(getattr(cfg, section), k)
            same = got == want if isinstance(want, str) else np.allclose(got, want, rtol=1e-6, atol=0) \
                if np.shape(got) == np.shape(want) else False
            if not same:
                out.append(f"{section}.{k}")
    return out


def _poses(items) -> str:
    """'camera.poses[0, 2]' (or the sampler's field) for [(where, value)] items."""
    idx = [w[len("camera.poses["):-1] for w, _ in items if w.startswith("camera.poses[")]
    return f"camera.poses[{', '.join(idx)}]" if idx else items[0][0]


def _outside_view(cfg) -> list[tuple[str, tuple[int, list[str]]]]:
    """[(pose, (corners outside, which images))] for the poses that lose a drop-zone corner."""
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
    optimal distance), working distance, the published precision (or "not published" and what the
    noise model predicts there) and where the precision figure comes from."""
    rows = [("name", "device", "resolution (binned)", "FOV deg (mm @ optimal)", "working distance m",
             "precision (published)", "precision source")]
    for name in names():
        dev = device(name)
        cfg = _build_cfg(config_sections(name))
        w, h = cfg.camera.resolution
        bins = ", ".join(f"{w // k}x{h // k}" for k in binning_factors(dev) if k > 1)
        fh, fv = field_of_view_deg(cfg)
        wd, p = dev["working_distance"], dev["precision"]
        mm = [2e3 * wd["optimal"] * math.tan(math.radians(a / 2)) for a in (fh, fv)]
        if p["published"]:
            prec = f"{p['value'] * 1e6:.0f} um {p['metric']} @ {p['distance']:g} m"
        else:
            model = predicted_precision(cfg, p["distance"])
            prec = f"not published (model: {model * 1e6:.0f} um @ {p['distance']:g} m, {dev['noise_model']['sibling']}'s sensor)"
        rows.append((name, dev["label"], f"{w}x{h} ({bins})", f"{fh:.1f} x {fv:.1f} ({mm[0]:.0f} x {mm[1]:.0f})",
                     f"{wd['range'][0]:g}-{wd['range'][1]:g} (optimal {wd['optimal']:g})", prec, p["source"]))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]) - 1)]
    return "\n".join("  ".join(c.ljust(wd) for c, wd in zip(r, widths)) + "  " + r[-1] for r in rows)
