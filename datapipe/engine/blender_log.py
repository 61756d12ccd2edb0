"""Blender's own output goes to the run's log file (`OUT/blender.log`), not the user's terminal.

Blender prints from C: three `render | Saved: '.../_passes.exr'` lines per render, importer timings,
Cycles warnings, all on the process's file descriptor 1 (stdout); DataPipe's own progress lines
are on stderr. Rebinding `sys.stdout` cannot catch C output, so around Blender work fd 1 is
pointed at a pipe (`os.dup2`) and a thread copies what arrives:
  - into the log file once the run folder is known (`log_to`; what came before, e.g. the mesh
    preflight's imports, is kept in memory and written first), appended on --resume with a header
    line per session;
  - to the terminal as well with `verbose` (`--verbose`);
  - lines Blender marks as errors (`| ERROR`, `| FATAL`, `Error: `) to stderr as well, so an error
    that matters is never only in the file.
fd 2 is left alone: DataPipe's progress, Python warnings and tracebacks reach the user as before.

The copying thread needs the GIL; Blender releases it while an operator runs (renders, imports),
which is where it prints, and the pipe is enlarged to 1 MiB where the OS allows it (Linux), so
Blender never blocks on a full pipe.
"""
from __future__ import annotations

import ctypes
import os
import re
import sys
import threading
import time
from pathlib import Path

from ..io.files import open_append

_ERROR_LINE = re.compile(rb"\|\s+(ERROR|FATAL)\b|^Error: ")
_MAX_PENDING = 1 << 20             # bytes kept in memory before the log file is known
_PIPE_SIZE = 1 << 20


def _flush_c_stdio() -> None:
    """Flush C's stdout buffer, so that what Blender printed lands where fd 1 pointed then."""
    try:
        if sys.platform == "win32":
            ctypes.CDLL("ucrtbase").fflush(None)
        else:
            ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):      # no C runtime reachable: Blender's output may come later
        pass


class BlenderLog:
    """Capture fd 1 during `with` blocks (re-enterable: the add-on captures each run step)."""

    def __init__(self, *, verbose: bool = False, echo_errors: bool = True):
        self.verbose = verbose
        self.echo_errors = echo_errors
        self.path: Path | None = None
        self._file = None
        self._pending = bytearray()        # output before the log file is known
        self._lock = threading.Lock()
        self._active = False

    # -- where the output goes ---------------------------------------------------------------------
    def log_to(self, path: str | os.PathLike) -> None:
        """From now on write to `path` (appended); output captured so far is written first."""
        path = Path(path)
        with self._lock:
            if self.path == path and self._file is not None:
                return
            if self._file is not None:
                self._file.close()
            self._file = open_append(path)       # inside a run's folder: never through a link
            self.path = path
            stamp = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime())
            self._file.write(f"=== DataPipe session {stamp} UTC, pid {os.getpid()}: Blender's own output\n"
                             .encode())
            self._file.write(bytes(self._pending))
            self._file.flush()
            self._pending.clear()

    def close(self) -> None:
        with self._lock:
            if self._file is not None:
                self._file.close()
                self._file = None

    def _take(self, data: bytes) -> None:
        with self._lock:
            if self._file is not None:
                self._file.write(data)
                self._file.flush()
            elif len(self._pending) < _MAX_PENDING:
                self._pending += data[:_MAX_PENDING - len(self._pending)]
        if self.verbose:
            _write_all(self._terminal, data)
        elif self.echo_errors:
            for line in data.splitlines(keepends=True):
                if _ERROR_LINE.search(line):
                    _write_all(2, b"blender: " + line.rstrip(b"\n") + b"\n")

    # -- capturing -----------------------------------------------------------------------------------
    def __enter__(self) -> "BlenderLog":
        if self._active:
            raise RuntimeError("BlenderLog is already capturing")
        self._active = True
        self._reader = None
        _flush_python_stdout()
        _flush_c_stdio()
        try:
            self._terminal = os.dup(1)
        except OSError:                    # no fd 1 (a Windows GUI without a console): nothing to capture
            return self
        read_fd, write_fd = os.pipe()
        _enlarge(write_fd)
        os.dup2(write_fd, 1)
        os.close(write_fd)                 # fd 1 is now the only write end: restoring it ends the reader
        self._reader = threading.Thread(target=self._read, args=(read_fd,), name="datapipe-blender-log",
                                        daemon=True)
        self._reader.start()
        return self

    def _read(self, fd: int) -> None:
        carry = b""
        try:
            while True:
                chunk = os.read(fd, 65536)
                if not chunk:
                    break
                data = carry + chunk       # hand on whole lines (the error filter reads lines)
                cut = data.rfind(b"\n") + 1
                carry = data[cut:]
                if cut:
                    self._take(data[:cut])
            if carry:
                self._take(carry + b"\n")
        finally:
            os.close(fd)

    def __exit__(self, exc_type, exc, tb) -> None:
        self._active = False
        if self._reader is None:
            return
        _flush_python_stdout()
        _flush_c_stdio()
        os.dup2(self._terminal, 1)         # closes the pipe's write end: the reader sees the end
        self._reader.join(timeout=10)      # (unless a child process inherited fd 1 and still runs)
        if not self._reader.is_alive():    # verbose: it writes to self._terminal until the end
            os.close(self._terminal)
        with self._lock:
            if self._file is not None:
                self._file.flush()
        if exc_type is not None and self.path is not None and not self.verbose:
            print(f"datapipe: Blender's own output is in {self.path}", file=sys.stderr, flush=True)


def _flush_python_stdout() -> None:
    try:
        if sys.stdout is not None:
            sys.stdout.flush()
    except (OSError, ValueError):          # closed or broken: nothing of ours is waiting in it
        pass


def _enlarge(fd: int) -> None:
    try:
        import fcntl
        fcntl.fcntl(fd, getattr(fcntl, "F_SETPIPE_SZ", 1031), _PIPE_SIZE)
    except (ImportError, OSError):
        pass                               # default pipe size (64 KiB on Linux/macOS)


def _write_all(fd: int, data: bytes) -> None:
    try:
        while data:
            data = data[os.write(fd, data):]
    except OSError:                        # the terminal went away: the log still has it
        pass
