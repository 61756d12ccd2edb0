"""objects[i].origin on real runs (issue #30 item 3): one box part whose mesh file has its origin at
a corner, run with origin "file" and "bbox_center". In both runs models/, models_info.json and the
poses are one frame: the exported model posed with the exported pose covers the rendered mask; the
bbox_center model is the file's shifted by the box centre c; diameters agree with bop_toolkit's
calc_model_info, whose calc_pts_diameter is "the maximum distance between any two points in the set"
(thodan/bop_toolkit@cea62d651c7e395b2e1962b9749e4e89693c6ac4:bop_toolkit_lib/misc.py): computed here
with scipy, and with the toolkit itself where `bop_toolkit_lib` imports; where the two
runs drop the part alike (they do: the world mesh is the same), the poses differ exactly by the
offset (R the same, t_c = t_f + R c)."""
import json

import numpy as np
from scipy.spatial.distance import pdist

from datapipe.io.models import load_models
from datapipe.io.silhouette import rasterize_silhouette
from datapipe.io.exr import read_mask

from test_pipeline import run, tiny_config

SIZE_MM = np.array([80.0, 60.0, 40.0])
C_MM = SIZE_MM / 2                     # the box centre in the file's frame (origin at a corner)


def _write_box(path):
    v = [[x, y, z] for x in (0, SIZE_MM[0]) for y in (0, SIZE_MM[1]) for z in (0, SIZE_MM[2])]
    f = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    path.write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v)
                    + "".join("f " + " ".join(str(i + 1) for i in q) + "\n" for q in f))
    return path


def _run(tmp_path, origin):
    cfg = tiny_config(num_renders=1, res=(64, 48), samples=1)
    cfg.structured_light.enabled = False
    cfg.objects = [cfg.objects[0]]
    o = cfg.objects[0]
    o.filepath, o.name, o.scale, o.obj_id = str(_write_box(tmp_path / "box.obj")), "box", 0.001, 1
    o.min_instances = o.max_instances = 1
    o.origin = origin
    cfg.render.outputs = ["rgb", "depth", "mask"]
    cfg.output.formats = ["native", "bop"]
    out = tmp_path / origin
    run(cfg, out)
    return out


def test_file_and_bbox_center_frames(tmp_path):
    runs = {origin: _run(tmp_path, origin) for origin in ("file", "bbox_center")}
    models = {k: load_models(out / "bop" / "models")[1] for k, out in runs.items()}
    info = {k: json.loads((out / "bop" / "models" / "models_info.json").read_text())["1"] for k, out in runs.items()}
    Vf, Vc = models["file"].verts_mm, models["bbox_center"].verts_mm
    assert np.abs((Vf - C_MM) - Vc).max() < 1e-3                                 # float32 PLY
    for k in runs:
        V = models[k].verts_mm
        assert abs(info[k]["diameter"] - pdist(V).max()) < 1e-3
        assert abs(info[k]["diameter"] - np.linalg.norm(SIZE_MM)) < 1e-3
    assert abs(info["bbox_center"]["min_x"] + C_MM[0]) < 1e-3 and abs(info["file"]["min_x"]) < 1e-3
    try:
        from bop_toolkit_lib import inout, misc
    except Exception:           # not installed, or its imageio / pypng missing
        inout = None
    if inout is not None:
        for k, out in runs.items():
            pts = inout.load_ply(str(out / "bop" / "models" / "obj_000001.ply"))["pts"]
            assert abs(misc.calc_pts_diameter(pts) - info[k]["diameter"]) < 1e-3
    poses = {}
    for k, out in runs.items():
        scene = json.loads(next(out.glob("scene.*/scene.json")).read_text())
        rd = scene["renders"][0]
        o = rd["objects"][0]
        T = np.array(o["T_cam_obj"])
        poses[k] = T
        W, H = rd["resolution"]
        sil, _, _ = rasterize_silhouette(models[k].verts_mm, models[k].faces, rd["K"], T[:3, :3], T[:3, 3] * 1000,
                                         W, H)
        visib = read_mask(out / scene["name"] / rd["name"] / "mask.exr") == o["mask_index"]
        assert visib.sum() > 20
        assert (visib & ~sil).sum() <= 0.05 * visib.sum(), k       # the exported frame covers what was rendered
    Rf, tf = poses["file"][:3, :3], poses["file"][:3, 3] * 1000
    Rc, tc = poses["bbox_center"][:3, :3], poses["bbox_center"][:3, 3] * 1000
    # the same drop (the world geometry is the same mesh either way; measured: R identical, t to 3e-6 mm)
    assert np.abs(Rf - Rc).max() < 1e-9
    assert np.abs(tc - (tf + Rf @ C_MM)).max() < 1e-3


def test_validate_warns_on_the_corner_origin_with_bop(tmp_path):
    from datapipe.engine.gate import run_checks
    cfg = tiny_config(num_renders=1, res=(64, 48), samples=1)
    cfg.objects = [cfg.objects[0]]
    cfg.objects[0].filepath, cfg.objects[0].scale = str(_write_box(tmp_path / "box.obj")), 0.001
    cfg.output.formats = ["native", "bop"]
    warnings = run_checks(cfg).warnings
    assert any(w.startswith("objects[0]: the mesh's origin") and 'objects[0].origin to "bbox_center"' in w
               for w in warnings), warnings
    cfg.objects[0].origin = "bbox_center"
    assert not any("the mesh's origin" in w for w in run_checks(cfg).warnings)
    cfg.objects[0].origin, cfg.output.formats = "file", ["native"]
    assert not any("the mesh's origin" in w for w in run_checks(cfg).warnings)
