"""The output folder's safety rules: an exclusive lock, the manifest of what a run wrote, and the
refusals that keep a user's files safe. No bpy.

- Lock: `OUT/.datapipe.lock`, an `fcntl.flock` held for the whole run (the kernel drops it when
  the process exits or crashes, so a stale lock file never blocks). It holds the holder's pid for
  the refusal message. The lock file alone does not make a folder "not empty".
- Manifest: `OUT/manifest.json` lists every file and folder of the run's own layout that appeared
  in OUT after the run started (`foreign` remembers what was there before, e.g. a README the user
  keeps next to a run, or notes in a scene folder; inside scene folders only the layout's own
  names count as the run's). `--force` removes exactly the listed paths and nothing else.
- Refusals before anything is written (exit status 1, the path and the fix): a symbolic link where
  the run writes (it could lead the writes out of OUT), a file of someone else's at a path the run
  writes, and a `scene.json` that is not this run's record.
"""
from __future__ import annotations

import errno
import fcntl
import json
import os
import re
import stat
from pathlib import Path
from typing import Iterator

from ..errors import DataPipeError, OutputStateError  # noqa: F401 (re-exported)
from . import layout
from .files import write_text_atomic

LOCK_FILE = ".datapipe.lock"
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
    """What a run wrote into OUT (see the module doc)."""

    def __init__(self, out: Path, foreign: list[str], files: list[str]):
        self.out, self._foreign, self._files = Path(out), set(foreign), set(files)

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
        """Begin (or, resuming, continue) the manifest of the run about to write into `out`: what
        is there now and is not the earlier run's is foreign (never removed, never adopted)."""
        earlier = cls.load(out)
        if resume and earlier is not None:
            m = earlier
        else:
            m = cls(out, cls.present_foreign(out, earlier, adopt_layout=resume), [])
        m.update()
        return m

    @staticmethod
    def present_foreign(out: Path, earlier: "Manifest | None", *, adopt_layout: bool) -> list[str]:
        """Paths in `out` now (top-level names; inside the layout's folders, every path) that are not
        the earlier run's. adopt_layout: a run resumed without a manifest owns the layout's names."""
        foreign = []
        for name in meaningful_entries(out):
            if name == MANIFEST_FILE:
                continue
            for rel, *_ in (walk(out, name) if _OWN_TOP.match(name) else [(name,)]):
                if earlier is not None and earlier.owns(rel):
                    continue
                if adopt_layout and earlier is None and is_run_path(rel):
                    continue
                foreign.append(rel)
        return foreign

    def only_itself(self) -> bool:
        """Whether the run wrote nothing but this manifest (it stopped before its first record, e.g.
        on a full disk): resuming it is starting it."""
        return not any((self.out / f).exists() for f in self.files if f != MANIFEST_FILE)

    def owns(self, rel: str) -> bool:
        """Whether `rel` is the run's: listed, or a layout name that was not there before the run."""
        return rel in self._files or (rel not in self._foreign and is_run_path(rel))

    @property
    def files(self) -> list[str]:
        return sorted(self._files)

    @property
    def foreign(self) -> list[str]:
        return sorted(self._foreign)

    def _ours_now(self) -> set[str]:
        """The listed paths and the run's paths in OUT now (a killed call's last files included)."""
        ours = set(self._files)
        for top in own_tops(self.out):
            ours.update(rel for rel, *_ in walk(self.out, top) if self.owns(rel))
        return ours

    def update(self) -> None:
        """Add every path of the run's layout that is in OUT now and was not there before the run."""
        self._files = self._ours_now() | {MANIFEST_FILE}
        write_text_atomic(self.out / MANIFEST_FILE,
                          json.dumps({MANIFEST_KEY: 1, "foreign": self.foreign, "files": self.files}, indent=0))

    def collisions(self) -> list[str]:
        """Files of someone else's (foreign) at names the run's layout writes: it would overwrite them."""
        return sorted(rel for top in own_tops(self.out) for rel, _, is_dir in walk(self.out, top)
                      if rel in self._foreign and is_run_path(rel) and not is_dir)

    def remove_listed(self) -> int:
        """Delete the run's files (deepest first), then its folders that are empty after it. A path
        that is not inside OUT, a foreign one, or a folder that still holds something else is kept."""
        root = self.out.resolve()
        removed = 0
        for rel in sorted(self._ours_now(), key=lambda r: r.count("/"), reverse=True):
            p = self.out / rel
            if ".." in Path(rel).parts or Path(rel).is_absolute() or rel in self._foreign:
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


def scene_folders(out: Path) -> dict[str, int]:
    """{folder name: scene index} of the scene folders (layout names) in `out`."""
    return {p.name: int(p.name[len(layout.SCENE_PREFIX):]) - 1 for p in layout.scene_dirs(out)
            if _SCENE_DIR.match(p.name)}


def refuse_collisions(manifest: Manifest) -> None:
    """OutputStateError when a foreign file sits at a name the run writes (it would be overwritten)."""
    hits = manifest.collisions()
    if hits:
        more = f" (and {len(hits) - 1} more)" if len(hits) > 1 else ""
        raise OutputStateError(
            f"output: {manifest.out / hits[0]}{more} is not a file of this run ({MANIFEST_FILE} lists it as "
            "there before the run) but sits where the run writes; DataPipe never overwrites it (fix: move it "
            "out of the folder, then run again, or choose another --out; nothing was written)")


def check_force(out: Path) -> Manifest:
    """The manifest `--force` will remove, or a refusal that names why nothing will be removed."""
    m = Manifest.load(out)
    if m is None:
        raise DataPipeError(f"output: refusing to empty {out}: it holds no DataPipe manifest "
                            f"({MANIFEST_FILE}), so nothing in it is known to be a run's own file "
                            "(fix: choose another folder, or delete what you do not need yourself)")
    return m
