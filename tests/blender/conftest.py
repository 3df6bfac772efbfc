"""Shared fixtures of the Blender tests."""
import bpy
import pytest


@pytest.fixture(autouse=True, scope="module")
def factory_scene_afterwards():
    """Every test module leaves the factory-empty file behind: renders leave their settings and
    data blocks in bpy.data, which the next module (on the same xdist worker) must not see.

    The tests make that file with read_homefile(use_empty=True, use_factory_startup=True): the
    same data as read_factory_settings(use_empty=True) (the same Cycles reference keys), without
    also resetting the preferences, which disables and re-enables every bundled add-on (Cycles'
    ~200 classes): 12 instead of 62 ms of CPU a call, called about twice a test. No test leaves a
    preference changed (the few that change one restore it)."""
    yield
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
