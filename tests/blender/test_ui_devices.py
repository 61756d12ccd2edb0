"""The add-on's device choice (Structured Light panel): choosing a device fills the camera, projector
and structured-light fields (binned), a preset's explicit fields win when it is shown, and the
sidebar's Config carries device and binning (round trip)."""
import pytest

from datapipe import config as C
from datapipe import devices
from datapipe.errors import ConfigError
from datapipe.ui.convert import config_to_props, props_to_config


@pytest.fixture(autouse=True)
def props(ui_props):
    config_to_props(C.default_config(), ui_props)
    return ui_props


def test_every_device_is_a_choice(props):
    items = {i.identifier for i in props.bl_rna.properties["device"].enum_items}
    assert items == {"NONE", *devices.names()}


def test_choosing_a_device_fills_the_fields(props):
    props.binning = 2                         # no device yet: nothing happens
    assert list(props.camera.resolution) == C.default_config().camera.resolution
    props.device = "photoneo_phoxi_m"
    cfg = props_to_config(props)
    want = C.Config.from_dict({"device": "photoneo_phoxi_m", "binning": 2, "objects": []})
    for section in ("camera", "projector", "structured_light"):
        for k, v in devices.config_sections("photoneo_phoxi_m", 2)[section].items():
            got = getattr(getattr(cfg, section), k)
            assert got == (pytest.approx(v, rel=1e-6) if isinstance(v, (float, list)) else v), k
    assert cfg.camera.resolution == [1032, 772] and cfg.structured_light.sensor == "photoneo_phoxi_m_bin2"
    assert cfg.device == "photoneo_phoxi_m" and cfg.binning == 2
    assert len(cfg.camera.poses) == 6 and len(cfg.objects) == 3        # the rest stays
    assert want.camera.focal_length == pytest.approx(cfg.camera.focal_length)
    props.binning = 1
    assert list(props.camera.resolution) == [2064, 1544]
    props.binning = 4                          # not offered by the PhoXi M: back to 1
    assert props.binning == 1 and list(props.camera.resolution) == [2064, 1544]


def test_showing_a_preset_keeps_its_own_fields(props):
    d = C.default_config().to_dict()
    d.update(device="zivid2plus_m60", binning=2)
    for k in ("focal_length", "sensor_width", "resolution"):
        d["camera"].pop(k)
    d["structured_light"]["steps"] = 6         # explicit: wins over the device's 4
    cfg = C.Config.from_dict(d)
    config_to_props(cfg, props)
    assert props.device == "zivid2plus_m60" and props.binning == 2
    assert props.structured_light.steps == 6 and list(props.camera.resolution) == [1224, 1024]
    back = props_to_config(props)
    assert back.device == "zivid2plus_m60" and back.binning == 2 and back.structured_light.steps == 6
    assert C.Config.from_dict(back.to_dict()).camera.resolution == [1224, 1024]


def test_unknown_device_is_refused_before_anything_changes(props):
    cfg = C.default_config()
    cfg.device = "nope"
    with pytest.raises(ConfigError) as e:
        config_to_props(cfg, props)
    assert "device" in e.value.paths()
    assert props.device == "NONE"
