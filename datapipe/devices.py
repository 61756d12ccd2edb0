"""Real-device sensor presets: structured-light scanners used in bin picking, as data. No bpy.

Each scanner is one JSON file in `datapipe/presets/devices/` (`<name>.json`): the vendor's published
figures with their sources, what had to be assumed (and why), the Config sections it fills
(`config`: camera, projector, structured_light at full resolution), the binning it offers and its
noise model (`sensor`: datapipe.sl.sensor.SensorModel fields, the full well calibrated so that the
simulated plane precision matches the data sheet: `datapipe.checks.device_checks.calibrate_full_well`).

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
from pathlib import Path

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
    shown = repr(name) if isinstance(name, str) and len(name) <= 60 else f"a {type(name).__name__}" \
        if not isinstance(name, str) else repr(name[:57] + "...")
    return Problem("device", f"unknown device {shown}", f"use one of {', '.join(names())} "
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
