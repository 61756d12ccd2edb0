"""Issue 22: a sidebar run refuses what `datapipe run` refuses, before any work, with the same message
in the panel; the gate's warnings show in the panel as `datapipe validate` prints them.

The add-on registered on the bpy wheel drives its operators (bpy.ops.datapipe.*); the CLI runs in
a subprocess on the preset the panels saved, and the message lines are compared as text."""
import os
import subprocess
import sys
from pathlib import Path

import bpy
import pytest

from datapipe.ui import runner

ROOT = Path(__file__).resolve().parents[2]
ERROR = "datapipe: error: "
WARNING = "datapipe: warning: "


def _cli(*args) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    return subprocess.run([sys.executable, "-m", "datapipe", *map(str, args)], capture_output=True, text=True,
                          cwd=ROOT, env=env, timeout=300)


def _cli_error(stderr: str) -> list[str]:
    """The message lines of the CLI's refusal ("datapipe: error: " and the lines after it)."""
    lines = stderr.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(ERROR))
    return [lines[start][len(ERROR):]] + lines[start + 1:]


def _broken_ply(path: Path) -> Path:
    """A binary PLY cut short: its header promises 100 vertices and 50 faces, 200 bytes follow."""
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 100\nproperty float x\nproperty float y\n"
                     b"property float z\nelement face 50\nproperty list uchar int vertex_indices\nend_header\n"
                     + bytes(range(200)))
    return path


def _datablocks() -> dict[str, int]:
    return {k: len(getattr(bpy.data, k)) for k in ("objects", "meshes", "materials", "collections", "images")}


def test_a_sidebar_run_with_a_broken_mesh_is_refused_with_the_clis_message(ui_props, tmp_path, monkeypatch):
    """Before the gate the panel's status said nothing of the refusal (only an operator report), and
    the sidebar's checks were assembled apart from the CLI's."""
    d = ui_props
    bpy.ops.datapipe.initialize(preset="builtin:default")
    d.objects[0].filepath = str(_broken_ply(tmp_path / "cut.ply"))
    preset = tmp_path / "broken.json"
    bpy.ops.datapipe.preset_save(filepath=str(preset))
    cli = _cli("run", preset, "--out", tmp_path / "cli_out")
    assert cli.returncode == 2, cli.stderr
    expected = _cli_error(cli.stderr)
    assert expected[1].startswith("  - objects[0].filepath: cannot import") and "cut.ply" in expected[1], expected
    assert not (tmp_path / "cli_out").exists()

    d.output.path = str(tmp_path / "ui_out")
    started = []
    monkeypatch.setattr(runner, "start", lambda *a, **kw: started.append(a))
    before = _datablocks()
    with pytest.raises(RuntimeError) as e:
        bpy.ops.datapipe.run(blocking=True)
    reported = str(e.value).strip().splitlines()
    assert reported[0].startswith("Error: ")
    assert [reported[0][len("Error: "):]] + reported[1:] == expected          # the operator's report
    assert d.status.splitlines() == ["Error: " + expected[0]] + expected[1:]  # the panel's status
    assert started == []                                  # refused before any work: no run started,
    assert not (tmp_path / "ui_out").exists()             # nothing written,
    assert _datablocks() == before                        # nothing left in the open file
    with pytest.raises(RuntimeError) as e:                # Check Settings says the same
        bpy.ops.datapipe.check()
    assert str(e.value).strip().splitlines() == reported


def test_the_gates_warnings_show_in_the_panel_as_on_the_cli(ui_props, tmp_path):
    """A part wider than the drop zone (part fit) and a device's bin out of its working distance:
    the panel lists the lines `datapipe validate` prints, and the check still passes."""
    d = ui_props
    bpy.ops.datapipe.initialize(preset="builtin:default")
    d.scene.drop_zone_scale = (0.02, 0.02, 0.1)         # a 4 cm wide zone: the 5 cm parts start on the walls
    d.output.path = str(tmp_path / "out")
    preset = tmp_path / "tight.json"
    bpy.ops.datapipe.preset_save(filepath=str(preset))
    cli = _cli("validate", preset)
    assert cli.returncode == 0, cli.stderr
    expected = [line[len(WARNING):] for line in cli.stderr.splitlines() if line.startswith(WARNING)]
    assert expected and all("drop zone" in w for w in expected), cli.stderr
    assert bpy.ops.datapipe.check() == {"FINISHED"}
    assert d.warnings.splitlines() == expected
    assert d.status == "Settings OK: ready to run"
