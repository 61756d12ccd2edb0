"""Headless entry points: `python -m datapipe run|demo|validate|show|bop|sensors`.

Works on the `bpy` wheel and inside Blender:
    blender -b scene.blend --python-expr "import datapipe.cli as c; c.main(['run', 'preset.json', '--out', 'out'])"
Exit status: 0 done; 2 a mistake in the input or arguments (one message: field path + fix, nothing
written); 1 the file system or an output folder's state stopped the run (path + fix; `--debug` shows
the traceback); 130 stopped by Ctrl-C/SIGTERM (`--resume` continues).
"""
from __future__ import annotations

import argparse
import errno
import json
import os
import signal
import sys
import threading
import time
import traceback
from contextlib import contextmanager
from pathlib import Path

from . import config as config_mod
from .engine.blender_log import BlenderLog
from .errors import ConfigError, DataPipeError
from .io.layout import BLENDER_LOG
from .io.outdir import OutLock, OutputStateError
from .checks.text_rules import output_folder_problem


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m datapipe", description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="command", required=True)

    def run_args(sp, preset: bool):
        if preset:
            sp.add_argument("preset", help="JSON preset or an original DataPipe inputs pickle")
        sp.add_argument("--out", help="output folder (default: the preset's output.path)")
        sp.add_argument("--seed", type=int, help="base seed (default: the preset's scene.seed)")
        sp.add_argument("--resume", action="store_true", help="continue a killed run in --out")
        sp.add_argument("--force", action="store_true", help="first remove the files an earlier run in --out "
                        "wrote (as its manifest.json lists them; nothing else), after every check passed")
        sp.add_argument("--shard", default="0/1", help="i/n: make only the i-th of n scene ranges (0-based)")
        sp.add_argument("--ray", nargs="?", const="local", default=None, metavar="ADDRESS",
                        help="fan the run out over Ray (no address: a local Ray instance)")
        sp.add_argument("--shards", type=int, default=None, help="with --ray: number of shards")
        sp.add_argument("--retries", type=int, default=2, help="with --ray: retries of a failed shard")
        sp.add_argument("--quiet", action="store_true", help="no per-render progress lines")
        sp.add_argument("--verbose", action="store_true", help="show Blender's own output on the terminal too "
                        f"(it always goes to OUT/{BLENDER_LOG})")
        sp.add_argument("--debug", action="store_true", help="show the traceback of a file-system error")
        sp.add_argument("--strict", action="store_true", help="stop at a render that fails a quality gate "
                        "(black or saturated RGB, no visible part, < 1%% structured-light depth, parts lost)")

    run_args(sub.add_parser("run", help="make a dataset from a preset"), preset=True)
    demo = sub.add_parser("demo", help="make the embedded demo dataset (a bin with a few small parts)")
    run_args(demo, preset=False)
    demo.add_argument("--structured-light", choices=("on", "off"), default=None,
                      help="override the demo's structured-light switch")
    v = sub.add_parser("validate", help="check a preset (mesh files imported too) and list every problem")
    v.add_argument("preset")
    v.add_argument("--verbose", action="store_true", help="show Blender's own output (mesh imports)")
    v.add_argument("--debug", action="store_true", help="show the traceback of a file-system error")
    s = sub.add_parser("show", help="contact sheets for a run folder")
    s.add_argument("run_dir")
    s.add_argument("--out", help="sheet folder (default: RUN_DIR/sheets)")
    s.add_argument("--max", type=int, default=None, help="at most this many per-render sheets")
    s.add_argument("--no-overview", action="store_true", help="skip overview.png")
    s.add_argument("--grid", type=int, default=None, metavar="N",
                   help="instead of per-render sheets: one grid.png of N random renders")
    s.add_argument("--grid-seed", type=int, default=0, help="which renders --grid draws (default 0)")
    sub.add_parser("sensors", help="list the real-device presets (\"device\": NAME in a preset) with their "
                   "resolution, field of view, working distance, precision and source")
    b = sub.add_parser("bop", help="export a finished native run as a BOP dataset")
    b.add_argument("run_dir")
    b.add_argument("--out", help="BOP folder (default: RUN_DIR/bop)")
    b.add_argument("--depth-scale", type=float, default=0.1, help="mm per depth PNG unit (default 0.1)")
    b.add_argument("--chunk-size", type=int, default=1000, help="images per BOP scene folder (default 1000)")
    b.add_argument("--split", default="train_pbr", help="split folder name (default train_pbr, as the official "
                   "physically based training splits)")
    b.add_argument("--rgb-format", choices=("jpg", "png"), default="jpg", help="RGB files (default jpg, as "
                   "the official train_pbr splits)")
    b.add_argument("--jpg-quality", type=int, default=95, help="JPEG quality 1..100 (default 95)")
    return p


def _printable(path) -> str:
    """A path for stdout: a file name's non-UTF-8 bytes (surrogate escapes in Python) as \\x.. escapes,
    so a strict UTF-8 terminal prints it instead of raising UnicodeEncodeError."""
    return os.fsencode(path).decode("utf-8", "backslashreplace")


def _err(msg: str, code: int = 2) -> int:
    print(f"datapipe: error: {msg}", file=sys.stderr)
    return code


_OS_FIXES = {
    errno.EACCES: "check the folder's permissions or choose another --out",
    errno.EPERM: "check the folder's permissions or choose another --out",
    errno.EROFS: "the file system is read-only: choose another --out",
    errno.ENOSPC: "free disk space (or choose another --out), then run again with --resume",
    errno.EDQUOT: "free disk space (or choose another --out), then run again with --resume",
    errno.ENOENT: "check that the folder exists and was not removed during the run",
    errno.ENOTDIR: "a part of the path is a file, not a folder: check the path",
    errno.EISDIR: "the path is a folder where a file was expected: check the path",
}


def _os_error(e: OSError) -> int:
    where = e.filename or "?"
    fix = _OS_FIXES.get(e.errno, "check the path and the disk, then run again (with --resume for a run)")
    return _err(f"{where}: {e.strerror or e} (fix: {fix})", 1)


def main(argv: list[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    debug = getattr(args, "debug", False)
    try:
        return _command(args)
    except OutputStateError as e:
        return _err(str(e), 1)
    except (ConfigError, DataPipeError) as e:
        return _err(str(e))
    except OSError as e:
        if debug:
            traceback.print_exc()
        return _os_error(e)
    except KeyboardInterrupt:
        print("datapipe: interrupted (nothing half-written is kept as complete; --resume continues a run)",
              file=sys.stderr)
        return 130
    except MemoryError:
        if debug:
            traceback.print_exc()
        return _err("out of memory (fix: lower the resolution, samples or structured_light.steps)", 1)


def _command(args) -> int:
    if args.command == "validate":
        from .checks.gate import memory_summary
        cfg = config_mod.load(args.preset)
        report = check_config(cfg, verbose=args.verbose)
        _print_warnings(report.warnings)
        cams = (f"{len(cfg.camera.poses)} camera poses" if cfg.camera.sampler.kind == "pool"
                else f"camera poses drawn by the {cfg.camera.sampler.kind} sampler")
        sl = cfg.structured_light
        sl_text = (f"on ({'; '.join(_sl_plan(cfg) + [memory_summary(report.cfg)])})" if sl.enabled else "off")
        print(f"{_printable(args.preset)}: OK ({cfg.scene.num_renders} renders, {len(cfg.objects)} object entries, "
              f"{cams}, structured light {sl_text})")
        return 0
    if args.command == "sensors":
        from .checks.device_checks import table
        print(table())
        return 0
    if args.command == "show":
        from . import show
        from .io.layout import SHEETS_DIR
        _refuse_links_in_run_dir(args, SHEETS_DIR)
        return show.run_command(args)
    if args.command == "bop":
        from .io.bop import export_bop
        from .io.layout import BOP_DIR
        _refuse_links_in_run_dir(args, BOP_DIR)
        out = Path(args.out) if args.out else Path(args.run_dir) / BOP_DIR
        export_bop(Path(args.run_dir), out, depth_scale=args.depth_scale, chunk_size=args.chunk_size,
                   split=args.split, rgb_format=args.rgb_format, jpg_quality=args.jpg_quality)
        print(f"BOP dataset written to {out}")
        return 0
    if args.command == "demo":
        cfg = config_mod.default_config()
        if args.structured_light is not None:
            cfg.structured_light.enabled = args.structured_light == "on"
        return _run(cfg, args, preset_path=None)
    cfg = config_mod.load(args.preset)
    return _run(cfg, args, preset_path=args.preset)


def check_config(cfg, verbose: bool = False):
    """What `validate` checks (also datapipe.api.validate(blender=True)): the gate of checks
    (datapipe/checks/gate.py) without an output folder: every field, before Blender is even imported,
    then the Blender preflight (mesh files imported and measured, scene.blend_file read), the part
    fit, the device's range and the memory. Raises ConfigError with every problem; writes nothing.
    Returns the gate's report (its `warnings`)."""
    from .checks import gate
    return gate.run_checks(cfg, blender_session=lambda: _blender(BlenderLog(verbose=verbose)))


def _print_warnings(warnings: list[str]) -> None:
    for w in warnings:
        print(f"datapipe: warning: {w}", file=sys.stderr)


def _refuse_links_in_run_dir(args, folder: str) -> None:
    """`show`/`bop` writing into the run folder (no --out): not through a link there."""
    if args.out is None:
        from .io.outdir import refuse_links_under
        refuse_links_under(Path(args.run_dir), folder)


def _sl_plan(cfg) -> list[str]:
    """What the structured-light camera will do, as `validate` tells it: the fringe mode "auto"
    resolves to, the images per render, exposure and the reflection filter."""
    from .core.structured_light import resolve_fringe_mode
    s = cfg.structured_light
    mode = resolve_fringe_mode(cfg)
    n = len(s.periods) * s.steps
    rows = config_mod.builds_row_code(s, mode)
    images = f"{n} fringe images" + (f" (+{s.steps} row code{' on shiny renders' if s.reflection_filter == 'auto' else ''})"
                                      if rows else "")
    if mode == "quadrature":
        images += (f", mixed from {1 + 2 * len(s.periods)} rendered images (white + cos, sin per period"
                   f"{'; +2 for the row code' if rows else ''})")
    why = ""
    if s.fringe_mode == "auto":
        shiny = "a configured material is shiny" if s.reflection_filter != "global" else \
            "reflection_filter global needs a path-traced row code"
        why = {"quadrature": f" (auto: {shiny}; quadrature path-traces every light path at 1 + 2F images, "
                             "as render does at F x N)",
               "render": f" (auto: {shiny}, and projector_gamma {s.projector_gamma:g} rules out quadrature)",
               "fast": " (auto: every configured material is diffuse)"}[mode]
    hdr = f", HDR {s.hdr}" if s.hdr else ""
    return [f"fringe mode {mode}{why}", images, f"exposure {s.exposure}{hdr}",
            f"reflection filter {s.reflection_filter}"]


def _run(cfg, args, preset_path) -> int:
    from .draws.seeds import parse_shard
    try:
        shard = parse_shard(args.shard)
    except ValueError as e:
        return _err(str(e))
    check_run_input(cfg, args.out, args.seed)
    if args.ray is not None:
        from .engine.distributed import run_distributed
        if preset_path is None:
            raise DataPipeError("--ray needs a preset file (fix: `python -m datapipe run "
                                f"{config_mod.presets_dir() / 'default.json'} --ray` runs the demo preset)")
        run_distributed(preset_path, args.out or cfg.output.path,
                        address=None if args.ray == "local" else args.ray,
                        num_shards=args.shards, seed=args.seed, retries=args.retries,
                        extra_args=(["--quiet"] if args.quiet else []) + (["--strict"] if args.strict else [])
                        + (["--verbose"] if args.verbose else []),
                        blender_session=lambda: _blender(BlenderLog(verbose=args.verbose)),
                        warn=_print_warnings)     # the driver's gate, before OUT/_shards/ is written
        return 0
    t0 = time.perf_counter()

    def print_event(p) -> None:
        if not args.quiet or p.stage in ("done", "cancelled"):
            print(p.line(), file=sys.stderr, flush=True)
    pipe, last = run_pipeline(cfg, args.out, resume=args.resume, force=args.force, shard=shard, seed=args.seed,
                              strict=args.strict, verbose=args.verbose, on_event=print_event,
                              on_step=None if args.quiet else _print_step)
    if last is not None and last.stage == "cancelled":
        return 130
    print(f"dataset: {_printable(pipe.out)} ({pipe.total} renders, {time.perf_counter() - t0:.1f} s)")
    return 0


def check_run_input(cfg, out, seed) -> None:
    """The checks of a run's own arguments before anything else (`run`, `demo`, datapipe.api.run):
    the output folder's name, and the seed applied to the config (whose fields the gate of checks
    then checks, in `run_pipeline` or the Ray driver). Raises DataPipeError; writes nothing."""
    if out is not None and not os.fspath(out).strip():
        raise DataPipeError("--out: empty folder name (fix: give the output folder, e.g. --out out; "
                            "nothing was written)")
    bad_out = out is not None and output_folder_problem(os.fspath(out))
    if bad_out:
        raise DataPipeError(f"--out: {bad_out[0]} (fix: {bad_out[1]}; nothing was written)")
    if seed is not None:
        cfg.scene.seed = seed


def run_pipeline(cfg, out, *, resume: bool = False, force: bool = False, shard: tuple[int, int] = (0, 1),
                 seed: int | None = None, strict: bool = False, verbose: bool = False,
                 on_event=None, on_step=None, on_warnings=_print_warnings):
    """Run a config (after `check_run_input`) in one process, as `run` does (also datapipe.api.run):
    the gate of checks (datapipe/checks/gate.py: fields, Blender preflight, part fit, device, memory,
    output folder; its warnings to `on_warnings`), then the pipeline under the
    folder's lock, Ctrl-C stopping after the render in progress, Blender's output in OUT/blender.log,
    and the overview sheet after a finished run. `on_event(Progress)` gets the loop's events (render,
    scene, done, ...), `on_step(Progress)` the lines inside a scene (maybe from the heartbeat thread).
    Returns (the Pipeline, its last event: stage "done" or "cancelled")."""
    from .engine.pipeline import Pipeline
    pipe = Pipeline(cfg, out, resume=resume, force=force, shard=shard, seed=seed, strict=strict, on_step=on_step)
    blender_log = BlenderLog(verbose=verbose)  # Blender's own output: OUT/blender.log (kept in
                                               # memory until the run folder may be written)
    report = pipe.check(blender_session=lambda: _blender(blender_log))    # the gate, before anything is written
    on_warnings(report.warnings)
    last = None
    with OutLock(pipe.out), _StopOnSignal(pipe), blender_log:
        pipe.check()                # again (rules + folder), under the lock: another run may have started
        for last in pipe.run():
            blender_log.log_to(pipe.out / BLENDER_LOG)   # the folder is prepared at the first event
            if on_event is not None:
                on_event(last)
        if last is not None and last.stage == "done":
            from .show import overview_after_run
            overview_after_run(pipe.out, pipe.cfg.output)
            pipe.manifest.update()  # the sheets are the run's files too
    blender_log.close()
    return pipe, last


def _print_step(p) -> None:
    """A line inside a scene (datapipe/engine/progress.py); may come from the heartbeat thread."""
    print(p.line(), file=sys.stderr, flush=True)


class _StopOnSignal:
    """SIGINT/SIGTERM during a run: the first asks the pipeline to stop at its next safe point (after
    the render in progress); the second stops the process at once (run.json says "cancelled", every
    file is written atomically, so --resume continues either way).

    A Python signal handler runs only between bytecodes, and a Cycles render is one long C call, so
    the signals are read from `signal.set_wakeup_fd` by a thread (Blender releases the GIL while it
    renders) instead."""

    def __init__(self, pipe):
        self.pipe = pipe
        self.count = 0

    def __enter__(self):
        if threading.current_thread() is not threading.main_thread():
            return self                     # signals can only be set up in the main thread
        self.rfd, self.wfd = os.pipe()
        os.set_blocking(self.wfd, False)
        self.saved = {s: signal.signal(s, lambda *a: None) for s in (signal.SIGINT, signal.SIGTERM)}
        self.saved_fd = signal.set_wakeup_fd(self.wfd, warn_on_full_buffer=False)
        threading.Thread(target=self._watch, name="datapipe-signals", daemon=True).start()
        return self

    def _watch(self) -> None:
        while True:
            try:
                data = os.read(self.rfd, 16)
            except OSError:
                return
            if not data:
                return
            for _ in data:
                self.count += 1
                if self.count == 1:
                    print("datapipe: stopping after the render in progress (press Ctrl-C again to stop at "
                          "once; --resume continues)", file=sys.stderr, flush=True)
                    self.pipe.cancel()
                else:
                    self._stop_now()

    def _stop_now(self) -> None:
        from .io import layout
        from .io.files import atomic_path, read_json
        path = self.pipe.out / layout.RUN_FILE
        try:
            rec = read_json(path)
            rec["status"] = "cancelled"
            # not the main thread's temporary name (it may be writing run.json right now)
            with atomic_path(path, path.with_name(f"{path.name}.{os.getpid()}.stop.tmp")) as tmp:
                tmp.write_text(json.dumps(rec, indent=1) + "\n")
        except Exception:                   # best effort: a resumable run needs no status
            pass
        print("datapipe: stopped at once; --resume continues", file=sys.stderr, flush=True)
        os._exit(130)

    def __exit__(self, *exc):
        if not hasattr(self, "saved"):
            return
        signal.set_wakeup_fd(self.saved_fd)
        for s, h in self.saved.items():
            signal.signal(s, h)
        os.close(self.wfd)                  # the watcher's read returns: it ends
        os.close(self.rfd)


@contextmanager
def _blender(log: BlenderLog):
    """Where the gate's Blender checks run: Blender's output into `log`, the bpy module's empty scene."""
    with log:
        _prepare_blender()
        yield


def _prepare_blender() -> None:
    """On the bpy module start from an empty scene; inside Blender with a .blend open, keep it."""
    with _leave_on_interrupt():
        import bpy
        if not bpy.data.filepath:
            bpy.ops.wm.read_factory_settings(use_empty=True)


@contextmanager
def _leave_on_interrupt():
    """Ctrl-C while the bpy module starts: Blender's add-on registration meets the KeyboardInterrupt
    half-way, prints pages of tracebacks and crashes (exit -11). Nothing is written before the run
    takes its lock, so leave at once instead, with one line and exit status 130."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def leave(*_):
        print("datapipe: interrupted while Blender was starting; nothing was written", file=sys.stderr, flush=True)
        os._exit(130)
    saved = signal.signal(signal.SIGINT, leave)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, saved)


if __name__ == "__main__":
    sys.exit(main())
