"""Device presets in a Config: the fill, explicit fields winning, binning, refusals, the JSON round
trip, validate's warnings, `python -m datapipe sensors`, and the fringe-memory check at full
resolution. The precision against the data sheets: tests/sl/test_sl_devices.py."""
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest

from datapipe import cli
from datapipe import config as C
from datapipe.checks import device_checks
from datapipe import devices
from datapipe.errors import ConfigError
from datapipe.sl.scanner import Scanner
from datapipe.sl.sensor import PRESETS, SensorModel

# what a device preset's fields may hold (presets/devices/*.json; datapipe/devices.py reads them)
BINNING_MODES = ("subsample", "average")   # subsample: every k-th pixel (per-pixel noise unchanged);
                                           # average: k x k pixels summed (k^2 the signal, k x the read noise)
METRICS = {   # the vendors' own precision definitions (how tests/sl/test_sl_devices.py measures them)
    "point_precision": "1 sigma of the XYZ position of a point between consecutive captures (Zivid)",
    "temporal_noise": "1 sigma of Z over time on an 80%-albedo diffuse surface (Photoneo)",
    "z_repeatability": "1 sigma of a single pixel's Z over repeated captures of a ceramic plate (Mech-Mind)",
}
SOURCE_REF = re.compile(r"^(https://\S+|[\w.-]+/[\w.-]+@[0-9a-f]{40}:\S+)$")   # a URL or repo@commit:path


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


def _numbers(node, path=""):
    """(path, number) for every number in a JSON tree (bools are not numbers)."""
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _numbers(v, f"{path}.{k}" if path else k)
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _numbers(v, f"{path}[{i}]")
    elif isinstance(node, (int, float)) and not isinstance(node, bool):
        yield path, node


@pytest.mark.parametrize("name", devices.names())
def test_every_number_in_a_preset_is_a_sourced_or_assumed_figure(name):
    """Issue #28: every number in presets/devices/*.json is a figure's value, and every figure says
    where it comes from (a source of the file, a URL or repo@40-hex:path, with the quoted phrase)
    or why it is assumed. No number hides in a note, a setting or the sensor."""
    raw = devices.raw(name)
    for ref in raw["sources"].values():
        assert SOURCE_REF.match(ref["ref"]), f"{name}: {ref['ref']} is neither a URL nor repo@commit:path"
        assert ref["what"]
    stray = [p for p, _ in _numbers({k: v for k, v in raw.items() if k != "figures"})]
    assert stray == [], f"{name}: numbers outside the figures: {stray}"
    for key, fig in raw["figures"].items():
        assert set(fig) <= {"value", "unit", "source", "quote", "note", "assumed", "short"}, (name, key)
        assert "value" in fig and "unit" in fig, (name, key)
        stray = [p for p, _ in _numbers({k: v for k, v in fig.items() if k != "value"})]
        assert not stray, (name, key, stray)
        if "source" in fig:
            assert fig["source"] in raw["sources"] and fig["quote"].strip() and "assumed" not in fig, (name, key)
        else:
            assert len(fig.get("assumed", "").strip()) > 20, f"{name}: figure {key} has neither a source nor a reason"
    text = json.dumps(raw).lower()
    for banned in ("recalled", "verify against", "from memory"):
        assert banned not in text, f"{name}: '{banned}' left in the preset"


def test_every_preset_is_complete():
    for name in devices.names():
        dev = devices.device(name)
        assert dev["precision"]["metric"] in METRICS
        assert dev["binning"]["mode"] in BINNING_MODES and 1 in dev["binning"]["factors"]
        lo, hi = dev["working_distance"]["range"]
        assert lo < dev["working_distance"]["optimal"] < hi and lo <= dev["precision"]["distance"] <= hi
        assert ("calibrated_to" in dev["noise_model"]) != ("sibling" in dev["noise_model"])


def _warnings(name, **scene):
    d = preset(device=name)
    d["scene"].update(scene)
    return device_checks.device_warnings(C.Config.from_dict(d))


def test_validate_warns_when_the_bin_is_outside_the_working_distance_or_the_view():
    # the demo rig: camera 0.8 m above the bin floor, a 0.3 x 0.2 m bin
    assert _warnings("zivid2plus_m60") == []                        # 0.3-1.1 m, 0.79 x 0.66 m seen at 0.8 m
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
    """At least 5 devices, each with its published precision or "not published"."""
    assert cli.main(["sensors"]) == 0
    out = capsys.readouterr().out
    assert len(devices.names()) >= 5
    for name in devices.names():
        dev = devices.device(name)
        line = next(ln for ln in out.splitlines() if ln.startswith(name))
        assert dev["label"] in line
        p = dev["precision"]
        if p["published"]:
            assert f"{p['value'] * 1e6:.0f} um" in line and dev["figures"]["precision.value"]["short"] in line
        else:
            assert "not published" in line
    assert "2448x2048 (1224x1024, 612x512)" in out
    assert "80 um point_precision @ 0.6 m" in out and "190 um temporal_noise @ 1.239 m" in out


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


# ------------------------------------------------------------------------------------------------
# the geometry DataPipe builds against the sourced figures (issue #28)

def _independent(name):
    """From the figures alone (numpy and scipy, not datapipe.devices): camera and projector
    intrinsics (fx, W, H), and the projector's pose in the camera's OpenCV frame."""
    from scipy.spatial.transform import Rotation
    f = {k: v["value"] for k, v in devices.raw(name)["figures"].items()}
    W, H = f["camera.resolution"]
    Wp, Hp = f["projector.resolution"]
    fp = f.get("projector.focal_px") or Wp / 2 / math.tan(math.radians(f["projector.field"][0] / 2))
    if "projector.translation" in f:                       # Zivid: the projector frame in the camera frame
        t = np.array(f["projector.translation"]) / 1000.0
        R = Rotation.from_rotvec(f["projector.rotation"]).as_matrix()
    else:                                                  # Photoneo: a housing with two toed-in optics
        b, side = f["baseline"] / 1000.0, f["projector.side"]
        a, p = math.radians(f["camera.tilt"]), math.radians(f["projector.tilt"])
        R_h_cam = Rotation.from_euler("y", side * a).as_matrix()     # camera turned towards the projector
        R_h_proj = Rotation.from_euler("y", -side * p).as_matrix()   # projector turned towards the camera
        t = R_h_cam.T @ np.array([side * b, 0.0, 0.0])
        R = R_h_cam.T @ R_h_proj
    return f, (f["camera.focal_px"], W, H), (fp, Wp, Hp), t, R


def _triangulation(t, R, Z):
    """(angle between the camera's and the projector's rays to the on-axis point at depth Z (deg),
    depth where the projector's axis crosses the camera's axis plane x = 0 (m))."""
    P = np.array([0.0, 0.0, Z])
    u = (P - t) / np.linalg.norm(P - t)
    angle = math.degrees(math.acos(u[2]))
    d = R[:, 2]                                            # the projector's optical axis
    s = -t[0] / d[0]
    return angle, t[2] + s * d[2]


@pytest.mark.parametrize("name", devices.names())
def test_geometry_matches_the_sourced_figures(name):
    """The Config a device fills (DataPipe's mm lens fields and Blender-axis projector pose, through
    geometry.T_cam_proj) against the same quantities derived independently from the figures: field
    of view, the area covered at the optimal distance, the working range, the projector's field and
    the triangulation angle and axis crossing (within 1%)."""
    from datapipe.geometry import T_cam_proj, projector_intrinsics
    f, (fx, W, H), (fp, Wp, Hp), t, R = _independent(name)
    dev = devices.device(name)
    cfg = C.Config.from_dict({"device": name, "objects": []})
    fh, fv = device_checks.field_of_view_deg(cfg)
    want_h, want_v = (2 * math.degrees(math.atan(n / 2 / fx)) for n in (W, H))
    assert (fh, fv) == pytest.approx((want_h, want_v), rel=0.01)
    Z = f["optimal_distance"] / 1000.0
    K = device_checks.camera_K(cfg)
    assert (W * Z / K[0, 0], H * Z / K[1, 1]) == pytest.approx((W * Z / fx, H * Z / fx), rel=0.01)
    assert dev["working_distance"]["range"] == pytest.approx([v / 1000.0 for v in f["working_distance"]], rel=0.01)
    Kp = projector_intrinsics(cfg)
    got_p = [2 * math.degrees(math.atan(n / 2 / Kp[0, 0])) for n in cfg.projector.resolution]
    want_p = f.get("projector.field") or [2 * math.degrees(math.atan(n / 2 / fp)) for n in (Wp, Hp)]
    assert got_p == pytest.approx(want_p, rel=0.01)
    T = T_cam_proj(cfg)
    assert T[:3, 3] == pytest.approx(t, abs=1e-6)                    # the projector where the figures put it
    assert T[:3, :3] == pytest.approx(R, abs=1e-6)
    got = _triangulation(T[:3, 3], T[:3, :3], Z)
    want = _triangulation(t, R, Z)
    assert got == pytest.approx(want, rel=0.01)


def test_zivid2plus_m60_is_zivids_model():
    """Issue #28's acceptance: 52.5 x 44.9 deg (+-1), projector 1000 x 720, camera-projector offset
    111 mm (+-3), working distance 0.30-1.10 m; Zivid's extrinsics turn the projector 0.085 rad
    towards the camera, so the axes cross near 1.31 m and the rays meet at 10.6 deg on axis at the
    0.6 m focus distance (the old preset: 33.5 x 28.3 deg, 1280 x 1024, 0.135 m, crossing at 0.6 m)."""
    from datapipe.geometry import T_cam_proj
    cfg = C.Config.from_dict({"device": "zivid2plus_m60", "objects": []})
    fh, fv = device_checks.field_of_view_deg(cfg)
    assert abs(fh - 52.5) <= 1.0 and abs(fv - 44.9) <= 1.0
    assert cfg.projector.resolution == [1000, 720]
    T = T_cam_proj(cfg)
    assert 0.108 <= np.linalg.norm(T[:3, 3]) <= 0.114 and T[0, 3] > 0          # on the camera's +x side
    assert devices.device("zivid2plus_m60")["working_distance"]["range"] == [0.3, 1.1]
    angle, crossing = _triangulation(T[:3, 3], T[:3, :3], 0.6)
    assert angle == pytest.approx(10.64, abs=0.05) and crossing == pytest.approx(1.312, abs=0.005)


def test_published_areas_agree_with_the_geometry():
    """Figures not used to build the geometry, against it (within 1%): the PhoXi M's scanning area at
    its 650 mm sweet spot is the camera's width (590 mm) and the projector's 36 deg height (421 mm);
    the PhoXi L's 1082 mm width at 1239 mm is the projector's 47.5 deg."""
    from datapipe.geometry import projector_intrinsics
    for name, Z, checks in (("photoneo_phoxi_m", 0.65, ((0, "camera", 0), (1, "projector", 1))),
                            ("photoneo_phoxi_l", 1.239, ((0, "projector", 0),))):
        cfg = C.Config.from_dict({"device": name, "objects": []})
        area = devices.device(name)["figures"]["scanning_area"]["value"]
        K, Kp = device_checks.camera_K(cfg), projector_intrinsics(cfg)
        for i, which, axis in checks:
            k, n = (K, cfg.camera.resolution[axis]) if which == "camera" else (Kp, cfg.projector.resolution[axis])
            span = n * Z / k[axis, axis] * 1000.0
            assert span == pytest.approx(area[i], rel=0.01), (name, which, span, area[i])


def test_devices_md_lists_every_figure():
    """docs/DEVICES.md holds one table row per figure of every device, with the JSON's value."""
    doc = (Path(__file__).resolve().parents[1] / "docs" / "DEVICES.md").read_text()
    for name in devices.names():
        section = doc.split(f"## `{name}`:")[1].split("\n## ")[0]
        for key, fig in devices.raw(name)["figures"].items():
            assert f"| `{key}` | {json.dumps(fig['value'])} |" in section, f"docs/DEVICES.md: {name} {key}"


def test_bin_picking_preset_fills_the_m60s_view():
    """bin_picking.json on the Zivid 2+ M60 (issue #28): no device warning (bin inside the working
    distance, every drop-zone corner inside the camera's and the projector's image at the nearest
    distance), and the bin's rim spans most of the image: >= 75% of its height looking straight down
    from the nearest distance (81% at 0.60 m: 0.30 m of rim at 0.45 m with f = 1240.5 px)."""
    from datapipe.draws.camera_sampler import look_at_pose
    cfg = C.load(C.presets_dir() / "bin_picking.json")
    assert cfg.device == "zivid2plus_m60" and cfg.binning == 2
    assert device_checks.device_warnings(cfg) == []
    (x, y, z), (hx, hy, hz) = cfg.scene.drop_zone_loc, cfg.scene.drop_zone_scale
    wall = cfg.scene.bin_wall_thickness
    rim = np.array([[x + sx * (hx + wall), y + sy * (hy + wall), z + hz] for sx in (-1, 1) for sy in (-1, 1)])
    T = np.linalg.inv(look_at_pose([x, y, z - hz], min(cfg.camera.sampler.distance), 0.0, 0.0, 0.0))
    pc = rim @ T[:3, :3].T + T[:3, 3]
    uv = pc @ device_checks.camera_K(cfg).T
    v = uv[:, 1] / uv[:, 2]
    assert (v.max() - v.min()) / cfg.camera.resolution[1] >= 0.75
