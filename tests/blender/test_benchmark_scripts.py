"""The benchmark scripts that import Blender at module level (tests/test_benchmarks_harness.py's
NEEDS_BLENDER) start and answer --help, so a broken one is seen in the suite, not at its next
long run."""
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tests"))
from test_benchmarks_harness import NEEDS_BLENDER  # noqa: E402


@pytest.mark.parametrize("name", sorted(NEEDS_BLENDER))
def test_blender_benchmark_answers_help(name):
    r = subprocess.run([sys.executable, str(ROOT / "benchmarks" / f"{name}.py"), "--help"], cwd=ROOT,
                       capture_output=True, text=True, timeout=120, env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin"})
    assert r.returncode == 0, r.stderr[-2000:]
    assert "--quick" in r.stdout
