"""The public API (datapipe/api.py, docs/API.md) without Blender: presets, configs in code,
validation, run's refusals before any work, decoding fringe stacks against analytic geometry, and
reading a run back against its files read independently (OpenEXR, OpenCV, json)."""
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import OpenEXR
import pytest

import datapipe
import datapipe.api as dp
import fixtures_native as fx
from fake_world import BoxWorld
from datapipe.config import load, presets_dir
from datapipe.engine.pipeline import Pipeline

pytestmark = pytest.mark.usefixtures("remembered_model_analysis")   # box models analysed once (tests/model_memo.py)

ROOT = Path(__file__).resolve().parents[1]


def exr_channel(path, name) -> np.ndarray:
    """A channel read with the OpenEXR binding itself (not datapipe.io.exr)."""
    with OpenEXR.File(str(path), separate_channels=True) as f:
        return np.asarray(f.parts[0].channels[name].pixels, dtype=np.float32)


# -- the names ---------------------------------------------------------------------------------------

def test_root_names_are_the_api_and_import_lazily():
    assert dp.__all__ == list(datapipe.API_NAMES)
    for name in dp.__all__:
        assert getattr(datapipe, name) is getattr(dp, name)
    with pytest.raises(AttributeError):
        datapipe.no_such_name
    # `import datapipe` (what Blender does to register the add-on) imports neither the API nor numpy:
    # only the leaf that holds the version number
    r = subprocess.run([sys.executable, "-c", "import sys, datapipe; print(sorted(m for m in sys.modules "
                        "if m.startswith(('datapipe.', 'numpy', 'bpy'))))"], cwd=ROOT, capture_output=True,
                       text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "['datapipe.version']"


# -- presets and configs -----------------------------------------------------------------------------

def test_load_preset_by_name_and_by_path(tmp_path):
    assert {"default", "bin_picking", "thesis_sensor"} <= set(dp.presets())
    by_name = dp.load_preset("bin_picking")
    assert by_name.to_dict() == load(presets_dir() / "bin_picking.json").to_dict()
    assert by_name.device == "zivid2plus_m60"
    cfg = dp.load_preset("default")
    cfg.scene.num_renders = 7
    path = tmp_path / "mine.json"
    path.write_text(json.dumps(cfg.to_dict()))
    assert dp.load_preset(path).scene.num_renders == 7
    assert dp.load_preset(str(path)).to_dict() == dp.load_preset(path).to_dict()


def test_load_preset_errors_name_the_fix(tmp_path):
    with pytest.raises(dp.ConfigError) as e:
        dp.load_preset("defualt")
    assert "defualt" in str(e.value) and "default" in e.value.problems[0].fix
    with pytest.raises(dp.ConfigError, match="preset not found"):
        dp.load_preset(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text('{"scene": {"num_renders": "many"}}')
    with pytest.raises(dp.ConfigError) as e:
        dp.load_preset(bad)
    assert "scene.num_renders" in e.value.paths()


def test_config_built_in_code_validates():
    cfg = dp.Config(objects=[dp.ObjectEntry(filepath=str(ROOT / "datapipe/assets/peg.obj"), max_instances=3)],
                    camera=dp.CameraConfig(poses=[dp.CameraPose(location=[0, 0, 0.8])]))
    assert dp.validate(cfg) == []
    cfg.scene.num_renders = 0
    cfg.objects[0].filepath = str(ROOT / "datapipe/assets/nothing.obj")
    problems = dp.validate(cfg)                       # a list, nothing raised
    assert [p.path for p in problems] == ["scene.num_renders", "objects[0].filepath"]
    assert all(p.fix for p in problems)
    assert dp.validate(cfg, check_files=False)[0].path == "scene.num_renders"
    assert [p.path for p in dp.validate(dp.Config())] == ["objects"]
    with pytest.raises(dp.ConfigError) as e:
        dp.check(cfg)
    assert e.value.problems == problems
    ok = dp.load_preset("default")
    assert dp.check(ok) is ok


@pytest.mark.parametrize("change, path", [
    (lambda c: setattr(c.scene, "num_renders", "many"), "scene.num_renders"),
    (lambda c: setattr(c.structured_light, "periods", None), "structured_light.periods"),
    (lambda c: setattr(c, "objects", None), "objects"),
    (lambda c: setattr(c.camera, "poses", [[0, 0, 1]]), "camera.poses[0]"),
])
def test_wrong_types_set_in_code_are_problems_not_tracebacks(tmp_path, change, path):
    cfg = dp.load_preset("default")
    change(cfg)
    assert path in [p.path for p in dp.validate(cfg)]
    with pytest.raises(dp.ConfigError) as e:
        dp.run(cfg, tmp_path / "out")
    assert path in e.value.paths() and not (tmp_path / "out").exists()
    with pytest.raises(dp.DataPipeError, match="must be a datapipe Config"):
        dp.validate(cfg.to_dict())


def test_preset_warnings_are_the_validate_commands():
    from datapipe.checks.device_checks import device_warnings
    from datapipe.checks.part_fit import part_fit_warnings
    cfg = dp.load_preset("bin_picking")
    cfg.camera.sampler.distance = [1.6, 1.7]          # beyond the Zivid's 1.1 m working distance
    warnings = dp.preset_warnings(cfg)
    assert warnings == part_fit_warnings(cfg) + device_warnings(cfg)
    assert any("working distance" in w or "1.1" in w for w in warnings), warnings


# -- run: the command line's checks before any work --------------------------------------------------

def test_run_refuses_a_bad_config_before_writing(tmp_path):
    had_bpy = "bpy" in sys.modules
    cfg = dp.load_preset("default")
    cfg.scene.num_renders = 0
    out = tmp_path / "new"
    with pytest.raises(dp.ConfigError) as e:
        dp.run(cfg, out)
    assert e.value.paths() == ["scene.num_renders"]
    assert cfg.scene.num_renders == 0 and not out.exists()
    with pytest.raises(dp.DataPipeError, match="brace"):
        dp.run(dp.load_preset("default"), tmp_path / "out{x}")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(dp.DataPipeError, match="shard"):
        dp.run(dp.load_preset("default"), out, shard=(2, 2))
    (out / "scene.0001").mkdir(parents=True)
    (out / "scene.0001" / "notes.txt").write_text("mine")
    with pytest.raises(dp.DataPipeError, match="not empty"):
        dp.run(dp.load_preset("default"), out)
    assert sorted(p.name for p in out.rglob("*")) == ["notes.txt", "scene.0001"]
    assert had_bpy or "bpy" not in sys.modules           # refused before Blender was started


def test_run_takes_the_command_lines_path():
    """api.run and `python -m datapipe run` are one code path (engine/session.py run_pipeline), not two copies."""
    import inspect
    from datapipe import cli
    assert "run_pipeline(" in inspect.getsource(cli._run) and "run_pipeline(" in inspect.getsource(dp.run)
    assert "check_run_input(" in inspect.getsource(cli._run) and "check_run_input(" in inspect.getsource(dp.run)


# -- decoding: a plane at 0.8 m, its projector columns from the preset by hand ------------------------

Z_PLANE = 0.8


def plane_stack(cfg, *, a=0.5, b=0.4, dark=0.02, noise=0.005, seed=0):
    """Fringe images of a plane at Z_PLANE in front of the camera of `cfg`, from first principles: the
    preset's projector (16 mm, 11.3 mm DMD of 912 x 570 px, 0.15 m left of the camera, turned
    8.5 deg towards it about the camera's y axis; Blender's axes converted to OpenCV's by hand) and
    the pattern formula of docs/CONVENTIONS.md at the exact projector column of each pixel centre."""
    K = dp.camera_matrix(cfg)
    W, H = cfg.camera.resolution
    u, v = np.meshgrid(np.arange(W, dtype=float), np.arange(H, dtype=float))
    X = np.stack([(u - K[0, 2]) / K[0, 0] * Z_PLANE, (v - K[1, 2]) / K[1, 1] * Z_PLANE, np.full(u.shape, Z_PLANE)], -1)
    assert cfg.projector.location == [-0.15, 0.0, 0.0] and math.isclose(cfg.projector.rotation[1], math.radians(-8.5))
    th = math.radians(8.5)      # Blender -8.5 deg about camera y = +8.5 deg about OpenCV's y (y, z flipped)
    R = np.array([[math.cos(th), 0, math.sin(th)], [0, 1, 0], [-math.sin(th), 0, math.cos(th)]])
    Xp = (X - np.array([-0.15, 0.0, 0.0])) @ R            # R^T (X - t): the projector's frame
    Wp, Hp = cfg.projector.resolution
    fp = 16.0 / 11.3 * Wp
    col = fp * Xp[..., 0] / Xp[..., 2] + (Wp - 1) / 2
    row = fp * Xp[..., 1] / Xp[..., 2] + (Hp - 1) / 2
    lit = (col > -0.5) & (col < Wp - 0.5) & (row > -0.5) & (row < Hp - 0.5)
    s = cfg.structured_light
    imgs = np.array([np.where(lit, a + b * np.cos(2 * np.pi * k * col / Wp + 2 * np.pi * n / s.steps), dark)
                     for k in s.periods for n in range(s.steps)])
    imgs += np.random.default_rng(seed).normal(0.0, noise, imgs.shape)
    return imgs.astype(np.float32), lit, col


def test_decode_a_captured_stack_with_the_presets_geometry():
    cfg = dp.load_preset("default")
    imgs, lit, col = plane_stack(cfg)
    res = dp.decode(imgs, cfg)
    inside = lit & (col > 2) & (col < cfg.projector.resolution[0] - 3)
    assert res.valid[inside].mean() > 0.99
    assert not res.valid[~lit].any()
    err_mm = np.abs(res.depth[res.valid] - Z_PLANE) * 1000
    # phase noise 0.005/0.4*sqrt(2/4) = 0.0088 rad -> 0.02 projector px on the 64-period fringe ->
    # ~0.07 mm at 0.8 m (dZ/dx = Z^2/(f_p b) = 3.3 mm/px); a wrong K, pose or period would be mm off
    assert np.median(err_mm) < 0.2 and np.percentile(err_mm, 99.9) < 1.0
    assert res.confidence[res.valid].min() >= 0.999
    assert (res.reason[~lit] != dp.Reason.VALID).all()
    pts = res.points[res.valid]
    np.testing.assert_allclose(pts[:, 2], res.depth[res.valid], rtol=1e-6)


def test_scan_radiance_like_the_pipeline():
    cfg = dp.load_preset("default")
    radiance, lit, col = plane_stack(cfg, noise=0.0)
    scan = dp.scan(radiance, cfg, seed=3)
    res = scan.result
    inside = lit & (col > 3) & (col < cfg.projector.resolution[0] - 4)
    assert res.valid[inside].mean() > 0.98
    err_mm = np.abs(res.depth[res.valid] - Z_PLANE) * 1000
    # the industrial sensor at auto exposure: README's sigma_Z = 0.13 mm at 0.8 m
    assert np.median(err_mm) < 0.3 and (err_mm > 5).mean() < 1e-3
    assert res.confidence[res.valid].min() >= 0.999
    assert np.nanmedian(scan.sigma_z) < 0.5e-3
    again = dp.scan(radiance, cfg, seed=3).result.depth
    np.testing.assert_array_equal(np.isnan(again), np.isnan(res.depth))      # seeded: the same scan
    with pytest.raises(dp.DataPipeError, match="radiance"):
        dp.scan(radiance[:5], cfg)


def test_patterns_are_the_convention():
    cfg = dp.load_preset("default")
    p = dp.patterns(cfg)
    Wp, Hp = cfg.projector.resolution
    s = cfg.structured_light
    assert p.shape == (len(s.periods) * s.steps, Hp, Wp)
    x = np.arange(Wp)
    for i, k in enumerate(s.periods):
        for n in range(s.steps):
            np.testing.assert_allclose(p[i * s.steps + n, 7], 0.5 + 0.5 * np.cos(2 * np.pi * k * x / Wp
                                                                                 + 2 * np.pi * n / s.steps), atol=1e-6)


# -- reading a run ----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def box_run(tmp_path_factory):
    """A run made by the real run loop on the fake world (tests/fake_world.py): every record the
    pipeline writes, visib_fract included."""
    tmp = tmp_path_factory.mktemp("api_run")
    cfg = fx.default_config(num_renders=3, min_per_scene=1, max_per_scene=2, resolution=(64, 48),
                            mesh_dir=tmp / "meshes")
    cfg.output.overview = False
    pipe = Pipeline(cfg, tmp / "run", world=BoxWorld.factory())
    events = list(pipe.run())
    assert events[-1].stage == "done"
    return cfg, pipe


def test_read_run_matches_the_files(box_run):
    cfg, pipe = box_run
    run = dp.read_run(pipe.out)
    assert run.status == "complete" and run.seed == cfg.scene.seed
    assert run.config.objects == cfg.objects and run.config.scene == cfg.scene
    scene_files = sorted(pipe.out.glob("scene.*/scene.json"))
    assert [s.name for s in run.scenes] == [p.parent.name for p in scene_files]
    assert len(run.renders) == sum(pipe.plan) == 3
    for s, path in zip(run.scenes, scene_files):
        record = json.loads(path.read_text())
        assert s.record == record
        for r, rd in zip(s.renders, record["renders"]):
            rdir = path.parent / rd["name"]
            np.testing.assert_array_equal(r.K, np.array(rd["K"]))
            np.testing.assert_array_equal(r.T_world_cam, np.array(rd["T_world_cam"]))
            assert r.resolution == tuple(rd["resolution"]) == (64, 48)
            np.testing.assert_array_equal(r.depth, exr_channel(rdir / "depth.exr", "Z"))
            mask = r.mask
            np.testing.assert_array_equal(mask, exr_channel(rdir / "mask.exr", "Y").astype(np.int32))
            np.testing.assert_array_equal(r.rgb, cv2.imread(str(rdir / "rgb.png"))[..., ::-1])
            assert r.normals.shape == (48, 64, 3) and r.sl_depth is None and r.sl_valid is None
            assert len(r.objects) == len(rd["objects"]) == len(record["objects"])
            for o, od in zip(r.objects, rd["objects"]):
                np.testing.assert_array_equal(o["T_cam_obj"], np.array(od["T_cam_obj"]))
                assert o["px_count_visib"] == int((mask == od["mask_index"]).sum())
                assert 0.0 <= o["visib_fract"] <= 1.0
    assert set(run.models_info) == {1, 2, 3} and all(run.model_file(i).is_file() for i in run.models_info)
    assert run.stats["visib_fract"]["instances"] == sum(len(r.objects) for r in run.renders)


def test_read_run_structured_light_maps(tmp_path):
    out = fx.make_native_run(tmp_path / "run", structured_light=True)
    run = dp.read_run(out)
    assert len(run.renders) == 4
    for r in run.renders:
        sl = r.sl_depth
        np.testing.assert_array_equal(sl, exr_channel(r.path / "sl_depth.exr", "Z"))
        np.testing.assert_array_equal(r.sl_valid, np.isfinite(sl))
        assert 0.5 < np.isfinite(sl).mean() < 1.0
        assert r.sl_debug is None


def test_read_run_refuses_what_is_not_a_run(tmp_path, box_run):
    with pytest.raises(dp.DataPipeError, match="not a folder"):
        dp.read_run(tmp_path / "missing")
    with pytest.raises(dp.DataPipeError, match="no run.json"):
        dp.read_run(tmp_path)
    (tmp_path / "run.json").write_text("{not json")
    with pytest.raises(dp.OutputStateError, match="corrupt"):
        dp.read_run(tmp_path)
    (tmp_path / "run.json").write_text("{}")
    (tmp_path / "scene.0001").mkdir()
    (tmp_path / "scene.0001" / "scene.json").write_text('{"complete": true, "renders": [{"name": "x"}]}')
    with pytest.raises(dp.OutputStateError, match="not a DataPipe scene.json"):
        dp.read_run(tmp_path)


def test_read_run_names_a_damaged_file(tmp_path):
    out = fx.make_native_run(tmp_path / "run")
    r = dp.read_run(out).renders[0]
    png = r.path / "rgb.png"
    png.write_bytes(png.read_bytes()[:40])
    with pytest.raises(OSError) as e:
        r.rgb
    assert e.value.filename == str(png) and "corrupt" in str(e.value)
    (r.path / "depth.exr").write_bytes(b"\x76\x2f\x31\x01" + b"\0" * 20)
    with pytest.raises(OSError, match="corrupt"):
        r.depth


@pytest.mark.parametrize("damage", ["truncated", "list", "folder", "fifo"])
def test_read_run_never_drops_a_damaged_scene_silently(tmp_path, damage):
    """A scene.json cut short, a JSON list, or a folder in its place: the scene was left out without
    a word before (issue 33); now OutputStateError naming the file, or, asked for, listed as skipped.
    A scene folder with no scene.json is a scene not finished: left out, as before."""
    out = fx.make_native_run(tmp_path / "run")
    whole = dp.read_run(out)
    victim = out / whole.scenes[1].name / "scene.json"
    text = victim.read_text()
    victim.unlink()
    if damage == "truncated":
        victim.write_text(text[: len(text) // 2])
    elif damage == "list":
        victim.write_text(json.dumps([json.loads(text)]))
    elif damage == "folder":
        victim.mkdir()
    else:
        os.mkfifo(victim)                       # read with O_NONBLOCK: refused, never waited on
    with pytest.raises(dp.OutputStateError) as e:
        dp.read_run(out)
    assert str(victim) in str(e.value) and "(fix:" in str(e.value)
    run = dp.read_run(out, skip_damaged=True)
    assert [s.name for s in run.scenes] == [s.name for s in whole.scenes if s.name != victim.parent.name]
    assert [p for p, _ in run.skipped] == [victim] and "scene.json" in run.skipped[0][1]
    (out / "scene.0099").mkdir()                # unfinished: no scene.json yet
    assert dp.read_run(out, skip_damaged=True).skipped == run.skipped
