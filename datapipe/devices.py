"""Real-device sensor presets: structured-light scanners used in bin picking, as data. No bpy.

Each scanner is one JSON file in `datapipe/presets/devices/` (`<name>.json`, docs/DEVICES.md lists
them all). Every number in it is a *figure*: `figures[name] = {"value", "unit", "source", "quote"}`
(`source` names an entry of the file's `sources`: a URL or `owner/repo@<40-hex commit>:path`, and
`quote` is the phrase the value comes from) or `{"value", "unit", "assumed": why}` when no public
source gives it. `tests/test_devices.py` walks each file and fails on any number outside a figure's
`value`, or a figure with neither a quoted source nor a stated assumption.

From the figures this module builds what the rest of DataPipe uses (`device(name)`): the Config
sections the device fills (`config`: camera, projector, structured_light at full resolution), its
working distance and precision in metres, the binning it offers and its noise model (`sensor`:
datapipe.sl.sensor.SensorModel fields). The noise model is either calibrated so that the simulated
plane precision matches the published figure (`noise_model.calibrated_to`: the effective full well
is a figure, solved by `datapipe.checks.device_checks.calibrate_full_well`), or, where a vendor
publishes no precision figure, a sibling device's sensor (`noise_model.sibling`, with the reason).

Geometry conventions of the figures (the vendors' own): the projector's pose is given in the camera's
optical frame (OpenCV: x right, y down, z forward) either as Zivid models it (`projector.translation`
in mm and `projector.rotation` as an axis-angle vector in rad: the projector frame's pose in the
camera frame, X_cam = R X_proj + t) or as Photoneo describes its scanners (`baseline` between the two
optical centres, `camera.tilt` and `projector.tilt` towards each other, `projector.side`: +1 on the
camera's +x side, -1 on its -x side). `_projector_pose` turns both into that pose, and
`_blender_pose` into DataPipe's projector location/rotation (Blender's camera axes: x right, y up,
z backwards, geometry.T_cam_proj's inverse convention).

A preset names a device at the top level and may bin the camera:

    {"device": "zivid2plus_m60", "binning": 2, "objects": [...], "camera": {"poses": [...]}}

`apply_device` fills the camera, projector and structured_light sections from the device before the
Config is built; every field the preset itself gives wins over the device's (a saved Config spells
every field out, so save -> load gives the same Config).

This module is data only (config/ and sl/sensor.py build on it); what a device means physically
(field of view, predicted precision, calibration, validate's warnings, `python -m datapipe sensors`)
is `datapipe.checks.device_checks`.
"""
from __future__ import annotations

import copy
import functools
import json
import math
import os
from pathlib import Path

from .errors import ConfigError, Problem

DEVICES_DIR = Path(__file__).resolve().parent / "presets" / "devices"
CALIBRATION_SUFFIXES = (".yml", ".yaml", ".json", ".xml")   # a `device` ending so names a calibration file
AUTO_SHARE = 0.8     # radiance 1.0 -> 80% of the full well (as the 'industrial' sensor): electrons_per_unit


@functools.lru_cache(maxsize=1)
def _raw() -> dict[str, dict]:
    """The JSON files as written (figures with their sources), by device name."""
    return {p.stem: json.loads(p.read_text()) for p in sorted(DEVICES_DIR.glob("*.json"))}


@functools.lru_cache(maxsize=1)
def _all() -> dict[str, dict]:
    raw = _raw()
    return {name: _build(name, raw) for name in raw}


def names() -> list[str]:
    return list(_all())


def raw(name: str) -> dict:
    """The device's JSON as written (a copy): its sources and figures."""
    device(name)                                 # the same refusal for an unknown name
    return copy.deepcopy(_raw()[name])


def device(name: str) -> dict:
    """The device preset `name` (a copy): its figures and what DataPipe builds from them (config,
    sensor, working_distance and precision in metres, binning); ConfigError naming the known devices
    otherwise."""
    try:
        return copy.deepcopy(_all()[name])
    except (KeyError, TypeError):
        raise ConfigError(_unknown(name)) from None


def is_calibration_path(device) -> bool:
    """A `device` value that names a file (a path separator or a calibration file suffix) rather than
    a preset of this module: the user's own rig, read by datapipe/config/calibration.py."""
    return isinstance(device, str) and (any(s in device for s in ("/", os.sep))
                                        or device.lower().endswith(CALIBRATION_SUFFIXES))


def _unknown(name) -> Problem:
    shown = repr(name) if isinstance(name, str) and len(name) <= 60 else f"a {type(name).__name__}" \
        if not isinstance(name, str) else repr(name[:57] + "...")
    return Problem("device", f"unknown device {shown}", f"use one of {', '.join(names())} "
                   "(`python -m datapipe sensors` lists them)")


# ------------------------------------------------------------------------------------------------
# figures -> what DataPipe uses

def _rotation(aa) -> list[list[float]]:
    """Rodrigues: the 3x3 rotation of an axis-angle vector (rad)."""
    th = math.sqrt(sum(a * a for a in aa))
    if th == 0.0:
        return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    x, y, z = (a / th for a in aa)
    c, s, C = math.cos(th), math.sin(th), 1.0 - math.cos(th)
    return [[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
            [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
            [z * x * C - y * s, z * y * C + x * s, c + z * z * C]]


def _projector_pose(f: dict) -> tuple[list[float], list[float]]:
    """(t in m, axis-angle in rad): the projector frame's pose in the camera's optical (OpenCV)
    frame, from Zivid's form (translation + rotation) or Photoneo's (baseline and tilts).

    Photoneo's form: the housing axis joins the two optical centres; the camera is turned by
    camera.tilt (a) towards the projector, the projector by projector.tilt (p) towards the camera
    (both about y). In the camera frame the projector then sits at x = side * b * cos(a), y = 0,
    z = b * sin(a) (ahead of the camera, which toes in towards it), turned by -side * (a + p) about y."""
    if "projector.translation" in f:
        return [v / 1000.0 for v in f["projector.translation"]["value"]], list(f["projector.rotation"]["value"])
    b = f["baseline"]["value"] / 1000.0
    a, p = (math.radians(f[k]["value"]) for k in ("camera.tilt", "projector.tilt"))
    side = f["projector.side"]["value"]
    return [side * b * math.cos(a), 0.0, b * math.sin(a)], [0.0, -side * (a + p), 0.0]


def _blender_pose(t, aa) -> tuple[list[float], list[float]]:
    """DataPipe's projector location and rotation (XYZ Euler, rad) in the camera object's Blender
    axes for the pose (t, aa) in the camera's OpenCV frame: geometry.T_cam_proj is
    F @ T_blender @ F with F = diag(1, -1, -1), and F is its own inverse, so T_blender = F T F:
    the location flips y and z, the rotation R_b = F R F (the same angle about the axis F aa)."""
    R = _rotation([aa[0], -aa[1], -aa[2]])
    # R = Rz(c) Ry(b) Rx(a) (geometry.euler_xyz_to_matrix): b = -asin(R[2][0])
    b = -math.asin(max(-1.0, min(1.0, R[2][0])))
    a = math.atan2(R[2][1], R[2][2])
    c = math.atan2(R[1][0], R[0][0])
    return [round(t[0], 9), round(-t[1], 9) + 0.0, round(-t[2], 9) + 0.0], [round(a, 9) + 0.0, round(b, 9) + 0.0,
                                                                          round(c, 9) + 0.0]


def _value(f: dict, key: str):
    return f[key]["value"]


def _build(name: str, raw_all: dict) -> dict:
    """The device as the rest of DataPipe uses it, from its figures (see the module docstring)."""
    r = raw_all[name]
    f = r["figures"]
    W, H = _value(f, "camera.resolution")
    pitch = _value(f, "camera.pixel_pitch") / 1000.0                     # mm
    camera = {"focal_length": round(_value(f, "camera.focal_px") * pitch, 6), "sensor_width": round(W * pitch, 6),
              "sensor_fit": "AUTO", "resolution": [W, H]}
    Wp, Hp = _value(f, "projector.resolution")
    ppitch = _value(f, "projector.pixel_pitch") / 1000.0
    if "projector.focal_px" in f:
        fp = _value(f, "projector.focal_px")
    else:                                   # a field of view (deg): the focal length across its width
        fp = Wp / 2 / math.tan(math.radians(_value(f, "projector.field")[0]) / 2)
    location, rotation = _blender_pose(*_projector_pose(f))
    projector = {"focal_length": round(fp * ppitch, 6), "sensor_width": round(Wp * ppitch, 6), "resolution": [Wp, Hp],
                 "location": location, "rotation": rotation}
    s = r["settings"]
    sl = {"enabled": True, "periods": _value(f, "patterns.periods"), "steps": _value(f, "patterns.steps"),
          "unwrap": s["unwrap"], "exposure": s["exposure"], "hdr": s["hdr"], "reflection_filter": s["reflection_filter"]}
    lo, hi = (v / 1000.0 for v in _value(f, "working_distance"))
    optimal = _value(f, "optimal_distance") / 1000.0
    published = "precision.value" in f
    p = {"metric": r["precision_metric"], "published": published,
         "value": _value(f, "precision.value") / 1000.0 if published else None,
         "distance": _value(f, "precision.distance") / 1000.0 if published else optimal,
         "target_albedo": _value(f, "precision.target_albedo"),
         "source": _precision_source(r)}
    nm = r["noise_model"]
    if "sibling" in nm:
        if nm["sibling"] not in raw_all or "sibling" in raw_all[nm["sibling"]]["noise_model"]:
            raise ValueError(f"{name}: noise_model.sibling must name a device with its own calibrated sensor")
        sf = raw_all[nm["sibling"]]["figures"]
    else:
        sf = f
    fw = _value(sf, "sensor.full_well")
    sensor = {"electrons_per_unit": round(AUTO_SHARE * fw, 3), "full_well": fw, "read_noise": _value(sf, "sensor.read_noise"),
              "adc_bits": _value(sf, "sensor.adc_bits"), "output": "uint16"}
    return {"label": r["label"], "vendor": r["vendor"], "principle": r["principle"], "sources": r["sources"],
            "figures": f, "assumptions": r.get("assumptions", []), "noise_model": nm,
            "working_distance": {"range": [lo, hi], "optimal": optimal}, "precision": p,
            "binning": {"factors": list(_value(f, "binning.factors")), "mode": r["binning_mode"]["mode"]},
            "sensor": sensor,
            "config": {"camera": camera, "projector": projector, "structured_light": sl}}


def _precision_source(r: dict) -> str:
    """Where the precision figure comes from, in a few words (its `short`) and its source, or "not
    published"."""
    f = r["figures"]
    if "precision.value" not in f:
        return "not published"
    fig = f["precision.value"]
    return fig["short"] + (f": {r['sources'][fig['source']]['ref']}" if "source" in fig else "")


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
    """A preset dict with its `device` filled in (the preset's own fields win). An unknown device, or
    a binning the device does not offer (or without a device), is appended to `problems` and `data`
    comes back without the fill."""
    name, binning = data.get("device"), data.get("binning", 1)
    problem = device_problem(name, binning)
    if problem is not None:
        problems.append(problem)
    if problem is not None or name is None:
        return data
    return _merge(config_sections(name, int(binning)), data)


def device_problem(name, binning) -> Problem | None:
    """The problem with `device`/`binning` values, None when both are fine (None: no device)."""
    if name is None:
        return None if binning == 1 else Problem("binning", f"binning {binning!r} without a device",
                                                 "give \"device\" (`python -m datapipe sensors`) or set "
                                                 "binning to 1")
    if not isinstance(name, str) or name not in _all():
        return _unknown(name)
    factors = binning_factors(_all()[name])
    if isinstance(binning, bool) or binning not in factors:
        return Problem("binning", f"{name} offers binning {factors}, got {binning!r}",
                       f"use one of {factors}")
    return None
