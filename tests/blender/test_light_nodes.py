"""Light node trees compiled into shader programs (Blackbody colours, gobos by the light's UV,
image textures on area lights, Light Falloff), and the IES, Sky Texture and Light Falloff nodes
in materials: what the add-on exports and the renders against Cycles 4.5 in the same bpy. The
IES-only pattern of light trees keeps its own path (test_ies_lights.py)."""

import math

import bpy
import numpy as np
import pytest

from blender_util import BOX_FILTER, core_has, load_addon, render_to_array
from light_scenes import add_light, camera, diffuse_material, empty_scene, plane, uv_sphere
from test_ies_lights import DOWNWARD
from test_lights import assert_agrees_with_cycles, one_light

load_addon()

needs_light_shaders = pytest.mark.skipif(not core_has("Scene", "add_point_light") or
                                         not hasattr(load_addon().core.get_core(), "sky_texture"),
                                         reason="the core has no light shaders")


def light_tree(obj):
    """(nodes, links, Emission node) of obj's light node tree, nodes on."""
    obj.data.use_nodes = True
    nt = obj.data.node_tree
    return nt.nodes, nt.links, nt.nodes["Emission"]


def checker_gobo(obj, scale=4.0, kelvin=4500.0, coords="UV"):
    """Emission Color = Blackbody(kelvin) x Checker(Texture Coordinate `coords`)."""
    nodes, links, emission = light_tree(obj)
    tc = nodes.new("ShaderNodeTexCoord")
    checker = nodes.new("ShaderNodeTexChecker")
    checker.inputs["Scale"].default_value = scale
    checker.inputs["Color1"].default_value = (1.0, 1.0, 1.0, 1.0)
    checker.inputs["Color2"].default_value = (0.1, 0.1, 0.1, 1.0)
    links.new(tc.outputs[coords], checker.inputs["Vector"])
    bb = nodes.new("ShaderNodeBlackbody")
    bb.inputs["Temperature"].default_value = kelvin
    mix = nodes.new("ShaderNodeMix")
    mix.data_type = 'RGBA'
    mix.blend_type = 'MULTIPLY'
    mix.inputs["Factor"].default_value = 1.0
    links.new(bb.outputs[0], mix.inputs[6])
    links.new(checker.outputs["Color"], mix.inputs[7])
    links.new(mix.outputs[2], emission.inputs["Color"])


def image_gobo(obj):
    """Emission Color = a 4 x 4 image of distinct colours (Closest) on the light's UV."""
    nodes, links, emission = light_tree(obj)
    img = bpy.data.images.new("gobo", 4, 4, float_buffer=True)
    rng = np.random.default_rng(7)
    px = np.concatenate([rng.uniform(0.05, 1.0, (16, 3)), np.ones((16, 1))], axis=1)
    img.pixels.foreach_set(px.astype(np.float32).ravel())
    img.pack()
    tex = nodes.new("ShaderNodeTexImage")
    tex.image = img
    tex.interpolation = 'Closest'
    tc = nodes.new("ShaderNodeTexCoord")
    links.new(tc.outputs["UV"], tex.inputs["Vector"])
    links.new(tex.outputs["Color"], emission.inputs["Color"])


def falloff(node_tree_owner, kind, strength, smooth=0.0):
    """Emission Strength = Light Falloff's `kind` output (Strength, Smooth)."""
    nodes, links, emission = light_tree(node_tree_owner)
    f = nodes.new("ShaderNodeLightFalloff")
    f.inputs["Strength"].default_value = strength
    f.inputs["Smooth"].default_value = smooth
    links.new(f.outputs[kind], emission.inputs["Strength"])


def floor_from_above(width=64, height=48):
    scene = empty_scene(width, height)
    plane("Floor", 8.0, diffuse_material("White", 0.8))
    camera((0.0, -2.2, 3.2), look_at=(0.0, 0.0, 0.0), lens=28.0)
    return scene


# ---------------------------------------------------------------- export

@needs_light_shaders
def test_textured_light_tree_becomes_a_program_with_cycles_power_estimate():
    empty_scene(16)
    obj = add_light('SPOT', energy=100.0)
    checker_gobo(obj)
    light, warnings = one_light()
    assert not warnings, warnings
    ops = [op[0] for op in light.args["shader"]]
    assert "checker" in ops and "uv" in ops
    # Cycles' estimate: a linked Color counts 1, the Strength (1) as it is.
    assert light.args["shader_power"] == pytest.approx(1.0)
    assert light.args["intensity"][0] == pytest.approx(100.0 / (4 * math.pi))


@needs_light_shaders
def test_lights_sent_again_reuse_their_images():
    """replace_lights on a kept scene (viewport light edits, persistent-data frames) adds a light
    tree's image once, not at every edit; a changed image is added."""
    from addon import scene_writer

    empty_scene(16)
    obj = add_light('AREA', energy=10.0, shape='RECTANGLE', size=1.0, size_y=1.0)
    image_gobo(obj)
    light, warnings = one_light()
    assert not warnings and light.images, warnings
    pc = load_addon().core.get_core()
    scene = pc.Scene()
    scene_writer.add_lights(scene, [light])
    count = scene.image_count()
    assert count == len(light.images)
    for _ in range(3):
        scene.clear_lights()
        scene_writer.add_lights(scene, [light])
    assert scene.image_count() == count
    light.images[0].pixels = light.images[0].pixels * 0.5
    scene.clear_lights()
    scene_writer.add_lights(scene, [light])
    assert scene.image_count() == count + 1


@needs_light_shaders
def test_light_falloff_strength_is_the_power_estimate():
    empty_scene(16)
    obj = add_light('POINT', energy=10.0)
    falloff(obj, "Linear", 7.0)
    light, warnings = one_light()
    assert not warnings, warnings
    assert any(op[0] == "light_falloff" and op[-1] == "LINEAR" for op in light.args["shader"])
    assert light.args["shader_power"] == pytest.approx(7.0)
    assert light.args["shader_matrix"].shape == (4, 4)


@needs_light_shaders
def test_constant_tree_keeps_the_constant_path():
    empty_scene(16)
    obj = add_light('AREA', energy=10.0)
    nodes, links, emission = light_tree(obj)
    bb = nodes.new("ShaderNodeBlackbody")  # folded by the compiler: a constant program
    links.new(bb.outputs[0], emission.inputs["Color"])
    light, warnings = one_light()
    assert not warnings, warnings
    assert "shader" in light.args  # (the core folds a constant program into the colour)


# ---------------------------------------------------------------- against Cycles

def _agree(scene, samples, max_bounces, region_tol, mean_tol=0.01):
    ours = render_to_array(scene, samples=samples, max_bounces=max_bounces)
    ref = render_to_array(scene, "CYCLES", samples=samples, max_bounces=max_bounces, **BOX_FILTER)
    assert_agrees_with_cycles(ours, ref, region_tol=region_tol, mean_tol=mean_tol)


def _spot_gobo():
    scene = floor_from_above()
    obj = add_light('SPOT', location=(0.2, 0.1, 2.0), rotation=(0.2, 0.1, 0.0), energy=300.0,
                    spot_size=math.radians(70), spot_blend=0.1, shadow_soft_size=0.0)
    checker_gobo(obj)
    return scene


def _area_image():
    scene = floor_from_above()
    obj = add_light('AREA', location=(0.0, 0.0, 0.8), rotation=(0.3, 0.0, 0.4), energy=60.0,
                    shape='RECTANGLE', size=1.6, size_y=1.0)
    image_gobo(obj)
    return scene


def _point_falloff():
    scene = floor_from_above()
    obj = add_light('POINT', location=(0.3, 0.2, 1.0), energy=20.0, shadow_soft_size=0.1)
    falloff(obj, "Linear", 1.0)
    return scene


def _sun_checker():
    # The sun's disc (20 degrees) reflected by a rough mirror floor towards the camera: its
    # checker by Cycles' distant-light uv shows in the highlight.
    scene = empty_scene(64, 48)
    mat = bpy.data.materials.new("Glossy")
    mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    glossy = nodes.new("ShaderNodeBsdfGlossy")
    glossy.inputs["Roughness"].default_value = 0.1
    mat.node_tree.links.new(glossy.outputs[0], nodes["Material Output"].inputs["Surface"])
    plane("Floor", 8.0, mat)
    camera((0.0, -2.2, 3.2), look_at=(0.0, 0.0, 0.0), lens=28.0)
    obj = add_light('SUN', rotation=(-0.6, 0.0, 0.2), energy=3.0, angle=math.radians(20))
    checker_gobo(obj, scale=3.0)
    return scene


# scene, samples, worst 8 x 8 region allowed. At 256 spp worst regions 0.6 / 0.5 / 0.01 / 4.2 %
# (Cycles against itself with another seed: 0.4 / 0.4 / 0.01 / 7.2 %, the sun's glossy
# highlight being the noisy one).
LIGHT_CASES = {
    "spot_blackbody_checker": (_spot_gobo, 256, 0.03),
    "area_image": (_area_image, 256, 0.03),
    "point_falloff_linear": (_point_falloff, 64, 0.03),  # (nearly noiseless)
    "sun_checker": (_sun_checker, 256, 0.1),
}


@needs_light_shaders
@pytest.mark.parametrize("case", list(LIGHT_CASES))
def test_light_tree_agrees_with_cycles(case):
    build, samples, region_tol = LIGHT_CASES[case]
    _agree(build(), samples, 1, region_tol=region_tol)


def _ies_material(strength):
    mat = bpy.data.materials.new("IES emission")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.remove(nodes["Principled BSDF"])
    emission = nodes.new("ShaderNodeEmission")
    ies = nodes.new("ShaderNodeTexIES")
    ies.mode = 'INTERNAL'
    block = bpy.data.texts.new("profile.ies")
    block.from_string(DOWNWARD)
    ies.ies = block
    ies.inputs["Strength"].default_value = strength
    links.new(ies.outputs["Fac"], emission.inputs["Strength"])
    links.new(emission.outputs[0], nodes["Material Output"].inputs["Surface"])
    return mat


def _falloff_material(kind, strength):
    mat = bpy.data.materials.new("Falloff emission")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.remove(nodes["Principled BSDF"])
    emission = nodes.new("ShaderNodeEmission")
    f = nodes.new("ShaderNodeLightFalloff")
    f.inputs["Strength"].default_value = strength
    links.new(f.outputs[kind], emission.inputs["Strength"])
    links.new(emission.outputs[0], nodes["Material Output"].inputs["Surface"])
    return mat


def _sky_material(sky_type, vector=None):
    mat = bpy.data.materials.new("Sky emission")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.remove(nodes["Principled BSDF"])
    emission = nodes.new("ShaderNodeEmission")
    sky = nodes.new("ShaderNodeTexSky")
    sky.sky_type = sky_type
    if sky_type == 'NISHITA':
        sky.sun_elevation = math.radians(20)
        sky.sun_rotation = math.radians(40)
        sky.sun_size = math.radians(8)  # a disc that covers pixels
    else:
        sky.sun_direction = (0.3, -0.5, 0.6)
    if vector is not None:
        geo = nodes.new("ShaderNodeNewGeometry")
        links.new(geo.outputs[vector], sky.inputs["Vector"])
    links.new(sky.outputs[0], emission.inputs["Color"])
    links.new(emission.outputs[0], nodes["Material Output"].inputs["Surface"])
    return mat


@needs_light_shaders
def test_ies_in_a_material_agrees_with_cycles():
    # A tilted emissive card facing down whose strength is the profile along the direction
    # leaving it (the IES node's default Vector: Incoming in object space), over a floor. At
    # 256 spp mean ratio 1.0005, worst 8 x 8 region 1.1 % (Cycles' seeds: 1.4 %).
    scene = floor_from_above()
    plane("Lamp", 0.6, _ies_material(0.05), location=(0.0, 0.3, 1.0),
          rotation_euler=(math.pi + 0.3, 0.0, 0.3))
    _agree(scene, 256, 1, region_tol=0.04)


@needs_light_shaders
def test_light_falloff_in_a_material_agrees_with_cycles():
    # An emissive card whose Strength is Light Falloff's Constant output: seen by the camera
    # (the camera ray's length) and lighting the floor (each light sample's distance).
    scene = floor_from_above()
    plane("Lamp", 0.8, _falloff_material("Constant", 3.0), location=(0.2, 0.0, 0.7),
          rotation_euler=(math.pi - 0.4, 0.0, 0.0))
    _agree(scene, 128, 1, region_tol=0.04)


SKY_CASES = {
    # Nishita's Vector is unavailable in 4.5 (Generated coordinates), the others read Incoming.
    "nishita_default": ('NISHITA', None),
    "hosek_incoming": ('HOSEK_WILKIE', "Incoming"),
    "preetham_normal": ('PREETHAM', "Normal"),
}


@needs_light_shaders
@pytest.mark.parametrize("case", list(SKY_CASES))
def test_sky_texture_in_a_material_agrees_with_cycles(case):
    sky_type, vector = SKY_CASES[case]
    scene = empty_scene(48, 48)
    uv_sphere("Sky ball", 1.0, _sky_material(sky_type, vector), segments=32,
              rotation_euler=(0.3, 0.2, 0.0))
    camera((0.0, -4.0, 0.8), look_at=(0.0, 0.0, 0.0), lens=40.0)
    # The emission seen directly: at 64 spp worst 8 x 8 regions 1.3 / 1.3 / 1.0 % (Cycles'
    # seeds: 1.9 / 1.1 / 1.0 %, the silhouette's anti-aliasing).
    _agree(scene, 64, 0, region_tol=0.04)
