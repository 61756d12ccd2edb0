"""Atomic writes and JSON readers. Every file is written to a temporary name and renamed, so a crash
leaves either the old or the new file, never half of one. A failed write (disk full, permission)
removes its temporary file and raises an OSError that names the file it was writing.

Inside a run's output folder the writes go through the folder's opened handle instead of paths
(datapipe/io/guard.py): no link is followed, and each file is recorded in the run's manifest."""
from __future__ import annotations

import errno
import json
import os
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from ..errors import DataPipeError
from . import guard


def _tmp(path: Path) -> Path:
    return path.with_name(path.name + ".tmp")


def named_os_error(e: OSError, path: str | os.PathLike) -> OSError:
    """`e` naming `path` (a write() or close() that fails for a full disk carries no file name)."""
    return OSError(e.errno, e.strerror or str(e), str(path))


def disk_full_error(path: str | os.PathLike, detail: str) -> OSError:
    """An OSError for a writer that reports failure without an errno (OpenCV returns False, OpenEXR
    raises RuntimeError, Blender writes a short file): ENOSPC when the message says so or less than
    1 MiB is free on the file's disk, else EIO; either way naming `path` and the free space."""
    try:
        free = shutil.disk_usage(Path(path).parent).free
    except OSError:
        free = None
    where = f"{free} bytes free on its disk" if free is not None else "free space unknown"
    if "No space left" in detail or (free is not None and free < 1 << 20):
        return OSError(errno.ENOSPC, f"No space left on device ({detail}; {where})", str(path))
    return OSError(errno.EIO, f"{detail} ({where})", str(path))


def _remove(path: Path) -> None:
    try:
        os.unlink(path)
    except OSError:
        pass


@contextmanager
def atomic_path(path: str | os.PathLike, tmp: str | os.PathLike | None = None) -> Iterator[Path]:
    """Yield the temporary name to write `path` through; renamed onto `path` when the block ends.
    On any failure the temporary file is removed; an OSError is re-raised naming `path`."""
    path = Path(path)
    tmp = Path(tmp) if tmp is not None else _tmp(path)
    g = guard.active_for(path)
    written = [str(tmp), tmp.name]
    try:
        if g is not None:
            with g.atomic(path, tmp.name) as through:
                written.append(str(through))
                yield through
        else:
            yield tmp
            os.replace(tmp, path)
    except OSError as e:
        if g is None:
            _remove(tmp)
        ours = (None, *written)
        if e.filename not in ours and e.filename2 not in ours[1:]:
            raise                          # about another file (a copy's unreadable source): its own name
        raise named_os_error(e, path) from e
    except BaseException:
        if g is None:
            _remove(tmp)
        raise


def make_dirs(path: str | os.PathLike) -> None:
    """`path` and its missing parents (`mkdir -p`); inside a run's output folder never through a link."""
    g = guard.active_for(path)
    if g is not None:
        g.make_dirs(path)
    else:
        Path(path).mkdir(parents=True, exist_ok=True)


def open_append(path: str | os.PathLike):
    """A binary file opened for appending (made when missing); inside a run's output folder never
    through a link."""
    g = guard.active_for(path)
    if g is None:
        return open(path, "ab")
    return os.fdopen(g.open_append(path), "ab")


def scratch_dir(fallback: str | os.PathLike) -> Path:
    """Where another program (Blender's File Output) may write scratch files by path: inside a run's
    output folder a private folder reached through its handle, else `fallback`."""
    g = guard.active_for(fallback)
    return g.scratch_dir() if g is not None else Path(fallback)


@contextmanager
def own_file(path: str | os.PathLike) -> Iterator[Path]:
    """A path to read a file the run wrote by: inside a run's output folder `/proc/self/fd/N` of the
    file opened through the folder's handle (datapipe/io/guard.py, `open_own`: never through a link,
    and only when the run's manifest records that file with that content; else OutputStateError
    naming it), so that nothing put at its name meanwhile is read as the run's; elsewhere `path`."""
    g = guard.active_for(path)
    if g is None:
        yield Path(path)
        return
    fd = g.open_own(path)
    try:
        yield Path(f"/proc/self/fd/{fd}")
    finally:
        os.close(fd)


def own_file_present(path: str | os.PathLike) -> bool:
    """Whether an optional output (a render's scanner depth) stands at `path`: inside a run's output
    folder anything at the name counts (a link there is then refused by `own_file`, not taken for
    "absent"); elsewhere a regular file, links followed."""
    if guard.active_for(path) is not None:
        return os.path.lexists(path)
    return Path(path).is_file()


def write_text_atomic(path: str | os.PathLike, text: str, *, fsync: bool = False) -> None:
    with atomic_path(path) as tmp, open(tmp, "w") as f:
        f.write(text)
        if fsync:
            f.flush()
            os.fsync(f.fileno())


def write_bytes_atomic(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def copy_atomic(src: str | os.PathLike, dst: str | os.PathLike) -> None:
    with atomic_path(dst) as tmp:
        shutil.copyfile(src, tmp)


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
    with atomic_path(path, path.with_name(path.stem + ".tmp" + path.suffix)) as tmp:
        if guard.active_for(path) is not None:     # tmp is /proc/self/fd/N: no extension to pick the codec by
            ok, buf = cv2.imencode(path.suffix, img, params or [])
            if not ok:
                raise disk_full_error(path, "OpenCV could not encode the image")
            with open(tmp, "wb") as f:
                f.write(buf.tobytes())
        elif not cv2.imwrite(str(tmp), img, params or []):
            raise disk_full_error(path, "OpenCV could not write the image")
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


def read_own_json_or_empty(path: str | os.PathLike) -> dict:
    """read_json_or_empty of a file the run wrote and reads back (a BOP chunk's JSON files), through
    `own_file`: in a run's output folder never through a link (a FIFO is not waited on), and only the
    file the run wrote, else OutputStateError naming it; {} when nothing stands there."""
    if not own_file_present(path):
        return {}
    with own_file(path) as p:
        return read_json_or_empty(p)


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
