"""The output folder's safety rules: an exclusive lock, the manifest of what a run wrote, and the
refusals that keep a user's files safe. No bpy.

- Lock: `OUT/.datapipe.lock`, an `fcntl.flock` held for the whole run (the kernel drops it when
  the process exits or crashes, so a stale lock file never blocks). It holds the holder's pid for
  the refusal message. The lock file alone does not make a folder "not empty".
- Manifest: `OUT/manifest.json` lists every file and folder of the run's own layout that appeared
  in OUT after the run started (`foreign` remembers what was there before, e.g. a README the user
  keeps next to a run). `--force` removes exactly the listed paths and nothing else.
"""
from __future__ import annotations

import errno
import fcntl
import json
import os
import re
from pathlib import Path

from .errors import DataPipeError
from .io import layout

LOCK_FILE = ".datapipe.lock"
MANIFEST_FILE = "manifest.json"
MANIFEST_KEY = "datapipe_manifest"     # format version marker: a foreign manifest.json is not ours

# Top-level names a run writes (native layout, BOP export, sheets, temporaries of atomic writes).
_OWN_TOP = re.compile("^(" + "|".join(re.escape(n) for n in (
    layout.RUN_FILE, layout.LEGACY_PICKLE, MANIFEST_FILE, layout.MODELS_DIR, layout.BOP_DIR, layout.SHEETS_DIR,
    layout.BLENDER_LOG))
    + "|" + re.escape(layout.SCENE_PREFIX) + r"\d{4,})(\.tmp)?$")


class OutputStateError(DataPipeError):
    """The output folder's state (a lock, a corrupt or foreign record) stops the run. Exit status 1."""


def meaningful_entries(out: Path) -> list[str]:
    """Names in `out` other than the lock file."""
    return sorted(p.name for p in out.iterdir() if p.name != LOCK_FILE)


class OutLock:
    """Exclusive lock on an output folder; the second holder is refused with the first one's pid."""

    def __init__(self, out: Path):
        self.out = Path(out)
        self.fd: int | None = None

    def acquire(self) -> "OutLock":
        self.out.mkdir(parents=True, exist_ok=True)
        path = self.out / LOCK_FILE
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            if e.errno not in (errno.EAGAIN, errno.EACCES, errno.EWOULDBLOCK):
                os.close(fd)
                raise
            holder = os.read(fd, 64).decode("ascii", "replace").strip() or "?"
            os.close(fd)
            raise OutputStateError(f"output: {self.out} is in use by another DataPipe run (pid {holder}) "
                                   "(fix: wait for it to finish or stop it, or choose another --out)") from None
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self.fd = fd
        return self

    def release(self) -> None:
        if self.fd is not None:
            try:
                os.unlink(self.out / LOCK_FILE)        # while still held: no other run can hold it now
            except OSError:
                pass
            fcntl.flock(self.fd, fcntl.LOCK_UN)
            os.close(self.fd)
            self.fd = None

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()


def read_record(path: Path, what: str) -> dict:
    """A run folder's JSON record, or OutputStateError naming the file and the fix."""
    try:
        data = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError):
        raise OutputStateError(f"output: {path} is corrupt (not the {what} a DataPipe run writes) (fix: if "
                               "the run's scenes matter, restore the file from a backup; otherwise choose "
                               "another --out)") from None
    if not isinstance(data, dict):
        raise OutputStateError(f"output: {path} is not a DataPipe {what} (fix: choose the folder of a DataPipe "
                               "run, or another --out)")
    return data


class Manifest:
    """What a run wrote into OUT (see the module doc)."""

    def __init__(self, out: Path, foreign: list[str], files: list[str]):
        self.out, self.foreign, self.files = Path(out), sorted(foreign), sorted(files)

    @classmethod
    def load(cls, out: Path) -> "Manifest | None":
        """The manifest of an earlier run in `out`, or None when there is none (or not ours)."""
        path = Path(out) / MANIFEST_FILE
        if not path.is_file():
            return None
        try:
            data = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError, RecursionError, OSError):
            return None
        if not isinstance(data, dict) or data.get(MANIFEST_KEY) != 1:
            return None
        files, foreign = data.get("files"), data.get("foreign")
        if not (isinstance(files, list) and isinstance(foreign, list)
                and all(isinstance(f, str) for f in files + foreign)):
            return None
        return cls(out, foreign, files)

    @classmethod
    def start(cls, out: Path, *, resume: bool) -> "Manifest":
        """Begin (or, resuming, continue) the manifest of the run about to write into `out`."""
        earlier = cls.load(out) if resume else None
        if earlier is not None:
            return earlier
        foreign = [n for n in meaningful_entries(out) if n != MANIFEST_FILE]
        m = cls(out, foreign, [])
        m.update()
        return m

    def update(self) -> None:
        """Add every path of the run's layout that is in OUT now and was not there before the run."""
        found = set(self.files)
        for top in sorted(self.out.iterdir()):
            if top.name in self.foreign or not _OWN_TOP.match(top.name):
                continue
            found.add(top.name)
            if top.is_dir() and not top.is_symlink():
                for root, dirs, files in os.walk(top):
                    rel = Path(root).relative_to(self.out)
                    found.update(str(rel / n) for n in dirs + files)
        found.add(MANIFEST_FILE)
        self.files = sorted(found)
        tmp = self.out / (MANIFEST_FILE + ".tmp")
        tmp.write_text(json.dumps({MANIFEST_KEY: 1, "foreign": self.foreign, "files": self.files}, indent=0))
        os.replace(tmp, self.out / MANIFEST_FILE)

    def remove_listed(self) -> int:
        """Delete the listed files (deepest first), then the listed folders that are empty after it.
        A path that is not inside OUT, or a folder that still holds something unlisted, is kept."""
        root = self.out.resolve()
        removed = 0
        for rel in sorted(self.files, key=lambda r: r.count("/"), reverse=True):
            p = self.out / rel
            if ".." in Path(rel).parts or Path(rel).is_absolute():
                continue
            try:
                if p.parent.resolve() != root.joinpath(*Path(rel).parts[:-1]):
                    continue                   # a symlinked folder on the way: it leads outside OUT
                if p.is_symlink() or p.is_file():
                    p.unlink()
                    removed += 1
                elif p.is_dir() and not any(p.iterdir()):
                    p.rmdir()
            except FileNotFoundError:
                pass
        return removed


def check_force(out: Path) -> Manifest:
    """The manifest `--force` will remove, or a refusal that names why nothing will be removed."""
    m = Manifest.load(out)
    if m is None:
        raise DataPipeError(f"output: refusing to empty {out}: it holds no DataPipe manifest "
                            f"({MANIFEST_FILE}), so nothing in it is known to be a run's own file "
                            "(fix: choose another folder, or delete what you do not need yourself)")
    return m
