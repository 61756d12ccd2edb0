"""The sidebar's BOP Models choice: a BOP entry survives config -> sidebar -> config, the panel
shows the BOP fields, the preview shows the entry's first object in metres."""
import bpy
import pytest

from datapipe import config as C
from datapipe.ui import preview
from datapipe.ui.convert import config_to_props, props_to_config

from test_bop_models import FLIP_Z, make_bop_models
from test_ui_panels import draw_all


def test_bop_entry_round_trip_and_preview(ui_props, tmp_path):
    src = make_bop_models(tmp_path / "models")
    cfg = C.default_config()
    cfg.objects = [C.ObjectEntry(bop_models=str(src), bop_obj_ids=[12, 7], max_instances=3),
                   C.ObjectEntry(filepath=str(C.assets_dir() / "nut.obj"), obj_id=40,
                                 symmetries={"symmetries_discrete": [FLIP_Z]})]
    config_to_props(cfg, ui_props)
    item = ui_props.objects[0]
    assert item.source == "BOP" and item.bop_obj_ids == "12, 7" and ui_props.objects[1].source == "FILE"
    back = props_to_config(ui_props)
    assert back.objects == cfg.objects
    back.validate()
    # typed ids that are not numbers: the validation names the field (no traceback)
    item.bop_obj_ids = "12, seven"
    problems = props_to_config(ui_props).problems()
    assert any(p.path == "objects[0].bop_obj_ids" for p in problems)
    item.bop_obj_ids = "7"
    ui_props.objects_index = 0
    log, problems = draw_all(bpy.context)
    assert problems == []
    drawn = {e[2] for e in log if e[0] == "prop" and type(e[1]).__name__ == "DATAPIPE_PG_object"}
    assert {"source", "bop_models", "bop_obj_ids", "symmetries"} <= drawn and "filepath" not in drawn
    bpy.ops.datapipe.object_preview()
    objs = [o for o in preview.tagged("object") if o.type == "MESH"]
    size = max(max(o.dimensions) for o in objs)
    assert size == pytest.approx(0.0346, abs=1e-3)            # the nut (obj 7): 34.6 mm across corners
    bpy.ops.datapipe.object_preview()


def test_load_preset_with_a_deep_models_info_names_the_file(ui_props, tmp_path):
    """A models_info.json nested 200,000 deep gave a RecursionError traceback from the add-on's Load
    Preset (its missing-files look reads the folder); now the preset loads and Check names the file."""
    import json
    src = make_bop_models(tmp_path / "models")
    (src / "models_info.json").write_text('{"7": ' + "[" * 200_000 + "]" * 200_000 + "}")
    cfg = C.default_config()
    cfg.objects = [C.ObjectEntry(bop_models=str(src), bop_obj_ids=[7])]
    preset = tmp_path / "deep.json"
    preset.write_text(json.dumps(cfg.to_dict()))
    bpy.ops.datapipe.preset_load(filepath=str(preset))
    assert ui_props.objects[0].bop_models == str(src)
    problems = props_to_config(ui_props).problems()
    assert any(p.path == "objects[0].bop_models" and "nested too deeply" in p.message
               and str(src / "models_info.json") in p.message for p in problems), [str(p) for p in problems]
