"""What every benchmark shares (no bpy): timing (wall and process CPU seconds, repeats with their best
and median, a child process's CPU and peak memory), the machine line of a report, result tables
(rows of dicts as Markdown and CSV under benchmarks/results/, the hand-written `<stem>_notes.md`
appended), the frame of a log-scaled plot (OpenCV: the environment has no plotting library) and the
command-line conventions (`--quick`: each script's smallest run, a smoke test; benchmarks/README.md
gives each one's measured time).

A benchmark script imports it as `from harness import ...` (scripts run as `python benchmarks/x.py`,
so benchmarks/ is on the path); `on_path("tests")` puts the repository (and tests/, whose scenes and
parts the benchmarks share) before the rest. `BENCH_RESULTS=DIR` sends every report to DIR instead
of benchmarks/results/, so a `--quick` check leaves the kept results as they are.
"""
from __future__ import annotations

import argparse
import csv
import gc
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
# where the reports go; BENCH_RESULTS points a smoke run (tests, a --quick check) elsewhere, so the
# kept results are not overwritten by a smaller run
RESULTS = Path(os.environ.get("BENCH_RESULTS") or ROOT / "benchmarks" / "results")


def on_path(*subdirs: str) -> None:
    """Put the repository and its `subdirs` (e.g. "tests", "tests/sl": the scenes and parts the tests
    share with the benchmarks) first on sys.path, so a script run from anywhere imports this
    checkout's datapipe."""
    for p in [ROOT / d for d in subdirs] + [ROOT]:
        if str(p) not in sys.path:
            sys.path.insert(0, str(p))


# -- timing ----------------------------------------------------------------------------------------
@dataclass
class Timing:
    """Seconds of each repeat: wall (`time.perf_counter`) and process CPU (`time.process_time`, all
    threads of this process: the figure other jobs on a shared machine inflate least)."""
    wall: list[float] = field(default_factory=list)
    cpu: list[float] = field(default_factory=list)

    @property
    def wall_s(self) -> float:
        return statistics.median(self.wall)

    @property
    def cpu_s(self) -> float:
        return statistics.median(self.cpu)

    @property
    def best_wall_s(self) -> float:
        return min(self.wall)

    @property
    def best_cpu_s(self) -> float:
        return min(self.cpu)


class Stopwatch:
    """`with Stopwatch() as t: ...` (or `t = Stopwatch().start()` ... `t.stop()`), then `t.wall_s`
    and `t.cpu_s` (process CPU seconds) of what ran between."""

    def start(self) -> "Stopwatch":
        self._w, self._c = time.perf_counter(), time.process_time()
        return self

    def stop(self) -> "Stopwatch":
        self.wall_s = time.perf_counter() - self._w
        self.cpu_s = time.process_time() - self._c
        return self

    def __enter__(self) -> "Stopwatch":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def preset_dict(path: Path) -> dict:
    """A preset's JSON as a dict, its objects' mesh paths made absolute, so that a benchmark can change
    it and load or write it anywhere (entries without a file, e.g. procedural distractors, as they are)."""
    path = Path(path)
    d = json.loads(path.read_text())
    for o in d.get("objects", []):
        if o.get("filepath"):
            o["filepath"] = str((path.parent / o["filepath"]).resolve())
    return d


def slug(name: str) -> str:
    """A case name as a file-name stem."""
    return "".join(ch if ch.isalnum() else "_" for ch in name)


def timed(fn, repeat: int = 1, warmup: bool = False) -> tuple[object, Timing]:
    """Call `fn()` `repeat` times (after one untimed call with `warmup`), garbage collected before
    each; returns the last result and the Timing of the timed calls."""
    if warmup:
        fn()
    t, out = Timing(), None
    for _ in range(repeat):
        gc.collect()
        with Stopwatch() as s:
            out = fn()
        t.wall.append(s.wall_s)
        t.cpu.append(s.cpu_s)
    return out, t


def clocked(fn) -> tuple[object, float, float]:
    """One call of `fn()`: (its result, wall seconds, process CPU seconds)."""
    with Stopwatch() as t:
        out = fn()
    return out, t.wall_s, t.cpu_s


def round_robin(fns: dict, repeat: int) -> dict[str, Timing]:
    """Each callable timed `repeat` times in turns (after one warm-up call each), so the load of a
    shared machine falls on all of them alike."""
    for f in fns.values():
        f()
    out = {k: Timing() for k in fns}
    for _ in range(repeat):
        for k, f in fns.items():
            _, t = timed(f)
            out[k].wall += t.wall
            out[k].cpu += t.cpu
    return out


def peak_rss_mib() -> float:
    """Peak resident memory of this process so far (Linux reports ru_maxrss in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def children_cpu_s() -> float:
    """CPU seconds of the waited-for child processes so far (user + system)."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


@dataclass
class ChildRun:
    returncode: int
    wall_s: float
    cpu_s: float            # the child's user + system seconds, every thread
    peak_rss_mib: float     # os.wait4's ru_maxrss: the child's peak, but never below parent_peak_mib
    parent_peak_mib: float = 0.0   # this process's own peak when it started the child

    @property
    def peak_is_childs(self) -> bool:
        """Whether `peak_rss_mib` is the child's own peak. Linux carries the spawning process's peak
        resident memory over fork and exec into the child's ru_maxrss (a child of a 1.5 GB-peak
        Python process that runs `pass` reports 1.5 GB), so a figure not above this process's own
        peak only bounds the child's from above. The benchmarks start their children from a small
        driver process, where this holds."""
        return self.peak_rss_mib > self.parent_peak_mib


def _own_peak_mib() -> float:
    """This process's own peak resident memory (Linux: VmHWM of /proc/self/status, the peak of its
    memory since its exec, which is what a child it starts inherits; ru_maxrss would also hold
    what its own parent carried into it), MiB; elsewhere ru_maxrss."""
    try:
        with open("/proc/self/status") as f:
            return next(int(ln.split()[1]) for ln in f if ln.startswith("VmHWM:")) / 1024
    except (OSError, StopIteration, ValueError):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / (1024 if sys.platform != "darwin" else 2 ** 20)


def run_child(cmd: list[str], **popen) -> ChildRun:
    """Run one command to its end and measure it alone (`os.wait4`: its own CPU and peak memory,
    not those of other children; the peak with the caveat of `ChildRun.peak_is_childs`)."""
    parent = _own_peak_mib()
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, **popen)
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return ChildRun(proc.returncode, time.perf_counter() - t0, usage.ru_utime + usage.ru_stime,
                    usage.ru_maxrss / 1024, parent)


# -- the machine line ------------------------------------------------------------------------------
def machine() -> str:
    """OS, architecture, logical CPUs, CPU model and memory of this machine, in one phrase."""
    model = ""
    try:
        model = next((ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name")), "")
    except OSError:
        pass
    mem = ""
    try:
        kb = int(next(ln.split()[1] for ln in open("/proc/meminfo") if ln.startswith("MemTotal")))
        mem = f", {kb / 2 ** 20:.0f} GiB RAM"
    except (OSError, StopIteration, ValueError):
        pass
    return f"{platform.system()} {platform.machine()}, {os.cpu_count()} logical CPUs ({model}){mem}"


def today() -> str:
    return time.strftime("%Y-%m-%d")


# -- tables ----------------------------------------------------------------------------------------
def md_table(header: list[str], rows: list[list]) -> list[str]:
    """Markdown table lines: the header, its rule, one line per row (cells as given, str()-ed)."""
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)] + [
        "| " + " | ".join(str(c) for c in r) + " |" for r in rows]


def column_table(rows: list[dict], cols: list[tuple[str, str]]) -> str:
    """A Markdown table of `rows` over `cols` = [(key, format)], as one string; a non-finite float
    is "-"."""
    def cell(f, v):
        return "-" if isinstance(v, float) and not np.isfinite(v) else f.format(v)
    head = "| " + " | ".join(c for c, _ in cols) + " |\n|" + "---|" * len(cols) + "\n"
    return head + "".join("| " + " | ".join(cell(f, r[c]) for c, f in cols) + " |\n" for r in rows)


def write_with_notes(path: Path, lines: list[str]) -> None:
    """Write a generated report with the hand-written findings of `<stem>_notes.md` appended."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    notes = path.with_name(f"{path.stem}_notes.md")
    if notes.is_file():
        lines = [*lines, notes.read_text()]
    path.write_text("\n".join(lines) + "\n")


def _columns(rows: list[dict]) -> list[str]:
    keys: dict[str, None] = {}
    for r in rows:
        keys.update(dict.fromkeys(r))
    return list(keys)


def write_rows_csv(path: Path, rows: list[dict], fields: list[str] | None = None, float_fmt: str | None = None) -> None:
    """Rows of one benchmark as CSV: the columns are `fields`, else every key in first-seen order
    (a row without one leaves it empty); `float_fmt` (e.g. ".6g") formats the floats."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fmt = (lambda v: format(v, float_fmt) if isinstance(v, float) else v) if float_fmt else (lambda v: v)
    with open(path, "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields or _columns(rows), restval="")
        w.writeheader()
        w.writerows({k: fmt(v) for k, v in r.items()} for r in rows)


def read_rows_csv(path: Path) -> list[dict]:
    """The rows of a CSV written by write_rows_csv, numbers as int or float; [] if there is none."""
    if not Path(path).is_file():
        return []
    with open(path, newline="") as f:
        rows = list(csv.DictReader(f))
    for r in rows:
        for k, v in r.items():
            try:
                r[k] = float(v) if any(c in v for c in ".en") else int(v)
            except (TypeError, ValueError):
                pass
    return rows


def append_row_csv(path: Path, row: dict) -> None:
    """Add one row to a CSV (rewritten with the union of the columns when they differ)."""
    write_rows_csv(path, [*read_rows_csv(path), row])


# -- plots -----------------------------------------------------------------------------------------
def log_x_frame(size: tuple[int, int], margin: int, x_range, y_range, x_ticks):
    """A white canvas with the plot area framed and vertical grid lines at `x_ticks` (values, drawn
    on a log10 axis); returns (image, px) where px(log10 x, y) is the pixel of a data point."""
    import cv2

    W, H = size
    m = margin
    (x0, x1), (y0, y1) = x_range, y_range
    img = np.full((H, W, 3), 255, np.uint8)

    def px(x, y):
        return int(m + (x - x0) / (x1 - x0) * (W - 2 * m)), int(H - m - (y - y0) / (y1 - y0) * (H - 2 * m))

    cv2.rectangle(img, (m, m), (W - m, H - m), (0, 0, 0), 1)
    for v in x_ticks:
        if x0 <= np.log10(v) <= x1:
            p = px(np.log10(v), y0)
            cv2.line(img, (p[0], m), (p[0], H - m), (225, 225, 225), 1)
            cv2.putText(img, f"{v:g}", (p[0] - 8, H - m + 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1)
    return img, px


# -- command line ----------------------------------------------------------------------------------
def parser(doc: str | None, quick: str | None = "the smallest run (a smoke test)") -> argparse.ArgumentParser:
    """An ArgumentParser described by the first line of the script's docstring, with `--quick`
    (unless `quick` is None)."""
    ap = argparse.ArgumentParser(description=(doc or "").strip().splitlines()[0] if doc else None)
    if quick is not None:
        ap.add_argument("--quick", action="store_true", help=quick)
    return ap


def sweep_parser(doc: str | None, cache_name: str, quick: str | None = "the smallest sweep (a smoke test)"):
    """The parser of a sweep whose renders are cached (resumable): `--quick`, `--cache DIR`
    (default <tmp>/<cache_name>), `--report-only` (the report from the cache, no Blender) and
    `--out DIR` (default benchmarks/results)."""
    ap = parser(doc, quick)
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / cache_name,
                    help="folder for rendered stacks and timings (resumable)")
    ap.add_argument("--report-only", action="store_true", help="the report from the cached renders, no Blender")
    ap.add_argument("--out", type=Path, default=RESULTS)
    return ap


def cached_renders(a, cases, render_all, log) -> dict:
    """The per-render timings of a sweep: read from the cache with --report-only, else rendered
    (`render_all(cases, cache, log)` renders what the cache lacks and returns them all)."""
    a.cache.mkdir(parents=True, exist_ok=True)
    if a.report_only:
        return json.loads((a.cache / "renders.json").read_text())
    return render_all(cases, a.cache, log)
