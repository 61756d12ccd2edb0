"""A run in this process, as `datapipe run` and `datapipe.api.run` make it: the run's own arguments
(`check_run_input`), the gate of checks with Blender's output kept in the run's log
(`check_config`, `blender_session`), then the pipeline under the output folder's lock, with Ctrl-C
stopping after the render in progress (`StopOnSignal`) and the overview sheet after a finished run
(`run_pipeline`). No bpy at import (bpy is imported when Blender is prepared)."""
from __future__ import annotations

import json
import os
import signal
import sys
import threading
from contextlib import contextmanager

from ..text_rules import output_folder_problem
from ..errors import DataPipeError
from ..io.layout import BLENDER_LOG
from ..io.outdir import OutLock
from .blender_log import BlenderLog


def check_config(cfg, verbose: bool = False):
    """What `validate` checks (also datapipe.api.validate(blender=True)): the gate of checks
    (datapipe/engine/gate.py) without an output folder: every field, before Blender is even imported,
    then the Blender preflight (mesh files imported and measured, scene.blend_file read), the part
    fit, the device's range and the memory. Raises ConfigError with every problem; writes nothing.
    Returns the gate's report (its `warnings`)."""
    from . import gate
    return gate.run_checks(cfg, blender_session=lambda: blender_session(BlenderLog(verbose=verbose)))


def print_warnings(warnings: list[str]) -> None:
    for w in warnings:
        print(f"datapipe: warning: {w}", file=sys.stderr)


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
                 on_event=None, on_step=None, on_warnings=print_warnings):
    """Run a config (after `check_run_input`) in one process, as `run` does (also datapipe.api.run):
    the gate of checks (datapipe/engine/gate.py: fields, Blender preflight, part fit, device, memory,
    output folder; its warnings to `on_warnings`), then the pipeline under the
    folder's lock, Ctrl-C stopping after the render in progress, Blender's output in OUT/blender.log,
    and the overview sheet after a finished run. `on_event(Progress)` gets the loop's events (render,
    scene, done, ...), `on_step(Progress)` the lines inside a scene (maybe from the heartbeat thread).
    Returns (the Pipeline, its last event: stage "done" or "cancelled")."""
    from .pipeline import Pipeline
    pipe = Pipeline(cfg, out, resume=resume, force=force, shard=shard, seed=seed, strict=strict, on_step=on_step)
    blender_log = BlenderLog(verbose=verbose)  # Blender's own output: OUT/blender.log (kept in
                                               # memory until the run folder may be written)
    report = pipe.check(blender_session=lambda: blender_session(blender_log))    # the gate, before anything is written
    on_warnings(report.warnings)
    last = None
    with OutLock(pipe.out), StopOnSignal(pipe), blender_log:
        pipe.check()                # again (rules + folder), under the lock: another run may have started
        for last in pipe.run():
            blender_log.log_to(pipe.out / BLENDER_LOG)   # the folder is prepared at the first event
            if on_event is not None:
                on_event(last)
        if last is not None and last.stage == "done":
            from ..show import overview_after_run
            with pipe.manifest.writing():       # the sheets are the run's files too
                overview_after_run(pipe.out, pipe.cfg.output)
                pipe.manifest.update()
            pipe.manifest.close()
    blender_log.close()
    return pipe, last


class StopOnSignal:
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
        from ..io import layout
        from ..io.files import atomic_path, read_json
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
def blender_session(log: BlenderLog):
    """Where the gate's Blender checks run: Blender's output into `log`, the bpy module's empty scene."""
    with log:
        _prepareblender_session()
        yield


def _prepareblender_session() -> None:
    """On the bpy module start from an empty scene; inside Blender with a .blend open, keep it."""
    with leave_on_interrupt():
        import bpy
        if not bpy.data.filepath:
            bpy.ops.wm.read_factory_settings(use_empty=True)


@contextmanager
def leave_on_interrupt():
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
