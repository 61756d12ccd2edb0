"""Fixtures for the structured-light tests (pure numpy; no bpy here, ever)."""
import os
import sys

import pytest

sys.path.insert(0, os.path.dirname(__file__))

import synth  # noqa: E402
from sl_helpers import PERIODS, STEPS  # noqa: E402


@pytest.fixture(scope="session")
def rig():
    """160x120 camera, 512x384 projector, 0.15 m baseline, 1 m above the ground plane."""
    return synth.make_rig()


@pytest.fixture(scope="session")
def plane_render(rig):
    cam, proj = rig
    return synth.render(synth.plane_scene(), cam, proj, PERIODS, STEPS)


@pytest.fixture(scope="session")
def box_render(rig):
    cam, proj = rig
    return synth.render(synth.box_scene(), cam, proj, PERIODS, STEPS)
