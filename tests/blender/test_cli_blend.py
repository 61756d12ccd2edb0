"""The documented `blender -b scene.blend --python-expr "import datapipe.cli as c; c.main([...])"` flow,
emulated with the bpy module: a .blend is open, so the CLI keeps it and its `drop_zone` object wins."""
import json
import subprocess
import sys
from pathlib import Path

import bpy
import numpy as np

from datapipe import config as C

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from cli_runs import small_config  # noqa: E402


def test_cli_inside_an_open_blend_uses_its_drop_zone(tmp_path):
    # a .blend whose drop zone sits 2 m to the side of the preset's
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(2.0, 0.0, 0.1))
    dz = bpy.context.active_object
    dz.name = "drop_zone"
    dz.scale = (0.3, 0.2, 0.2)            # half extents 0.15 x 0.1 x 0.1 m
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))

    cfg = small_config(1, (32, 24))
    for pose in cfg.camera.poses:          # look at the .blend's drop zone
        pose.location[0] += 2.0
    C.save(cfg, tmp_path / "preset.json")
    out = tmp_path / "out"
    code = (f"import bpy; bpy.ops.wm.open_mainfile(filepath={str(blend)!r}); import datapipe.cli as c; "
            f"raise SystemExit(c.main(['run', {str(tmp_path / 'preset.json')!r}, '--out', {str(out)!r}, '--quiet']))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    scene = json.loads((out / "scene.0001" / "scene.json").read_text())
    rend = scene["renders"][0]
    T_world_cam = np.array(rend["T_world_cam"])
    xs = [(T_world_cam @ np.array(o["T_cam_obj"]))[0, 3] for o in rend["objects"]]
    assert xs and all(abs(x - 2.0) < 0.15 for x in xs), xs     # inside the .blend's zone, not the preset's
