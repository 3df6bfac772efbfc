"""Shared fixtures of the Blender tests."""
import bpy
import pytest


@pytest.fixture(autouse=True, scope="module")
def factory_scene_afterwards():
    """Every test module leaves the factory-empty file behind: renders leave their settings and
    data blocks in bpy.data, which the next module (on the same xdist worker) must not see."""
    yield
    bpy.ops.wm.read_factory_settings(use_empty=True)
