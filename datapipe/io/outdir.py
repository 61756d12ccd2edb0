"""The output folder's safety rules: an exclusive lock, the manifest of what a run wrote, and the
refusals that keep a user's files safe. No bpy.

- Lock: `OUT/.datapipe.lock`, an `fcntl.flock` held for the whole run (the kernel drops it when
  the process exits or crashes, so a stale lock file never blocks). It holds the holder's pid for
  the refusal message. The lock file alone does not make a folder "not empty". Released by
  unlinking it while held; so an acquire checks, once it holds the lock, that the file it locked
  is still the one at the path (else it locked a file just released and unlinked: it tries again).
- Manifest, by record: every file the run writes goes through datapipe/io/guard.py, which records
  its path, size and sha256 (before the rename that puts it in place) in `OUT/.datapipe.journal`,
  folded into `OUT/manifest.json` at each scene's end. A content hash, not size + mtime_ns: the
  manifest is then the same bytes for a resumed or sharded run as for an uninterrupted one (a
  time would differ), and a copy of the folder (`cp -r`, a new mtime) stays the run's. The cost
  is reading each file once more from the page cache as it is written: 1.5 ms per MB measured
  (sha256, hashlib), about 45 ms for a 30 MB EXR against renders of seconds to minutes. A check
  compares the size first (a changed size needs no reading), and a file this process wrote is
  known by its inode, size and mtime_ns without reading it again. A file is the run's only when
  the record says so: its name counts for nothing. `--force` removes exactly the recorded files
  whose content is still the recorded one, and the folders the run made once they are empty.
- Refusals before anything is written (exit status 1, the path and the fix): a symbolic link where
  the run writes (it could lead the writes out of OUT), a file the run did not write at a path it
  writes, and a `scene.json` that is not this run's record. During the run the guard refuses the
  same at the write itself.
"""
from __future__ import annotations

import errno
import fcntl
import hashlib
import json
import os
import re
import stat
import threading
import time
from pathlib import Path
from typing import Iterator

from ..errors import DataPipeError, OutputStateError  # noqa: F401 (re-exported)
from . import guard, layout
from .files import write_text_atomic

LOCK_FILE = ".datapipe.lock"
JOURNAL_FILE = ".datapipe.journal"     # the records made since manifest.json was last written
MANIFEST_FILE = "manifest.json"
MANIFEST_KEY = "datapipe_manifest"     # format version marker: a foreign manifest.json is not ours

# Top-level names a run writes (native layout, BOP export, sheets, temporaries of atomic writes).
_OWN_TOP = re.compile("^(" + "|".join(re.escape(n) for n in (
    layout.RUN_FILE, layout.LEGACY_PICKLE, MANIFEST_FILE, layout.MODELS_DIR, layout.BOP_DIR, layout.SHEETS_DIR,
    layout.BLENDER_LOG))
    + "|" + re.escape(layout.SCENE_PREFIX) + r"\d{4,})(\.tmp)?$")
_SCENE_DIR = re.compile("^" + re.escape(layout.SCENE_PREFIX) + r"\d{4,}$")
# Inside a scene folder: scene.json (+ its temporary) and the render folders ...
_IN_SCENE = re.compile("^(" + re.escape(layout.SCENE_FILE) + r"(\.tmp)?|" + re.escape(layout.RENDER_PREFIX) + r"\d{4,})$")
# ... and inside a render folder the output maps (+ their temporaries) and Blender's scratch EXRs (`_passes.exr`).
_IN_RENDER = re.compile("^((" + "|".join(sorted({Path(n).stem for n in layout.RENDER_FILES.values()}))
                        + r")\.|_[A-Za-z_]+\d*\.exr$)")


def is_run_path(rel: str) -> bool:
    """Whether `rel` (relative to OUT, '/'-separated) is a name the run's layout writes. Inside
    scene folders only the layout's names are; anything else there (notes, a folder of yours) is not."""
    parts = rel.split("/")
    if not _OWN_TOP.match(parts[0]):
        return False
    if not _SCENE_DIR.match(parts[0]) or len(parts) == 1:
        return True                        # run.json, models/..., bop/..., sheets/..., a scene folder
    if not _IN_SCENE.match(parts[1]):
        return False
    if len(parts) == 2:
        return True
    return len(parts) == 3 and parts[1] != layout.SCENE_FILE and bool(_IN_RENDER.match(parts[2]))


def walk(out: Path, top: str) -> Iterator[tuple[str, bool, bool]]:
    """(relative path, is a symbolic link, is a real folder) of `top` and everything under it, links
    never followed; from the directory entries (no stat per file), without recursion (a tree of
    any depth)."""
    try:
        mode = os.lstat(out / top).st_mode
    except FileNotFoundError:
        return
    yield top, stat.S_ISLNK(mode), stat.S_ISDIR(mode)
    todo = [top] if stat.S_ISDIR(mode) else []
    while todo:
        rel = todo.pop()
        with os.scandir(out / rel) as entries:
            for e in entries:
                sub, is_dir = f"{rel}/{e.name}", e.is_dir(follow_symlinks=False)
                yield sub, e.is_symlink(), is_dir
                if is_dir:
                    todo.append(sub)


def own_tops(out: Path) -> list[str]:
    return sorted(p.name for p in out.iterdir() if _OWN_TOP.match(p.name)) if out.is_dir() else []


def meaningful_entries(out: Path) -> list[str]:
    """Names in `out` other than the lock file and the journal (and a killed run's scratch folder)."""
    return sorted(p.name for p in out.iterdir() if p.name not in (LOCK_FILE, JOURNAL_FILE)
                  and not p.name.startswith(guard.SCRATCH_PREFIX))


class OutLock:
    """Exclusive lock on an output folder; the second holder is refused with the first one's pid."""

    def __init__(self, out: Path):
        self.out = Path(out)
        self.fd: int | None = None

    def acquire(self) -> "OutLock":
        self.out.mkdir(parents=True, exist_ok=True)
        for _ in range(1000):              # each try again follows a release that unlinked the file we locked
            if self._try_acquire():
                return self
            time.sleep(0.001)
        raise OutputStateError(f"output: {self.out / LOCK_FILE} keeps being replaced while DataPipe takes the "
                               "lock (fix: stop the other program that removes it, or choose another --out)")

    def _try_acquire(self) -> bool:
        """True holding the lock; False when the file locked was no longer the one at the path."""
        path = self.out / LOCK_FILE
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW, 0o644)
        except OSError as e:
            if e.errno == errno.ELOOP:
                raise _link_refusal(self.out, path) from None
            raise
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
        try:
            now = os.stat(path, follow_symlinks=False)
        except FileNotFoundError:
            now = None
        held = os.fstat(fd)
        if now is None or (now.st_dev, now.st_ino) != (held.st_dev, held.st_ino):
            os.close(fd)                   # released (unlinked) between our open and our lock
            return False
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        self.fd = fd
        return True

    def release(self) -> None:
        if self.fd is not None:
            try:
                os.unlink(self.out / LOCK_FILE)        # while still held; a process that opened it before
            except OSError:                            # locks a file no longer at the path: it tries again
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


def _link_refusal(out: Path, path: Path) -> OutputStateError:
    return OutputStateError(
        f"output: {path} is a symbolic link (to {os.readlink(path)}); DataPipe writes only inside {out} and "
        "never through a link, which could lead its writes (and --force) to files elsewhere (fix: replace the "
        "link by a real folder or file, or remove it, or choose another --out; nothing was written)")


def refuse_links(out: Path) -> None:
    """OutputStateError for the first symbolic link at a path the run writes or removes: the lock
    file, a name of the layout (at the top, in models/, bop/, sheets/, scene and render folders)."""
    if not out.is_dir():
        return
    if (out / LOCK_FILE).is_symlink():
        raise _link_refusal(out, out / LOCK_FILE)
    for top in own_tops(out):
        for rel, link, _ in walk(out, top):
            if link and is_run_path(rel):               # a link of yours beside the run's files stays
                raise _link_refusal(out, out / rel)


def refuse_links_under(out: Path, top: str) -> None:
    """OutputStateError for the first symbolic link at `out`/`top` or inside it (a folder written
    whole: `show`'s sheets or the BOP export in a run folder, a distributed run's shards)."""
    for rel, link, _ in walk(out, top):
        if link:
            raise _link_refusal(out, out / rel)


def foreign_scene_record(scene_dir: Path, scene_id: int, seed: int | None) -> str | None:
    """Why `scene_dir`/scene.json is not the record a DataPipe run writes for scene `scene_id` (with
    `seed`, when given), or None when it is (or when there is no scene.json)."""
    path = scene_dir / layout.SCENE_FILE
    if not path.exists():
        return None
    try:
        scene = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError, RecursionError):
        return "it is not JSON"
    if not isinstance(scene, dict):
        return f"it holds a JSON {type(scene).__name__}, not a scene record"
    if scene.get("name") != scene_dir.name or scene.get("scene_id") != scene_id \
            or not isinstance(scene.get("renders"), list):
        return f"it is not the record of {scene_dir.name} (its name, scene_id or renders differ)"
    if seed is not None and scene.get("seed") != seed:
        return f"its seed {scene.get('seed')!r} is not this run's {seed}"
    return None


def refuse_foreign_scenes(out: Path, scenes: dict[str, tuple[int, int | None]]) -> None:
    """OutputStateError for the first scene folder of `scenes` ({folder name: (scene index, seed or
    None)}) whose scene.json is someone else's: the run would overwrite it (or, --force, delete it)."""
    for name, (i, seed) in sorted(scenes.items()):
        sdir = out / name
        why = foreign_scene_record(sdir, i, seed) if sdir.is_dir() else None
        if why:
            raise OutputStateError(
                f"output: {sdir / layout.SCENE_FILE} is not this run's scene record ({why}); DataPipe neither "
                f"overwrites nor deletes it (fix: move your file out of {sdir}, then run again, or choose "
                "another --out; nothing was written)")


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
        if rel not in self._files:
            return False
        versions = self._files[rel]
        if versions is None or self._known.get(rel) == _stamp(st):
            return True
        if not any(v[0] == st.st_size for v in versions):
            return False                         # a changed size: no need to read it
        return [st.st_size, _digest(self.out / rel)] in versions

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
    def remove_listed(self) -> tuple[int, list[str]]:
        """Delete the run's files whose content is still what it wrote (deepest first), its
        temporaries, then the folders it made that are empty after it; never through a link.
        Returns (how many files were removed, the files kept in OUT: everything else)."""
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
        kept = sorted(rel for name in meaningful_entries(self.out) for rel, _, is_dir in walk(self.out, name)
                      if not is_dir)
        return removed, kept


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


def scene_folders(out: Path) -> dict[str, int]:
    """{folder name: scene index} of the scene folders (layout names) in `out`."""
    return {p.name: int(p.name[len(layout.SCENE_PREFIX):]) - 1 for p in layout.scene_dirs(out)
            if _SCENE_DIR.match(p.name)}


_WRITES_TOP = {layout.RUN_FILE, layout.LEGACY_PICKLE}
_WRITES_MODELS = re.compile(r"^obj_\d{6}\.ply$|^" + re.escape(layout.MODELS_INFO) + "$")
_WRITES_RENDER = set(layout.RENDER_FILES.values())


def _files_run_writes(out: Path, scenes: list[str]) -> Iterator[str]:
    """The files in OUT now at a name the run is about to write: run.json, the pickle, models/,
    and in the scene folders `scenes` scene.json and the render maps (bop/ and sheets/ are
    checked at the write itself, by the guard)."""
    for name in sorted(_WRITES_TOP):
        yield name
    models = out / layout.MODELS_DIR
    if models.is_dir() and not models.is_symlink():
        for p in sorted(models.iterdir()):
            if _WRITES_MODELS.match(p.name):
                yield f"{layout.MODELS_DIR}/{p.name}"
    for sname in scenes:
        sdir = out / sname
        if not sdir.is_dir() or sdir.is_symlink():
            continue
        yield f"{sname}/{layout.SCENE_FILE}"
        for rdir in sorted(sdir.glob(layout.RENDER_PREFIX + "*")):
            if rdir.is_dir() and not rdir.is_symlink():
                for n in sorted(_WRITES_RENDER):
                    yield f"{sname}/{rdir.name}/{n}"


def refuse_collisions(out: Path, manifest: "Manifest | None", scenes: list[str]) -> None:
    """OutputStateError when a file the run did not write (no record, or changed since) stands at a
    name the run is about to write: it would be overwritten."""
    hits = []
    for rel in _files_run_writes(out, scenes):
        try:
            st = os.lstat(out / rel)
        except OSError:
            continue
        if stat.S_ISREG(st.st_mode) and (manifest is None or not manifest.may_replace(rel, st)):
            hits.append(rel)
    if hits:
        more = f" (and {len(hits) - 5} more)" if len(hits) > 5 else ""
        raise OutputStateError(
            f"output: {', '.join(str(out / h) for h in hits[:5])}{more}: not written by this run ({MANIFEST_FILE} "
            "has no record of it, or it changed since) but where the run writes; DataPipe never overwrites "
            "or adopts it (fix: move it out of the folder, then run again, or choose another --out; nothing was "
            "written)")


def check_force(out: Path) -> Manifest:
    """The manifest `--force` will remove, or a refusal that names why nothing will be removed."""
    m = Manifest.load(out)
    if m is None:
        raise DataPipeError(f"output: refusing to empty {out}: it holds no DataPipe manifest "
                            f"({MANIFEST_FILE}), so nothing in it is known to be a run's own file "
                            "(fix: choose another folder, or delete what you do not need yourself)")
    return m
