"""The scanner as a BOP-Industrial sensor (issue #30 item 1), read back without bop_toolkit.

Paths are spelled here as bop_toolkit's multi-sensor templates build them
(thodan/bop_toolkit@cea62d651c7e395b2e1962b9749e4e89693c6ac4:bop_toolkit_lib/dataset_params.py:
`{modality}_{sensor}/{im_id:06d}.png`, `scene_camera_{sensor}.json`, `scene_gt_{sensor}.json`,
`scene_gt_info_{sensor}.json`, `mask_{sensor}/` and `mask_visib_{sensor}/{im_id:06d}_{gt_id:06d}.png`);
tests/test_bop_toolkit.py runs the toolkit's own templates and loaders where it is importable.
Files are parsed by tests/bop_reference.py and OpenCV, never by the writer's helpers."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

import fixtures_native as fx
from bop_reference import iter_gt, ref_load_json, ref_png
from datapipe.errors import DataPipeError
from datapipe.io.bop import export_bop
from datapipe.io.bop_sensor import sensor_for_config
from datapipe.io.exr import read_exr

pytestmark = pytest.mark.usefixtures("remembered_model_analysis")   # box models analysed once (tests/model_memo.py)

SENSOR = "photoneo"        # one of xyzibd's sensor names, so the toolkit's own templates apply as they are


def add_gray(run):
    """A 12-bit grey image per structured-light render, as the pipeline writes with 'sl_gray'."""
    grays = {}
    for sj in sorted(run.glob("scene.*/scene.json")):
        scene = json.loads(sj.read_text())
        for rd in scene["renders"]:
            W, H = rd["resolution"]
            g = np.random.default_rng(rd["image_id"]).integers(0, 4096, (H, W)).astype(np.uint16)
            assert cv2.imwrite(str(sj.parent / rd["name"] / "sl_gray.png"), g)
            grays[rd["image_id"]] = g
    return grays


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    run = fx.make_native_run(tmp_path_factory.mktemp("native"), structured_light=True, truncate=True)
    grays = add_gray(run)
    root = tmp_path_factory.mktemp("bop") / "ds"
    summary = export_bop(run, root, sensor=SENSOR)
    assert summary["sensor"] == SENSOR and summary["images"] == 4
    return run, root, grays


def native_render(run, image_id):
    for sj in sorted(run.glob("scene.*/scene.json")):
        for rd in json.loads(sj.read_text())["renders"]:
            if rd["image_id"] == image_id:
                return rd, sj.parent / rd["name"]
    raise KeyError(image_id)


def test_sensor_folders_hold_the_scanner(exported):
    run, root, grays = exported
    n = 0
    for image_id, cdir, im_id, cam, gts, infos in iter_gt(root):
        rd, rdir = native_render(run, image_id)
        stem = f"{im_id:06d}"
        cams_s = ref_load_json(cdir / f"scene_camera_{SENSOR}.json")
        gts_s = ref_load_json(cdir / f"scene_gt_{SENSOR}.json")
        infos_s = ref_load_json(cdir / f"scene_gt_info_{SENSOR}.json")
        # one camera: the scanner's K and pose are the render's
        np.testing.assert_allclose(np.reshape(cams_s[im_id]["cam_K"], (3, 3)), rd["K"], rtol=1e-12)
        T_cw = np.linalg.inv(np.array(rd["T_world_cam"]))
        np.testing.assert_allclose(np.reshape(cams_s[im_id]["cam_R_w2c"], (3, 3)), T_cw[:3, :3], atol=1e-12)
        np.testing.assert_allclose(cams_s[im_id]["cam_t_w2c"], T_cw[:3, 3] * 1000.0, atol=1e-9)
        s = cams_s[im_id]["depth_scale"]
        assert s == pytest.approx(0.1)
        assert gts_s[im_id] == gts
        # depth_S: the native structured-light depth within half a depth_scale step (plus float32 EXR
        # rounding, < 1e-4 mm at 1 m); 0 exactly where the scanner has no depth
        png = ref_png(cdir / f"depth_{SENSOR}" / f"{stem}.png")
        assert png.dtype == np.uint16
        ref = read_exr(rdir / "sl_depth.exr")["Z"].astype(np.float64) * 1000.0
        nodata = ~np.isfinite(ref)
        assert nodata.any() and (~nodata).any()
        np.testing.assert_array_equal(png == 0, nodata)
        err = np.abs(png[~nodata] * s - ref[~nodata])
        assert err.max() <= s / 2 + 1e-3, err.max()
        # gray_S: the scanner's own grey image, bit for bit (16-bit PNG of 12-bit DN)
        np.testing.assert_array_equal(ref_png(cdir / f"gray_{SENSOR}" / f"{stem}.png"), grays[image_id])
        for gt_id, info in enumerate(infos_s[im_id]):
            name = f"{stem}_{gt_id:06d}.png"
            full = ref_png(cdir / f"mask_{SENSOR}" / name) > 0
            visib = ref_png(cdir / f"mask_visib_{SENSOR}" / name) > 0
            np.testing.assert_array_equal(full, ref_png(cdir / "mask" / name) > 0)
            np.testing.assert_array_equal(visib, ref_png(cdir / "mask_visib" / name) > 0)
            # calc_gt_info's px_count_valid on depth_S: silhouette pixels with a scanner depth
            assert info["px_count_valid"] == int((full & (png > 0)).sum())
            classic = infos[gt_id]
            for k in ("bbox_obj", "bbox_visib", "px_count_all", "px_count_visib", "visib_fract"):
                assert info[k] == classic[k], k
            assert info["px_count_valid"] <= classic["px_count_valid"]     # the scanner has holes
            n += 1
    assert n >= 8


def test_classic_folders_stay_and_the_export_names_its_sensor(exported):
    run, root, _ = exported
    chunk = root / "train_pbr" / "000000"
    for sub in ("rgb", "depth", "mask", "mask_visib", f"gray_{SENSOR}", f"depth_{SENSOR}", f"mask_{SENSOR}",
                f"mask_visib_{SENSOR}"):
        assert (chunk / sub).is_dir(), sub
    meta = ref_load_json(chunk / "datapipe.json")
    assert all(m["sensor"] == SENSOR for m in meta.values())


def test_no_structured_light_no_sensor_folders(tmp_path):
    run = fx.make_native_run(tmp_path / "native", structured_light=False)
    export_bop(run, tmp_path / "bop")
    chunk = tmp_path / "bop" / "train_pbr" / "000000"
    assert not [p.name for p in chunk.iterdir() if p.name.endswith("_sl") or p.name.endswith("_sl.json")]
    assert "sensor" not in next(iter(ref_load_json(chunk / "datapipe.json").values()))


def test_default_sensor_names():
    assert sensor_for_config({"device": None}) == "sl"
    assert sensor_for_config({"device": "zivid2plus_m60"}) == "zivid"
    assert sensor_for_config({"device": "photoneo_phoxi_m"}) == "photoneo"
    assert sensor_for_config({"device": "zivid2plus_m60", "output": {"bop_sensor": "xyz"}}) == "xyz"


@pytest.mark.parametrize("bad", ["", "my_sensor", "Zivid", "a/b", "gray", "x" * 33, "../up"])
def test_bad_sensor_name_refused_before_any_work(exported, tmp_path, bad):
    run = exported[0]
    with pytest.raises(DataPipeError, match=r"sensor.*fix: use 1 to 32 lowercase letters and digits"):
        export_bop(run, tmp_path / "bop", sensor=bad)
    assert not (tmp_path / "bop").exists()


def test_bad_sensor_name_in_the_config(tmp_path):
    cfg = fx.default_config(structured_light=True, formats=("native", "bop"))
    cfg.output.bop_sensor = "my sensor"
    probs = [p for p in cfg.problems(check_files=False) if p.path == "output.bop_sensor"]
    assert probs and "lowercase letters and digits" in probs[0].fix


@pytest.mark.parametrize("kind", ["sl_gray", "point_cloud"])
def test_scanner_outputs_need_structured_light(kind):
    cfg = fx.default_config(structured_light=False)
    cfg.render.outputs = ["rgb", "depth", "mask", kind]
    probs = [p for p in cfg.problems(check_files=False) if p.path == "render.outputs[3]"]
    assert probs and "structured_light.enabled" in probs[0].fix and kind in probs[0].fix
    cfg.structured_light.enabled = True
    assert not [p for p in cfg.problems(check_files=False) if p.path.startswith("render.outputs")]


def test_bop_with_structured_light_without_sl_gray_warns():
    from datapipe.io.bop_sensor import sensor_warnings
    cfg = fx.default_config(structured_light=True, formats=("native", "bop"))
    assert "sl_gray" not in cfg.render.outputs
    assert any("'sl_gray'" in w for w in sensor_warnings(cfg))
    cfg.render.outputs = [*cfg.render.outputs, "sl_gray"]
    assert sensor_warnings(cfg) == []
    cfg.structured_light.enabled = False
    cfg.render.outputs = cfg.render.outputs[:-1]
    assert sensor_warnings(cfg) == []


def test_cli_sensor_option(exported, tmp_path, capsys):
    from datapipe.cli import main
    run = exported[0]
    assert main(["bop", str(run), "--out", str(tmp_path / "bad"), "--sensor", "My_Sensor"]) == 2
    err = capsys.readouterr().err
    assert "sensor" in err and "fix: use 1 to 32 lowercase letters and digits" in err
    assert not (tmp_path / "bad").exists()
    assert main(["bop", str(run), "--out", str(tmp_path / "ok"), "--sensor", "xyz"]) == 0
    assert (tmp_path / "ok" / "train_pbr" / "000000" / "scene_gt_info_xyz.json").is_file()


def test_export_names_the_sensor_after_the_runs_device(tmp_path):
    run = fx.make_native_run(tmp_path / "native", structured_light=True)
    rj = json.loads((run / "run.json").read_text())
    rj["config"]["device"] = "zivid2plus_m60"
    (run / "run.json").write_text(json.dumps(rj))
    assert export_bop(run, tmp_path / "bop")["sensor"] == "zivid"
    assert (tmp_path / "bop" / "train_pbr" / "000000" / "depth_zivid").is_dir()
    rj["config"]["output"]["bop_sensor"] = "cam"
    (run / "run.json").write_text(json.dumps(rj))
    assert export_bop(run, tmp_path / "bop2")["sensor"] == "cam"
