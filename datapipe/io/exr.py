"""OpenEXR read/write with the OpenEXR package. No bpy.

Our own files are single-part, float32, ZIP-compressed, with plain channel names. `read_exr` also
reads Blender's multilayer files: bpy 4.2 writes one part with every channel ("Image.R",
"Depth.V", ...), bpy 5.0 one part per pass; both come back as one flat {channel: array} dict.

A file that cannot be read whole (truncated by a full disk, garbled) is an OSError naming it: the
OpenEXR binding only prints a warning and returns no parts for a truncated file.
"""
from __future__ import annotations

import errno
import os
from pathlib import Path

import numpy as np
import OpenEXR

from .files import atomic_path, disk_full_error


def write_exr(path: str | os.PathLike, channels: dict[str, np.ndarray], *, half: bool = False) -> None:
    """Write 2-D arrays (same shape) as one EXR part, atomically (write then rename)."""
    path = Path(path)
    dtype = np.float16 if half else np.float32
    data = {}
    shape = None
    for name, arr in channels.items():
        arr = np.ascontiguousarray(arr, dtype=dtype)
        if arr.ndim != 2:
            raise ValueError(f"EXR channel {name!r} must be 2-D, got shape {arr.shape}")
        if shape is not None and arr.shape != shape:
            raise ValueError(f"EXR channel {name!r} has shape {arr.shape}, others {shape}")
        shape = arr.shape
        data[name] = arr
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path, path.with_name(path.name + ".tmp.exr")) as tmp:
        try:
            with OpenEXR.File(header, data) as f:
                f.write(str(tmp))
        except RuntimeError as e:          # the binding's I/O errors carry no errno
            raise disk_full_error(path, str(e)) from None


def unreadable(path: str | os.PathLike, detail: str) -> OSError:
    return OSError(errno.EIO, f"the EXR file is truncated or corrupt ({detail}; was the disk full?)", str(path))


def read_exr(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """All channels of all parts, as float32 2-D arrays, row 0 = top of the image."""
    path = str(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(errno.ENOENT, os.strerror(errno.ENOENT), path)
    out: dict[str, np.ndarray] = {}
    try:
        with OpenEXR.File(path, header_only=True) as f:
            declared = {c.name for part in f.parts for c in part.header.get("channels", [])}
        with OpenEXR.File(path, separate_channels=True) as f:
            for part in f.parts:
                for name, ch in part.channels.items():
                    out[name] = np.asarray(ch.pixels, dtype=np.float32)
    except RuntimeError as e:
        raise unreadable(path, str(e)) from None
    missing = declared - set(out)
    if missing or not out:
        raise unreadable(path, f"{len(missing)} of its {len(declared)} channels unreadable")
    return out


def read_depth(path) -> np.ndarray:
    return read_exr(path)["Z"]


def read_mask(path) -> np.ndarray:
    """Instance mask: pass index per pixel (0 = background) as int32."""
    return np.rint(read_exr(path)["Y"]).astype(np.int32)


COORDS_CHANNELS = ("R", "G", "B")     # x, y, z of BOP's object_coords/*.exr: OpenCV reads R, G, B as one
                                      # 3-channel image (in its B, G, R order); it reads X, Y, Z as grey


def read_object_coords(path) -> np.ndarray:
    """(H, W, 3) x, y, z of an object-coordinate EXR: channels R, G, B (BOP export since issue #30)
    or X, Y, Z (the native object_coords.exr, and BOP exports written before)."""
    ch = read_exr(path)
    names = COORDS_CHANNELS if all(c in ch for c in COORDS_CHANNELS) else ("X", "Y", "Z")
    missing = [c for c in names if c not in ch]
    if missing:
        raise OSError(errno.EIO, f"not an object-coordinate EXR: no channels R, G, B or X, Y, Z "
                      f"(it has {', '.join(sorted(ch))})", str(path))
    return np.stack([ch[c] for c in names], axis=-1)


def read_normals(path) -> np.ndarray:
    ch = read_exr(path)
    return np.stack([ch["X"], ch["Y"], ch["Z"]], axis=-1)
