"""Device presets in a Config: the fill, explicit fields winning, binning, refusals, the JSON round
trip, validate's warnings, `python -m datapipe sensors`, and the fringe-memory check at full
resolution. The precision against the data sheets: tests/sl/test_sl_devices.py."""
import json
import math

import pytest

from datapipe import cli
from datapipe import config as C
from datapipe.checks import device_checks
from datapipe import devices
from datapipe.errors import ConfigError
from datapipe.sl.scanner import Scanner
from datapipe.sl.sensor import PRESETS, SensorModel


def preset(**top) -> dict:
    """The demo preset as a dict, plus top-level fields (its camera poses and bin stay)."""
    d = C.default_config().to_dict()
    for section in ("camera", "projector", "structured_light"):     # leave them to the device
        for k in ("focal_length", "sensor_width", "resolution", "location", "rotation", "periods", "steps",
                  "sensor", "exposure", "hdr", "sensor_fit", "clip_start", "clip_end"):
            d[section].pop(k, None)
    d.update(top)
    return d


def test_device_fills_camera_projector_and_structured_light():
    cfg = C.Config.from_dict(preset(device="zivid2plus_m60"))
    dev = devices.device("zivid2plus_m60")["config"]
    assert cfg.camera.resolution == [2448, 2048]
    assert cfg.camera.focal_length == dev["camera"]["focal_length"]
    assert cfg.projector.location == dev["projector"]["location"]
    assert cfg.structured_light.enabled and cfg.structured_light.sensor == "zivid2plus_m60"
    assert cfg.structured_light.hdr == "auto"
    assert len(cfg.camera.poses) == 6                      # the preset's own poses stay
    assert cfg.problems(check_files=False) == []
    scanner = Scanner.from_config(cfg)                     # the scanner a run builds from it
    assert scanner.sensor == PRESETS["zivid2plus_m60"]


def test_explicit_fields_win_over_the_device():
    d = preset(device="photoneo_phoxi_m")
    d["camera"]["resolution"] = [1032, 772]
    d["structured_light"]["steps"] = 6
    d["projector"]["power"] = 9.0
    cfg = C.Config.from_dict(d)
    assert cfg.camera.resolution == [1032, 772] and cfg.structured_light.steps == 6
    assert cfg.projector.power == 9.0
    assert cfg.camera.focal_length == devices.device("photoneo_phoxi_m")["config"]["camera"]["focal_length"]


def test_binning_halves_the_resolution_and_averaging_quarters_the_relative_shot_noise():
    full = C.Config.from_dict(preset(device="photoneo_phoxi_m"))
    binned = C.Config.from_dict(preset(device="photoneo_phoxi_m", binning=2))
    assert binned.camera.resolution == [1032, 772]
    assert binned.camera.focal_length == full.camera.focal_length        # same lens, larger pixels
    s1, s2 = (SensorModel.preset(c.structured_light.sensor) for c in (full, binned))
    assert s2.full_well == 4 * s1.full_well and s2.read_noise == 2 * s1.read_noise
    zivid = C.Config.from_dict(preset(device="zivid2plus_m60", binning=4))  # subsampling: same sensor
    assert zivid.camera.resolution == [612, 512] and zivid.structured_light.sensor == "zivid2plus_m60"
    assert zivid.problems(check_files=False) == []                       # finest fringe still >= 3 px


def test_unknown_device_and_binning_are_refused_with_the_choices():
    with pytest.raises(ConfigError) as e:
        C.Config.from_dict(preset(device="zivid_one"))
    assert e.value.paths() == ["device"]
    assert all(n in str(e.value) for n in devices.names())
    with pytest.raises(ConfigError) as e:
        C.Config.from_dict(preset(device="mech_eye_nano", binning=4))
    assert e.value.paths() == ["binning"] and "[1, 2]" in str(e.value)
    with pytest.raises(ConfigError) as e:
        C.Config.from_dict(preset(binning=2))
    assert e.value.paths() == ["binning"]
    cfg = C.default_config()
    cfg.device = "nope"                                    # set in code: validate() says it too
    assert [p.path for p in cfg.problems(check_files=False)] == ["device"]


@pytest.mark.parametrize("name", devices.names())
def test_round_trip(name, tmp_path):
    cfg = C.Config.from_dict(preset(device=name, binning=devices.binning_factors(devices.device(name))[-1]))
    C.save(cfg, tmp_path / "p.json")
    back = C.load(tmp_path / "p.json")
    assert back == cfg
    assert json.loads((tmp_path / "p.json").read_text())["device"] == name


def test_every_preset_is_complete_and_cited():
    for name in devices.names():
        dev = devices.device(name)
        assert dev["precision"]["metric"] in devices.METRICS
        assert all(s["url"].startswith("https://") for s in dev["sources"])
        assert dev["binning"]["mode"] in devices.BINNING_MODES and 1 in dev["binning"]["factors"]
        assert dev["assumptions"], f"{name}: say what was assumed"
        lo, hi = dev["working_distance"]["range"]
        assert lo < dev["working_distance"]["optimal"] < hi and lo <= dev["precision"]["distance"] <= hi


def _warnings(name, **scene):
    d = preset(device=name)
    d["scene"].update(scene)
    return device_checks.device_warnings(C.Config.from_dict(d))


def test_validate_warns_when_the_bin_is_outside_the_working_distance_or_the_view():
    # the demo rig: camera 0.8 m above the bin floor, a 0.3 x 0.2 m bin
    assert _warnings("zivid2plus_m60") == []                        # 0.35-1.1 m, 0.48 x 0.40 m seen at 0.8 m
    far = _warnings("mech_eye_nano")                               # 0.3-0.6 m
    assert len(far) == 1 and far[0].startswith("camera.poses[0, 1, 2, 3, 4, 5]: the bin floor is up to 0.800 m")
    assert "working distance (0.3-0.6 m)" in far[0] and "fix:" in far[0]
    wide = _warnings("zivid2plus_m60", drop_zone_scale=[0.4, 0.3, 0.1])
    assert len(wide) == 1 and "field of view" in wide[0] and "8 of the drop zone's 8 corners" in wide[0]
    near = _warnings("zivid2plus_m60", drop_zone_loc=[0.0, 0.0, 0.55])     # a bin 0.15 m below the camera
    assert any("nearer than the Zivid 2+ M60's working distance" in w for w in near)
    assert device_checks.device_warnings(C.default_config()) == []       # no device, no warning


def test_validate_warns_when_the_preset_changes_what_makes_the_device():
    d = preset(device="zivid2plus_m60")
    d["camera"]["focal_length"] = 16.0                      # e.g. a camera section copied from another preset
    d["structured_light"]["steps"] = 6                      # a decoding choice: not the device's optics
    w = [ln for ln in device_checks.device_warnings(C.Config.from_dict(d)) if "differ" in ln]
    assert len(w) == 1 and w[0].startswith("camera.focal_length: differ from the Zivid 2+ M60's")
    d = preset(device="zivid2plus_m60", binning=2)
    d["camera"]["resolution"] = [2448, 2048]                # full resolution with binning 2
    d["projector"]["rotation"] = [1.0, 0.0, 0.0, 0.0]
    w = [ln for ln in device_checks.device_warnings(C.Config.from_dict(d)) if "differ" in ln]
    assert w and w[0].startswith("camera.resolution, projector.rotation: differ")


def test_sensors_command_lists_every_device(capsys):
    assert cli.main(["sensors"]) == 0
    out = capsys.readouterr().out
    for name in devices.names():
        dev = devices.device(name)
        line = next(ln for ln in out.splitlines() if ln.startswith(name))
        assert dev["label"] in line and dev["sources"][0]["url"] in line
        assert f"{dev['precision']['value'] * 1e6:.0f} um" in line
    assert "2448x2048 (1224x1024, 612x512)" in out


def test_full_resolution_fringe_stack_passes_the_memory_check():
    """The 2448 x 2048 Zivid preset (12 fringe images + 4 of the row code, HDR fused stack): ~2.4 GiB,
    under the check's 16 GiB (a 24 GiB machine); 32 steps would be refused before any work."""
    cfg = C.Config.from_dict(preset(device="zivid2plus_m60"))
    need = C.fringe_memory_bytes(cfg)
    assert 2.0 * 2**30 < need < 3.0 * 2**30
    assert cfg.problems(check_files=False) == []
    cfg.structured_light.steps = 32
    msg = [str(p) for p in cfg.problems(check_files=False) if p.path == "structured_light.steps"]
    assert msg and "GiB" in msg[0] and "limit 16 GiB" in msg[0]


def test_field_of_view_matches_the_published_pixel_spacing():
    """Zivid 2+: 0.32 mm between pixels at 1300 mm (the M130's published figure, same imager and
    angle per pixel) -> 2448 px span 783 mm there."""
    cfg = C.Config.from_dict(preset(device="zivid2plus_m60"))
    fh, _ = device_checks.field_of_view_deg(cfg)
    assert 2 * 1300 * math.tan(math.radians(fh / 2)) == pytest.approx(2448 * 0.32, rel=1e-3)
