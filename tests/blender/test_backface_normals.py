"""Normal values on back-facing mesh hits against Cycles in the same bpy: Cycles'
shader_setup_from_ray turns N and Ng towards the viewer there, so the Geometry node's Normal
and True Normal and the Texture Coordinate's Normal (object space) and Reflection read the
flipped normal; closures fed from those outputs still shade as with their default normal."""

import bpy
import bmesh  # (after bpy, which provides it)
import numpy as np
import pytest

from blender_util import core_available, load_addon, render_to_array
import material_scenes as ms

load_addon()

pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")

CENTRES = dict(pixel_filter_type='BOX', filter_width=0.01)  # every sample at the pixel centre


def open_sphere(name, material, **transform):
    """A smooth sphere with its top cap removed: the camera sees its inside through the hole."""
    def build(bm):
        bmesh.ops.create_uvsphere(bm, u_segments=24, v_segments=12, radius=0.7)
        bmesh.ops.delete(bm, geom=[v for v in bm.verts if v.co.z > 0.35], context='VERTS')
    return ms.add_mesh_object(name, build, (material,), smooth=True, **transform)


def normal_scene(source, output, mirrored=False, size=48):
    """Emission = `output` of a `source` node mapped by 0.5 v + 0.5, on an open sphere (seen
    inside and out, rotated so object space differs from world space) and a plane from behind;
    mirrored: both scaled by -1 along x (Cycles flips Ng for a negative scale first)."""
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scene.render.resolution_x = scene.render.resolution_y = size
        scene.render.resolution_percentage = 100
        ms.set_world((0.0, 0.0, 0.0))
        mat, nodes, links, out = ms.new_material("N")
        node = nodes.new(source)
        mad = nodes.new("ShaderNodeVectorMath")
        mad.operation = 'MULTIPLY_ADD'
        mad.inputs[1].default_value = (0.5, 0.5, 0.5)
        mad.inputs[2].default_value = (0.5, 0.5, 0.5)
        emit = nodes.new("ShaderNodeEmission")
        links.new(node.outputs[output], mad.inputs[0])
        links.new(mad.outputs[0], emit.inputs["Color"])
        links.new(emit.outputs[0], out.inputs["Surface"])
        open_sphere("Bowl", mat, location=(-0.6, 0.0, 0.5), rotation_euler=(0.5, 0.2, 0.7))
        ms.add_plane("Back", 1.2, mat, location=(0.85, 0.2, 0.6), rotation_euler=(-1.2, 0.0, 0.3))
        if mirrored:
            for obj in (bpy.data.objects["Bowl"], bpy.data.objects["Back"]):
                obj.scale = (-1.0, 1.0, 1.0)
        ms.add_camera((0.0, -3.5, 2.6), (0.0, 0.0, 0.5))
        return scene
    return build


@pytest.mark.parametrize("mirrored", [False, True])
@pytest.mark.parametrize("source, output", [
    ("ShaderNodeNewGeometry", "Normal"),
    ("ShaderNodeNewGeometry", "True Normal"),
    ("ShaderNodeNewGeometry", "Backfacing"),
    ("ShaderNodeTexCoord", "Normal"),
    ("ShaderNodeTexCoord", "Reflection"),
])
def test_normal_outputs_face_the_viewer_as_cycles(source, output, mirrored):
    build = normal_scene(source, output, mirrored)
    ours = render_to_array(build(), "PATHLIGHT", samples=1, max_bounces=1, **CENTRES)
    cycles = render_to_array(build(), "CYCLES", samples=1, max_bounces=1, **CENTRES)
    # A grazing silhouette pixel may be hit by one engine alone (a unit normal mapped so is
    # never black): compared where both hit or both miss, and such pixels must stay rare.
    same = (ours[..., :3].max(-1) > 0.0) == (cycles[..., :3].max(-1) > 0.0)
    assert same.mean() > 0.995, f"{(~same).sum()} pixels hit by one engine only"
    ours, cycles = ours * same[..., None], cycles * same[..., None]
    ms.assert_agree(ours, cycles, f"{source} {output}{' mirrored' if mirrored else ''}")
    diff = np.abs(ours[..., :3] - cycles[..., :3])
    assert diff.mean() < 2e-3, f"mean abs difference {diff.mean():.2e}"
    # The scene shows back faces: the bowl's inside and the plane's back cover many pixels.
    backfacing = normal_scene("ShaderNodeNewGeometry", "Backfacing", mirrored)
    back = render_to_array(backfacing(), "PATHLIGHT", samples=1, max_bounces=1, **CENTRES)
    assert (back[..., 0] > 0.99).mean() > 0.05


def bsdf_scene(linked, bump, size=48):
    """A rough Principled on the open sphere and the plane under a lamp, its Normal input (or
    a Bump's, when `bump`) unlinked or fed from the Geometry node's Normal."""
    def build():
        scene = ms.studio(size=size, camera=((0.0, -3.5, 2.6), (0.0, 0.0, 0.5)))
        mat, nodes, links, out = ms.new_material("B")
        bsdf = nodes.new("ShaderNodeBsdfPrincipled")
        bsdf.inputs["Roughness"].default_value = 0.4
        bsdf.inputs["Base Color"].default_value = (0.7, 0.5, 0.3, 1.0)
        links.new(bsdf.outputs[0], out.inputs["Surface"])
        target = bsdf.inputs["Normal"]
        if bump:
            b = nodes.new("ShaderNodeBump")
            b.inputs["Strength"].default_value = 0.6
            tex = nodes.new("ShaderNodeTexNoise")
            tex.inputs["Scale"].default_value = 6.0
            links.new(tex.outputs["Fac"], b.inputs["Height"])
            links.new(b.outputs["Normal"], target)
            target = b.inputs["Normal"]
        if linked:
            links.new(nodes.new("ShaderNodeNewGeometry").outputs["Normal"], target)
        open_sphere("Bowl", mat, location=(-0.6, 0.0, 0.5), rotation_euler=(0.5, 0.2, 0.7))
        ms.add_plane("Back", 1.2, mat, location=(0.85, 0.2, 0.6), rotation_euler=(-1.2, 0.0, 0.3))
        return scene
    return build


@pytest.mark.parametrize("bump", [False, True])
def test_closures_fed_the_geometry_normal_shade_as_with_the_default(bump):
    """The Normal output faces the viewer (Cycles' convention for every normal value); a BSDF's
    or Bump's Normal input fed from it must take the same side as their default normal, on
    the bowl's inside and the plane's back as on front faces (same samples: near-identical)."""
    default = render_to_array(bsdf_scene(False, bump)(), "PATHLIGHT", samples=16, max_bounces=4)
    linked = render_to_array(bsdf_scene(True, bump)(), "PATHLIGHT", samples=16, max_bounces=4)
    assert default[..., :3].mean() > 0.02
    ratio, worst, rel = ms.compare(linked, default)
    assert abs(ratio - 1.0) < 0.005 and worst < 0.01, (ratio, worst, np.round(rel, 3))
