"""Atomic writes and JSON readers. Every file is written to a temporary name and renamed, so a crash
leaves either the old or the new file, never half of one."""
from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import DataPipeError


def _tmp(path: Path) -> Path:
    return path.with_name(path.name + ".tmp")


def write_text_atomic(path: str | os.PathLike, text: str, *, fsync: bool = False) -> None:
    path = Path(path)
    tmp = _tmp(path)
    with open(tmp, "w") as f:
        f.write(text)
        if fsync:
            f.flush()
            os.fsync(f.fileno())
    os.replace(tmp, path)


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    path = Path(path)
    tmp = _tmp(path)
    tmp.write_bytes(data)
    os.replace(tmp, path)


def copy_atomic(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    dst = Path(dst)
    shutil.copyfile(src, _tmp(dst))
    os.replace(_tmp(dst), dst)


def _plain(obj: Any):
    """numpy -> lists/floats so json can write it."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (np.floating, np.integer, np.bool_)):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def write_json_atomic(path: str | os.PathLike, data: Any) -> None:
    """JSON with one-space indent (numpy arrays and Paths allowed), atomically."""
    write_text_atomic(path, json.dumps(data, indent=1, default=_plain) + "\n")


def imwrite_atomic(path: str | os.PathLike, img: np.ndarray, params: list[int] | None = None) -> Path:
    """cv2.imwrite through a temporary file with the same extension (cv2 picks the codec by it);
    `params` as cv2.imwrite's (e.g. [cv2.IMWRITE_JPEG_QUALITY, 95])."""
    import cv2

    path = Path(path)
    tmp = path.with_name(path.stem + ".tmp" + path.suffix)
    if not cv2.imwrite(str(tmp), img, params or []):
        raise DataPipeError(f"could not write {path} (check the output folder)")
    os.replace(tmp, path)
    return path


def read_json(path: str | os.PathLike) -> Any:
    with open(path) as f:
        return json.load(f)


def read_json_or_empty(path: str | os.PathLike) -> dict:
    """{} for a missing file; a clear error for a broken one (a file this run must not overwrite blindly)."""
    try:
        return read_json(path)
    except FileNotFoundError:
        return {}
    except json.JSONDecodeError as e:
        raise DataPipeError(f"{path} is not valid JSON ({e}); delete it (or its folder) and write it again") from None


def json_lines_text(data: Any, *, compact: bool = False) -> str:
    """bop_toolkit's JSON layout: a dict keyed by integers gets one entry per line, keys sorted
    numerically; anything else sorted keys with indent 2; compact = no whitespace (COCO files)."""
    if compact:
        return json.dumps(data, separators=(",", ":")) + "\n"
    if isinstance(data, dict) and data and all(str(k).lstrip("-").isdigit() for k in data):
        keys = sorted(data, key=lambda k: int(k))
        body = ",\n".join(f'  "{int(k)}": {json.dumps(data[k], sort_keys=True)}' for k in keys)
        return "{\n" + body + "\n}\n"
    return json.dumps(data, indent=2, sort_keys=True) + "\n"


def write_json_lines_atomic(path: str | os.PathLike, data: Any, *, compact: bool = False) -> None:
    """`json_lines_text`, written atomically and flushed to disk (datasets others copy right away)."""
    write_text_atomic(path, json_lines_text(data, compact=compact), fsync=True)
