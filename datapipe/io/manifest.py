"""The manifest of a run, by record: what the run wrote into its output folder, as it wrote it.
No bpy.

Every file the run writes goes through datapipe/io/guard.py, which records here its path, size
and SHA-256 before the rename that puts it in place, appended to `OUT/.datapipe.journal` and
folded into `OUT/manifest.json` at each scene's end (a killed run's last files are recorded too).
A file is the run's only when the record says so; its name counts for nothing. Why a content hash
and not size + mtime_ns, and which files are recorded by path only: docs/OUTPUT_SAFETY.md.
"""
from __future__ import annotations

import errno
import hashlib
import json
import os
import stat
import threading
from pathlib import Path

from ..errors import OutputStateError
from . import guard, layout
from .files import write_text_atomic

MANIFEST_FILE = "manifest.json"
MANIFEST_KEY = "datapipe_manifest"     # format version marker: a foreign manifest.json is not ours
JOURNAL_FILE = ".datapipe.journal"     # the records made since manifest.json was last written


class Manifest:
    """What a run wrote into OUT, by record (see the module doc): {path: [[size, sha256], ...]}
    of every file (None: recorded by path only: a file whose bytes hold a time, one the run
    appends to, or one listed by a manifest of format 1), the folders it made and its temporary
    files (device, inode). Kept in manifest.json, with the records made since
    its last writing appended to the journal (a killed run's last files are recorded too)."""

    def __init__(self, out: Path, files: dict | None = None, dirs=(), tmps: dict | None = None):
        self.out = Path(out)
        self._files: dict[str, list | None] = dict(files or {})
        self._dirs: set[str] = set(dirs)
        self._tmps: dict[str, list] = dict(tmps or {})
        self._known: dict[str, tuple] = {}      # files this process wrote: their stat when written
        self._journal_fd: int | None = None
        self._lock = threading.Lock()

    # -- reading ----------------------------------------------------------------------------------
    @classmethod
    def load(cls, out: Path) -> "Manifest | None":
        """The manifest of an earlier run in `out` (its journal applied), or None when there is none
        (or not ours)."""
        m = cls._read(Path(out))
        journal = _read_journal(Path(out))
        if m is None and not journal:
            return None
        m = m or cls(out)
        for entry in journal:
            m._apply(entry)
        return m

    @classmethod
    def _read(cls, out: Path) -> "Manifest | None":
        path = out / MANIFEST_FILE
        try:
            if not stat.S_ISREG(os.lstat(path).st_mode):
                return None
            data = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError, UnicodeDecodeError, RecursionError):
            return None
        if not isinstance(data, dict):
            return None
        files, dirs, tmps = data.get("files"), data.get("dirs", []), data.get("temporaries", {})
        if data.get(MANIFEST_KEY) == 1 and isinstance(files, list) and all(isinstance(f, str) for f in files):
            # format 1 listed paths only: each stays the run's, whatever its content now
            is_dir = {f: (out / f).is_dir() and not (out / f).is_symlink() for f in files}
            return cls(out, {f: None for f in files if not is_dir[f]}, [f for f in files if is_dir[f]])
        if data.get(MANIFEST_KEY) != 2 or not (isinstance(files, dict) and isinstance(dirs, list)
                                                 and isinstance(tmps, dict)):
            return None
        if not all(v is None or (isinstance(v, list) and all(_is_content(x) for x in v)) for v in files.values()):
            return None
        return cls(out, {k: v and [list(x) for x in v] for k, v in files.items()},
                   [d for d in dirs if isinstance(d, str)], {k: v for k, v in tmps.items() if _is_version(v)})

    def _apply(self, entry) -> None:
        if not (isinstance(entry, list) and entry and isinstance(entry[0], str) and len(entry) >= 2
                and isinstance(entry[1], str)):
            return                                   # a line cut short by a kill
        kind, rel = entry[0], entry[1]
        if kind == "f" and _is_content(entry[2:]):
            versions = self._files.get(rel) or []
            if entry[2:] not in versions:
                versions.append(list(entry[2:]))
            self._files[rel] = versions
        elif kind == "d" and len(entry) == 2:
            self._dirs.add(rel)
        elif kind == "t" and _is_version(entry[2:]):
            self._tmps[rel] = list(entry[2:])
        elif kind == "a" and len(entry) == 2:
            self._files[rel] = None              # by path only (see record_append)

    @classmethod
    def start(cls, out: Path, *, resume: bool) -> "Manifest":
        """Begin (or, resuming, continue) the manifest of the run about to write into `out`: only
        what the run writes from now on (and, resuming, what it wrote before) is ever its own."""
        earlier = cls.load(out) if resume else None
        m = earlier if earlier is not None else cls(out)
        with m.writing():
            m.update()
        return m

    def only_itself(self) -> bool:
        """Whether the run wrote nothing but this manifest (it stopped before its first record, e.g.
        on a full disk): resuming it is starting it."""
        return not any((self.out / f).exists() for f in self._files if f != MANIFEST_FILE)

    @property
    def files(self) -> list[str]:
        """Every path the run wrote (files and the folders it made)."""
        return sorted(set(self._files) | self._dirs)

    # -- the ledger of datapipe/io/guard.py -------------------------------------------------------
    def record_file(self, rel: str, st: os.stat_result, digest: str) -> None:
        if rel in (MANIFEST_FILE, JOURNAL_FILE):
            self._known[rel] = _stamp(st)        # the record itself: ours when it is a DataPipe manifest
            return
        self._journal(["a", rel] if _by_path(rel) else ["f", rel, st.st_size, digest])
        self._known[rel] = _stamp(st)            # this process wrote it: no need to read it again

    def record_dir(self, rel: str) -> None:
        self._journal(["d", rel])

    def record_tmp(self, rel: str, st: os.stat_result) -> None:
        self._journal(["t", rel, st.st_dev, st.st_ino])

    def record_append(self, rel: str) -> None:
        """A file the run made and appends to (blender.log): its content grows after every record,
        so it is the run's by the record of its path (as the files whose bytes hold a time)."""
        if rel != JOURNAL_FILE:
            self._journal(["a", rel])

    def is_own_tmp(self, rel: str, st: os.stat_result) -> bool:
        return self._tmps.get(rel) == [st.st_dev, st.st_ino]

    def may_replace(self, rel: str, st: os.stat_result) -> bool:
        """Whether the file `st` at `rel` is one the run wrote, with the content it wrote."""
        if rel == JOURNAL_FILE:
            return True
        if rel == MANIFEST_FILE:                 # written by this process, else read as a DataPipe manifest
            return self._known.get(rel) == _stamp(st) or Manifest._read(self.out) is not None
        return self._recorded(rel, st, lambda: _digest(self.out / rel))

    def owns(self, rel: str, st: os.stat_result, fd: int) -> bool:
        """Whether the opened file `fd` (its fstat `st`) at `rel` is one the run wrote, with the
        content it wrote: as may_replace, the content read through `fd`, never again by path."""
        return self._recorded(rel, st, lambda: _fd_digest(fd))

    def _recorded(self, rel: str, st: os.stat_result, digest) -> bool:
        if rel not in self._files:
            return False
        versions = self._files[rel]
        if versions is None or self._known.get(rel) == _stamp(st):
            return True
        if not any(v[0] == st.st_size for v in versions):
            return False                         # a changed size: no need to read it
        return [st.st_size, digest()] in versions

    def _content(self, rel: str) -> list | None:
        try:
            st = os.lstat(self.out / rel)
        except OSError:
            return None
        return [st.st_size, _digest(self.out / rel)] if stat.S_ISREG(st.st_mode) else None

    def _journal(self, entry: list) -> None:
        with self._lock:
            self._apply(entry)
            if self._journal_fd is None:
                self._journal_fd = _open_journal(self.out)
            os.write(self._journal_fd, (json.dumps(entry) + "\n").encode())

    def close(self) -> None:
        if self._journal_fd is not None:
            os.close(self._journal_fd)
            self._journal_fd = None

    def writing(self):
        """A context in which writes under OUT go through the guard and are recorded here."""
        return guard.guarding(self.out, self)

    # -- writing it -------------------------------------------------------------------------------
    def update(self) -> None:
        """Write manifest.json (every record so far) and empty the journal."""
        with self._lock:
            for rel, versions in self._files.items():
                if versions is not None and len(versions) > 1:     # keep the one on disk (a kill may
                    now = self._content(rel)                        # have come before a rename)
                    self._files[rel] = [v for v in versions if v == now] or versions[-1:]
            for rel in [r for r, v in self._tmps.items() if _ino(self.out / r) != v]:
                del self._tmps[rel]                                  # renamed into place
            text = json.dumps({MANIFEST_KEY: 2, "files": dict(sorted(self._files.items())),
                               "dirs": sorted(self._dirs), "temporaries": dict(sorted(self._tmps.items()))},
                              indent=0)
        write_text_atomic(self.out / MANIFEST_FILE, text)
        with self._lock:
            if self._journal_fd is None:
                self._journal_fd = _open_journal(self.out)
            os.ftruncate(self._journal_fd, 0)

    # -- --force ----------------------------------------------------------------------------------
    def remove_listed(self) -> int:
        """Delete the run's files whose content is still what it wrote (deepest first), its
        temporaries, then the folders it made that are empty after it; never through a link.
        Returns how many files were removed."""
        removed = 0
        with guard.guarding(self.out) as g:
            for rel in sorted(self._files, key=lambda r: (-r.count("/"), r)):
                if rel not in (MANIFEST_FILE, JOURNAL_FILE):
                    removed += _remove(g, self.out, rel, lambda st, rel=rel: self.may_replace(rel, st))
            for rel in sorted(self._tmps):
                _remove(g, self.out, rel, lambda st, rel=rel: self.is_own_tmp(rel, st))
            for rel in sorted(self._dirs, key=lambda r: (-r.count("/"), r)):
                _remove(g, self.out, rel, None)
            if Manifest._read(self.out) is not None:
                _remove(g, self.out, MANIFEST_FILE, lambda st: True)
            _remove(g, self.out, JOURNAL_FILE, lambda st: True)
        self.close()
        return removed


def _by_path(rel: str) -> bool:
    """Files whose bytes say when or where the run ran: run.json (its steps' seconds), the BOP COCO
    files (`date_created`), the sheets (their titles name the run's folder). Recorded by path, so
    that manifest.json is the same bytes for a resumed run (or one in another folder) as for an
    uninterrupted one."""
    return rel == layout.RUN_FILE or rel.endswith("_coco.json") or rel.startswith(layout.SHEETS_DIR + "/")


def _is_version(v) -> bool:
    return isinstance(v, list) and len(v) == 2 and all(isinstance(x, int) and not isinstance(x, bool) for x in v)


def _is_content(v) -> bool:
    return (isinstance(v, list) and len(v) == 2 and isinstance(v[0], int) and not isinstance(v[0], bool)
            and isinstance(v[1], str))


def _stamp(st: os.stat_result) -> tuple:
    return st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns


def _digest(path: Path) -> str | None:
    """sha256 of a regular file (never through a link at its name), or None."""
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError:
        return None
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(fd).st_mode):
            return None
        return hashlib.file_digest(f, "sha256").hexdigest()


def _fd_digest(fd: int) -> str:
    """sha256 of the opened regular file `fd`, read from its start (its offset left as it was)."""
    with os.fdopen(os.dup(fd), "rb") as f:
        at = f.seek(0, os.SEEK_CUR)
        f.seek(0)
        digest = hashlib.file_digest(f, "sha256").hexdigest()
        f.seek(at)
    return digest


def _ino(path: Path) -> list | None:
    try:
        st = os.lstat(path)
    except OSError:
        return None
    return [st.st_dev, st.st_ino] if stat.S_ISREG(st.st_mode) else None


def _open_journal(out: Path) -> int:
    g = guard.active_for(out / JOURNAL_FILE)
    if g is not None:
        return g.open_append(out / JOURNAL_FILE)
    try:
        return os.open(out / JOURNAL_FILE, os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC,
                       0o666)
    except OSError as e:
        if e.errno == errno.ELOOP:
            raise guard.link_refusal(out, JOURNAL_FILE) from None
        raise


def _read_journal(out: Path) -> list:
    try:
        fd = os.open(out / JOURNAL_FILE, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC)
    except OSError:
        return []
    with os.fdopen(fd, "rb") as f:
        if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
            return []
        entries = []
        for line in f.read().splitlines():
            try:
                entries.append(json.loads(line))
            except (json.JSONDecodeError, UnicodeDecodeError, RecursionError):
                pass                                  # a line cut short by a kill
        return entries


def _remove(g: "guard.OutGuard | None", out: Path, rel: str, check) -> int:
    """Remove OUT/`rel` when `check(its stat)` says it is the run's (`check` None: a folder, when
    empty); never through a link on the way. Returns 1 when a file was removed."""
    folder, _, name = rel.rpartition("/")
    if g is None:                                 # no dir_fd here: the old path checks
        p = out / rel
        if p.parent.resolve() != out.resolve().joinpath(*Path(rel).parts[:-1]):
            return 0
        try:
            st = os.lstat(p)
            if check is None:
                if stat.S_ISDIR(st.st_mode) and not any(p.iterdir()):
                    p.rmdir()
                return 0
            if stat.S_ISREG(st.st_mode) and check(st):
                p.unlink()
                return 1
        except OSError:
            pass
        return 0
    try:
        d = g.open_dir(folder, create=False)
    except (OSError, OutputStateError):
        return 0                                  # gone, or a link on the way: leads outside OUT
    try:
        st = os.stat(name, dir_fd=d, follow_symlinks=False)
        if check is None:
            if stat.S_ISDIR(st.st_mode):
                os.rmdir(name, dir_fd=d)          # only when empty (ENOTEMPTY otherwise)
            return 0
        if stat.S_ISREG(st.st_mode) and check(st):
            os.unlink(name, dir_fd=d)
            return 1
    except OSError:
        pass
    finally:
        os.close(d)
    return 0
