"""Tests that need the bpy module. Each test starts from Blender's empty factory scene."""
import pytest

bpy = pytest.importorskip("bpy")


@pytest.fixture(autouse=True)
def factory_scene():
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield bpy.context.scene


def pytest_collection_modifyitems(items):
    for item in items:
        item.add_marker(pytest.mark.blender)


@pytest.fixture
def ui_props(tmp_path, monkeypatch):
    """The add-on registered (unless already), user presets in tmp; yields Scene.datapipe."""
    from datapipe import ui
    from datapipe.ui import runner
    monkeypatch.setenv("DATAPIPE_USER_PRESETS", str(tmp_path / "user_presets"))
    was = hasattr(bpy.types.Scene, "datapipe")
    if not was:
        ui.register()
    yield bpy.context.scene.datapipe
    runner.stop_for_unregister()
    if not was:
        ui.unregister()
