"""benchmarks/harness.py, what every benchmark times and writes with (no bpy), and every benchmark
script: each imports with bpy blocked (those listed as needing Blender excepted: they are run by
tests/blender/test_benchmark_scripts.py) and answers `--help`, so a broken script is seen here and
not at its next long run.

CPU times are judged against the kernel's own account of this process (resource.getrusage), not
the clock the harness reads (time.process_time)."""
import csv
import json
import math
import resource
import subprocess
import os
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"
sys.path.insert(0, str(BENCH))
import harness  # noqa: E402

# benchmark scripts that import bpy at module level (their --help runs in tests/blender)
NEEDS_BLENDER = {"bench_physics", "bench_view_cost"}
# getrusage counts in scheduler ticks (<= 4 ms at 250 Hz) and the interpreter's own work around the
# timed block adds a few ms: 50 ms is ample, and far below the 300 ms the busy loop takes
CPU_TOL_S = 0.05


def _rusage_cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def test_preset_dict_makes_mesh_paths_absolute_and_leaves_shapes(tmp_path):
    """A benchmark writes its changed preset elsewhere (or loads it from a string): the mesh paths
    must then point at the preset's own assets, and a procedural distractor (no file) stays as it is."""
    (tmp_path / "presets").mkdir()
    pre = tmp_path / "presets" / "p.json"
    pre.write_text(json.dumps({"objects": [{"filepath": "../assets/peg.obj"},
                                           {"filepath": None, "shape": {"kind": "box"}}]}))
    d = harness.preset_dict(pre)
    assert d["objects"][0]["filepath"] == str((tmp_path / "assets" / "peg.obj").resolve())
    assert d["objects"][1] == {"filepath": None, "shape": {"kind": "box"}}
    shipped = harness.preset_dict(ROOT / "datapipe" / "presets" / "bin_picking.json")
    assert all(Path(o["filepath"]).is_file() for o in shipped["objects"])
    assert harness.slug("pattern BLUE_NOISE, samples 15") == "pattern_BLUE_NOISE__samples_15"


def test_md_table_and_csv_round_trip(tmp_path):
    rows = [{"case": "a", "cpu_s": 1.5, "n": 3}, {"case": "b", "cpu_s": 0.25, "n": 4, "extra": "x"}]
    assert harness.md_table(["case", "n"], [["a", 3], ["b", 4]]) == ["| case | n |", "|---|---|", "| a | 3 |",
                                                                    "| b | 4 |"]
    path = tmp_path / "sub" / "r.csv"
    harness.write_rows_csv(path, rows)
    with open(path, newline="") as f:
        read = list(csv.reader(f))
    assert read[0] == ["case", "cpu_s", "n", "extra"]                   # every key, first seen first
    assert read[1] == ["a", "1.5", "3", ""] and read[2] == ["b", "0.25", "4", "x"]
    assert harness.read_rows_csv(path) == [{"case": "a", "cpu_s": 1.5, "n": 3, "extra": ""},
                                           {"case": "b", "cpu_s": 0.25, "n": 4, "extra": "x"}]
    harness.append_row_csv(path, {"case": "c", "new": 7})                # a new column: the file is rewritten
    assert [r["case"] for r in harness.read_rows_csv(path)] == ["a", "b", "c"]
    assert list(harness.read_rows_csv(path)[0]) == ["case", "cpu_s", "n", "extra", "new"]
    harness.write_rows_csv(path, [{"v": 1 / 3}], float_fmt=".3g")
    assert path.read_text().splitlines() == ["v", "0.333"]
    assert harness.read_rows_csv(tmp_path / "missing.csv") == []


def test_column_table_and_notes(tmp_path):
    t = harness.column_table([{"a": 1.0, "b": math.nan}], [("a", "{:.2f}"), ("b", "{:.1f}")])
    assert t == "| a | b |\n|---|---|\n| 1.00 | - |\n"
    (tmp_path / "rep_notes.md").write_text("## Findings\nby hand")
    harness.write_with_notes(tmp_path / "rep.md", ["# Title", "", "table"])
    assert (tmp_path / "rep.md").read_text() == "# Title\n\ntable\n## Findings\nby hand\n"
    harness.write_with_notes(tmp_path / "other.md", ["# Other"])          # no notes file: the lines alone
    assert (tmp_path / "other.md").read_text() == "# Other\n"


def test_cpu_time_of_a_busy_loop_and_of_a_sleep():
    """A loop that spins until the kernel has counted 0.3 s of this process's CPU measures 0.3 s of
    CPU; a 0.3 s sleep measures 0.3 s of wall and (almost) no CPU."""
    start, t0 = _rusage_cpu(), time.perf_counter()
    with harness.Stopwatch() as busy:
        while _rusage_cpu() - start < 0.3:
            pass
    spent, elapsed = _rusage_cpu() - start, time.perf_counter() - t0
    assert busy.cpu_s == pytest.approx(spent, abs=CPU_TOL_S)
    # wall against the clock read around it (not against the CPU: other threads of the test process,
    # Blender's or a BLAS pool's, add CPU that no single thread's wall time bounds)
    assert 0 < busy.wall_s <= elapsed and busy.wall_s == pytest.approx(elapsed, abs=CPU_TOL_S)
    with harness.Stopwatch() as idle:
        time.sleep(0.3)
    assert idle.wall_s >= 0.3 and idle.cpu_s < CPU_TOL_S


def test_timed_repeats_and_round_robin():
    calls = []
    out, t = harness.timed(lambda: calls.append(1) or len(calls), repeat=3, warmup=True)
    assert len(calls) == 4 and out == 4                       # the warm-up is not timed, the last result is returned
    assert len(t.wall) == len(t.cpu) == 3 and t.best_wall_s <= t.wall_s and t.best_cpu_s <= t.cpu_s
    order = []
    tt = harness.round_robin({"a": lambda: order.append("a"), "b": lambda: order.append("b")}, 2)
    assert order == ["a", "b", "a", "b", "a", "b"]                      # warm-ups, then in turns
    assert set(tt) == {"a", "b"} and len(tt["a"].wall) == 2


def _run_child_from_a_small_parent(code: str, parent_mib: int = 0) -> dict:
    """harness.run_child of `python -c code` (one thread: numpy's BLAS pool would otherwise add its
    threads' CPU, and a single-threaded child cannot spend more CPU than wall time), called from a
    fresh Python process that first held `parent_mib` MiB and let it go: the measurement does not
    depend on how large this test process has grown (Linux carries the spawning process's peak
    into the child's ru_maxrss, see harness.ChildRun.peak_is_childs)."""
    one = {**os.environ, **{k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}}
    driver = (f"import json, sys; sys.path.insert(0, {str(BENCH)!r}); import harness, numpy as np\n"
              f"a = np.ones({parent_mib} * 2**20, np.uint8); del a\n"
              f"c = harness.run_child([sys.executable, '-c', {code!r}])\n"
              "print(json.dumps({**c.__dict__, 'peak_is_childs': c.peak_is_childs}))\n")
    out = subprocess.run([sys.executable, "-c", driver], env=one, capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def test_child_cpu_and_peak_memory():
    """A child that spins 0.3 s of its own CPU and holds 200 MiB: os.wait4 reports both."""
    code = ("import resource, numpy as np\n"
            "a = np.ones(200 * 2**20, np.uint8)\n"
            "cpu = lambda: sum(resource.getrusage(resource.RUSAGE_SELF)[:2])\n"
            "s = cpu()\n"
            "while cpu() - s < 0.3: pass\n")
    c = _run_child_from_a_small_parent(code)
    assert c["returncode"] == 0
    assert c["cpu_s"] >= 0.3 - CPU_TOL_S and c["wall_s"] >= c["cpu_s"] - CPU_TOL_S
    assert 200 <= c["peak_rss_mib"] < 2000
    assert c["peak_is_childs"]
    assert harness.run_child([sys.executable, "-c", "raise SystemExit(3)"]).returncode == 3


def test_a_childs_peak_memory_below_the_parents_is_flagged():
    """A child that holds nothing, started by a process that once held 600 MiB: ru_maxrss says
    >= 600 MiB (the parent's peak, carried over fork and exec), and run_child says it is not the
    child's own."""
    c = _run_child_from_a_small_parent("pass", parent_mib=600)
    assert c["peak_rss_mib"] >= 600 and c["parent_peak_mib"] >= 600
    assert not c["peak_is_childs"]


def test_machine_line_names_the_cpus():
    import os
    assert f"{os.cpu_count()} logical CPUs" in harness.machine()


# Blender's modules are refused (None in sys.modules: every import of them raises ImportError), so
# an installed bpy wheel cannot hide a script that needs it
_IMPORT_ALL = """
import contextlib, io, json, sys
sys.modules.update(dict.fromkeys(('bpy', 'mathutils', 'bmesh')))
sys.path.insert(0, sys.argv[1])
bad = {}
for m in json.loads(sys.argv[2]):
    try:
        mod = __import__(m)
        if hasattr(mod, 'main'):
            sys.argv = [m + '.py', '--help']
            with contextlib.redirect_stdout(io.StringIO()):
                try:
                    mod.main()
                    bad[m] = 'main(--help) returned instead of printing its help'
                except SystemExit as e:
                    if e.code not in (0, None):
                        bad[m] = f'--help exited {e.code}'
    except Exception as e:
        bad[m] = f'{type(e).__name__}: {e}'
print(json.dumps(bad))
"""


def test_every_benchmark_imports_and_parses_help():
    """Every module of benchmarks/ imports with bpy absent and each script's main answers --help;
    the ones that need Blender are exactly the listed ones (the block is real)."""
    mods = sorted(p.stem for p in BENCH.glob("*.py"))
    assert len(mods) > 20 and "bench_sl" in mods                # the walk sees the scripts
    r = subprocess.run([sys.executable, "-c", _IMPORT_ALL, str(BENCH), json.dumps(mods)], cwd=ROOT,
                       capture_output=True, text=True, timeout=240, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0, r.stderr
    bad = json.loads(r.stdout.strip().splitlines()[-1])
    assert set(bad) == NEEDS_BLENDER, bad
    assert all("import of bpy halted" in bad[m] for m in NEEDS_BLENDER), bad
