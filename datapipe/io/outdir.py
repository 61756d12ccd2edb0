"""The output folder's safety rules: an exclusive lock, the manifest of what a run wrote, and the
refusals that keep a user's files safe. No bpy.

- Lock: `OUT/.datapipe.lock`, an `fcntl.flock` held for the whole run (the kernel drops it when
  the process exits or crashes, so a stale lock file never blocks). It holds the holder's pid for
  the refusal message. The lock file alone does not make a folder "not empty". Released by
  unlinking it while held; so an acquire checks, once it holds the lock, that the file it locked
  is still the one at the path (else it locked a file just released and unlinked: it tries again).
- Manifest, by record (datapipe/io/manifest.py): the path, size and SHA-256 of each file the run
  wrote, recorded as it wrote it. `--force` removes exactly the recorded files whose content is
  still the recorded one, and the folders the run made once they are empty.
- Refusals before anything is written (exit status 1, the path and the fix): a symbolic link where
  the run writes (it could lead the writes out of OUT), a file the run did not write at a path it
  writes, and a `scene.json` that is not this run's record. During the run the guard refuses the
  same at the write itself.
"""
from __future__ import annotations

import errno
import fcntl
import json
import os
import re
import stat
import time
from pathlib import Path
from typing import Iterator

from ..errors import DataPipeError, OutputStateError  # noqa: F401 (re-exported)
from . import guard, layout
from .manifest import JOURNAL_FILE, MANIFEST_FILE, MANIFEST_KEY, Manifest  # noqa: F401 (re-exported)

LOCK_FILE = ".datapipe.lock"

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


def remove_run_files(manifest: Manifest) -> tuple[int, list[str]]:
    """--force: remove what the manifest records as the run's (Manifest.remove_listed); returns (how
    many files were removed, every file kept in OUT: the ones the run did not write, or changed)."""
    removed = manifest.remove_listed()
    out = manifest.out
    kept = sorted(rel for name in meaningful_entries(out) for rel, _, is_dir in walk(out, name) if not is_dir)
    return removed, kept
