"""Progress events of a run, and the lines inside a scene: which step runs, what it renders, how
far it is, and the ETA. No bpy at import.

The run loop (engine/pipeline.py) yields `Progress` events between its steps (a render done, a scene
done). Inside a scene the world's work blocks for minutes (a drop, a Cycles call), so the loop
starts a `Tracker` for the run and hands it to the world (`World.report_to`, datapipe/world.py: the
world reports through the `Reporter` it is handed, `begin`, `advance`, `note`, `cycles`, and never
imports this module; outside a run it holds `SILENT`). The tracker hands
`Progress(stage="step")` events to the sink the pipeline was given (`on_step`: the CLI prints the
line, the add-on shows it), each at a step's start and then at least every `heartbeat_s` seconds
while the step lasts: from the caller when it advances (simulation frames) and from a heartbeat
thread while Blender holds the main thread (a Cycles call). Cycles' own progress comes from
`bpy.app.handlers.render_stats` ("Sample 5/16", "Rendered 2/4 Tiles"), hooked for each call.

ETA (`estimate_eta`): the rest of the current step (for a Cycles call its own "Remaining" estimate
less the time since it said so, else the rate of its samples since the first one it reported;
elapsed x (1 - f) / f when the step reports its fraction f: frames, tiles; else its mean duration
so far minus the time spent), the mean durations of the
render's later steps, and the renders after this one at the run's measured seconds per render.
Whatever is not known yet (no render finished) is left out and the ETA is shown as a lower bound
("ETA > 3m10s").
"""
from __future__ import annotations

import re
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable

from ..io import layout

STEP = "step"                # Progress.stage of a line inside a scene
# the steps of a render, in order (placement and simulation only in a scene's first render)
STEPS = ("placement", "simulation", "render", "write", "fringes", "decode", "maps", "annotate")
STEP_LABELS = {"placement": "placing parts", "simulation": "simulating", "render": "rendering (Cycles)",
               "write": "writing", "fringes": "structured light (Cycles)", "decode": "decoding",
               "maps": "writing structured-light maps", "annotate": "annotating"}
HEARTBEAT_S = 30.0


@dataclass
class Progress:
    stage: str                 # force | setup | scene | step | render | scene_done | skip | done | cancelled
    done: int                  # renders finished in this run (skipped-complete scenes included)
    total: int                 # renders this run (this shard) makes
    scene: int | None = None
    render: int | None = None
    elapsed: float = 0.0
    eta: float | None = None
    seconds: dict = field(default_factory=dict)    # per-stage seconds of the last render / scene
    message: str = ""
    step: str | None = None    # stage "step": one of STEPS
    what: str = ""             # what the step does or renders ("native: rgb, depth", "12 fringe layers")
    count: tuple | None = None     # (done, planned, unit) of the step: frames, samples, tiles
    step_elapsed: float = 0.0
    eta_lower: bool = False    # the ETA leaves out what cannot be estimated yet: a lower bound

    def line(self) -> str:
        eta = ""
        if self.eta is not None:
            eta = f", ETA {'> ' if self.eta_lower else ''}{fmt_s(self.eta)}"
        stages = ", ".join(f"{k} {v:.2f}s" for k, v in self.seconds.items() if v > 0)
        stages = f" ({stages})" if stages else ""
        where = ""
        if self.scene is not None:
            where = f" {layout.scene_name(self.scene)}"
            if self.render is not None:
                where += f"/{layout.render_name(self.render)}"
        message = self.message
        if self.stage == STEP:
            message = self.step_text()
        return f"[{self.done}/{self.total}]{where} {message}{stages}{eta}".rstrip()

    def step_text(self) -> str:
        text = STEP_LABELS.get(self.step or "", self.step or "")
        if self.what:
            text += f" {self.what}"
        if self.count is not None:
            n, of, unit = self.count
            text += f": {unit} {n}/{of}" if of else f": {unit} {n}"
        if self.step_elapsed >= 1.0:
            text += f", {fmt_s(self.step_elapsed)} in"
        if self.message:
            text += f" - {self.message}"
        return text


def fmt_s(s: float) -> str:
    s = int(round(s))
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else (f"{s // 60}m{s % 60:02d}s" if s >= 60 else f"{s}s")


def estimate_eta(step: str, step_elapsed: float, fraction: float | None, history: dict[str, float],
                 per_render: float | None, renders_after: int, *, render_follows: bool = True,
                 rest: float | None = None) -> tuple[float | None, bool]:
    """(seconds left in the run, lower bound?) while `step` of a render runs (module doc).
    `history`: mean seconds per render of each step seen so far; `per_render`: the run's measured
    seconds per render (scenes' drops included), None before the first render finished.
    `render_follows=False`: the step is the scene's own file writing after its renders, so no step
    of the render in progress follows it (only `renders_after` whole renders). `rest`: the seconds
    left in the step when the step itself says (a Cycles call: `Tracker.step_rest`)."""
    lower = False
    if rest is None:
        if fraction is not None and fraction > 0:
            rest = step_elapsed * (1.0 - min(fraction, 1.0)) / min(fraction, 1.0)
        elif step in history:
            rest = max(0.0, history[step] - step_elapsed)
        else:
            rest, lower = 0.0, True
    later = STEPS[STEPS.index(step) + 1:] if step in STEPS and render_follows else ()
    for s in later:              # (after a render step no scene step follows)
        if s in history:
            rest += history[s]
        elif not history:
            lower = True          # nothing finished yet: which steps follow is not known
    if renders_after > 0:
        if per_render is None:
            lower = True
        else:
            rest += per_render * renders_after
    if lower and rest <= 0:
        return None, True
    return rest, lower


class Tracker:
    """The run's step lines (module doc). `emit(Progress)` may be called from the heartbeat thread."""

    def __init__(self, emit: Callable[[Progress], None], heartbeat_s: float = HEARTBEAT_S,
                 clock: Callable[[], float] = time.perf_counter, cpu_clock: Callable[[], float] = time.process_time):
        # cpu_clock: the whole process's CPU time, every thread (Cycles' and numpy's included)
        self.emit_fn, self.heartbeat_s, self.clock, self.cpu_clock = emit, float(heartbeat_s), clock, cpu_clock
        self._lock = threading.RLock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.done = self.total = 0
        self.scene: int | None = None
        self.render: int | None = None
        self.per_render: float | None = None
        self.renders_after = 0
        self.step: str | None = None
        self.what = ""
        self.count: tuple | None = None
        self.cycles_status = ""
        self._frac: float | None = None             # a Cycles call's fraction done over its tiles
        self._cyc_remaining: tuple | None = None     # (clock, seconds) of Cycles' last "Remaining: ..."
        self._cyc_first: tuple | None = None         # (clock, sample) of the call's first sample count
        self._cyc_last: tuple | None = None          # (clock, sample) of its latest one
        self._t_step = self._t_emit = self._c_step = 0.0
        self._t0 = clock()
        self._totals: dict[str, dict] = {}          # step -> {"wall_s", "cpu_s", "n"} over the whole run
        self._sums: dict[str, list[float]] = {}     # step -> its seconds in each render that had it
        self._this: dict[str, float] = {}           # step -> seconds in the render in progress

    # -- where the run is ----------------------------------------------------------------------------
    def at(self, *, done: int, total: int, scene: int, render: int | None, per_render: float | None,
           renders_after: int) -> None:
        with self._lock:
            self._close_step()
            self.done, self.total, self.scene, self.render = done, total, scene, render
            self.per_render, self.renders_after = per_render, renders_after

    def render_done(self) -> None:
        """The render in progress finished: its steps' seconds join the history."""
        with self._lock:
            self._close_step()
            for k, v in self._this.items():
                self._sums.setdefault(k, []).append(v)
            self._this = {}

    def history(self) -> dict[str, float]:
        return {k: sum(v) / len(v) for k, v in self._sums.items() if v}

    # -- steps -----------------------------------------------------------------------------------------
    def begin(self, step: str, what: str = "") -> None:
        with self._lock:
            self._close_step()
            self.step, self.what, self.count, self.cycles_status, self._frac = step, what, None, "", None
            self._cyc_remaining = self._cyc_first = self._cyc_last = None
            self._t_step, self._c_step = self.clock(), self.cpu_clock()
            self._emit()

    def advance(self, n: int, of: int | None, unit: str = "frame") -> None:
        with self._lock:
            self.count = (int(n), int(of) if of else 0, unit)
            if self.clock() - self._t_emit >= self.heartbeat_s:
                self._emit()

    def note(self, message: str) -> None:
        with self._lock:
            self._emit(message)

    def end(self) -> None:
        """The step in progress is over (none follows before the next `at` or `begin`)."""
        with self._lock:
            self._close_step()

    def _close_step(self) -> None:
        if self.step is not None:
            wall, cpu = self.clock() - self._t_step, self.cpu_clock() - self._c_step
            self._this[self.step] = self._this.get(self.step, 0.0) + wall
            tot = self._totals.setdefault(self.step, {"wall_s": 0.0, "cpu_s": 0.0, "n": 0})
            tot["wall_s"] += wall
            tot["cpu_s"] += cpu
            tot["n"] += 1
        self.step, self.count = None, None

    def totals(self) -> dict[str, dict]:
        """Wall and CPU seconds of each step over the run so far, and how many times it ran
        (run.json's `stats.steps`; a step open now is not in it yet)."""
        with self._lock:
            return {k: dict(v) for k, v in self._totals.items()}

    def fraction(self) -> float | None:
        if self._frac is not None:
            return self._frac
        c = self.count
        # a drop stops when it settles, not at max_frames; a Cycles call's sample count says little
        # of its time (a call without tiles reports "Sample 1/16" once, then nothing until it is
        # done: measured; the setup before it is not sampling): `step_rest` reads it instead
        if c is None or not c[1] or c[2] in ("frame", "sample"):
            return None
        return c[0] / c[1]

    def step_rest(self) -> tuple[float | None, bool]:
        """(seconds left in the Cycles call in progress, at least that?) from Cycles' own
        "Remaining" (less the time since it said so; past it, 0 and a lower bound) or, without it,
        from its sample rate since the first sample count it reported; (None, False) when neither
        is known (the step's fraction or its history then gives the ETA)."""
        now = self.clock()
        if self._frac is None and self._cyc_remaining is not None:
            t, secs = self._cyc_remaining
            rest = secs - (now - t)
            return (rest, False) if rest > 0 else (0.0, True)
        first, last = self._cyc_first, self._cyc_last          # set with the count (cycles_stats)
        if self._frac is None and first is not None and last[1] > first[1]:
            per_sample = (last[0] - first[0]) / (last[1] - first[1])
            return max(0.0, per_sample * (self.count[1] - last[1]) - (now - last[0])), False
        return None, False

    def progress(self, message: str = "") -> Progress:
        now = self.clock()
        elapsed = now - self._t_step if self.step else 0.0
        eta, lower = (None, False)
        if self.step is not None:
            rest, rest_lower = self.step_rest()
            eta, lower = estimate_eta(self.step, elapsed, self.fraction(), self.history(), self.per_render,
                                      self.renders_after,
                                      render_follows=not (self.step == "write" and self.render is None),
                                      rest=rest)
            lower = lower or rest_lower
        return Progress(STEP, self.done, self.total, scene=self.scene, render=self.render,
                        elapsed=now - self._t0, eta=eta, eta_lower=lower, message=message or self.cycles_status,
                        step=self.step, what=self.what, count=self.count, step_elapsed=elapsed)

    def _emit(self, message: str = "") -> None:
        self._t_emit = self.clock()
        if self.step is None and not message:
            return
        self.emit_fn(self.progress(message))

    @contextmanager
    def cycles(self, step: str, what: str):
        """Around one Cycles call: a step line saying what it renders, then its samples/tiles through
        bpy.app.handlers.render_stats while it runs."""
        self.begin(step, what)
        import bpy

        def on_stats(*args):
            text = next((a for a in args if isinstance(a, str)), None)
            if text:
                self.cycles_stats(text)
        bpy.app.handlers.render_stats.append(on_stats)
        try:
            yield
        finally:
            try:
                bpy.app.handlers.render_stats.remove(on_stats)
            except ValueError:
                pass

    # -- the heartbeat -------------------------------------------------------------------------------
    def start(self) -> "Tracker":
        self._stop.clear()
        self._thread = threading.Thread(target=self._beat, name="datapipe-progress", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5)
            self._thread = None

    def _beat(self) -> None:
        # wakes every `tick` and speaks one tick early, so no gap exceeds heartbeat_s
        tick = max(0.05, min(0.5, self.heartbeat_s / 5))
        while not self._stop.wait(tick):
            with self._lock:
                if self.step is not None and self.clock() - self._t_emit >= self.heartbeat_s - tick:
                    self._emit()

    def cycles_stats(self, text: str) -> None:
        """One `render_stats` string of Cycles: samples, tiles, or what it does now."""
        with self._lock:
            s = _SAMPLE.search(text)
            t = _TILES.search(text)
            if s is not None:
                n, of = int(s.group(1)), int(s.group(2))
                self.count, self.cycles_status, self._frac = (n, of, "sample"), "", None
                now = self.clock()
                if self._cyc_first is None and n > 0:
                    self._cyc_first = (now, n)
                self._cyc_last = (now, n)
                r = _REMAINING.search(text)
                self._cyc_remaining = (now, _seconds(r)) if r is not None else None
                if t is not None and int(t.group(2)) > 1 and of > 0:     # samples count per tile
                    tiles, ntiles = int(t.group(1)), int(t.group(2))
                    self.cycles_status = f"tile {min(tiles + 1, ntiles)}/{ntiles}"
                    self._frac = min(1.0, (tiles + n / of) / ntiles)
            else:
                self.cycles_status = text.rsplit("|", 1)[-1].strip()[:80]


_SAMPLE = re.compile(r"Sample (\d+)/(\d+)")
_REMAINING = re.compile(r"Remaining:\s*(?:(\d+):)?(\d+):(\d+(?:\.\d+)?)")   # Cycles: [hh:]mm:ss.ss


def _seconds(m) -> float:
    return int(m.group(1) or 0) * 3600 + int(m.group(2)) * 60 + float(m.group(3))
_TILES = re.compile(r"Rendered (\d+)/(\d+) Tiles")
