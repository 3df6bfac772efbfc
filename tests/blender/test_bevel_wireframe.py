"""The Wireframe and Bevel nodes against Cycles in the same bpy (issue 21).

Wireframe: a subdivided, tilted plane seen in perspective emits the node's Fac, in world units
and in pixels (Cycles' compact ray differentials: the camera's pixel cone at the hit), sampled
at the pixel centres so both engines see the same points; the edges' pixels must agree.
Bevel: a flat-shaded cube whose normal is bevelled, seen directly with the normal as emission
and lit by a sun through a Diffuse BSDF, compared by regions at convergence."""

import math

import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, core_available, load_addon, render_to_array
import material_scenes as ms

import bmesh  # noqa: E402  (after bpy)

load_addon()

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

CENTRES = dict(pixel_filter_type='BOX', filter_width=0.01)


def wire_scene(size, pixel, ortho=False):
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = 64
        scene.render.resolution_percentage = 100
        ms.set_world((0.0, 0.0, 0.0))
        mat, nodes, links, out = ms.new_material("Wire")
        wire = nodes.new("ShaderNodeWireframe")
        wire.use_pixel_size = pixel
        wire.inputs["Size"].default_value = size
        emit = nodes.new("ShaderNodeEmission")
        links.new(wire.outputs["Fac"], emit.inputs["Color"])
        links.new(emit.outputs[0], out.inputs["Surface"])

        def grid(bm):
            bmesh.ops.create_grid(bm, x_segments=5, y_segments=4, size=1.5)
        ms.add_mesh_object("Grid", grid, (mat,), rotation_euler=(math.radians(35), 0.0, math.radians(20)))
        cam = ms.add_camera((0.0, -4.0, 2.5), (0.0, 0.0, 0.0), lens=40.0)
        if ortho:
            cam.data.type = 'ORTHO'
            cam.data.ortho_scale = 3.5
        return scene
    return build


@pytest.mark.parametrize("size, pixel, ortho", [(0.06, False, False), (2.0, True, False), (1.5, True, True)],
                         ids=["world", "pixels", "pixels-ortho"])
def test_wireframe_matches_cycles(size, pixel, ortho):
    build = wire_scene(size, pixel, ortho)
    ours = render_to_array(build(), "PATHLIGHT", samples=1, max_bounces=1, **CENTRES)[..., 0]
    cycles = render_to_array(build(), "CYCLES", samples=1, max_bounces=1, **CENTRES)[..., 0]
    lit = cycles > 0.5
    assert 0.08 < lit.mean() < 0.6, lit.mean()  # the lines are there, and not everywhere
    # Pixels whose centre lies within float rounding of a line's border may differ.
    differ = np.abs(ours - cycles) > 0.5
    assert differ.mean() < 0.01, f"{differ.sum()} of {differ.size} pixels differ"


def test_wireframe_pixel_size_scales_with_resolution():
    """In pixels, the lines keep their width in pixels when the image doubles."""
    fractions = []
    for res in (48, 96):
        scene = wire_scene(2.0, True)()
        img = render_to_array(scene, "PATHLIGHT", samples=1, max_bounces=1, resolution_x=res,
                              resolution_y=res, **CENTRES)[..., 0]
        fractions.append((img > 0.5).mean())
    # Twice the pixels across, the same line width in pixels: about half the covered fraction.
    assert 0.4 < fractions[1] / fractions[0] < 0.62, fractions


def bevel_scene(emit_normal, radius=0.25):
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = 48
        scene.render.resolution_percentage = 100
        ms.set_world((0.0, 0.0, 0.0) if emit_normal else (0.05, 0.05, 0.05))
        mat, nodes, links, out = ms.new_material("Bevelled")
        bevel = nodes.new("ShaderNodeBevel")
        bevel.samples = 8
        bevel.inputs["Radius"].default_value = radius
        if emit_normal:  # the normal mapped to a colour, seen directly
            mad = nodes.new("ShaderNodeVectorMath")
            mad.operation = 'MULTIPLY_ADD'
            mad.inputs[1].default_value = (0.5, 0.5, 0.5)
            mad.inputs[2].default_value = (0.5, 0.5, 0.5)
            emit = nodes.new("ShaderNodeEmission")
            links.new(bevel.outputs["Normal"], mad.inputs[0])
            links.new(mad.outputs[0], emit.inputs["Color"])
            links.new(emit.outputs[0], out.inputs["Surface"])
        else:
            diffuse = nodes.new("ShaderNodeBsdfDiffuse")
            diffuse.inputs["Color"].default_value = (0.8, 0.8, 0.8, 1.0)
            links.new(bevel.outputs["Normal"], diffuse.inputs["Normal"])
            links.new(diffuse.outputs[0], out.inputs["Surface"])
            sun = ms.add_sun(energy=3.0, tilt_deg=40.0)
            sun.rotation_euler = (math.radians(25), math.radians(40), 0.0)

        def cube(bm):
            bmesh.ops.create_cube(bm, size=1.5)
        ms.add_mesh_object("Cube", cube, (mat,), rotation_euler=(0.0, 0.0, math.radians(30)))
        ms.add_camera((3.0, -4.0, 3.0), (0.0, 0.0, 0.0), lens=50.0)
        return scene
    return build


@pytest.mark.parametrize("emit_normal", [True, False], ids=["normal", "sunlit"])
def test_bevel_matches_cycles(emit_normal):
    build = bevel_scene(emit_normal)
    bounces = 1 if emit_normal else 4
    ours = render_to_array(build(), "PATHLIGHT", samples=256, max_bounces=bounces, **BOX_FILTER)
    cycles = render_to_array(build(), "CYCLES", samples=256, max_bounces=bounces, **BOX_FILTER)
    ratio, worst, _ = ms.compare(ours, cycles)
    assert abs(ratio - 1.0) < 0.01 and worst < 0.03, (ratio, worst)
    # The test has power: the unbevelled cube differs from Cycles' bevelled one by far more.
    flat = render_to_array(bevel_scene(emit_normal, 0.0)(), "PATHLIGHT", samples=16,
                           max_bounces=bounces, **BOX_FILTER)
    assert ms.compare(flat, cycles)[1] > 0.1
