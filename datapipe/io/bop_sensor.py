"""The scanner's name in a BOP-Industrial export: gray_{sensor}/, depth_{sensor}/, scene_camera_{sensor}.json ...

bop_toolkit names the sensors of its industrial datasets after the device's maker or product
(thodan/bop_toolkit@cea62d651c7e395b2e1962b9749e4e89693c6ac4:bop_toolkit_lib/dataset_params.py,
xyzibd: `p["im_modalities"] = {"photoneo": ["gray", "depth"], "xyz": ["gray", "depth"], "realsense": ...}`).
DataPipe does the same: the first word of the device preset's vendor, lowercased, letters and
digits only ("Zivid" -> "zivid", "Photoneo (Zebra Technologies)" -> "photoneo", "Mech-Mind" ->
"mechmind"); "sl" for a custom rig (no `device`); `output.bop_sensor` (or `bop --sensor`) overrides it.

A name must be usable inside the toolkit's path templates: folder `{modality}_{sensor}` and file
`scene_gt_{sensor}.json` on every file system, so lowercase ASCII letters and digits only (an
underscore would make `mask_visib_{sensor}` ambiguous to read back, a path separator or dot would
leave the chunk folder), 1 to 32 characters, and not a BOP modality word.
"""
from __future__ import annotations

import re

from ..errors import DataPipeError

CUSTOM_RIG = "sl"
MAX_LEN = 32
_NAME = re.compile(r"^[a-z0-9]{1,%d}$" % MAX_LEN)
RESERVED = ("rgb", "gray", "depth", "mask", "visib", "coco", "info", "gt", "camera")   # BOP's own words


def sensor_name_problem(name) -> tuple[str, str] | None:
    """(what is wrong, the fix) for a sensor name BOP paths cannot hold; None when it is fine."""
    fix = "use 1 to 32 lowercase letters and digits, e.g. \"zivid\", \"photoneo\" or \"sl\""
    if not isinstance(name, str):
        return f"must be a string, got {type(name).__name__}", fix
    if not _NAME.match(name):
        shown = name if len(name) <= 40 else name[:37] + "..."
        return f"{shown!r} cannot be part of a BOP folder name (gray_NAME/, scene_gt_NAME.json)", fix
    if name in RESERVED:
        return f"{name!r} is one of BOP's own words ({', '.join(RESERVED)})", fix
    return None


def check_sensor_name(name, field: str = "output.bop_sensor") -> str:
    bad = sensor_name_problem(name)
    if bad:
        raise DataPipeError(f"{field}: {bad[0]} (fix: {bad[1]})")
    return name


def vendor_name(vendor: str) -> str:
    """First word of a vendor's name, lowercased, letters and digits only."""
    word = re.split(r"[\s(]", vendor.strip(), maxsplit=1)[0]
    return re.sub(r"[^a-z0-9]", "", word.lower())[:MAX_LEN] or CUSTOM_RIG


def sensor_for_config(cfg: dict | None) -> str:
    """The sensor name of a run from its config dict (run.json's "config"): output.bop_sensor, else
    the device's vendor, else "sl" (no device, or a calibration file of your own rig)."""
    cfg = cfg if isinstance(cfg, dict) else {}
    given = (cfg.get("output") or {}).get("bop_sensor") if isinstance(cfg.get("output"), dict) else None
    if given is not None:
        return check_sensor_name(given)
    dev = cfg.get("device")
    if isinstance(dev, str):
        from ..devices import device, is_calibration_path
        if is_calibration_path(dev):            # a calibration file of the user's own rig: a custom rig
            return CUSTOM_RIG
        return vendor_name(device(dev)["vendor"])
    return CUSTOM_RIG


def sensor_warnings(cfg) -> list[str]:
    """A BOP run with structured light but without the scanner's grey image: its sensor folders lack gray_S/."""
    if "bop" in cfg.output.formats and cfg.structured_light.enabled and "sl_gray" not in cfg.render.outputs:
        return ["render.outputs: the BOP output's scanner sensor gets no gray_NAME/ images without 'sl_gray' "
                "(fix: add 'sl_gray' to render.outputs for a complete BOP-Industrial sensor)"]
    return []
