"""Writes that cannot leave the output folder. No bpy.

While a run holds its output folder (`guarding(out, ledger)`), every write under it goes through
an opened directory handle of the folder instead of a path (datapipe/io/files.py asks `active_for`):

- each folder on the way is entered with `O_DIRECTORY | O_NOFOLLOW` from the folder's handle (made
  with `mkdir(dir_fd=...)` when missing), so a symbolic link put at `scene.0005`, a render folder or
  `models/` at any moment is refused at the next write into it, never followed;
- the temporary file is created with `O_CREAT | O_EXCL | O_NOFOLLOW` in that folder, so a link put
  at its name is refused; the writer (json, OpenEXR, cv2, shutil) writes through `/proc/self/fd/N`,
  which reaches the file that was created whatever its name now points at;
- the rename is `os.replace(src_dir_fd=, dst_dir_fd=)`, after checking that the temporary name still
  holds the file written and that what stands at the destination is not a link, not a folder and,
  when it is a file, one the run wrote (the ledger: datapipe/io/outdir.py's Manifest);
- the ledger records each file (path, size, sha256) before it is renamed into place;
- a file the run wrote and reads back (the BOP export reads the run's models/ and render maps) is
  opened the same way (`open_own`): never through a link, and only when the ledger records that very
  file with that content, so a link or a file of the user's put there meanwhile is refused, not read
  as the run's.

Linux only (dir_fd and /proc/self/fd): elsewhere `active_for` returns None and the writes use paths
as before (docs/RUNNING.md, data safety). Every refusal is an OutputStateError naming the path (exit 1).
"""
from __future__ import annotations

import errno
import hashlib
import os
import stat
import threading
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Protocol

from ..errors import OutputStateError

SUPPORTED = (os.open in os.supports_dir_fd and os.rename in os.supports_dir_fd   # os.replace: the same call
             and os.path.isdir("/proc/self/fd"))
_DIR_FLAGS = os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW | os.O_CLOEXEC
SCRATCH_PREFIX = ".datapipe.scratch."      # Blender's own pass files: a private folder inside OUT


class Ledger(Protocol):
    """What the run wrote (datapipe/io/outdir.py, Manifest)."""

    def record_file(self, rel: str, st: os.stat_result, digest: str) -> None: ...

    def record_dir(self, rel: str) -> None: ...

    def record_tmp(self, rel: str, st: os.stat_result) -> None: ...

    def record_append(self, rel: str) -> None: ...

    def is_own_tmp(self, rel: str, st: os.stat_result) -> bool: ...

    def may_replace(self, rel: str, st: os.stat_result) -> bool: ...

    def owns(self, rel: str, st: os.stat_result, fd: int) -> bool: ...


def link_refusal(out: Path, rel: str, target: str | None = None) -> OutputStateError:
    path = Path(out) / rel
    if target is None:
        try:
            target = os.readlink(path)
        except OSError:
            target = "?"
    return OutputStateError(
        f"output: {path} is a symbolic link (to {target}); DataPipe writes only inside {out} and never "
        "through a link, which could lead its writes (and --force) to files elsewhere (fix: replace the link "
        "by a real folder or file, or remove it, then run again with --resume, or choose another --out)")


def not_ours_refusal(out: Path, rel: str) -> OutputStateError:
    return OutputStateError(
        f"output: {Path(out) / rel} is not a file this run wrote (its manifest has no record of it, or it "
        "changed since) but stands where the run writes; DataPipe never overwrites it and never adopts it "
        "(fix: move it out of the folder, then run again with --resume, or choose another --out)")


def read_refusal(out: Path, rel: str, why: str) -> OutputStateError:
    """A file the run reads back as its own (a model, a render map) that is no longer the one it wrote."""
    return OutputStateError(
        f"output: {Path(out) / rel} {why}; the run reads it back as its own file, and DataPipe never reads "
        "another file (or one through a link) as the run's (fix: leave the output folder alone during a run; "
        "move what was put there out of the folder, then run again with --resume, which makes a scene whose "
        "files are missing again, or, where that is refused again (the run's models/ is written only when a run "
        "starts), with --force, which keeps every file of yours; or choose another --out)")


class OutGuard:
    """An output folder's opened handle and the writes made through it (see the module doc)."""

    def __init__(self, out: str | os.PathLike, ledger: Ledger | None = None):
        self.out = Path(os.path.abspath(out))
        self.ledger = ledger
        self.root_fd = os.open(self.out, os.O_RDONLY | os.O_DIRECTORY | os.O_CLOEXEC)
        self._scratch: tuple[str, int] | None = None
        self._lock = threading.Lock()

    def close(self) -> None:
        if self._scratch is not None:
            name, fd = self._scratch
            self._scratch = None
            try:
                for n in os.listdir(fd):
                    os.unlink(n, dir_fd=fd)
                os.rmdir(name, dir_fd=self.root_fd)
            except OSError:
                pass
            os.close(fd)
        os.close(self.root_fd)

    # -- paths ------------------------------------------------------------------------------------
    def rel(self, path: str | os.PathLike) -> str | None:
        """`path` relative to OUT ('/'-separated; lexically, no link is resolved), or None outside."""
        p = os.path.abspath(path)
        root = str(self.out)
        if p == root or not p.startswith(root + os.sep):
            return None
        return p[len(root) + 1:].replace(os.sep, "/")

    def open_dir(self, rel_dir: str, *, create: bool) -> int:
        """A handle of folder `rel_dir` of OUT ('' = OUT), every folder on the way entered without
        following a link (and made when missing and `create`). The caller closes it."""
        fd = os.dup(self.root_fd)
        done: list[str] = []
        try:
            for name in [n for n in rel_dir.split("/") if n]:
                if name in (".", ".."):
                    raise OutputStateError(f"output: {self.out / rel_dir}: a path with '{name}' leaves the "
                                           "output folder (fix: a plain relative name)")
                done.append(name)
                nxt = self._enter(fd, name, "/".join(done), create)
                os.close(fd)
                fd = nxt
            return fd
        except BaseException:
            os.close(fd)
            raise

    def _enter(self, fd: int, name: str, rel: str, create: bool) -> int:
        for _ in range(3):
            try:
                return os.open(name, _DIR_FLAGS, dir_fd=fd)
            except FileNotFoundError:
                if not create:
                    raise
                if self.ledger is not None:    # before the mkdir, as a file before its rename: a run
                    self.ledger.record_dir(rel)  # killed between the two still owns the folder it made
                try:
                    os.mkdir(name, 0o777, dir_fd=fd)
                except FileExistsError:
                    continue                   # made meanwhile (or a link put there): look again
            except OSError as e:
                if e.errno in (errno.ELOOP, errno.ENOTDIR):
                    self._refuse_non_dir(fd, name, rel)
                raise
        return os.open(name, _DIR_FLAGS, dir_fd=fd)

    def _refuse_non_dir(self, fd: int, name: str, rel: str) -> None:
        st = os.stat(name, dir_fd=fd, follow_symlinks=False)
        if stat.S_ISLNK(st.st_mode):
            raise link_refusal(self.out, rel, os.readlink(name, dir_fd=fd))
        raise OutputStateError(f"output: {self.out / rel} is a file where the run makes a folder (fix: move it "
                               "out of the folder, then run again with --resume, or choose another --out)")

    def make_dirs(self, path: str | os.PathLike) -> None:
        rel = self.rel(path)
        if rel is not None:
            os.close(self.open_dir(rel, create=True))

    # -- atomic writes ----------------------------------------------------------------------------
    @contextmanager
    def atomic(self, path: str | os.PathLike, tmp_name: str) -> Iterator[Path]:
        """Yield a path to write `path`'s new content to (`/proc/self/fd/N` of a temporary file
        `tmp_name` made beside it); renamed onto `path` when the block ends (see the module doc)."""
        rel = self.rel(path)
        folder, name = rel.rpartition("/")[::2] if "/" in rel else ("", rel)
        rel_tmp = f"{folder}/{tmp_name}" if folder else tmp_name
        d = self.open_dir(folder, create=True)
        try:
            fd = self._create_tmp(d, tmp_name, rel_tmp)
            try:
                yield Path(f"/proc/self/fd/{fd}")
                st = os.fstat(fd)
                self._same_file(d, tmp_name, rel_tmp, st)
                self.check_destination(d, name, rel)
                if self.ledger is not None:                # before the rename: a kill after it leaves it recorded
                    with open(f"/proc/self/fd/{fd}", "rb") as f:
                        digest = hashlib.file_digest(f, "sha256").hexdigest()
                    self.ledger.record_file(rel, st, digest)
                os.replace(tmp_name, name, src_dir_fd=d, dst_dir_fd=d)
            except BaseException:
                self._remove_if_same(d, tmp_name, fd)
                raise
            finally:
                os.close(fd)
        finally:
            os.close(d)

    def _create_tmp(self, d: int, tmp_name: str, rel_tmp: str) -> int:
        flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | os.O_NOFOLLOW | os.O_CLOEXEC
        for _ in range(2):
            try:
                fd = os.open(tmp_name, flags, 0o666, dir_fd=d)
            except FileExistsError:
                st = os.stat(tmp_name, dir_fd=d, follow_symlinks=False)
                if stat.S_ISLNK(st.st_mode):
                    raise link_refusal(self.out, rel_tmp, os.readlink(tmp_name, dir_fd=d)) from None
                if stat.S_ISREG(st.st_mode) and self.ledger is not None and self.ledger.is_own_tmp(rel_tmp, st):
                    os.unlink(tmp_name, dir_fd=d)          # the run's own, left by a killed call
                    continue
                raise not_ours_refusal(self.out, rel_tmp) from None
            if self.ledger is not None:
                self.ledger.record_tmp(rel_tmp, os.fstat(fd))
            return fd
        raise not_ours_refusal(self.out, rel_tmp)

    def _same_file(self, d: int, tmp_name: str, rel_tmp: str, st: os.stat_result) -> None:
        """The temporary name still holds the file written (not a link or file put there meanwhile)."""
        try:
            now = os.stat(tmp_name, dir_fd=d, follow_symlinks=False)
        except FileNotFoundError:
            raise OutputStateError(f"output: {self.out / rel_tmp} was removed while the run wrote it (fix: "
                                   "leave the output folder alone during a run; --resume continues)") from None
        if stat.S_ISLNK(now.st_mode):
            raise link_refusal(self.out, rel_tmp, os.readlink(tmp_name, dir_fd=d))
        if (now.st_dev, now.st_ino) != (st.st_dev, st.st_ino):
            raise not_ours_refusal(self.out, rel_tmp)

    def check_destination(self, d: int, name: str, rel: str) -> None:
        """Refuse a link, a folder, or a file the run did not write at `name` in folder `d`."""
        try:
            st = os.stat(name, dir_fd=d, follow_symlinks=False)
        except FileNotFoundError:
            return
        if stat.S_ISLNK(st.st_mode):
            raise link_refusal(self.out, rel, os.readlink(name, dir_fd=d))
        if not stat.S_ISREG(st.st_mode) or (self.ledger is not None and not self.ledger.may_replace(rel, st)):
            raise not_ours_refusal(self.out, rel)

    @staticmethod
    def _remove_if_same(d: int, name: str, fd: int) -> None:
        try:
            st, now = os.fstat(fd), os.stat(name, dir_fd=d, follow_symlinks=False)
            if (now.st_dev, now.st_ino) == (st.st_dev, st.st_ino):
                os.unlink(name, dir_fd=d)
        except OSError:
            pass

    # -- reads of the run's own files ---------------------------------------------------------------
    def open_own(self, path: str | os.PathLike) -> int:
        """A read-only handle of the file the run wrote at `path` (see the module doc): every folder
        on the way entered without following a link, the file opened with O_NOFOLLOW (O_NONBLOCK: a
        FIFO put there is not waited on), and, with a ledger, only when it records this very file
        with this content. A link, a file that is not the run's (or changed), a removed file or
        folder: OutputStateError naming it. The caller closes the handle."""
        rel = self.rel(path)
        folder, _, name = rel.rpartition("/")
        try:
            d = self.open_dir(folder, create=False)
        except FileNotFoundError:
            raise read_refusal(self.out, folder, "was removed during the run") from None
        try:
            try:
                fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW | os.O_NONBLOCK | os.O_CLOEXEC, dir_fd=d)
            except FileNotFoundError:
                raise read_refusal(self.out, rel, "was removed during the run") from None
            except OSError as e:
                if e.errno == errno.ELOOP:
                    raise read_refusal(self.out, rel, f"was replaced during the run by a symbolic link (to "
                                                      f"{os.readlink(name, dir_fd=d)})") from None
                raise
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode) or (self.ledger is not None and not self.ledger.owns(rel, st, fd)):
                os.close(fd)
                raise read_refusal(self.out, rel, "is not the file the run wrote there (its manifest has no record "
                                                  "of this content)")
            return fd
        finally:
            os.close(d)

    # -- other writes -----------------------------------------------------------------------------
    def open_append(self, path: str | os.PathLike) -> int:
        """A file of OUT opened for appending, never through a link: made (and recorded) when
        missing, else only when it is the run's."""
        rel = self.rel(path)
        folder, _, name = rel.rpartition("/")
        d = self.open_dir(folder, create=True)
        flags = os.O_WRONLY | os.O_APPEND | os.O_NOFOLLOW | os.O_CLOEXEC
        try:
            try:
                fd = os.open(name, flags | os.O_CREAT | os.O_EXCL, 0o666, dir_fd=d)
                if self.ledger is not None:
                    self.ledger.record_append(rel)
                return fd
            except FileExistsError:
                self.check_destination(d, name, rel)
                return os.open(name, flags, dir_fd=d)
        finally:
            os.close(d)

    def open_source(self, path: str | os.PathLike) -> int:
        """A handle of a folder files are moved in from (a shard's scene folder): inside OUT entered
        as every folder of OUT (no link on the way), elsewhere opened at the path given. The caller
        closes it."""
        rel = self.rel(path)
        if rel is not None:
            return self.open_dir(rel, create=False)
        return os.open(path, _DIR_FLAGS & ~os.O_NOFOLLOW)

    def move_in(self, src_dir: int, name: str, rel: str, *, copy: bool = False, by_path: bool = False) -> None:
        """Put the regular file `name` of the opened folder `src_dir` at OUT/`rel`, never through a
        link: the source opened without following one, the destination folder entered as for an
        atomic write and checked as its destination is; recorded (path, size, SHA-256, or by path
        only when `by_path`: a log the run appended to) before it is renamed into place (copied
        through a temporary beside it when `copy` or on another filesystem)."""
        folder, _, dname = rel.rpartition("/")
        src_rel = name
        try:
            fd = os.open(name, os.O_RDONLY | os.O_NOFOLLOW | os.O_CLOEXEC, dir_fd=src_dir)
        except OSError as e:
            if e.errno == errno.ELOOP:
                raise OutputStateError(
                    f"output: {self._source_path(src_dir, src_rel)} is a symbolic link (to "
                    f"{os.readlink(name, dir_fd=src_dir)}) where a file of the run was to be moved into {self.out}; "
                    "DataPipe never moves or follows a link (fix: remove the link, make that scene again with "
                    "--resume, then run again)") from None
            raise
        try:
            st = os.fstat(fd)
            if not stat.S_ISREG(st.st_mode):
                raise OutputStateError(f"output: {self._source_path(src_dir, src_rel)} is not a regular file "
                                       "(fix: remove it, then run again)")
            if copy:
                self._copy_in(fd, rel, by_path)
                return
            d = self.open_dir(folder, create=True)
            try:
                self.check_destination(d, dname, rel)
                self._record(fd, rel, st, by_path)
                try:
                    os.replace(name, dname, src_dir_fd=src_dir, dst_dir_fd=d)
                except OSError as e:
                    if e.errno != errno.EXDEV:
                        raise
                    self._copy_in(fd, rel, by_path)
                    self._remove_if_same(src_dir, name, fd)
                    return
                now = os.stat(dname, dir_fd=d, follow_symlinks=False)
                if (now.st_dev, now.st_ino) != (st.st_dev, st.st_ino):      # the source name was swapped meanwhile
                    raise not_ours_refusal(self.out, rel)
            finally:
                os.close(d)
        finally:
            os.close(fd)

    def move_tree(self, src: str | os.PathLike, rel: str, *, copy: bool = False) -> None:
        """Every file under folder `src` put at the same place under OUT/`rel` by `move_in` (its
        temporaries `*.tmp` left out), folders made as a write makes them; a moved-from folder is
        removed once empty. A link met on either side is refused, naming it."""
        fd = self.open_source(src)
        try:
            self._move_entries(fd, rel, copy)
        finally:
            os.close(fd)

    def _move_entries(self, src_dir: int, rel: str, copy: bool) -> None:
        self.make_dirs(self.out / rel)
        with os.scandir(src_dir) as it:
            entries = sorted((e.name, e.is_dir(follow_symlinks=False)) for e in it)
        for name, is_dir in entries:
            if not is_dir:
                if not name.endswith(".tmp"):
                    self.move_in(src_dir, name, f"{rel}/{name}", copy=copy)
                continue
            try:
                sub = os.open(name, _DIR_FLAGS, dir_fd=src_dir)
            except OSError as e:
                if e.errno in (errno.ELOOP, errno.ENOTDIR):
                    raise OutputStateError(
                        f"output: {self._source_path(src_dir, name)} is no longer a folder (a symbolic link or a "
                        f"file was put there) while its files were moved into {self.out} (fix: remove it, make "
                        "that scene again with --resume, then run again)") from None
                raise
            try:
                self._move_entries(sub, f"{rel}/{name}", copy)
            finally:
                os.close(sub)
            if not copy:
                try:
                    os.rmdir(name, dir_fd=src_dir)
                except OSError:
                    pass                            # not empty (a temporary left out): stays with its shard

    def _copy_in(self, src_fd: int, rel: str, by_path: bool) -> None:
        import shutil
        name = rel.rpartition("/")[2]
        with self.atomic(self.out / rel, name + ".tmp") as through, open(through, "wb") as f:
            os.lseek(src_fd, 0, os.SEEK_SET)
            with os.fdopen(os.dup(src_fd), "rb") as src:
                shutil.copyfileobj(src, f)
        if by_path and self.ledger is not None:
            self.ledger.record_append(rel)

    def _record(self, fd: int, rel: str, st: os.stat_result, by_path: bool) -> None:
        if self.ledger is None:
            return
        if by_path:
            self.ledger.record_append(rel)
            return
        os.lseek(fd, 0, os.SEEK_SET)
        with os.fdopen(os.dup(fd), "rb") as f:
            digest = hashlib.file_digest(f, "sha256").hexdigest()
        self.ledger.record_file(rel, st, digest)

    @staticmethod
    def _source_path(src_dir: int, name: str) -> str:
        try:
            return os.path.join(os.readlink(f"/proc/self/fd/{src_dir}"), name)
        except OSError:
            return name

    def scratch_dir(self) -> Path:
        """A private folder inside OUT for files another program writes by path (Blender's pass
        files), as `/proc/self/fd/N`: reached through its handle whatever is put at its name."""
        with self._lock:
            if self._scratch is None:
                name = f"{SCRATCH_PREFIX}{os.getpid()}"
                try:
                    os.mkdir(name, 0o700, dir_fd=self.root_fd)
                except FileExistsError:
                    pass                    # a killed call's (same pid again is rare): entered below, or refused
                self._scratch = (name, self.open_dir(name, create=False))
            return Path(f"/proc/self/fd/{self._scratch[1]}")


# ------------------------------------------------------------------------------------------------
# the guards of this process (a run's output folder while it runs)

_active: list[OutGuard] = []


def active_for(path: str | os.PathLike) -> OutGuard | None:
    """The guard whose output folder holds `path` (lexically), if any."""
    for g in reversed(_active):
        if g.rel(path) is not None:
            return g
    return None


@contextmanager
def guarding(out: str | os.PathLike, ledger: Ledger | None = None) -> Iterator[OutGuard | None]:
    """Route every write under `out` through an OutGuard while the block runs (None where the
    platform lacks dir_fd or /proc/self/fd)."""
    if not SUPPORTED:
        yield None
        return
    g = OutGuard(out, ledger)
    _active.append(g)
    try:
        yield g
    finally:
        _active.remove(g)
        g.close()
