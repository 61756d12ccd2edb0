"""OpenEXR read/write with the OpenEXR package. No bpy.

Our own files are single-part, float32, ZIP-compressed, with plain channel names. `read_exr` also
reads Blender's multilayer files: bpy 4.2 writes one part with every channel ("Image.R",
"Depth.V", ...), bpy 5.0 one part per pass; both come back as one flat {channel: array} dict.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import OpenEXR


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
    tmp = path.with_name(path.name + ".tmp.exr")
    with OpenEXR.File(header, data) as f:
        f.write(str(tmp))
    os.replace(tmp, path)


def read_exr(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """All channels of all parts, as float32 2-D arrays, row 0 = top of the image."""
    out: dict[str, np.ndarray] = {}
    with OpenEXR.File(str(path), separate_channels=True) as f:
        for part in f.parts:
            for name, ch in part.channels.items():
                out[name] = np.asarray(ch.pixels, dtype=np.float32)
    return out


def read_depth(path) -> np.ndarray:
    return read_exr(path)["Z"]


def read_mask(path) -> np.ndarray:
    """Instance mask: pass index per pixel (0 = background) as int32."""
    return np.rint(read_exr(path)["Y"]).astype(np.int32)


def read_normals(path) -> np.ndarray:
    ch = read_exr(path)
    return np.stack([ch["X"], ch["Y"], ch["Z"]], axis=-1)
