"""Drives `Pipeline.run()` from the UI: step by step under `bpy.app.timers` (Blender stays responsive,
with window-manager progress and a status line), or in one blocking loop when there is no event loop
(background mode: the bpy module, `blender -b`, tests), where timers never tick.

One run at a time per Blender process; its state lives here (not in the .blend), so a file saved
mid-run never believes it is still running. Blender's own output during each step (render
`Saved:` lines, importer timings) goes to the run's `blender.log` (datapipe.engine.blender_log), not the
system console; lines Blender marks as errors are shown there as well.
"""
from __future__ import annotations

import threading
import time
import traceback

import bpy

from ..engine.blender_log import BlenderLog
from ..errors import DataPipeError
from ..io.layout import BLENDER_LOG

TICK_S = 0.05            # pause between two pipeline steps (lets Blender redraw and handle events)


class Run:
    def __init__(self, pipeline, scene_name: str):
        self.pipeline = pipeline
        self.gen = pipeline.run()
        self.scene_name = scene_name
        self.started = time.perf_counter()
        self.last = None                     # last Progress
        self.cancel_requested = False
        self.error: str | None = None
        self.finished = False
        self.in_step = False                 # the pipeline itself may open a .blend (scene.blend_file)
        self.blender_log = BlenderLog()
        self.last_step = None                # last line inside a scene (datapipe/engine/progress.py)
        if getattr(pipeline, "on_step", False) is None:
            pipeline.on_step = self.on_step

    # -- status -----------------------------------------------------------------------------------
    def _props(self):
        scene = bpy.data.scenes.get(self.scene_name)
        if scene is None:                    # the run opened scene.blend_file: report in its scene
            scene = getattr(bpy.context, "scene", None)
        return getattr(scene, "datapipe", None) if scene is not None else None

    def set_status(self, text: str, fraction: float | None = None) -> None:
        props = self._props()
        if props is not None:
            props.status = text[:1000]
            if fraction is not None:
                props.progress = max(0.0, min(100.0, 100.0 * fraction))
        _redraw()

    def on_progress(self, p) -> None:
        self.last = p
        text = p.line() if hasattr(p, "line") else f"[{p.done}/{p.total}] {p.message}"
        if self.cancel_requested and p.stage not in ("cancelled", "done"):
            text += "  (cancelling after this render)"
        self.set_status(text, p.done / p.total if p.total else 1.0)
        wm = _wm()
        if wm is not None:
            wm.progress_update(p.done)

    def on_step(self, p) -> None:
        """A line inside a scene: shown at once from Blender's main thread (a step starting, the
        simulation's frames), the window redrawn although the pipeline step has not returned yet;
        the heartbeat thread's lines (during a Cycles call, when Blender cannot redraw anyway) are
        only kept (`last_step`), never touching bpy off the main thread."""
        self.last_step = p
        if threading.current_thread() is threading.main_thread():
            text = p.line() + ("  (cancelling after this render)" if self.cancel_requested else "")
            self.set_status(text, p.done / p.total if p.total else 1.0)
            if not bpy.app.background:
                try:      # the usual way to show a change while an operator still runs
                    bpy.ops.wm.redraw_timer(type="DRAW_WIN_SWAP", iterations=1)
                except RuntimeError:
                    pass

    # -- stepping ---------------------------------------------------------------------------------
    def step(self) -> bool:
        """Advance one pipeline event. False when the run is over (finished, cancelled, failed)."""
        self.in_step = True
        try:
            with self._capture():
                p = next(self.gen)
        except StopIteration:
            self.finish()
            return False
        except DataPipeError as e:            # ConfigError included: a user-fixable problem
            self.fail(str(e))
            return False
        except Exception as e:                # a bug: keep Blender alive, show it, print the traceback
            traceback.print_exc()
            self.fail(f"internal error ({type(e).__name__}: {e}); see the system console")
            return False
        finally:
            self.in_step = False
        self.on_progress(p)
        return True

    def _capture(self) -> BlenderLog:
        """Blender's output of this step: into OUT/blender.log once the run has prepared its folder
        (the pipeline's first event; nothing renders before it)."""
        out = getattr(self.pipeline, "out", None)
        if out is not None and getattr(self.pipeline, "manifest", None) is not None:
            self.blender_log.log_to(out / BLENDER_LOG)
        return self.blender_log

    def finish(self) -> None:
        self.finished = True
        p = self.last
        if p is not None and p.stage == "cancelled":
            self.set_status(f"Cancelled at {p.done}/{p.total}: everything written so far is kept "
                            "(Resume continues the run)")
        elif p is not None:
            if p.stage == "done":
                self._overview()
            self.set_status(f"Done: {p.done}/{p.total} renders in {self.pipeline.out}", 1.0)
        _end(self)

    def _overview(self) -> None:
        """The run's overview sheet (output.overview); a failure to draw it does not fail the run."""
        from ..show import overview_after_run
        try:
            with self.pipeline.manifest.writing():     # the sheet is the run's file too
                overview_after_run(self.pipeline.out, self.pipeline.cfg.output)
                self.pipeline.manifest.update()
            self.pipeline.manifest.close()
        except Exception:
            traceback.print_exc()

    def fail(self, message: str) -> None:
        self.finished = True
        if self.blender_log.path is not None:
            message += f" (Blender's own output: {self.blender_log.path})"
        self.error = message
        self.set_status(f"Error: {message}")
        print(f"DataPipe: run failed: {message}")
        try:
            self.gen.close()
        except Exception:
            traceback.print_exc()
        _end(self)

    def cancel(self) -> None:
        self.cancel_requested = True
        self.pipeline.cancel()
        self.set_status((self.last.line() if self.last is not None else "") + "  (cancelling after this render)")


_ACTIVE: Run | None = None


def active() -> Run | None:
    return _ACTIVE


def is_running() -> bool:
    return _ACTIVE is not None and not _ACTIVE.finished


def _wm():
    try:
        return bpy.context.window_manager
    except AttributeError:
        return None


def _redraw() -> None:
    wm = _wm()
    if wm is None:
        return
    for window in wm.windows:
        screen = window.screen
        if screen is None:
            continue
        for area in screen.areas:
            if area.type == "VIEW_3D":
                area.tag_redraw()


def _end(run: Run) -> None:
    global _ACTIVE
    run.blender_log.close()
    wm = _wm()
    if wm is not None:
        wm.progress_end()
    if _ACTIVE is run:
        _ACTIVE = None
    if _on_load_pre in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_on_load_pre)


@bpy.app.handlers.persistent
def _on_load_pre(*args):
    """The user opens another file mid-run: stop (what was written stays) rather than carry on in
    the new file. A load the pipeline makes itself (scene.blend_file, inside a step) is its own."""
    run = _ACTIVE
    if run is not None and not run.finished and not run.in_step:
        print("DataPipe: another file is being opened; the run stops here (Resume continues it)")
        stop_for_unregister()


def start(pipeline, scene_name: str, *, blocking: bool) -> Run:
    """Start `pipeline`. Blocking: run to the end here and return. Else: step it under a timer."""
    global _ACTIVE
    if is_running():
        raise DataPipeError("run: a run is already in progress (fix: wait for it or click Cancel)")
    run = Run(pipeline, scene_name)
    _ACTIVE = run
    wm = _wm()
    if wm is not None:
        wm.progress_begin(0, max(1, pipeline.total))
    run.set_status(f"[0/{pipeline.total}] starting", 0.0)
    if blocking:
        while run.step():
            pass
        return run
    if _on_load_pre not in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.append(_on_load_pre)
    # persistent: a run that opens scene.blend_file must keep ticking after that load
    bpy.app.timers.register(_tick, first_interval=TICK_S, persistent=True)
    return run


def _tick():
    run = _ACTIVE
    if run is None or run.finished:
        return None
    return TICK_S if run.step() else None


def cancel() -> bool:
    run = _ACTIVE
    if run is None or run.finished:
        return False
    run.cancel()
    return True


def stop_for_unregister() -> None:
    """Unregistering (or another file opened) mid-run: stop stepping, what was written stays."""
    global _ACTIVE
    if bpy.app.timers.is_registered(_tick):
        bpy.app.timers.unregister(_tick)
    if _on_load_pre in bpy.app.handlers.load_pre:
        bpy.app.handlers.load_pre.remove(_on_load_pre)
    run, _ACTIVE = _ACTIVE, None
    if run is not None and not run.finished:
        run.finished = True
        run.blender_log.close()
        run.pipeline.cancel()
        try:
            run.gen.close()
        except Exception:
            traceback.print_exc()
        wm = _wm()
        if wm is not None:
            wm.progress_end()
