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
