"""BOP export read back by an independent reader written to the BOP format document
(bop_toolkit docs/bop_datasets_format.md), checked against the fixture's analytic ground truth.

Nothing here imports the writer's helpers for reading: PLY, PNG and JSON are parsed by
tests/bop_reference.py. The same checks on a real Blender run: tests/blender/test_bop_real_run.py."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from datapipe.io.bop import BopWriter, export_bop
from datapipe.io.models import write_models
from datapipe.errors import DataPipeError
from datapipe.io.exr import read_exr, write_exr

import fixtures_native as fx
from bop_reference import iter_gt, ref_load_json, ref_png, ref_read_ply

TESTS = Path(__file__).resolve().parent


# ------------------------------------------------------------------------------------------------
# fixtures

@pytest.fixture(scope="module")
def native_run(tmp_path_factory):
    return fx.make_native_run(tmp_path_factory.mktemp("native"), structured_light=True, truncate=True)


@pytest.fixture(scope="module")
def bop(native_run, tmp_path_factory):
    root = tmp_path_factory.mktemp("bop") / "ds"
    summary = export_bop(native_run, root)
    assert summary["images"] == 4 and summary["scenes"] == 2
    return root


def analytic_truth(native_run, image_id):
    """(K, T_world_cam, [(obj_id, T_world_obj)], W, H) of an image from the fixture's own geometry."""
    for sj in sorted(native_run.glob("scene.*/scene.json")):
        scene = json.loads(sj.read_text())
        for rd in scene["renders"]:
            if rd["image_id"] == image_id:
                objs = fx.scene_objects(0, scene["scene_id"], truncate=True)
                pos, tgt = fx.DEFAULT_POSES[rd["pose_index"]]
                return np.array(rd["K"]), fx.look_at(pos, tgt), objs, *rd["resolution"], sj.parent / rd["name"]
    raise KeyError(image_id)


# ------------------------------------------------------------------------------------------------
# tests

def test_every_file_and_field(bop, native_run):
    cam = ref_load_json(bop / "camera.json")
    assert set(cam) == {"cx", "cy", "fx", "fy", "width", "height", "depth_scale"}
    assert cam["width"] == 320 and cam["height"] == 240 and isinstance(cam["width"], int)
    assert cam["depth_scale"] == pytest.approx(0.1)
    assert cam["cx"] == pytest.approx(159.5) and cam["cy"] == pytest.approx(119.5)

    info = ref_load_json(bop / "models" / "models_info.json")
    assert set(info) == {1, 2, 3}
    for obj_id, half in enumerate(fx.BOX_HALF, start=1):
        e = info[obj_id]
        assert set(e) == {"diameter", "min_x", "min_y", "min_z", "size_x", "size_y", "size_z"}
        size_mm = 2000 * np.array(half)
        assert [e["size_x"], e["size_y"], e["size_z"]] == pytest.approx(size_mm)
        assert [e["min_x"], e["min_y"], e["min_z"]] == pytest.approx(-size_mm / 2)
        assert e["diameter"] == pytest.approx(np.linalg.norm(size_mm))          # the box diagonal
        V, F = ref_read_ply(bop / "models" / f"obj_{obj_id:06d}.ply")
        V0, F0, N0 = fx.box_mesh(half)
        np.testing.assert_allclose(V[:, :3], V0 * 1000, atol=1e-3)              # millimetres
        np.testing.assert_allclose(V[:, 3:6], N0, atol=1e-6)
        np.testing.assert_array_equal(F, F0)

    n_images = 0
    for image_id, cdir, im_id, cam_e, gts, infos in iter_gt(bop):
        n_images += 1
        assert set(cam_e) >= {"cam_K", "depth_scale", "cam_R_w2c", "cam_t_w2c"}
        assert len(cam_e["cam_K"]) == 9 and len(cam_e["cam_R_w2c"]) == 9 and len(cam_e["cam_t_w2c"]) == 3
        assert all(isinstance(x, float) for x in cam_e["cam_K"] + cam_e["cam_R_w2c"] + cam_e["cam_t_w2c"])
        stem = f"{im_id:06d}"
        rgb = ref_png(cdir / "rgb" / f"{stem}.jpg")                          # train_pbr: JPEG
        assert rgb.shape == (240, 320, 3) and rgb.dtype == np.uint8
        for sub in ("depth", "depth_sl"):
            d = ref_png(cdir / sub / f"{stem}.png")
            assert d.shape == (240, 320) and d.dtype == np.uint16
        assert len(gts) == len(infos) >= 2
        for gt_id, (g, inf) in enumerate(zip(gts, infos)):
            assert set(g) == {"obj_id", "cam_R_m2c", "cam_t_m2c"}
            assert isinstance(g["obj_id"], int) and g["obj_id"] in (1, 2, 3)
            R = np.array(g["cam_R_m2c"]).reshape(3, 3)
            np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
            assert np.linalg.det(R) == pytest.approx(1.0)
            assert len(g["cam_t_m2c"]) == 3
            assert set(inf) == {"bbox_obj", "bbox_visib", "px_count_all", "px_count_valid", "px_count_visib",
                                "visib_fract"}
            assert all(isinstance(inf[k], int) for k in ("px_count_all", "px_count_valid", "px_count_visib"))
            assert len(inf["bbox_obj"]) == 4 and len(inf["bbox_visib"]) == 4
            for sub in ("mask", "mask_visib"):
                m = ref_png(cdir / sub / f"{stem}_{gt_id:06d}.png")
                assert m.shape == (240, 320) and m.dtype == np.uint8
                assert set(np.unique(m)) <= {0, 255}
    assert n_images == 4
    # no temporary files left behind
    assert not [p for p in bop.rglob("*") if ".tmp" in p.name]


def test_poses_match_analytic_truth_and_land_on_masks(bop, native_run):
    checked = 0
    for image_id, cdir, im_id, cam_e, gts, infos in iter_gt(bop):
        K_true, T_wc, objs, W, H, _ = analytic_truth(native_run, image_id)
        K = np.array(cam_e["cam_K"]).reshape(3, 3)
        np.testing.assert_allclose(K, K_true)
        # camera pose: P_w2i = K [R_w2c | t_w2c]
        T_cw = np.linalg.inv(T_wc)
        np.testing.assert_allclose(np.array(cam_e["cam_R_w2c"]).reshape(3, 3), T_cw[:3, :3], atol=1e-9)
        np.testing.assert_allclose(cam_e["cam_t_w2c"], T_cw[:3, 3] * 1000, atol=1e-6)
        depth_mm = ref_png(cdir / "depth" / f"{im_id:06d}.png").astype(np.float64) * cam_e["depth_scale"]
        for gt_id, (g, (obj_id, T_wo)) in enumerate(zip(gts, objs)):
            assert g["obj_id"] == obj_id
            T_co = T_cw @ T_wo
            R = np.array(g["cam_R_m2c"]).reshape(3, 3)
            t = np.array(g["cam_t_m2c"])
            np.testing.assert_allclose(R, T_co[:3, :3], atol=1e-9)
            np.testing.assert_allclose(t, T_co[:3, 3] * 1000, atol=1e-6)
            V, _ = ref_read_ply(cdir.parents[1] / "models" / f"obj_{obj_id:06d}.ply")
            pc = V[:, :3] @ R.T + t
            uv = pc @ K.T
            uv = uv[:, :2] / uv[:, 2:]
            px = np.rint(uv).astype(int)
            inside = (px[:, 0] >= 0) & (px[:, 0] < W) & (px[:, 1] >= 0) & (px[:, 1] < H)
            # vertices facing the camera and off the floor (a vertex touching the floor has the floor's depth)
            n_cam = V[:, 3:6] @ R.T
            facing = (n_cam * -pc).sum(1) > 0
            height = (V[:, :3] / 1000.0 @ T_wo[:3, :3].T + T_wo[:3, 3])[:, 2]
            cand = facing & (height > 0.002)
            px, z, cand = px[inside], pc[inside, 2], cand[inside]
            mv = ref_png(cdir / "mask_visib" / f"{im_id:06d}_{gt_id:06d}.png") > 0
            mfull = ref_png(cdir / "mask" / f"{im_id:06d}_{gt_id:06d}.png") > 0
            # visible vertices: the depth image sees them (within 1 mm) -> they must land on mask_visib
            dz = depth_mm[px[:, 1], px[:, 0]]
            vis = cand & (np.abs(dz - z) < 1.0)
            if vis.sum() >= 10:
                frac = mv[px[vis, 1], px[vis, 0]].mean()
                assert frac > 0.9, (image_id, gt_id, frac)
                checked += 1
            # every vertex in the image lands on (or within a pixel of) the full silhouette
            near = cv2.dilate(mfull.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
            assert near[px[:, 1], px[:, 0]].all()
            assert not (mv & ~mfull).any()                        # visible part within the silhouette
    assert checked >= 6


def test_depth_matches_exr_to_the_quantisation(bop, native_run):
    for image_id, cdir, im_id, cam_e, gts, infos in iter_gt(bop):
        *_, rdir = analytic_truth(native_run, image_id)
        s = cam_e["depth_scale"]
        for sub, exr in (("depth", "depth.exr"), ("depth_sl", "sl_depth.exr")):
            png = ref_png(cdir / sub / f"{im_id:06d}.png").astype(np.float64)
            ref = read_exr(rdir / exr)["Z"].astype(np.float64) * 1000.0
            nodata = ~np.isfinite(ref)
            np.testing.assert_array_equal(png == 0, nodata)
            err = np.abs(png[~nodata] * s - ref[~nodata])
            assert err.max() <= s / 2 + 1e-3, (sub, err.max())
        if (rdir / "sl_depth.exr").is_file():
            assert (ref_png(cdir / "depth_sl" / f"{im_id:06d}.png") == 0).any()   # holes stay holes


def test_gt_info_recounted_from_masks_and_analytic_silhouettes(bop, native_run):
    for image_id, cdir, im_id, cam_e, gts, infos in iter_gt(bop):
        K, T_wc, objs, W, H, rdir = analytic_truth(native_run, image_id)
        inst = np.rint(read_exr(rdir / "mask.exr")["Y"]).astype(int)
        # an extended canvas (one image size beyond each border) for truncated silhouettes
        K_big = K.copy()
        K_big[0, 2] += W
        K_big[1, 2] += H
        for gt_id, (inf, obj) in enumerate(zip(infos, objs)):
            mv = ref_png(cdir / "mask_visib" / f"{im_id:06d}_{gt_id:06d}.png") > 0
            np.testing.assert_array_equal(mv, inst == gt_id + 1)
            _, alone, _ = fx.raycast(K_big, T_wc, [obj], 3 * W, 3 * H)
            sil_big = alone == 1
            sil = sil_big[H:2 * H, W:2 * W]
            mfull = ref_png(cdir / "mask" / f"{im_id:06d}_{gt_id:06d}.png") > 0
            assert (mfull ^ sil).sum() <= 2, (image_id, gt_id, (mfull ^ sil).sum())
            assert inf["px_count_visib"] == mv.sum()
            assert abs(inf["px_count_all"] - sil_big.sum()) <= 2
            assert inf["visib_fract"] == pytest.approx(inf["px_count_visib"] / inf["px_count_all"])
            ys, xs = np.nonzero(mv)
            assert inf["bbox_visib"] == [xs.min(), ys.min(), xs.max() - xs.min(), ys.max() - ys.min()]
            ys, xs = np.nonzero(sil_big)
            xs, ys = xs - W, ys - H
            np.testing.assert_allclose(inf["bbox_obj"], [xs.min(), ys.min(), xs.max() - xs.min(),
                                                         ys.max() - ys.min()], atol=1)
            assert inf["px_count_valid"] == sil.sum()             # the floor gives depth everywhere
    # the truncated part really is counted: some object is cut by the border
    fracs = [i["visib_fract"] for *_, infos in iter_gt(bop) for i in infos]
    assert min(fracs) < 0.6 and max(fracs) == 1.0


def ref_rle_decode(rle):
    """COCO uncompressed RLE -> bool (H, W): runs alternate 0/1 starting with 0, column-major."""
    h, w = rle["size"]
    flat = np.zeros(h * w, bool)
    pos, val = 0, False
    for c in rle["counts"]:
        flat[pos:pos + c] = val
        pos += c
        val = not val
    assert pos == h * w
    return flat.reshape((h, w), order="F")


def test_coco_annotations_decode_to_the_visible_masks(bop):
    n = 0
    for cdir in sorted((bop / "train_pbr").iterdir()):
        coco = json.loads((cdir / "scene_gt_coco.json").read_text())
        assert set(coco) >= {"images", "annotations", "categories"}
        assert [c["id"] for c in coco["categories"]] == [1, 2, 3]
        gts = ref_load_json(cdir / "scene_gt.json")
        infos = ref_load_json(cdir / "scene_gt_info.json")
        images = {im["id"]: im for im in coco["images"]}
        assert sorted(images) == sorted(gts)
        assert len({a["id"] for a in coco["annotations"]}) == len(coco["annotations"])
        by_image = {}
        for a in coco["annotations"]:
            by_image.setdefault(a["image_id"], []).append(a)
        for im_id, anns in by_image.items():
            assert (cdir / images[im_id]["file_name"]).is_file()
            visible = [(g, i, k) for k, (g, i) in enumerate(zip(gts[im_id], infos[im_id])) if i["px_count_visib"] > 0]
            assert len(anns) == len(visible)
            for a, (g, i, gt_id) in zip(anns, visible):
                mv = ref_png(cdir / "mask_visib" / f"{im_id:06d}_{gt_id:06d}.png") > 0
                np.testing.assert_array_equal(ref_rle_decode(a["segmentation"]), mv)
                assert a["category_id"] == g["obj_id"] and a["area"] == mv.sum() and a["iscrowd"] == 0
                assert a["ignore"] == (i["visib_fract"] < 0.1)
                full = ref_png(cdir / "mask" / f"{im_id:06d}_{gt_id:06d}.png") > 0
                ys, xs = np.nonzero(full)
                assert a["bbox"] == [xs.min(), ys.min(), xs.max() - xs.min() + 1, ys.max() - ys.min() + 1]
                n += 1
    assert n >= 8


def test_chunking(native_run, tmp_path):
    root = tmp_path / "bop"
    export_bop(native_run, root, chunk_size=2)
    chunks = sorted(p.name for p in (root / "train_pbr").iterdir())
    assert chunks == ["000000", "000001"]
    seen = {}
    for c in chunks:
        gt = ref_load_json(root / "train_pbr" / c / "scene_gt.json")
        assert sorted(gt) == [0, 1]
        assert sorted(p.name for p in (root / "train_pbr" / c / "rgb").iterdir()) == ["000000.jpg", "000001.jpg"]
        meta = ref_load_json(root / "train_pbr" / c / "datapipe.json")
        for im_id, m in meta.items():
            seen[m["image_id"]] = (int(c), im_id)
    assert seen == {0: (0, 0), 1: (0, 1), 2: (1, 0), 3: (1, 1)}


def test_incremental_scenes_survive_a_restart(native_run, tmp_path):
    root = tmp_path / "bop"
    w = BopWriter(root, chunk_size=1000)
    assert w.add_scene(native_run / "scene.0001") == [0, 1]
    first = (root / "train_pbr/000000/scene_gt.json").read_text()
    assert sorted(ref_load_json(root / "train_pbr/000000/scene_gt.json")) == [0, 1]
    # a new writer (a resumed run) appends to what is on disk, and re-adding a scene is idempotent
    w2 = BopWriter(root, chunk_size=1000)
    w2.add_scene(native_run / "scene.0002")
    w2.add_scene(native_run / "scene.0001")
    w2.finish()
    gt = ref_load_json(root / "train_pbr/000000/scene_gt.json")
    assert sorted(gt) == [0, 1, 2, 3]
    assert json.loads(first)["0"] == gt[0]
    ref = tmp_path / "ref"
    export_bop(native_run, ref)
    for name in ("scene_camera", "scene_gt", "scene_gt_info", "scene_gt_coco"):
        a, b = (ref_load_json(r / f"train_pbr/000000/{name}.json") for r in (root, ref))
        for d in (a, b):
            d.get("info", {}).pop("date_created", None)           # when each was made
        assert a == b


def test_models_eval_cut_short_is_made_again_by_the_next_scene(native_run, tmp_path):
    """A run stopped while models_eval/ was written (disk full, kill) leaves models/ complete but
    models_eval/ without its models_info.json (the last file written): the next writer (--resume)
    makes models_eval/ again instead of finishing a dataset without it."""
    root = tmp_path / "bop"
    BopWriter(root, chunk_size=1000).add_scene(native_run / "scene.0001")
    whole = {p.name: p.read_bytes() for p in (root / "models_eval").iterdir()}
    (root / "models_eval" / "models_info.json").unlink()
    next(p for p in (root / "models_eval").glob("obj_*.ply")).unlink()
    BopWriter(root, chunk_size=1000).add_scene(native_run / "scene.0002")
    assert {p.name: p.read_bytes() for p in (root / "models_eval").iterdir()} == whole


def test_incomplete_scene_and_missing_model_are_clear_errors(native_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(native_run, run)
    (run / "scene.0002" / "scene.json").unlink()
    summary = export_bop(run, tmp_path / "bop")                    # incomplete scenes are left out
    assert summary["scenes"] == 1 and summary["images"] == 2
    with pytest.raises(DataPipeError, match="not complete"):
        BopWriter(tmp_path / "bop2").add_scene(run / "scene.0002")
    (run / "models" / "obj_000001.ply").unlink()
    (run / "models" / "obj_000002.ply").unlink()
    (run / "models" / "obj_000003.ply").unlink()
    with pytest.raises(DataPipeError, match="no model"):
        export_bop(run, tmp_path / "bop3")


def test_depth_out_of_range_is_refused_with_the_fix(tmp_path):
    cfg = fx.default_config(num_renders=1, min_per_scene=1, max_per_scene=1)
    run = fx.make_native_run(tmp_path / "run", cfg=cfg)
    rdir = run / "scene.0001" / "render.0001"
    d = read_exr(rdir / "depth.exr")["Z"]
    d[0, 0] = 7.0                                                  # beyond 65535 * 0.1 mm
    write_exr(rdir / "depth.exr", {"Z": d})
    with pytest.raises(DataPipeError, match=r"depth_scale=0\.2"):
        export_bop(run, tmp_path / "bop")
    export_bop(run, tmp_path / "bop_ok", depth_scale=0.2)
    png = ref_png(tmp_path / "bop_ok/train_pbr/000000/depth/000000.png")
    assert png[0, 0] == 35000
    assert ref_load_json(tmp_path / "bop_ok/train_pbr/000000/scene_camera.json")[0]["depth_scale"] == 0.2


def test_write_models_ascii_binary_and_exact_diameter(tmp_path):
    rng = np.random.default_rng(3)
    pts = rng.normal(size=(300, 3)) * [0.03, 0.01, 0.02]
    faces = rng.integers(0, 300, size=(100, 3))
    normals = rng.normal(size=(300, 3))
    for binary in (True, False):
        d = tmp_path / ("bin" if binary else "ascii")
        write_models(d, {7: (pts, faces, normals)}, binary=binary)
        V, F = ref_read_ply(d / "obj_000007.ply")
        np.testing.assert_allclose(V[:, :3], pts * 1000, atol=2e-3)
        np.testing.assert_array_equal(F, faces)
        info = ref_load_json(d / "models_info.json")[7]
        mm = pts * 1000
        brute = np.sqrt(((mm[:, None] - mm[None]) ** 2).sum(-1)).max()
        assert info["diameter"] == pytest.approx(brute, rel=1e-9)
        assert info["min_x"] == pytest.approx(mm[:, 0].min())
        assert info["size_z"] == pytest.approx(np.ptp(mm[:, 2]))
    with pytest.raises(DataPipeError, match="start at 1"):
        write_models(tmp_path / "bad", {0: (pts, faces, normals)})


def psnr(a, b):
    return 10 * np.log10(255.0 ** 2 / np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))


def test_rgb_jpeg_quality_and_png(bop, native_run, tmp_path):
    """JPEG at the default quality 95 stays close to the native PNG; a lower quality is further
    from it (the setting reaches the encoder); rgb_format png copies the native file exactly."""
    root = tmp_path / "bop"
    export_bop(native_run, root / "q50", jpg_quality=50)
    export_bop(native_run, root / "png", rgb_format="png")
    for image_id, cdir, im_id, *_ in iter_gt(bop):
        *_, rdir = analytic_truth(native_run, image_id)
        native = ref_png(rdir / "rgb.png")
        q95 = ref_png(cdir / "rgb" / f"{im_id:06d}.jpg")
        q50 = ref_png(root / "q50" / cdir.relative_to(bop) / "rgb" / f"{im_id:06d}.jpg")
        assert psnr(native, q95) > 38 and psnr(native, q95) > psnr(native, q50) + 3
        png = root / "png" / cdir.relative_to(bop) / "rgb" / f"{im_id:06d}.png"
        assert png.read_bytes() == (rdir / "rgb.png").read_bytes()
    coco = json.loads((root / "png/train_pbr/000000/scene_gt_coco.json").read_text())
    assert all(im["file_name"].endswith(".png") for im in coco["images"])
    with pytest.raises(DataPipeError, match="jpg_quality"):
        export_bop(native_run, root / "bad", jpg_quality=0)
    with pytest.raises(DataPipeError, match="rgb_format"):
        export_bop(native_run, root / "bad", rgb_format="tif")
    assert not (root / "bad").exists()


def test_coco_info_block(bop):
    import datetime
    info = json.loads((bop / "train_pbr/000000/scene_gt_coco.json").read_text())["info"]
    assert {"description", "url", "version", "year", "contributor", "date_created"} <= set(info)
    created = datetime.datetime.fromisoformat(info["date_created"])
    assert info["year"] == created.year and created.tzinfo is not None
    assert abs((datetime.datetime.now(datetime.timezone.utc) - created).total_seconds()) < 3600


def test_models_eval_cover_the_models_at_the_toolkit_spacing(bop):
    """models_eval/: every point of each model's surface within 1 mm (bop_toolkit's sampling
    distance) of an eval point, eval points on the model's surface."""
    from scipy.spatial import cKDTree
    from datapipe.io.symmetry import point_triangle_distance, sample_surface
    rng = np.random.default_rng(3)
    for obj_id in (1, 2, 3):
        V, F = ref_read_ply(bop / "models" / f"obj_{obj_id:06d}.ply")
        Ve, Fe = ref_read_ply(bop / "models_eval" / f"obj_{obj_id:06d}.ply")
        surface, _ = sample_surface(V[:, :3], F, 50_000, rng)
        gap, _ = cKDTree(Ve[:, :3]).query(surface)
        assert gap.max() <= 1.0, (obj_id, gap.max())
        some = Ve[rng.choice(len(Ve), size=min(len(Ve), 500), replace=False), :3]
        d = point_triangle_distance(some[:, None, :], V[:, :3][F][None]).min(axis=1)
        assert d.max() < 1e-3                                  # on the surface (float32 PLY)
        assert len(Fe) > 0 and np.linalg.norm(Ve[:, 3:6], axis=1) == pytest.approx(1, abs=1e-5)


def test_models_eval_info_is_measured_on_models_eval(bop):
    """models_eval/models_info.json is measured on models_eval's own meshes, as bop_toolkit's
    calc_model_info does (misc.calc_pts_diameter: the largest distance between two of the file's
    vertices; here over the convex hull's vertices, where the farthest pair lies), not a copy of models/'s; symmetries are the object's own."""
    from scipy.spatial import ConvexHull
    info = ref_load_json(bop / "models_eval" / "models_info.json")
    base = ref_load_json(bop / "models" / "models_info.json")
    assert set(info) == set(base) == {1, 2, 3}
    for obj_id, e in info.items():
        V, _ = ref_read_ply(bop / "models_eval" / f"obj_{obj_id:06d}.ply")
        P = V[:, :3].astype(np.float64)
        H = P[ConvexHull(P).vertices]          # the two farthest points are hull vertices
        d = np.sqrt(((H[:, None] - H[None]) ** 2).sum(-1).max())
        # float64 sums of float32 coordinates: the same number to rounding (1e-9 relative)
        assert e["diameter"] == pytest.approx(d, rel=1e-9)
        lo, hi = P.min(0), P.max(0)
        assert [e["min_x"], e["min_y"], e["min_z"]] == pytest.approx(lo, abs=1e-9)
        assert [e["size_x"], e["size_y"], e["size_z"]] == pytest.approx(hi - lo, abs=1e-9)
        assert {k: v for k, v in e.items() if k.startswith("symmetries_")} == \
            {k: v for k, v in base[obj_id].items() if k.startswith("symmetries_")}


def test_object_coords_read_by_opencv_as_three_channels(native_run, tmp_path, monkeypatch):
    """BOP's object_coords/IMID.exr: OpenCV reads H x W x 3 (channels R, G, B = model x, y, z in mm,
    in OpenCV's B, G, R order); DataPipe's reader reads it and the X, Y, Z files written before."""
    from datapipe.io.exr import read_object_coords
    run = tmp_path / "native"
    shutil.copytree(native_run, run)
    truth = {}
    for sj in sorted(run.glob("scene.*/scene.json")):
        for rd in json.loads(sj.read_text())["renders"]:
            W, H = rd["resolution"]
            xyz = np.random.default_rng(rd["image_id"]).uniform(-0.05, 0.05, (H, W, 3)).astype(np.float32)
            xyz[: H // 3] = np.nan                                    # off parts
            write_exr(sj.parent / rd["name"] / "object_coords.exr", {c: xyz[..., i] for i, c in enumerate("XYZ")})
            truth[rd["image_id"]] = xyz
    root = tmp_path / "bop"
    export_bop(run, root)
    monkeypatch.setenv("OPENCV_IO_ENABLE_OPENEXR", "1")
    for image_id, xyz in truth.items():
        path = root / "train_pbr" / "000000" / "object_coords" / f"{image_id:06d}.exr"
        im = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        assert im is not None and im.shape == xyz.shape and im.dtype == np.float32
        # float32 metres x 1000 in float32: relative 1e-7
        np.testing.assert_allclose(im[..., ::-1], xyz * 1000.0, rtol=1e-6, equal_nan=True)
        np.testing.assert_allclose(read_object_coords(path), xyz * 1000.0, rtol=1e-6, equal_nan=True)
        old = tmp_path / "old.exr"
        write_exr(old, {c: xyz[..., i] * 1000.0 for i, c in enumerate("XYZ")})
        np.testing.assert_allclose(read_object_coords(old), xyz * 1000.0, rtol=1e-6, equal_nan=True)
