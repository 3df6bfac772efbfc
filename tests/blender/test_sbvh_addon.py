"""Spatial splits through Blender: Render ▸ Performance ▸ Spatial Splits reaches the core's BVH
build of final renders (the render log names the choice; references > triangles on a mesh of
big and thin triangles at angles), the image is the one rendered without them (hits are the
same up to near-ties), and the viewport never uses them."""
import logging

import bpy
import numpy as np
import pytest

from blender_util import core_available, core_has, empty_scene_with_camera, load_addon, render_to_array
from core_scenes import sliver_room

load_addon()
pytestmark = pytest.mark.skipif(not core_available() or not core_has("Scene", "spatial_splits"),
                                reason="pathlight_core without spatial splits")


def room_scene():
    """The camera inside a rotated room of huge wall triangles, beams and small spheres, lit by
    a point light."""
    sc = empty_scene_with_camera(resolution=40)
    pos, tris = sliver_room(seed=6, spheres=30, beams=30, sphere_res=(16, 8))
    mesh = bpy.data.meshes.new("room")
    mesh.vertices.add(len(pos))
    mesh.vertices.foreach_set("co", pos.ravel())
    mesh.loops.add(tris.size)
    mesh.loops.foreach_set("vertex_index", tris.ravel())
    mesh.polygons.add(len(tris))
    mesh.polygons.foreach_set("loop_start", np.arange(0, tris.size, 3))
    mesh.update()
    obj = bpy.data.objects.new("room", mesh)
    sc.collection.objects.link(obj)
    light = bpy.data.objects.new("lamp", bpy.data.lights.new("lamp", 'POINT'))
    light.data.energy = 2000.0
    light.location = (0.5, 0.5, 1.0)  # the room's walls are 4 or more from the origin
    bpy.data.objects["Camera"].location = (0.0, -1.5, 0.0)
    sc.collection.objects.link(light)
    return sc


def bvh_lines(caplog):
    return [r.getMessage() for r in caplog.records if r.getMessage().startswith("Pathlight: BVH ")]


def test_setting_reaches_the_build_and_keeps_the_image(caplog):
    images = []
    for on in (False, True):
        sc = room_scene()
        assert sc.pathlight.use_spatial_splits is False  # default: off
        sc.pathlight.use_spatial_splits = on
        with caplog.at_level(logging.INFO, logger="addon.session"):
            images.append(render_to_array(sc, "PATHLIGHT", samples=4, seed=5, max_bounces=2))
    lines = bvh_lines(caplog)
    assert len(lines) == 2, lines
    assert lines[0].startswith("Pathlight: BVH without spatial splits (")
    assert lines[1].startswith("Pathlight: BVH with spatial splits (")
    refs, tris = (int(x.replace(",", "")) for x in lines[1].split("(")[1].split(" references to ")[:1] +
                  [lines[1].split(" references to ")[1].split(" triangles")[0]])
    assert tris < refs <= int(tris * 1.3)
    off, on = images
    assert off[..., :3].mean() > 0.01  # the render shows something
    # The same hits up to near-ties: the same image but for a few pixels whose paths met a tie.
    same = np.all(off == on, axis=-1)
    assert same.mean() > 0.97, same.mean()
    assert abs(on[..., :3].mean() / off[..., :3].mean() - 1.0) < 0.01


@pytest.mark.skipif(not core_has("Scene", "set_shader"), reason="core without live edits")
def test_viewport_builds_without_spatial_splits():
    from addon.core import get_core
    from addon.viewport import ViewportSession
    sc = room_scene()
    sc.pathlight.use_spatial_splits = True
    sc.pathlight.preview_samples = 1
    vs = ViewportSession(get_core())
    try:
        vs.set_view(None, 16, 16)
        vs.sync(bpy.context.evaluated_depsgraph_get())
        st = vs.scene.stats()
        assert st["spatial_splits"] is False and st["blas_references"] == st["blas_triangles"] > 0
    finally:
        vs.free()
