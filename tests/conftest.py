"""Shared fixtures that need no Blender (tests/sl must never import bpy)."""
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture
def assets_dir():
    return ROOT / "datapipe" / "assets"


@pytest.fixture(scope="module")
def remembered_model_analysis():
    """For the modules of fake-world runs (`pytestmark = pytest.mark.usefixtures(...)`): each box model's
    symmetries and evaluation resampling computed once per session, not once per run (tests/model_memo.py
    says why that checks the same); undone when the module ends."""
    from model_memo import remember_model_analysis
    with pytest.MonkeyPatch.context() as mp:
        remember_model_analysis(mp)
        yield
