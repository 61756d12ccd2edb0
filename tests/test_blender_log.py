"""datapipe.engine.blender_log: output written at the file-descriptor level (as Blender's C code writes it:
`write(1, ...)` and C's buffered `printf`) goes to the log file, not the terminal; `verbose` shows
it too; error lines reach stderr; what came before the log file is known is written first; stderr
(DataPipe's progress) is untouched. Each case runs in a subprocess, whose real fds 1 and 2 are
read back. No bpy."""
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

pytestmark = pytest.mark.skipif(sys.platform == "win32", reason="uses libc's printf through ctypes")

PRELUDE = """
import ctypes, os, sys
sys.path.insert(0, {root!r})
from datapipe.engine.blender_log import BlenderLog
libc = ctypes.CDLL(None)
def c_print(text):                         # C stdio, buffered when fd 1 is not a terminal
    libc.printf(text.encode() + b"\\n")
"""


def _run(tmp_path, body: str) -> tuple[subprocess.CompletedProcess, Path]:
    log = tmp_path / "blender.log"
    code = PRELUDE.format(root=str(ROOT)) + textwrap.dedent(body).replace("LOG", repr(str(log)))
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    return r, log


def test_c_level_output_goes_to_the_log_not_the_terminal(tmp_path):
    r, log = _run(tmp_path, """
        print("before", flush=True)
        b = BlenderLog()
        with b:
            c_print("from preflight (before the log file is known)")
        with b:
            b.log_to(LOG)
            os.write(1, b"00:02.031  render           | Saved: '/o/_passes.exr'\\n")
            c_print("Cycles chatter")
            print("[1/4] progress line", file=sys.stderr, flush=True)
        b.close()
        print("after", flush=True)
    """)
    assert r.returncode == 0, r.stderr
    assert r.stdout == "before\nafter\n"
    assert r.stderr == "[1/4] progress line\n"
    text = log.read_text()
    assert text.startswith("=== DataPipe session ") and text.count("=== DataPipe session") == 1
    lines = text.splitlines()[1:]
    assert lines == ["from preflight (before the log file is known)",
                     "00:02.031  render           | Saved: '/o/_passes.exr'", "Cycles chatter"]


def test_verbose_shows_it_too_and_a_second_session_appends(tmp_path):
    r, log = _run(tmp_path, """
        for session in (1, 2):
            b = BlenderLog(verbose=session == 2)
            with b:
                b.log_to(LOG)
                c_print(f"session {session}: Saved: x")
            b.close()
    """)
    assert r.returncode == 0, r.stderr
    assert r.stdout == "session 2: Saved: x\n"
    text = log.read_text()
    assert text.count("=== DataPipe session") == 2
    assert "session 1: Saved: x" in text and "session 2: Saved: x" in text


def test_blender_errors_reach_stderr_and_a_failure_names_the_log(tmp_path):
    r, log = _run(tmp_path, """
        b = BlenderLog()
        try:
            with b:
                b.log_to(LOG)
                c_print("00:01.000  compositor       | ERROR Invalid path template in File Output node")
                c_print("Error: Cannot read file")
                c_print("harmless chatter")
                raise RuntimeError("boom")
        except RuntimeError:
            pass
    """)
    assert r.returncode == 0, r.stderr
    assert r.stdout == ""
    assert r.stderr.splitlines() == [
        "blender: 00:01.000  compositor       | ERROR Invalid path template in File Output node",
        "blender: Error: Cannot read file",
        f"datapipe: Blender's own output is in {log}"]
    assert "harmless chatter" in log.read_text()


def test_output_without_a_log_file_is_dropped(tmp_path):
    """`validate` has no run folder: Blender's chatter goes nowhere (its errors still to stderr)."""
    r, log = _run(tmp_path, """
        with BlenderLog():
            c_print("OBJ import of 'peg.obj' took 0.25 ms")
        print("OK")
    """)
    assert r.returncode == 0, r.stderr
    assert (r.stdout, r.stderr) == ("OK\n", "")
    assert not log.exists()
