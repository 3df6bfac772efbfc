"""Material preview thumbnails. Headless bpy renders no previews (ID.preview_ensure() only
allocates the icon: the preview job needs Blender's window manager), and Blender's preview
scenes are built into its binary. So the engine is checked to ask for previews, and a scene
mimicking a material preview (a small sphere with the material, an area light, a world, tiny
resolution, the scene defaults) renders through the same path without errors."""

import bpy
import numpy as np
import pytest

from blender_util import core_available, empty_scene_with_camera, load_addon, render_to_array

pytestmark = pytest.mark.skipif(not core_available(), reason="core module not built")


def test_engine_renders_material_previews():
    load_addon()
    from addon.engine import PathlightRenderEngine
    assert PathlightRenderEngine.bl_use_preview is True


def test_preview_like_scene_renders():
    load_addon()
    sc = empty_scene_with_camera(48)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=1.5, segments=24, ring_count=12)
    sphere = bpy.context.object
    mat = bpy.data.materials.new("Preview")
    mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.8, 0.2, 0.1, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.3
    sphere.data.materials.append(mat)
    light = bpy.data.objects.new("Key", bpy.data.lights.new("Key", "AREA"))
    light.location = (-2.0, -4.0, 3.0)
    light.rotation_euler = (0.9, 0.0, -0.4)
    light.data.energy = 300.0
    sc.collection.objects.link(light)
    sc.world = bpy.data.worlds.new("PreviewWorld")
    sc.world.color = (0.05, 0.05, 0.05)
    img = render_to_array(sc, samples=8)
    assert img.shape == (48, 48, 4) and np.all(np.isfinite(img))
    centre = img[18:30, 18:30, :3].mean(axis=(0, 1))
    assert centre[0] > centre[1] > 0  # the red material is lit
