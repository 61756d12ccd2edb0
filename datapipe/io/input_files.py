"""Reading the user's input files (presets, mesh files, glTF buffers, models_info.json) so that none
can hang or exhaust the machine. No bpy.

A path may name a FIFO (a read waits for a writer that never comes), a device (/dev/zero never ends)
or a file far larger than any part or preset. Every input is therefore read only when it is a
regular file within its size limit, both checked before the first byte is read: the file is opened
with O_NONBLOCK (opening a FIFO for reading then returns at once instead of waiting for a writer)
and judged by fstat of that open descriptor, so the checked file is the one read.

Limits (docs/INPUT_LIMITS.md):
    MAX_MESH_BYTES  4 GiB: a mesh file or a glTF buffer. A binary glTF carries its total length
                    in a uint32 (Khronos glTF 2.0 specification, GLB header,
                    https://registry.khronos.org/glTF/specs/2.0/glTF-2.0.html: "`length` is the total
                    length of the Binary glTF, including Header and all Chunks, in bytes"), so
                    2^32 bytes is the format's own ceiling;
                    the same limit serves OBJ / PLY / STL (a 4 GiB part mesh is ~80 million
                    triangles, far beyond what a bin-picking part needs).
    MAX_JSON_BYTES  256 MiB: a preset, a .gltf's JSON, a models_info.json (the largest BOP
                    models_info.json files are a few hundred kB; an assumption with margin).
"""
from __future__ import annotations

import json
import os
import stat

from ..errors import DataPipeError

MAX_MESH_BYTES = 2**32
MAX_JSON_BYTES = 256 * 2**20


def _kind(mode: int) -> str:
    if stat.S_ISDIR(mode):
        return "a folder"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode):
        return "a character device"
    if stat.S_ISBLK(mode):
        return "a block device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    return "not a plain file"


def not_regular_message(path, mode: int) -> str:
    """'PATH is a FIFO (named pipe), not a regular file' for a non-regular st_mode."""
    return f"{path} is {_kind(mode)}, not a regular file"


def too_large_message(path, size: int, limit: int) -> str:
    return f"{path} is {size:,} bytes, more than the {limit:,} bytes DataPipe reads from one input file"


def file_problem(path, limit: int | None) -> str | None:
    """None when `path` is a regular file (links followed) of at most `limit` bytes (None: any size);
    else why not, without opening it. A missing path: 'file not found'."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        if os.path.islink(path):
            return f"file not found: {path} is a symbolic link to nothing (its target is missing, or a loop)"
        return f"file not found: {path}"
    except OSError as e:
        if os.path.islink(path):       # ELOOP: a link loop
            return f"file not found: {path} is a symbolic link to nothing (its target is missing, or a loop)"
        return f"cannot read {path}: {e.strerror or e}"
    except ValueError:                 # a NUL byte or a lone surrogate: no file can have that name
        return f"file not found: {path!r} is not a name a file can have"
    if not stat.S_ISREG(st.st_mode):
        return not_regular_message(path, st.st_mode)
    if limit is not None and st.st_size > limit:
        return too_large_message(path, st.st_size, limit)
    return None


def read_regular(path, limit: int | None, head: int | None = None) -> bytes:
    """The bytes of regular file `path` (its first `head` bytes when given), refusing before reading
    anything that is not a regular file or is larger than `limit`: DataPipeError with the reason
    (no field: the caller adds it). Never blocks on a FIFO, never reads a device."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise DataPipeError(file_problem(path, limit) or f"file not found: {path}") from None
    except OSError as e:
        raise DataPipeError(f"cannot read {path}: {e.strerror or e}") from None
    except ValueError:
        raise DataPipeError(f"file not found: {path!r} is not a name a file can have") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise DataPipeError(not_regular_message(path, st.st_mode))
        if limit is not None and st.st_size > limit:
            raise DataPipeError(too_large_message(path, st.st_size, limit))
        want = st.st_size if head is None else min(head, st.st_size)
        chunks, got = [], 0
        while got < want:                   # a file that shrinks meanwhile just ends early
            b = os.read(fd, min(want - got, 1 << 24))
            if not b:
                break
            chunks.append(b)
            got += len(b)
        return b"".join(chunks)
    except OSError as e:
        raise DataPipeError(f"cannot read {path}: {e.strerror or e}") from None
    finally:
        os.close(fd)


def read_json_file(path, limit: int = MAX_JSON_BYTES):
    """A JSON input file (a regular file within `limit`), parsed; DataPipeError with the reason for
    a file that is not one, is not UTF-8 JSON, or is nested too deeply for Python's parser."""
    raw = read_regular(path, limit)
    try:
        return json.loads(raw.decode("utf-8-sig"))
    except RecursionError:
        raise DataPipeError(f"{path}: JSON nested too deeply to be read (Python's parser stops at about "
                            "1,000 levels)") from None
    except UnicodeDecodeError:
        raise DataPipeError(f"{path}: not UTF-8 text, so not JSON") from None
    except ValueError as e:           # JSONDecodeError, and integers past Python's 4,300 digits
        raise DataPipeError(f"{path}: not valid JSON ({e})") from None
