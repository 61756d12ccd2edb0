"""Blender's own output in a CLI run: into OUT/blender.log, not the terminal; with --verbose on the
terminal too. A tiny real run (1 render at 80x60, structured light on: 3 Cycles calls, each
printing `render | Saved: '..._passes.exr'`-style lines) in a subprocess, whose stdout and
stderr are read back."""
import json
import subprocess
import sys

from datapipe import config as C

SAVED = "| Saved: '"


def _tiny(path):
    cfg = C.default_config()
    cfg.camera.resolution = [80, 60]
    cfg.structured_light.periods = [1, 4, 16]
    cfg.render.samples = 2
    cfg.render.threads = 2
    cfg.scene.num_renders = cfg.scene.min_renders_per_scene = cfg.scene.max_renders_per_scene = 1
    cfg.output.overview = False
    C.save(cfg, path)
    return path


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "datapipe", *map(str, args)], capture_output=True, text=True,
                          timeout=600)


def test_blender_output_goes_to_the_log_and_to_the_terminal_with_verbose(tmp_path):
    preset, out = _tiny(tmp_path / "tiny.json"), tmp_path / "out"
    r = _cli("run", preset, "--out", out)
    assert r.returncode == 0, r.stderr
    assert SAVED not in r.stdout and SAVED not in r.stderr and "OBJ import" not in r.stdout, r.stdout + r.stderr
    assert "[1/1] scene.0001/render.0001 rendered" in r.stderr        # DataPipe's progress still shows
    log = (out / "blender.log").read_text()
    assert log.count(SAVED) == 3 and "_passes.exr'" in log, log     # RGB/depth, SL flat, SL bounce
    assert "OBJ import of 'peg.obj'" in log                          # the preflight's imports, kept first
    assert "blender.log" in json.loads((out / "manifest.json").read_text())["files"]

    r = _cli("run", preset, "--out", out, "--force", "--verbose", "--quiet")
    assert r.returncode == 0, r.stderr
    assert r.stdout.count(SAVED) == 3 and SAVED not in r.stderr, r.stdout + r.stderr
    log = (out / "blender.log").read_text()                           # --force removed the first run's
    assert log.count("=== DataPipe session") == 1 and log.count(SAVED) == 3

    r = _cli("run", preset, "--out", out, "--resume", "--quiet")      # nothing to do: appended, not replaced
    assert r.returncode == 0, r.stderr
    assert (out / "blender.log").read_text().startswith(log) and SAVED not in r.stdout + r.stderr
