"""Contact sheets: files written, sizes, and panels where `panel_rects` says they are."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from datapipe import cli, show
from datapipe.errors import DataPipeError
from datapipe.io.exr import read_exr

import fixtures_native as fx


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("show")
    sl = fx.make_native_run(base / "sl", structured_light=True, truncate=True)
    cfg = fx.default_config(num_renders=2, min_per_scene=1, max_per_scene=1, resolution=(640, 480))
    plain = fx.make_native_run(base / "plain", cfg=cfg)
    return sl, plain


def crop(img, rect):
    x, y, w, h = rect
    return img[y:y + h, x:x + w]


def test_sheets_written_with_panels_in_place(runs, tmp_path):
    run, _ = runs
    paths = show.make_sheets(run, tmp_path / "sheets")
    names = sorted(p.name for p in paths)
    assert names == ["overview.png", "scene.0001_render.0001.png", "scene.0001_render.0002.png",
                     "scene.0002_render.0001.png", "scene.0002_render.0002.png"]
    assert paths[-1].name == "overview.png"
    rects = show.panel_rects(320, 240)
    for sd in sorted(run.glob("scene.*")):
        for rdir in sorted(sd.glob("render.*")):
            sheet = cv2.imread(str(tmp_path / "sheets" / f"{sd.name}_{rdir.name}.png"))
            assert sheet.shape[:2][::-1] == show.sheet_size(320, 240)
            # the mask panel: coloured exactly where an instance is, black elsewhere
            mask = np.rint(read_exr(rdir / "mask.exr")["Y"]).astype(int)
            panel = crop(sheet, rects["mask"])
            assert panel.shape[:2] == mask.shape
            np.testing.assert_array_equal(panel.any(axis=2), mask > 0)
            for idx in np.unique(mask[mask > 0]):                 # one colour per instance
                assert len(np.unique(panel[mask == idx], axis=0)) == 1
            # the RGB panel is the render itself
            rgb = cv2.imread(str(rdir / "rgb.png"))
            np.testing.assert_array_equal(crop(sheet, rects["rgb"]), rgb)
            # depth panels: no-data pixels are black, valid ones coloured
            z = read_exr(rdir / "depth.exr")["Z"]
            assert crop(sheet, rects["depth"]).any(axis=2)[np.isfinite(z)].all()
            sl = read_exr(rdir / "sl_depth.exr")["Z"]
            slp = crop(sheet, rects["sl_depth"])
            assert not slp[~np.isfinite(sl)].any()
            assert slp.any(axis=2)[np.isfinite(sl)].mean() > 0.99
            diffp = crop(sheet, rects["diff"])
            assert not diffp[~np.isfinite(sl)].any()
            # poses: drawn lines in instance colours over a darkened RGB
            poses = crop(sheet, rects["poses"]).astype(int)
            assert (np.abs(poses - rgb.astype(int) * 0.6).max(axis=2) > 40).sum() > 50


def test_large_renders_are_scaled_and_sl_off_is_said(runs, tmp_path):
    _, run = runs
    paths = show.make_sheets(run, tmp_path / "s2")
    sheet = cv2.imread(str(paths[0]))
    W, H = show.sheet_size(640, 480)
    assert sheet.shape[:2] == (H, W) and W < 3 * 640
    rects = show.panel_rects(640, 480)
    x, y, w, h = rects["mask"]
    assert (w, h) == (480, 360)
    mask = np.rint(read_exr(run / "scene.0001/render.0001/mask.exr")["Y"]).astype(int)
    small = cv2.resize((mask > 0).astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
    np.testing.assert_array_equal(crop(sheet, rects["mask"]).any(axis=2), small)
    # "structured light off": a flat grey tile with text (grey 70 background, light text)
    tile = crop(sheet, rects["sl_depth"])
    assert (tile == 70).all(axis=2).mean() > 0.9 and (tile > 150).any()


def test_overview_and_cli(runs, tmp_path, capsys):
    run, plain = runs
    assert cli.main(["show", str(run), "--out", str(tmp_path / "o")]) == 0
    ov = cv2.imread(str(tmp_path / "o" / "overview.png"))
    assert ov is not None and ov.shape[1] > 1000
    assert "5 sheet(s)" in capsys.readouterr().out
    p = show.make_overview(plain)
    assert p == plain / "sheets" / "overview.png" and p.is_file()
    assert cli.main(["show", str(tmp_path / "nothing")]) == 2
    assert "no such run folder" in capsys.readouterr().err


def test_error_range_and_colours():
    assert show.error_range(np.array([0.1, -0.3, 0.2])) == 0.5
    assert show.error_range(np.array([4.0, -4.5])) == 5
    cols = {show.instance_color(i) for i in range(1, 60)}
    assert len(cols) > 40 and (0, 0, 0) not in cols


def test_no_scene_is_a_clear_error(tmp_path):
    (tmp_path / "run").mkdir()
    with pytest.raises(DataPipeError, match="no complete scene"):
        show.make_sheets(tmp_path / "run")


def test_grid_tiles_are_the_drawn_renders(runs, tmp_path, capsys):
    run, _ = runs
    rgbs = {f"{sd.name}/{rd.name}": cv2.imread(str(rd / "rgb.png"))
            for sd in sorted(run.glob("scene.*")) for rd in sorted(sd.glob("render.*"))}
    img = show.grid_image(run, 3, seed=1)
    tw = show.GRID_TILE_W
    th = round(tw * 240 / 320)
    cap = 16 * 3 + 4
    assert img.shape[1] == show.PAD + 2 * (tw + show.PAD)              # 3 tiles: 2 columns ...
    assert img.shape[0] == show.HEADER + 2 * (th + cap + show.PAD)     # ... 2 rows
    found = []
    for k in range(3):
        row, col = divmod(k, 2)
        x, y = show.PAD + col * (tw + show.PAD), show.HEADER + row * (th + cap + show.PAD)
        tile = img[y:y + th, x:x + tw].astype(int)
        err = {name: np.abs(tile - cv2.resize(rgb, (tw, th), interpolation=cv2.INTER_AREA)).mean()
               for name, rgb in rgbs.items()}
        best = min(err, key=err.get)
        assert err[best] < 0.5
        found.append(best)
    assert len(set(found)) == 3 and found == sorted(found)               # distinct, in scene/render order
    assert np.array_equal(img, show.grid_image(run, 3, seed=1))          # the seed fixes the draw
    assert show.grid_image(run, 50).shape == show.grid_image(run, 4).shape   # fewer renders: all of them
    assert cli.main(["show", str(run), "--grid", "2", "--out", str(tmp_path / "g")]) == 0
    assert (tmp_path / "g" / "grid.png").is_file() and "grid written" in capsys.readouterr().out
    assert not (tmp_path / "g" / "overview.png").exists()
    with pytest.raises(DataPipeError, match="at least one"):
        show.grid_image(run, 0)


def test_grid_captions_show_drawn_values():
    sc = {"lighting": {"key_power": 61.2, "key_color_temperature": 4100.0, "ambient": 0.12}}
    rd = {"name": "render.0002", "objects": [{}, {}],
          "camera_sampler": {"distance": 0.712, "tilt_deg": 18.4, "roll_deg": -33.0}}
    from pathlib import Path
    assert show._grid_caption(Path("scene.0003"), sc, rd) == [
        "scene.0003/render.0002  2 obj", "0.71 m, tilt 18, roll -33 deg", "61 W 4100 K amb 0.12"]
    assert show._grid_caption(Path("scene.0001"), {}, {"name": "render.0001"}) == ["scene.0001/render.0001  0 obj"]
    # per-render lighting (with an environment map) wins over the scene's; the textures' kinds
    rd["lighting"] = {"key_power": 30.0, "key_color_temperature": 5000.0, "ambient": 0.0,
                      "environment": {"map": "sky.hdr", "strength": 1.25, "rotation_deg": 10.0}}
    sc["textures"] = {"bin": {"kind": "brick"}, "floor": {"kind": "noise"}, "parts": [{}, {}]}
    assert show._grid_caption(Path("scene.0003"), sc, rd)[2:] == ["30 W 5000 K amb 0.00 env 1.2",
                                                                 "tex brick / noise / 2 parts"]
