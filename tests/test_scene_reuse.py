"""Renders that use the mesh cache (animation frames, persistent data) keep their committed
core scene: the next render reuses it, with only the camera, lights, world, materials and
moved matrices set again, when every mesh is unchanged; its image equals a fresh render's."""

import bpy
import numpy as np
import pytest

from blender_util import core_available, render_to_array
from test_animation import _animated_scene

pytestmark = pytest.mark.skipif(not core_available(), reason="core module not built")


def _scene_with_material():
    sc = _animated_scene()
    for obj in (sc.camera, bpy.data.objects["Mover"]):  # moved by hand here, not by keyframes
        obj.animation_data_clear()
    mat = bpy.data.materials.new("Paint")
    mat.use_nodes = True
    mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.8, 0.2, 0.1, 1.0)
    bpy.data.objects["Mover"].data.materials.append(mat)
    # A textured floor: a kept scene must map its shader programs to the images it holds.
    image = bpy.data.images.new("Checker", 16, 16)
    image.generated_type = 'COLOR_GRID'
    floor = bpy.data.materials.new("Floor")
    floor.use_nodes = True
    nodes, links = floor.node_tree.nodes, floor.node_tree.links
    tex, coords = nodes.new("ShaderNodeTexImage"), nodes.new("ShaderNodeTexCoord")
    tex.image = image
    links.new(coords.outputs["Generated"], tex.inputs["Vector"])
    links.new(tex.outputs["Color"], nodes["Principled BSDF"].inputs["Base Color"])
    bpy.data.objects["Floor"].data.materials.append(floor)
    return sc


def _move_camera(sc):
    sc.camera.location.z += 0.4


def _recolour_and_dim(sc):
    bsdf = bpy.data.materials["Paint"].node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.1, 0.3, 0.9, 1.0)
    bpy.data.objects["Lamp"].data.energy = 250.0


def _move_object(sc):
    bpy.data.objects["Mover"].location.x += 0.7


def _edit_mesh(sc):
    mesh = bpy.data.objects["Mover"].data
    mesh.vertices[0].co.z += 0.3
    mesh.update()


STEPS = (None, _move_camera, _recolour_and_dim, _move_object, _edit_mesh)


def _render_steps(persistent):
    from addon import render_cache
    render_cache.clear()
    sc = _scene_with_material()
    sc.render.use_persistent_data = persistent
    images, states = [], []
    kept = render_cache.SCENE_CACHE
    try:
        for step in STEPS:
            if step is not None:
                step(sc)
            images.append(render_to_array(sc))
            if persistent:
                assert len(kept.image_ids) == 1  # the floor's texture is in the core scene
            states.append((kept.reused, kept.scene, kept.scene.stats()["geometry_builds"]
                           if kept.scene is not None else None))
    finally:
        sc.render.use_persistent_data = False
        render_cache.clear()
    return images, states


def test_persistent_data_reuses_the_committed_scene():
    fresh, fresh_states = _render_steps(persistent=False)
    assert all(state == (False, None, None) for state in fresh_states)  # nothing kept
    kept, states = _render_steps(persistent=True)
    reused = [s[0] for s in states]
    # The camera, a material and a light changed: the same scene, no BVH build. A moved
    # (merged) object: the same scene, its geometry rebuilt. An edited mesh: a new scene.
    assert reused == [False, True, True, True, False]
    first = states[0][1]
    assert [s[1] is first for s in states] == [True, True, True, True, False]
    assert [s[2] for s in states] == [1, 1, 1, 2, 1]
    for step, a, b in zip(STEPS, fresh, kept):
        np.testing.assert_array_equal(a, b, err_msg=getattr(step, "__name__", "first render"))
    # Each step changed the image (so the kept scene really took the change).
    for a, b in zip(kept, kept[1:]):
        assert not np.array_equal(a, b)
