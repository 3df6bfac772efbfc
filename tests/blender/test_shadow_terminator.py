"""Cycles' shadow terminator geometry offset (Object > Shading; 0.1 by default): light samples
of smooth-shaded triangles near the terminator start on the smooth surface the vertex normals
describe, and reach light just below the flat triangle's plane. Low-poly smooth spheres under a
grazing sun show it most; Pathlight against Cycles in the same bpy, with the default offset,
a larger one, and none."""
import bpy
import numpy as np
import pytest

from blender_util import core_available, load_addon, render_to_array
import material_scenes as ms

load_addon()
pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


def low_poly_scene(offset, roughness=0.0):
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = 64
        ms.set_world((0.02, 0.02, 0.02))

        def ico(bm):
            import bmesh  # (after bpy)
            bmesh.ops.create_uvsphere(bm, u_segments=12, v_segments=6, radius=0.45)
        mat = ms.diffuse("Ball", (0.8, 0.8, 0.8))
        mat.node_tree.nodes["Diffuse BSDF"].inputs["Roughness"].default_value = roughness  # Oren-Nayar
        ball = ms.add_mesh_object("Ball", ico, (mat,), smooth=True)
        ball.shadow_terminator_geometry_offset = offset
        ms.add_sun(3.0, 70.0)  # low: a long terminator across the front
        ms.add_camera((0.0, -1.8, 0.3), (0.0, 0.0, 0.0))
        return scene
    return build


@pytest.mark.parametrize("offset", [0.1, 0.4, 0.0])
def test_terminator_offset_matches_cycles(offset):
    ours, cycles = ms.render_pair(low_poly_scene(offset), 64)
    ms.assert_agree(ours, cycles, f"offset {offset}")


def test_oren_nayar_silhouette_matches_cycles():
    """A rough diffuse (Oren-Nayar) lobe at the smooth sphere's lit silhouette, where the smooth
    normal turns away from the view: lit from its own side with the view counting as grazing,
    as Cycles' max(N.V, 0)."""
    ours, cycles = ms.render_pair(low_poly_scene(0.1, roughness=0.9), 64)
    ms.assert_agree(ours, cycles, "oren-nayar")


def test_offset_shows_on_low_poly_spheres():
    """The offset changes the picture by far more than the engines differ (so the test above
    tells a missing offset apart)."""
    with_offset = render_to_array(low_poly_scene(0.4)(), "PATHLIGHT", samples=16)
    without = render_to_array(low_poly_scene(0.0)(), "PATHLIGHT", samples=16)
    assert ms.compare(with_offset, without)[1] > 0.1
