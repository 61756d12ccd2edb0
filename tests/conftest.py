"""Shared fixtures that need no Blender (tests/sl must never import bpy)."""
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def assets_dir():
    return ROOT / "datapipe" / "assets"
