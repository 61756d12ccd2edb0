"""BOP in, BOP out on a real run: three objects of a BOP-format models folder (made here: mm PLY +
models_info.json with symmetries, BOP ids 7, 12, 30) dropped and rendered with object-coordinate
maps; the BOP export keeps the source's ids, diameters and symmetries, and the maps agree with
the z-buffer (an independent pass) at the pixel centres."""
import json

import bpy
import numpy as np

from datapipe.io.exr import read_depth, read_exr, read_mask

from test_bop_models import BOP_PARTS, make_bop_models
from test_pipeline import run, tiny_config


def test_bop_models_in_object_coords_out(tmp_path):
    src = make_bop_models(tmp_path / "itodd" / "models")
    cfg = tiny_config(num_renders=2, res=(128, 96))
    cfg.structured_light.enabled = False
    cfg.objects = [cfg.objects[0]]
    cfg.objects[0].filepath, cfg.objects[0].name = "", ""
    cfg.objects[0].bop_models, cfg.objects[0].bop_obj_ids = str(src), [7, 12, 30]
    cfg.objects[0].min_instances = cfg.objects[0].max_instances = 2
    cfg.render.outputs = ["rgb", "depth", "mask", "object_coords"]
    cfg.output.formats = ["native", "bop"]
    out = tmp_path / "out"
    run(cfg, out)
    assert [vl.name for vl in bpy.context.scene.view_layers] == ["datapipe"]     # its layer removed after

    # models: ids, diameters and symmetries are the source's
    source = json.loads((src / "models_info.json").read_text())
    bop = out / "bop"
    for folder in ("models", "models_eval"):
        info = json.loads((bop / folder / "models_info.json").read_text())
        assert sorted(info, key=int) == ["7", "12", "30"]
        for k, e in info.items():
            if folder == "models":
                assert abs(e["diameter"] - source[k]["diameter"]) < 1e-3      # float32 PLY round trip
            else:   # measured on the resampled points, all on the surface, every surface point within
                    # 1 mm of one: at most the model's diameter, at least 2 mm less
                assert source[k]["diameter"] - 2.0 <= e["diameter"] <= source[k]["diameter"] + 1e-3
            for key in ("symmetries_discrete", "symmetries_continuous"):
                assert e.get(key) == source[k].get(key), (k, key)
        assert sorted(p.name for p in (bop / folder).glob("*.ply")) == \
            ["obj_000007.ply", "obj_000012.ply", "obj_000030.ply"]

    n_checked = 0
    for sj in sorted(out.glob("scene.*/scene.json")):
        scene = json.loads(sj.read_text())
        for rd in scene["renders"]:
            rdir = sj.parent / rd["name"]
            for o in rd["objects"]:
                assert o["obj_id"] in BOP_PARTS and o["name"].startswith(f"obj_{o['obj_id']:06d}_")
            xyz = read_exr(rdir / "object_coords.exr")
            P = np.stack([xyz[c] for c in "XYZ"], axis=-1).astype(np.float64)
            depth = read_depth(rdir / "depth.exr").astype(np.float64)
            mask = read_mask(rdir / "mask.exr")
            np.testing.assert_array_equal(np.isnan(P[..., 0]), mask == 0)     # NaN exactly off parts
            for o in rd["objects"]:
                sel = mask == o["mask_index"]
                if sel.sum() < 10:
                    continue
                T = np.array(o["T_cam_obj"])
                z = (P[sel] @ T[:3, :3].T + T[:3, 3])[:, 2]
                err_mm = np.abs(z - depth[sel]) * 1000.0
                assert np.median(err_mm) < 0.1, (rd["name"], o["name"], np.median(err_mm))
                n_checked += 1
            # the BOP copy: the same map in mm, per image
            meta = json.loads((bop / "train_pbr/000000/datapipe.json").read_text())
            im_id = next(int(k) for k, m in meta.items() if m["image_id"] == rd["image_id"])
            b = read_exr(bop / "train_pbr/000000/object_coords" / f"{im_id:06d}.exr")
            np.testing.assert_allclose(b["R"], xyz["X"] * 1000.0, rtol=1e-6, equal_nan=True)   # R, G, B = x, y, z
    assert n_checked >= 3
    gt = json.loads((bop / "train_pbr/000000/scene_gt.json").read_text())
    assert {g["obj_id"] for gts in gt.values() for g in gts} <= set(BOP_PARTS)
