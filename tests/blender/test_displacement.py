"""The material output's Displacement with Cycles' default method, Bump Only: Cycles turns the
displacement into a bump of the shading normal (its bump_from_displacement: the offset's
component along the normal at the point and at two offsets, a Bump of strength 1 and distance
1, then Set Normal for everything in the shader). Pathlight against Cycles in the same bpy, on
planes and spheres lit by a low sun, with the Displacement node in object and world space and
the Vector Displacement node."""
import math

import bpy
import numpy as np
import pytest

from blender_util import Warnings, core_available, load_addon
import material_scenes as ms

load_addon()
pytestmark = pytest.mark.skipif(not core_available(), reason="pathlight_core is not built")


def displaced_material(name, scale=0.05, space='OBJECT', vector=False, reads_normal=False, method='BUMP'):
    """A Principled BSDF whose displacement is a Noise Texture on object coordinates (a
    Displacement node, or a Vector Displacement of the noise's colour). reads_normal: the base
    colour comes from a Layer Weight (Facing), which reads the shading normal after the bump."""
    mat, nodes, links, out = ms.new_material(name)
    mat.displacement_method = method
    bsdf = ms.set_inputs(nodes.new("ShaderNodeBsdfPrincipled"), Base_Color=(0.7, 0.7, 0.7, 1.0),
                         Roughness=0.45)
    links.new(bsdf.outputs[0], out.inputs["Surface"])
    coord = nodes.new("ShaderNodeTexCoord")
    noise = ms.set_inputs(nodes.new("ShaderNodeTexNoise"), Scale=6.0, Detail=2.0)
    links.new(coord.outputs["Object"], noise.inputs["Vector"])
    if vector:
        disp = ms.set_inputs(nodes.new("ShaderNodeVectorDisplacement"), Scale=scale, Midlevel=0.5)
        disp.space = space
        links.new(noise.outputs["Color"], disp.inputs["Vector"])
    else:
        disp = ms.set_inputs(nodes.new("ShaderNodeDisplacement"), Scale=scale, Midlevel=0.5)
        disp.space = space
        links.new(noise.outputs["Fac"], disp.inputs["Height"])
    links.new(disp.outputs[0], out.inputs["Displacement"])
    if reads_normal:
        lw = ms.set_inputs(nodes.new("ShaderNodeLayerWeight"), Blend=0.6)
        links.new(lw.outputs["Facing"], bsdf.inputs["Base Color"])
    return mat


def scene(material_fn, shape="plane", scale=(1.0, 1.0, 1.0)):
    def build():
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        sc = bpy.context.scene
        sc.render.resolution_x = sc.render.resolution_y = 64
        ms.set_world((0.05, 0.05, 0.05))
        if shape == "plane":
            obj = ms.add_plane("Plane", 1.0, material_fn(), rotation_euler=(0.0, 0.0, 0.3))
        else:
            obj = ms.add_sphere("Ball", 0.4, material_fn(), location=(0.0, 0.0, 0.0))
        obj.scale = scale
        ms.add_sun(3.0, 55.0)
        ms.add_camera((0.0, 0.0, 1.6), (0.0, 0.0, 0.0))
        return sc
    return build


CASES = {
    "object": (lambda: displaced_material("Object"), "plane", (1.0, 1.0, 1.0)),
    "object-scaled": (lambda: displaced_material("Scaled"), "plane", (1.3, 0.8, 2.0)),
    "world": (lambda: displaced_material("World", space='WORLD'), "plane", (1.3, 0.8, 2.0)),
    "vector": (lambda: displaced_material("Vector", scale=0.03, vector=True), "plane", (1.0, 1.0, 1.0)),
    "sphere-reads-normal": (lambda: displaced_material("Facing", reads_normal=True), "sphere",
                            (1.0, 1.0, 1.0)),
}


@pytest.mark.parametrize("case", list(CASES))
def test_bump_from_displacement_matches_cycles(case):
    material_fn, shape, scale = CASES[case]
    ours, cycles = ms.render_pair(scene(material_fn, shape, scale), 64)
    ms.assert_agree(ours, cycles, case)
    # The displacement shows: the image differs from the undisplaced one by far more than the
    # engines differ from each other.
    flat, _ = ms.render_pair(scene(lambda: displaced_material("Flat", scale=0.0), shape, scale), 16)
    effect = np.abs(ours - flat)[..., :3].mean()
    assert effect > 0.01 and effect > 5 * np.abs(ours - cycles)[..., :3].mean(), effect


def test_displacement_compiles_to_a_bump_and_set_normal_without_a_warning():
    from addon.export import export_scene
    scene(lambda: displaced_material("Disp"))()
    warn = Warnings()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warn)
    assert not warn, list(warn)
    (mat,) = [m for m in data.materials if m.name == "Disp"]
    names = [op[0] for op in mat.program]
    assert "bump" in names and "set_normal" in names
    assert names.index("set_normal") < names.index("closure")


def test_true_displacement_is_no_longer_rendered_as_bump():
    """'DISPLACEMENT' moves the vertices (test_true_displacement.py): no bump, no warning."""
    from addon.export import export_scene
    scene(lambda: displaced_material("True", method='DISPLACEMENT'))()
    warn = Warnings()
    data = export_scene(bpy.context.evaluated_depsgraph_get(), warn)
    assert not any("true displacement" in w for w in warn), list(warn)
    (mat,) = [m for m in data.materials if m.name == "True"]
    assert "set_normal" not in [op[0] for op in mat.program]
    assert mat.displacement is not None
